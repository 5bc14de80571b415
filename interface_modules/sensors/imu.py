"""IMU model: specific force and angular rate in the FRD body frame, with a MEMS error model.

Error-free values at sample ``j`` (sampling time ``t_j``, covering ``[t_j, t_j + 1/rate)``):

- ``ax = a_mean + g sin(theta)``: ``a_mean`` is the truth's mean acceleration over the sample
  interval (the truth's constant step acceleration when the IMU runs at the truth rate), ``theta =
  atan(grade)`` in the direction of travel at ``s(t_j)``. Integrating ``ax - g sin(theta)`` with the
  truth's scheme (see ``motion``) reproduces the truth's speed and arc length.
- ``ay = v^2 k`` (centripetal, ``k`` signed curvature in the direction of travel, > 0 right turn),
- ``az = -g cos(theta) - v^2 dtheta/dx`` (vertical curves; a level IMU at rest reads ``-g``),
- ``gx = 0``, ``gy = v dtheta/dx`` (pitch rate), ``gz = v k`` (yaw rate),
- with a :class:`CantModel` (the databases carry no superelevation, so a scenario may give the
  line's design rule) the car body rolls into the curve: lateral and vertical components are
  rotated by the roll angle and ``gx`` is the roll rate (see :func:`true_imu`).

Errors, per axis, in this order: mounting misalignment (a fixed small rotation, angles ~
N(0, misalignment_sigma)), scale error ``(1 + N(0, scale_sigma))``, turn-on bias ~ N(0, bias_sigma),
bias random walk (increments N(0, bias_rw^2 / rate)), white noise N(0, density^2 * rate), configured
bias steps, quantisation to the LSB, then stuck episodes (repeat the last output).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import ScenarioError
from ..faults import IMU_AXES, Fault, stuck_indices
from ..motion import Trajectory
from ..presets import G_MPS2, ImuSpec
from .stream import SampleStream

#: step of the central difference used for dtheta/ds [m]
PITCH_DIFF_STEP_M = 0.5


def decimation(truth_rate_hz: float, rate_hz: float, what: str) -> int:
    """Truth samples per sensor sample; the sensor rate must divide the truth rate."""
    n = truth_rate_hz / rate_hz
    if rate_hz <= 0 or abs(n - round(n)) > 1e-9 or round(n) < 1:
        raise ScenarioError(f"{what} rate {rate_hz} Hz must divide the truth rate {truth_rate_hz} Hz")
    return int(round(n))


def rotation_from_angles(angles_rad: np.ndarray) -> np.ndarray:
    """Rotation matrix of the rotation vector ``angles_rad`` (Rodrigues)."""
    theta = float(np.linalg.norm(angles_rad))
    if theta < 1e-15:
        return np.eye(3)
    k = angles_rad / theta
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(theta) * kx + (1.0 - np.cos(theta)) * (kx @ kx)


@dataclass(frozen=True)
class CantModel:
    """Superelevation from the curvature (the track databases carry none): the design rule of a line.

    ``cant = min(max_cant_m, rail_spacing_m * v_design^2 |k| / g)``, the outer rail raised, so the car
    body rolls towards the inside of the curve by ``asin(cant / rail_spacing_m)``, averaged along the
    line over ``transition_m`` (the cant ramp).
    """

    design_speed_mps: float  #: speed at which the cant balances the centripetal force [m/s]
    max_cant_m: float  #: largest cant [m]
    rail_spacing_m: float  #: distance between the rail centres: 1.5 m standard gauge, 1.06 m metre gauge [m]
    transition_m: float = 40.0  #: cant changes are spread over this length (1:400 for 100 mm) [m]

    def roll_rad(self, curvature_per_m):
        """Signed roll angle [rad], > 0 right side down (a right-hand curve), for the signed curvature."""
        k = np.asarray(curvature_per_m, dtype=float)
        cant = np.minimum(
            self.max_cant_m, self.rail_spacing_m * self.design_speed_mps**2 * np.abs(k) / G_MPS2
        )
        return np.sign(k) * np.arcsin(np.clip(cant / self.rail_spacing_m, 0.0, 1.0))

    def roll_profile(self, track, step_m: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """(arc length grid [m], roll [rad]) along the whole line, averaged over ``transition_m``.

        The moving average is the cant ramp: the cant never changes faster than a real ramp would,
        whatever the resolution of the curvature.
        """
        n = int(np.ceil(track.length_m / step_m)) + 1
        s = np.linspace(0.0, track.length_m, n)
        roll = self.roll_rad(np.asarray(track.curvature_at(s), dtype=float))
        width = max(int(round(self.transition_m / (s[1] - s[0]))), 1) if n > 1 else 1
        if width > 1:
            padded = np.pad(roll, (width // 2, width - 1 - width // 2), mode="edge")
            roll = np.convolve(padded, np.ones(width) / width, mode="valid")
        return s, roll


def true_imu(
    traj: Trajectory, track, decim: int, cant: CantModel | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Error-free (t_s, specific force (n, 3), rates (n, 3)) at every ``decim``-th truth sample.

    Without cant the body frame is the track's level frame. With cant, the level-frame vectors
    ``f = (ax, v^2 k, -g cos(theta) - v^2 dtheta/dx)`` and ``w = (0, v dtheta/dx, v k)`` are rotated into
    the body rolled by ``phi`` (body y = (0, cos phi, sin phi), body z = (0, -sin phi, cos phi)), and gx
    is the roll rate (mean over the sample interval); ax is unchanged.
    """
    n = traj.t_s.size // decim
    idx = np.arange(n) * decim
    t = traj.t_s[idx]
    s = traj.s_m[idx]
    v = traj.v_mps[idx]
    d = traj.direction[idx].astype(float)
    a_mean = traj.a_mps2[: n * decim].reshape(n, decim).mean(axis=1)
    grade = np.asarray(track.grade_at(s), dtype=float)
    theta = np.arctan(d * grade)
    h = PITCH_DIFF_STEP_M
    lo = np.clip(s - h, 0.0, track.length_m)
    hi = np.clip(s + h, 0.0, track.length_m)
    span = np.maximum(hi - lo, 1e-9)
    dtheta_ds = np.arctan(np.asarray(track.grade_at(hi), float)) - np.arctan(
        np.asarray(track.grade_at(lo), float)
    )
    dtheta_dx = dtheta_ds / span  # d(d*theta)/d(d*s): the sign of travel cancels
    k = d * np.asarray(track.curvature_at(s), dtype=float)
    fx = a_mean + G_MPS2 * np.sin(theta)
    fy = v * v * k
    fz = -G_MPS2 * np.cos(theta) - v * v * dtheta_dx
    wx = np.zeros(n)
    wy = v * dtheta_dx
    wz = v * k
    if cant is not None:
        grid, roll = cant.roll_profile(track)
        phi = d * np.interp(s, grid, roll)  # rolls towards the inside of the curve in either direction
        # roll rate = mean over the sample interval (roll at the next sample's position minus this one's),
        # so integrating gx gives the roll angle exactly, like ax gives the speed
        step = decim * traj.dt_s
        nxt = np.minimum(idx + decim, traj.s_m.size - 1)
        s_next = np.where(idx + decim < traj.s_m.size, traj.s_m[nxt], s + d * v * step)
        phi_next = d * np.interp(s_next, grid, roll)
        c, sn = np.cos(phi), np.sin(phi)
        fy, fz = fy * c + fz * sn, -fy * sn + fz * c
        wy, wz = wy * c + wz * sn, -wy * sn + wz * c
        wx = (phi_next - phi) / step
    return t, np.column_stack((fx, fy, fz)), np.column_stack((wx, wy, wz))


def simulate_imu(
    traj: Trajectory,
    track,
    spec: ImuSpec,
    rate_hz: float,
    faults: list[Fault],
    rng: np.random.Generator,
    truth_rate_hz: float,
    cant: CantModel | None = None,
) -> SampleStream:
    """IMU samples with errors (see module doc)."""
    decim = decimation(truth_rate_hz, rate_hz, "IMU")
    t, f_true, w_true = true_imu(traj, track, decim, cant)
    n = t.size
    dt = 1.0 / rate_hz
    # draw order is fixed: misalignment, scales, turn-on biases, random walks, white noise
    c_mis = rotation_from_angles(rng.normal(0.0, spec.misalignment_sigma, 3))
    acc_scale = 1.0 + rng.normal(0.0, spec.accel_scale_sigma, 3)
    gyr_scale = 1.0 + rng.normal(0.0, spec.gyro_scale_sigma, 3)
    acc_b0 = rng.normal(0.0, spec.accel_bias_sigma, 3)
    gyr_b0 = rng.normal(0.0, spec.gyro_bias_sigma, 3)
    acc_rw = np.cumsum(rng.normal(0.0, spec.accel_bias_rw * np.sqrt(dt), (n, 3)), axis=0)
    gyr_rw = np.cumsum(rng.normal(0.0, spec.gyro_bias_rw * np.sqrt(dt), (n, 3)), axis=0)
    acc_w = rng.normal(0.0, spec.accel_noise_density * np.sqrt(rate_hz), (n, 3))
    gyr_w = rng.normal(0.0, spec.gyro_noise_density * np.sqrt(rate_hz), (n, 3))
    f = (f_true @ c_mis.T) * acc_scale + acc_b0 + acc_rw + acc_w
    w = (w_true @ c_mis.T) * gyr_scale + gyr_b0 + gyr_rw + gyr_w
    meas = np.hstack((f, w))
    events: list[tuple[float, str, str]] = []
    for fault in faults:
        if fault.kind == "imu_bias_step":
            col = IMU_AXES.index(fault.axis)
            meas[fault.active(t), col] += fault.value
            events.append((float(fault.start_s), "imu_bias_step", f"{fault.axis} {fault.value:+g}"))
            if fault.end_s is not None:
                events.append((float(fault.end_s), "imu_bias_step_end", fault.axis))
    meas[:, :3] = quantise(meas[:, :3], spec.accel_lsb)
    meas[:, 3:] = quantise(meas[:, 3:], spec.gyro_lsb)
    stuck = [fl for fl in faults if fl.kind == "stuck"]
    if stuck:
        meas = meas[stuck_indices(t, stuck)]
    values = {name: meas[:, i].copy() for i, name in enumerate(IMU_AXES)}
    truth = {name: col for name, col in zip(IMU_AXES, np.hstack((f_true, w_true)).T, strict=True)}
    truth["acc_bias_turn_on"] = acc_b0
    truth["gyro_bias_turn_on"] = gyr_b0
    return SampleStream("imu", t, values, np.ones(n, dtype=bool), events, truth)


def quantise(x: np.ndarray, lsb: float) -> np.ndarray:
    """Round to the nearest multiple of ``lsb`` (no quantisation when ``lsb <= 0``)."""
    if lsb <= 0:
        return x
    return np.round(x / lsb) * lsb
