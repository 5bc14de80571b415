"""Shared test configuration: deterministic hypothesis profile (no wall-clock deadlines: CI is noisy)."""

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
