"""SFA: the track-constrained positioning filter.

Import-light on purpose: the ``sfa`` command imports ``sfa.cli`` (and so this package) for every
subcommand, so the public names below are resolved lazily and nothing here compiles numba kernels.
"""

from __future__ import annotations

from importlib import import_module

_EXPORTS = {
    "TrackFilter": "sfa.filter",
    "Estimate": "sfa.filter",
    "Update": "sfa.filter",
    "FilterConfig": "sfa.config",
    "FilterStatus": "sfa.layout",
    "Outcome": "sfa.layout",
    "ImuMeas": "sfa.measurements",
    "OdoMeas": "sfa.measurements",
    "GpsMeas": "sfa.measurements",
    "InitMeas": "sfa.measurements",
    "filter_config_for": "sfa.presets",
    "SfaError": "sfa.errors",
    "FilterConfigError": "sfa.errors",
    "FilterStateError": "sfa.errors",
    "MeasurementTypeError": "sfa.errors",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'sfa' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value
