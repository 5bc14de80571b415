"""GNSS receiver model: WGS84 fixes of the antenna on the track with correlated and white errors.

Truth: ``track.latlon_at(s)`` and ``track.alt_at(s) + antenna_height_m`` at each fix time. Errors
per horizontal axis (east, north): a first-order Gauss-Markov process, exactly discretised
(``x_{k+1} = phi x_k + sqrt(1 - phi^2) sigma_gm w_k``, ``phi = exp(-dt / tau)``, stationary start),
plus white noise ``N(0, white_sigma^2)``, plus configured multipath steps and ramps. The vertical
error is an independent process with the same split, scaled to ``vertical_sigma_m`` in total.
Offsets become degrees through the WGS84 meridian and prime-vertical radii at the fix.

Satellites: ``num_sv = round(num_sv_mean + GM(num_sv_sigma, 60 s))`` clipped to 5..32; the reported
``sigma_h`` is ``reported_sigma_h_m * sqrt(num_sv_mean / num_sv)`` (fewer satellites, worse DOP).

Outages (tunnels and ``gnss_outage`` faults): ``mode = "no_fix"`` sends fix_quality 0, num_sv 0,
lat = lon = alt = 0 and ``sigma_h = NO_FIX_SIGMA_H_M`` (a datagram that carries no usable position);
``"silent"`` sends nothing. The receiver needs ``reacquire_s`` after an outage before its next fix,
and its Gauss-Markov error restarts from the stationary distribution (a new solution).
"""

from __future__ import annotations

import numpy as np

from ..faults import Fault, stuck_indices
from ..motion import Trajectory
from ..presets import GpsSpec
from ..synthetic import meridian_radius_m, normal_radius_m
from .imu import decimation
from .stream import SampleStream

NO_FIX_SIGMA_H_M = 1.0e4  #: sigma_h sent with fix_quality 0 [m]
NUM_SV_TAU_S = 60.0  #: correlation time of the satellite count [s]


def gauss_markov(
    n: int,
    dt_s: float,
    sigma: float,
    tau_s: float,
    rng: np.random.Generator,
    restart: np.ndarray | None = None,
) -> np.ndarray:
    """First-order Gauss-Markov samples (stationary start; fresh draw where ``restart`` is True)."""
    out = np.empty(n)
    if n == 0:
        return out
    phi = float(np.exp(-dt_s / tau_s)) if tau_s > 0 else 0.0
    q = sigma * np.sqrt(1.0 - phi * phi)
    w = rng.normal(0.0, 1.0, n)
    fresh = sigma * w
    drive = q * w
    x = fresh[0]
    out[0] = x
    restart_list = restart.tolist() if restart is not None else None
    for k in range(1, n):
        if restart_list is not None and restart_list[k]:
            x = fresh[k]
        else:
            x = phi * x + drive[k]
        out[k] = x
    return out


def outage_mask(t: np.ndarray, s: np.ndarray, faults: list[Fault], mode: str) -> np.ndarray:
    """Fix times inside any gnss_outage of the given mode (by arc length zone or time window)."""
    mask = np.zeros(t.size, dtype=bool)
    for f in faults:
        if f.kind != "gnss_outage" or f.mode != mode:
            continue
        if f.from_m is not None:
            mask |= (s >= f.from_m) & (s <= f.to_m)
        else:
            mask |= f.active(t)
    return mask


def simulate_gps(
    traj: Trajectory,
    track,
    spec: GpsSpec,
    rate_hz: float,
    faults: list[Fault],
    rng: np.random.Generator,
    truth_rate_hz: float,
    antenna_height_m: float = 0.0,
) -> SampleStream:
    """GNSS fixes with errors (see module doc)."""
    decim = decimation(truth_rate_hz, rate_hz, "GPS")
    idx = np.arange(traj.t_s.size // decim) * decim
    t = traj.t_s[idx]
    s = traj.s_m[idx]
    n = t.size
    dt = 1.0 / rate_hz
    lat_true, lon_true = (np.asarray(x, dtype=float) for x in track.latlon_at(s))
    alt_true = np.asarray(track.alt_at(s), dtype=float) + antenna_height_m

    no_fix = outage_mask(t, s, faults, "no_fix")
    silent = outage_mask(t, s, faults, "silent")
    out = no_fix | silent
    # reacquisition: no fix for reacquire_s after each outage; the solution restarts afterwards
    ends = np.flatnonzero(out[:-1] & ~out[1:]) + 1
    reacq = np.zeros(n, dtype=bool)
    for e in ends:
        reacq |= (t >= t[e]) & (t < t[e] + spec.reacquire_s)
    no_fix |= reacq & ~silent
    unusable = no_fix | silent
    restart = np.zeros(n, dtype=bool)
    restart[1:] = unusable[:-1] & ~unusable[1:]

    total_h = np.hypot(spec.gm_sigma_m, spec.white_sigma_m)
    ratio_v = spec.vertical_sigma_m / total_h if total_h > 0 else 0.0
    # draw order is fixed: east, north, up (GM then white), satellite count
    e_err = gauss_markov(n, dt, spec.gm_sigma_m, spec.gm_tau_s, rng, restart) + rng.normal(
        0, spec.white_sigma_m, n
    )
    n_err = gauss_markov(n, dt, spec.gm_sigma_m, spec.gm_tau_s, rng, restart) + rng.normal(
        0, spec.white_sigma_m, n
    )
    u_err = ratio_v * (
        gauss_markov(n, dt, spec.gm_sigma_m, spec.gm_tau_s, rng, restart)
        + rng.normal(0, spec.white_sigma_m, n)
    )
    num_sv = np.clip(
        np.round(spec.num_sv_mean + gauss_markov(n, dt, spec.num_sv_sigma, NUM_SV_TAU_S, rng)), 5, 32
    )

    events: list[tuple[float, str, str]] = []
    for f in faults:
        if f.kind == "multipath_step":
            m = f.active(t)
            e_err[m] += f.east_m
            n_err[m] += f.north_m
            events.append((float(f.start_s), "multipath_step", f"E {f.east_m:+.1f} m N {f.north_m:+.1f} m"))
            events.append((float(f.end_s), "multipath_end", ""))
        elif f.kind == "multipath_ramp":
            m = f.active(t)
            frac = np.clip((t - f.start_s) / (f.end_s - f.start_s), 0.0, 1.0)
            e_err[m] += f.east_m * frac[m]
            n_err[m] += f.north_m * frac[m]
            events.append(
                (float(f.start_s), "multipath_ramp", f"to E {f.east_m:+.1f} m N {f.north_m:+.1f} m")
            )
            events.append((float(f.end_s), "multipath_end", ""))
    for start, stop in _runs(unusable):
        events.append((float(t[start]), "gnss_lost", "silent" if silent[start] else "fix_quality 0"))
        if stop < n:
            events.append((float(t[stop]), "gnss_fix", f"after {t[stop] - t[start]:.1f} s"))

    lat = lat_true + np.degrees(n_err / meridian_radius_m(lat_true))
    lon = lon_true + np.degrees(e_err / (normal_radius_m(lat_true) * np.cos(np.radians(lat_true))))
    alt = alt_true + u_err
    fix_quality = np.full(n, spec.fix_quality, dtype=np.int64)
    sigma_h = spec.reported_sigma_h_m * np.sqrt(spec.num_sv_mean / num_sv)
    lat[no_fix] = 0.0
    lon[no_fix] = 0.0
    alt[no_fix] = 0.0
    fix_quality[no_fix] = 0
    num_sv = num_sv.astype(np.int64)
    num_sv[no_fix] = 0
    sigma_h[no_fix] = NO_FIX_SIGMA_H_M
    values = {
        "lat": lat,
        "lon": lon,
        "alt": alt,
        "fix_quality": fix_quality,
        "num_sv": num_sv,
        "sigma_h": sigma_h,
    }
    stuck = [fl for fl in faults if fl.kind == "stuck"]
    if stuck:
        keep = stuck_indices(t, stuck)
        values = {k: v[keep] for k, v in values.items()}
    truth = {
        "lat": lat_true,
        "lon": lon_true,
        "alt": alt_true,
        "east_err": e_err,
        "north_err": n_err,
        "s": s,
        "usable": ~unusable,
    }
    return SampleStream("gps", t, values, ~silent, events, truth)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the True runs of ``mask`` (stop exclusive)."""
    padded = np.concatenate(([False], mask, [False])).astype(np.int8)
    diff = np.diff(padded)
    return list(zip(np.flatnonzero(diff == 1).tolist(), np.flatnonzero(diff == -1).tolist(), strict=True))
