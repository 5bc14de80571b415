"""Sensor fault zones and episodes, as configured in a scenario's ``[[faults]]`` tables.

Kinds (``sensor`` in brackets) and the fields each uses:

- ``gnss_outage`` (gps): by arc length ``from_m..to_m`` or by time ``start_s..end_s``; ``mode`` is
  ``"no_fix"`` (datagrams with fix_quality 0) or ``"silent"`` (no datagrams). Tunnels are outages.
- ``multipath_step`` (gps): offset ``east_m, north_m`` added from ``start_s`` to ``end_s``.
- ``multipath_ramp`` (gps): offset growing linearly from 0 at ``start_s`` to ``east_m, north_m`` at
  ``end_s``, then gone.
- ``odo_slip`` (odometer): speed reads ``(1 + value)`` times too high (``value < 0``: slide) from
  ``start_s`` to ``end_s`` with 0.5 s ramps.
- ``imu_bias_step`` (imu): ``value`` [m/s^2 or rad/s] added to ``axis`` (ax..gz) from ``start_s`` on
  (until ``end_s`` if given).
- ``stuck`` (any sensor): repeats its last output from ``start_s`` to ``end_s``.
- ``silent`` (any module, also control): sends nothing from ``start_s`` to ``end_s``.
- ``restart`` (any module): at ``start_s`` the sender restarts: its sequence counter jumps back to
  its configured start value.

Times are seconds from the scenario start (sensor-set time minus the start epoch).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import ScenarioError

FAULT_KINDS = (
    "gnss_outage",
    "multipath_step",
    "multipath_ramp",
    "odo_slip",
    "imu_bias_step",
    "stuck",
    "silent",
    "restart",
)
#: the sensor a kind applies to, when it is fixed
KIND_SENSOR = {
    "gnss_outage": "gps",
    "multipath_step": "gps",
    "multipath_ramp": "gps",
    "odo_slip": "odometer",
    "imu_bias_step": "imu",
}
MODULES = ("imu", "odometer", "gps", "control")
IMU_AXES = ("ax", "ay", "az", "gx", "gy", "gz")


@dataclass(frozen=True)
class Fault:
    """One configured fault (see module doc for which fields each kind uses)."""

    kind: str  #: one of FAULT_KINDS
    sensor: str  #: module it applies to: imu, odometer, gps, control
    start_s: float | None = None  #: start time from the scenario start [s]
    end_s: float | None = None  #: end time from the scenario start [s] (None: until the end)
    from_m: float | None = None  #: start of an arc-length zone [m]
    to_m: float | None = None  #: end of an arc-length zone [m]
    mode: str = "no_fix"  #: gnss_outage: "no_fix" or "silent"
    axis: str = "ax"  #: imu_bias_step: ax, ay, az, gx, gy, gz
    value: float = 0.0  #: imu_bias_step [m/s^2 | rad/s]; odo_slip speed error [fraction]
    east_m: float = 0.0  #: multipath offset east [m]
    north_m: float = 0.0  #: multipath offset north [m]
    label: str = ""  #: free text recorded in the events (e.g. the tunnel's name)

    def validate(self) -> Fault:
        """Return self if consistent, else raise ScenarioError naming the problem."""
        where = f"fault {self.kind!r}"
        if self.kind not in FAULT_KINDS:
            raise ScenarioError(f"unknown fault kind {self.kind!r} (known: {', '.join(FAULT_KINDS)})")
        if self.sensor not in MODULES:
            raise ScenarioError(f"{where}: unknown sensor {self.sensor!r} (known: {', '.join(MODULES)})")
        fixed = KIND_SENSOR.get(self.kind)
        if fixed is not None and self.sensor != fixed:
            raise ScenarioError(f"{where}: applies to sensor {fixed!r}, not {self.sensor!r}")
        if self.kind in ("stuck",) and self.sensor == "control":
            raise ScenarioError(f"{where}: the control module cannot be stuck")
        by_zone = self.from_m is not None or self.to_m is not None
        if self.kind == "gnss_outage" and by_zone:
            if self.from_m is None or self.to_m is None or not self.from_m < self.to_m:
                raise ScenarioError(f"{where}: needs from_m < to_m")
        elif self.start_s is None:
            raise ScenarioError(f"{where}: needs start_s")
        if self.start_s is not None and self.end_s is not None and not self.end_s > self.start_s:
            raise ScenarioError(f"{where}: needs end_s > start_s")
        if (
            self.kind in ("multipath_step", "multipath_ramp", "odo_slip", "stuck", "silent")
            and self.end_s is None
        ):
            if self.kind != "silent":
                raise ScenarioError(f"{where}: needs end_s")
        if self.kind == "gnss_outage" and self.mode not in ("no_fix", "silent"):
            raise ScenarioError(f"{where}: mode must be 'no_fix' or 'silent', not {self.mode!r}")
        if self.kind == "imu_bias_step" and self.axis not in IMU_AXES:
            raise ScenarioError(f"{where}: axis must be one of {', '.join(IMU_AXES)}")
        if self.kind == "odo_slip" and not -0.95 <= self.value <= 5.0:
            raise ScenarioError(f"{where}: value (speed error fraction) must be in -0.95..5")
        return self

    def active(self, t_s: np.ndarray) -> np.ndarray:
        """Boolean mask of the times inside the fault's time window."""
        start = -np.inf if self.start_s is None else self.start_s
        end = np.inf if self.end_s is None else self.end_s
        return (t_s >= start) & (t_s < end)


def of_sensor(faults: tuple[Fault, ...], sensor: str, *kinds: str) -> list[Fault]:
    """The faults of one module, optionally of given kinds."""
    return [f for f in faults if f.sensor == sensor and (not kinds or f.kind in kinds)]


def stuck_indices(t_s: np.ndarray, faults: list[Fault]) -> np.ndarray:
    """Index of the sample whose value each sample repeats (itself when not stuck)."""
    idx = np.arange(t_s.size)
    for f in faults:
        mask = f.active(t_s)
        if not mask.any():
            continue
        first = int(np.argmax(mask))
        held = max(first - 1, 0)
        idx[mask] = held
    return idx


def trapezoid_episode(t_s: np.ndarray, start_s: float, end_s: float, ramp_s: float) -> np.ndarray:
    """Shape in 0..1: ramps up over ``ramp_s`` after ``start_s``, down over ``ramp_s`` before ``end_s``."""
    ramp = max(min(ramp_s, 0.5 * (end_s - start_s)), 1e-9)
    up = (t_s - start_s) / ramp
    down = (end_s - t_s) / ramp
    return np.clip(np.minimum(up, down), 0.0, 1.0)
