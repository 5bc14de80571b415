"""sfa.config: the gate thresholds and the interval quantile are scipy.stats' values, bit for bit."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2, norm

from sfa.config import FilterConfig


@settings(max_examples=400, deadline=None)
@given(p=st.floats(min_value=0.5, max_value=0.999999999), dof=st.integers(min_value=1, max_value=4))
def test_gate_nis_is_scipy_stats_chi2_ppf(p, dof):
    assert FilterConfig().gate_nis(p, dof) == float(chi2.ppf(p, dof))


@settings(max_examples=400, deadline=None)
@given(c=st.floats(min_value=0.01, max_value=0.999999999))
def test_interval_z_is_scipy_stats_norm_ppf(c):
    assert FilterConfig().interval_z(c) == float(norm.ppf(0.5 + 0.5 * c))


def test_the_default_configuration_array_uses_those_values():
    cfg = FilterConfig()
    arr = cfg.to_array()
    assert cfg.gate_nis(cfg.gate_prob_odo, 1) == float(chi2.ppf(cfg.gate_prob_odo, 1))
    assert float(chi2.ppf(cfg.gate_prob_odo, 1)) in arr and float(chi2.ppf(cfg.gate_prob_gps, 2)) in arr
