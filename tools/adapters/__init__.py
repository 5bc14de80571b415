"""Real-data adapters: recorded sensor logs -> captures (pcap), track databases and truth for ``sfa replay``.

``sfa convert smartloc`` (:mod:`tools.adapters.smartloc`) and ``sfa convert dresden``
(:mod:`tools.adapters.dresden`); what is real and what is synthesised: docs/real-data.md.
"""
