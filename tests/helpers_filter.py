"""Helpers shared by the filter's tests (seeded synthetic runs through TrackFilter)."""

from __future__ import annotations

from sfa.filter import TrackFilter


def run_filter(db, cfg, measurements):
    """Per-message run: (updates, estimates after each measurement, filter)."""
    f = TrackFilter(db, cfg)
    updates, estimates = [], []
    for m in measurements:
        updates.append(f.process(m))
        estimates.append(f.estimate())
    return updates, estimates, f
