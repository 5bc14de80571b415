"""sfa.config: the gate thresholds and the interval quantile are scipy.stats' values, bit for bit;
the configuration slots (``slot``) are declared once, numbered by sfa.layout and all written."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2, norm

from sfa import layout as L
from sfa.config import CFG_SLOTS, FilterConfig


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


# ---------------------------------------------------------------- configuration slots (sfa.config.slot)


def _declared() -> dict[str, str]:
    """slot name -> the FilterConfig field that declares it."""
    return {f.metadata["slot"]: f.name for f in fields(FilterConfig) if "slot" in f.metadata}


def _all_distinct() -> FilterConfig:
    """A valid config whose numeric fields all differ from each other and from the defaults."""
    base = FilterConfig()
    changes: dict[str, object] = {}
    for k, f in enumerate(fields(base)):
        v = getattr(base, f.name)
        if isinstance(v, bool):
            if not v:  # a flag off by default is written as 0: on, so that its slot is seen written
                changes[f.name] = True
            continue
        if isinstance(v, int):
            changes[f.name] = v + 1 + k
        elif f.name.startswith("gate_prob") or f.name.endswith(("confidence", "probability")):
            changes[f.name] = v - 1e-5 * (k + 1)
        else:
            changes[f.name] = v * (1.0 + 1e-3 * (k + 1)) + 1e-3 * (k + 1)
    changes["reversal_log_prior"] = base.reversal_log_prior / 2
    return base.replace(**changes)


def test_every_slot_is_declared_once_and_numbered_in_declaration_order():
    names = [f.metadata["slot"] for f in fields(FilterConfig) if "slot" in f.metadata]
    assert len(names) == len(set(names))
    assert tuple(names) == CFG_SLOTS
    assert L.NCFG == len(CFG_SLOTS)
    in_layout = {k: v for k, v in vars(L).items() if k.startswith("K_")}
    assert in_layout == {name: i for i, name in enumerate(CFG_SLOTS)}
    assert sorted(in_layout.values()) == list(range(L.NCFG))


def test_a_slot_declared_twice_or_misnamed_fails_at_import():
    import dataclasses

    import sfa.config as C

    @dataclasses.dataclass(frozen=True)
    class Twice(FilterConfig):
        extra: float = C.slot(1.0, "K_Q_BA")

    with pytest.raises(RuntimeError, match="declared twice.*K_Q_BA"):
        C._declared_slots(Twice)

    @dataclasses.dataclass(frozen=True)
    class Misnamed(FilterConfig):
        extra: float = C.slot(1.0, "k_extra")

    with pytest.raises(RuntimeError, match="not K_<UPPER>.*k_extra"):
        C._declared_slots(Misnamed)


def test_to_array_writes_every_slot_from_its_field():
    cfg = _all_distinct()
    arr = cfg.to_array()
    assert arr.shape == (L.NCFG,) and arr.dtype == np.float64
    assert np.all(arr != 0.0) and np.all(np.isfinite(arr))  # no slot left at a zero
    default = FilterConfig()
    base = default.to_array()
    for name, field_name in _declared().items():  # each slot follows the field that declares it
        i, v = getattr(L, name), getattr(default, field_name)
        if isinstance(v, bool):
            assert default.replace(**{field_name: not v}).to_array()[i] != base[i], (name, field_name)
        else:
            assert arr[i] != base[i], (name, field_name)


def test_every_field_reaches_the_kernels():
    """A field without a slot of its own must change some slot (it is read by another's value)."""
    base = FilterConfig()
    arr = base.to_array()
    declared = set(_declared().values())
    for f in fields(base):
        if f.name in declared:
            continue
        v = getattr(base, f.name)
        changed = base.replace(**{f.name: (not v) if isinstance(v, bool) else v * 1.5 + 0.01})
        assert np.any(changed.to_array() != arr), f.name


def test_computed_slots_say_what_they_hold():
    for f in fields(FilterConfig):
        if "slot" in f.metadata and f.metadata["value"] is not None:
            assert f.metadata["doc"].endswith("]"), (f.metadata["slot"], "doc with its unit")


def test_named_slot_values():
    cfg = _all_distinct()
    arr = cfg.to_array()
    assert arr[L.K_Q_BA] == cfg.accel_bias_rw_mps2_rts ** 2
    assert arr[L.K_Q_ACC] == cfg.accel_noise_density_mps2_rthz ** 2 + cfg.accel_model_noise_mps2_rthz ** 2
    assert arr[L.K_GATE_GPS] == cfg.gate_nis(cfg.gate_prob_gps, 2) == float(chi2.ppf(cfg.gate_prob_gps, 2))
    assert arr[L.K_GATE_ODO] == cfg.gate_nis(cfg.gate_prob_odo, 1)
    assert arr[L.K_SEP_GATE] == cfg.gate_nis(cfg.separation_probability, 1)
    assert arr[L.K_Z_INTERVAL] == cfg.interval_z()
    assert arr[L.K_FAULT_SIGMA_SCALE] == cfg.interval_z(cfg.fault_confidence) / cfg.interval_z()
    assert arr[L.K_SEP_FLOOR_VAR] == cfg.separation_floor_m ** 2
    assert arr[L.K_SLIP_CONFIRM_N] == float(cfg.slip_confirm_n)
    assert arr[L.K_ODO_SIGMA_MIN] == cfg.odo_sigma_min_mps
    assert arr[L.K_SNAP_PERIOD] == cfg.snapshot_period_s
    assert arr[L.K_USE_GYRO] == 1.0 and arr[L.K_REVERSAL] == 1.0
    off = cfg.replace(slip_rewind=False, use_gyro=False, reversal_hypotheses=False,
                      gyro_tilt_compensation=False).to_array()
    assert off[L.K_SNAP_PERIOD] == -1.0
    assert off[L.K_USE_GYRO] == off[L.K_REVERSAL] == off[L.K_GYRO_TILT] == 0.0


def test_layout_imports_no_numpy():
    code = "import sys, sfa.layout as L; print(L.NCFG, [m for m in ('numpy', 'scipy') if m in sys.modules])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60,
                         cwd=Path(__file__).resolve().parents[1])
    assert out.stdout.split() == [str(len(CFG_SLOTS)), "[]"]
