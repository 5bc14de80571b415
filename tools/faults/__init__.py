"""Fault injection: a deterministic UDP fault proxy and reliability campaigns (``sfa faults``).

- :mod:`tools.faults.config`: the impairment profile (frozen dataclass, TOML loader).
- :mod:`tools.faults.core`: the sans-I/O proxy core (``now`` is an argument, seeded generator).
- :mod:`tools.faults.forge`: forged, replayed and garbage datagrams.
- :mod:`tools.faults.proxy`: the thin asyncio layer of ``sfa faults proxy``.
- :mod:`tools.faults.campaign`: the scenario matrix, its runners (replay path, live processes,
  network namespace) and the results tables.
"""
