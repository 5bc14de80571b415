"""Odometer / Doppler radar model: signed speed with its 1-sigma per sample.

``speed = v (1 + scale) (1 + slip(t)) + N(0, sigma(v)^2)``, quantised to the LSB, with
``sigma(v) = sqrt(sigma_floor^2 + (sigma_fraction v)^2)``; ``scale ~ N(0, scale_sigma)`` is drawn once.
The datagram's sigma is what the sensor can know: ``sigma(|speed reading|)`` (it does not know
about slip), at least ``MIN_REPORTED_SIGMA_MPS``. A wheel sensor (``slip_prone``) reads exactly 0
at standstill (no tachometer pulses).

Slip/slide (``slip(t)``): configured ``odo_slip`` episodes plus, for wheel sensors, spontaneous
episodes: a Poisson process of rate ``slip_rate_per_h``; a candidate starting while the train
accelerates (a > 0.3 m/s^2) becomes a slip (wheel spins: over-reads), one while braking
(a < -0.3 m/s^2) a slide (under-reads), others are discarded; magnitude ~ U(0.03, slip_max_fraction),
duration ~ U(1, 5) s, 0.5 s ramps. Dropouts: each sample independently missing with
``dropout_prob``.
"""

from __future__ import annotations

import numpy as np

from ..faults import Fault, stuck_indices, trapezoid_episode
from ..motion import Trajectory
from ..presets import OdometerSpec
from .imu import decimation, quantise
from .stream import SampleStream

#: acceleration beyond which a spontaneous slip/slide episode can start [m/s^2]
SLIP_ACCEL_THRESHOLD_MPS2 = 0.3
#: smallest sigma a datagram carries (the wire requires sigma > 0; matters only for error-free presets) [m/s]
MIN_REPORTED_SIGMA_MPS = 0.001
#: ramp time of slip/slide episodes [s]
SLIP_RAMP_S = 0.5


def sigma_mps(spec: OdometerSpec, speed_mps):
    """The sensor's 1-sigma speed noise at ``speed_mps`` [m/s]."""
    v = np.abs(speed_mps)
    return np.sqrt(spec.sigma_floor_mps**2 + (spec.sigma_fraction * v) ** 2)


def simulate_odometer(
    traj: Trajectory,
    spec: OdometerSpec,
    rate_hz: float,
    faults: list[Fault],
    rng: np.random.Generator,
    truth_rate_hz: float,
) -> SampleStream:
    """Odometer samples with errors (see module doc)."""
    decim = decimation(truth_rate_hz, rate_hz, "odometer")
    idx = np.arange(traj.t_s.size // decim) * decim
    t = traj.t_s[idx]
    v = traj.v_mps[idx]
    a = traj.a_mps2[idx]
    n = t.size
    duration = float(traj.t_s[-1]) if traj.t_s.size else 0.0
    # draw order is fixed: scale, spontaneous episodes, white noise, dropouts
    scale = rng.normal(0.0, spec.scale_sigma)
    slip = np.zeros(n)
    events: list[tuple[float, str, str]] = []
    if spec.slip_prone and spec.slip_rate_per_h > 0 and duration > 0:
        count = rng.poisson(spec.slip_rate_per_h * duration / 3600.0)
        starts = np.sort(rng.uniform(0.0, duration, count))
        mags = rng.uniform(0.03, max(spec.slip_max_fraction, 0.03), count)
        lengths = rng.uniform(1.0, 5.0, count)
        for t0, mag, length in zip(starts, mags, lengths, strict=True):
            a0 = float(np.interp(t0, traj.t_s, traj.a_mps2))
            if a0 > SLIP_ACCEL_THRESHOLD_MPS2:
                sign, kind = 1.0, "odo_slip"
            elif a0 < -SLIP_ACCEL_THRESHOLD_MPS2:
                sign, kind = -1.0, "odo_slide"
            else:
                continue
            slip += sign * mag * trapezoid_episode(t, t0, t0 + length, SLIP_RAMP_S)
            events.append((float(t0), kind, f"spontaneous {sign * mag:+.1%} for {length:.1f} s"))
    for fault in faults:
        if fault.kind == "odo_slip":
            slip += fault.value * trapezoid_episode(t, fault.start_s, fault.end_s, SLIP_RAMP_S)
            events.append(
                (
                    float(fault.start_s),
                    "odo_slip" if fault.value >= 0 else "odo_slide",
                    f"configured {fault.value:+.1%} until {fault.end_s:.1f} s",
                )
            )
    noise = rng.normal(0.0, 1.0, n) * sigma_mps(spec, v)
    dropped = rng.random(n) < spec.dropout_prob
    speed = quantise(v * (1.0 + scale) * (1.0 + slip) + noise, spec.lsb_mps)
    if spec.slip_prone:
        speed = np.where(v == 0.0, 0.0, speed)
    stuck = [fl for fl in faults if fl.kind == "stuck"]
    if stuck:
        speed = speed[stuck_indices(t, stuck)]
    values = {"speed": speed, "sigma": np.maximum(sigma_mps(spec, speed), MIN_REPORTED_SIGMA_MPS)}
    truth = {"speed": v, "accel": a, "slip": slip, "scale": np.array([scale])}
    for t_drop in t[dropped][:1000]:
        events.append((float(t_drop), "odo_dropout", ""))
    return SampleStream("odometer", t, values, ~dropped, events, truth)
