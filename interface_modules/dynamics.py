"""Longitudinal train dynamics of the ATO seed (section 5), as pure functions.

    M_eff dv/dt = u - F_davis(v) - M g sin(theta(s)) - F_curve(R(s))

with ``F_davis = A + B v + C v^2`` (only while moving), ``theta = atan(grade)`` in the direction of
travel and Roeckl's curve resistance. ``u`` is the traction (> 0) or braking (< 0) force, limited by
:func:`traction_limit_n` (tractive effort, power, adhesion) and :func:`brake_limit_n`.
All functions accept floats or numpy arrays.
"""

from __future__ import annotations

import numba
import numpy as np

from .presets import G_MPS2
from .trains import TrainSpec

#: curvature below which a track counts as straight (radius > 100 km) [1/m]
STRAIGHT_CURVATURE_PER_M = 1e-5


def davis_resistance_n(spec: TrainSpec, speed_mps):
    """Running resistance ``A + B v + C v^2`` [N] at speed ``v >= 0`` (no wind)."""
    v = np.abs(speed_mps)
    return spec.davis_a_n + spec.davis_b_n_per_mps * v + spec.davis_c_n_per_mps2 * v * v


def grade_force_n(spec: TrainSpec, grade):
    """Gravity component along the track ``M g sin(atan(grade))`` [N]; > 0 opposes climbing motion."""
    g = np.asarray(grade, dtype=float)
    return spec.mass_kg * G_MPS2 * g / np.sqrt(1.0 + g * g)


def curve_resistance_n(spec: TrainSpec, curvature_per_m):
    """Curve resistance [N] for the signed curvature ``k`` (radius ``1/|k|``); 0 on straight track."""
    kabs = np.abs(np.asarray(curvature_per_m, dtype=float))
    radius = np.where(kabs > STRAIGHT_CURVATURE_PER_M, 1.0 / np.maximum(kabs, 1e-12), np.inf)
    if spec.gauge == "metre":
        k_m, b_m = 0.4, 20.0
        coef = np.where(np.isfinite(radius), k_m / np.maximum(radius - b_m, 10.0), 0.0)
    else:
        big = np.where(np.isfinite(radius), 0.65 / np.maximum(radius - 55.0, 10.0), 0.0)
        small = np.where(np.isfinite(radius), 0.5 / np.maximum(radius - 30.0, 10.0), 0.0)
        coef = np.where(radius >= 300.0, big, small)
    return spec.mass_kg * G_MPS2 * coef


def traction_limit_n(spec: TrainSpec, speed_mps: float) -> float:
    """Largest tractive force [N]: min(tractive effort, adhesion, power / v)."""
    adhesion = spec.adhesion_coefficient * spec.adhesive_mass_fraction * spec.mass_kg * G_MPS2
    limit = min(spec.max_tractive_effort_n, adhesion)
    v = abs(speed_mps)
    if v > 1e-6:
        limit = min(limit, spec.max_power_w / v)
    return limit


def brake_limit_n(spec: TrainSpec) -> float:
    """Largest service braking force [N] (positive number)."""
    return spec.service_brake_mps2 * spec.mass_kg


def max_accel_mps2(spec: TrainSpec, speed_mps):
    """Acceleration available on level straight track at ``speed_mps`` [m/s^2] (vectorised)."""
    v = np.abs(np.asarray(speed_mps, dtype=float))
    adhesion = spec.adhesion_coefficient * spec.adhesive_mass_fraction * spec.mass_kg * G_MPS2
    force = np.minimum(min(spec.max_tractive_effort_n, adhesion), spec.max_power_w / np.maximum(v, 1e-6))
    return (force - davis_resistance_n(spec, v)) / spec.effective_mass_kg


def curve_speed_limit_mps(spec: TrainSpec, curvature_per_m):
    """Speed at which the uncompensated lateral acceleration reaches the allowed limit [m/s]."""
    kabs = np.abs(np.asarray(curvature_per_m, dtype=float))
    return np.sqrt(spec.max_lateral_accel_mps2 / np.maximum(kabs, STRAIGHT_CURVATURE_PER_M))


def acceleration_mps2(
    spec: TrainSpec, force_n: float, speed_mps: float, grade_force: float, curve_force: float
) -> float:
    """Resulting acceleration [m/s^2] for the applied force ``force_n`` (scalar, hot loop).

    ``grade_force`` and ``curve_force`` come from :func:`grade_force_n` and
    :func:`curve_resistance_n` at the train's position. The model has no rollback: a train at rest
    whose net force would not move it forwards stays at rest (service brake or static friction
    holds it); the Davis constant term and curve resistance act as breakaway resistance.
    """
    m_eff = spec.mass_kg * (1.0 + spec.rotating_mass_factor)
    v = abs(speed_mps)
    if v <= 0.0:
        drive = force_n - grade_force - spec.davis_a_n - curve_force
        return drive / m_eff if drive > 0.0 else 0.0
    f_davis = spec.davis_a_n + spec.davis_b_n_per_mps * v + spec.davis_c_n_per_mps2 * v * v
    return (force_n - f_davis - grade_force - curve_force) / m_eff


@numba.njit(cache=True, inline="always")
def train_step(u, v, fg, fc, a_davis, b_davis, c_davis, m_eff, dt):
    """One Euler step of M_eff dv/dt = u - Davis(v) - grade - curve [N]: (acceleration [m/s^2], next
    speed [m/s]). At rest the brakes hold the train (no rollback); the speed never goes below zero."""
    if v <= 0.0:
        drive_f = u - fg - a_davis - fc
        a = drive_f / m_eff if drive_f > 0.0 else 0.0
    else:
        a = (u - (a_davis + b_davis * v + c_davis * v * v) - fg - fc) / m_eff
    v_next = v + a * dt
    if v_next < 0.0:
        a = -v / dt
        v_next = 0.0
    return a, v_next
