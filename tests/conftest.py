"""Shared test configuration: deterministic hypothesis profile (no wall-clock deadlines: CI is noisy)."""

from hypothesis import HealthCheck, settings

settings.register_profile(
    "sfa",
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("sfa")
