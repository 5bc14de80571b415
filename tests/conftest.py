"""Shared test configuration: deterministic hypothesis profile (no wall-clock deadlines: CI is noisy),
and the synthetic track database the listener tests run on."""

import pytest
from hypothesis import HealthCheck, settings

from sfa.cli import configure_numba_cache

configure_numba_cache()  # before any test imports numba: no stale compiled kernels after an edit

settings.register_profile(
    "sfa",
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("sfa")


@pytest.fixture(scope="module")
def track(tmp_path_factory):
    """The synthetic track database (sfa.synthetic.build_track_db), one real SQLite file per module."""
    from sfa.synthetic import build_track_db
    from track_db import TrackDatabase

    return TrackDatabase.open(build_track_db(tmp_path_factory.mktemp("trk") / "synthetic.db"))
