"""Rolling-stock presets for the longitudinal train model.

Each :class:`TrainSpec` holds what the control-oriented model of the ATO seed (section 5) needs:
mass, rotating-mass factor, Davis resistance ``A + B v + C v^2``, traction envelope (maximum
tractive effort, power, adhesion), braking limits, jerk limit, and the comfort limits the planner
uses. Numbers are class values for the vehicle type, not a certified fleet data sheet; sources:

- ``tram``: 5-section low-floor metre-gauge tram of the Jena fleet class (Solaris Tramino Jena /
  Combino-like): ~42 t with a normal load, 4 x 105 kW = 420 kW, 70 km/h top speed (BOStrab
  tramway limit for street running), service braking 1.3 m/s^2 (VDV 150 / BOStrab para. 36
  require >= 1.3 m/s^2 service and >= 2.73 m/s^2 emergency braking incl. track brakes),
  starting acceleration ~1.2 m/s^2 (manufacturer brochures for 30-45 t low-floor trams).
  Davis coefficients scaled from Rochard & Schmid, "A review of methods to measure and calculate
  train resistances", Proc. IMechE F 214 (2000), for a 40 t vehicle with a ~8 m^2 frontal area.
- ``regional-emu``: 4-car regional EMU (Stadler FLIRT / CAF Civia class): ~130 t loaded,
  2.6 MW, 160 km/h, 200 kN starting tractive effort, 1.0 m/s^2 service braking (EN 14531-1
  service braking for regional multiple units), Davis terms from Rochard & Schmid (2000) for
  multiple units (A ~ 2 kN, B ~ 30 N s/m, C ~ 6 N s^2/m^2).
- ``high-speed``: 8-car high-speed train (ETR 1000 / Frecciarossa 1000 class): ~500 t, 9.8 MW,
  300 km/h in service, 370 kN starting tractive effort, 0.7 m/s^2 service braking at high speed,
  Davis terms of the TGV/ICE class from Rochard & Schmid (2000) (A ~ 4 kN, B ~ 60 N s/m,
  C ~ 9.5 N s^2/m^2), the order of magnitude the ATO seed's model uses.

Curve resistance follows Roeckl's empirical formula, the ``k(p)/r(p)`` term of the seed:
``F_curve = M g k / (R - b)`` with ``(k, b) = (0.65 m, 55 m)`` for standard gauge (R >= 300 m),
``(0.5 m, 30 m)`` below 300 m and ``(0.4 m, 20 m)`` for metre gauge.
"""

from __future__ import annotations

from dataclasses import dataclass

from .presets import G_MPS2

KMH = 1.0 / 3.6  #: one km/h [m/s]


@dataclass(frozen=True)
class TrainSpec:
    """Longitudinal model parameters of one train (single rigid body)."""

    mass_kg: float  #: total mass M including the normal load [kg]
    rotating_mass_factor: float  #: equivalent rotating mass as a fraction of M (effective mass M (1 + f)) [-]
    adhesive_mass_fraction: float  #: share of the weight on powered axles [-]
    adhesion_coefficient: float  #: usable wheel-rail adhesion for traction [-]
    davis_a_n: float  #: Davis constant term A [N]
    davis_b_n_per_mps: float  #: Davis linear term B [N/(m/s)]
    davis_c_n_per_mps2: float  #: Davis aerodynamic term C [N/(m/s)^2]
    max_tractive_effort_n: float  #: starting tractive effort [N]
    max_power_w: float  #: traction power at the wheel [W]
    service_brake_mps2: float  #: maximum service braking deceleration (brake force / M) [m/s^2]
    max_speed_mps: float  #: vehicle maximum speed [m/s]
    jerk_limit_mps3: float  #: comfort limit on the rate of change of the commanded acceleration [m/s^3]
    plan_accel_mps2: float  #: acceleration the planner assumes (below the traction envelope) [m/s^2]
    plan_decel_mps2: float  #: deceleration the planner assumes for stops and restrictions [m/s^2]
    max_lateral_accel_mps2: float  #: uncompensated lateral acceleration allowed in curves [m/s^2]
    gauge: str  #: "standard" (1435 mm) or "metre" (1000 mm): picks the curve-resistance formula

    @property
    def effective_mass_kg(self) -> float:
        """Mass including the rotating-mass allowance [kg]."""
        return self.mass_kg * (1.0 + self.rotating_mass_factor)


TRAIN_PRESETS: dict[str, TrainSpec] = {
    "tram": TrainSpec(
        mass_kg=42_000.0,
        rotating_mass_factor=0.08,
        adhesive_mass_fraction=0.67,
        adhesion_coefficient=0.20,
        davis_a_n=1_100.0,
        davis_b_n_per_mps=22.0,
        davis_c_n_per_mps2=3.2,
        max_tractive_effort_n=56_000.0,
        max_power_w=420_000.0,
        service_brake_mps2=1.3,
        max_speed_mps=70.0 * KMH,
        jerk_limit_mps3=1.0,
        plan_accel_mps2=1.0,
        plan_decel_mps2=0.9,
        max_lateral_accel_mps2=0.8,
        gauge="metre",
    ),
    "regional-emu": TrainSpec(
        mass_kg=130_000.0,
        rotating_mass_factor=0.07,
        adhesive_mass_fraction=0.5,
        adhesion_coefficient=0.18,
        davis_a_n=2_000.0,
        davis_b_n_per_mps=30.0,
        davis_c_n_per_mps2=6.0,
        max_tractive_effort_n=200_000.0,
        max_power_w=2_600_000.0,
        service_brake_mps2=1.0,
        max_speed_mps=160.0 * KMH,
        jerk_limit_mps3=0.75,
        plan_accel_mps2=0.8,
        plan_decel_mps2=0.7,
        max_lateral_accel_mps2=1.0,
        gauge="standard",
    ),
    "high-speed": TrainSpec(
        mass_kg=500_000.0,
        rotating_mass_factor=0.04,
        adhesive_mass_fraction=0.5,
        adhesion_coefficient=0.15,
        davis_a_n=4_000.0,
        davis_b_n_per_mps=60.0,
        davis_c_n_per_mps2=9.5,
        max_tractive_effort_n=370_000.0,
        max_power_w=9_800_000.0,
        service_brake_mps2=0.7,
        max_speed_mps=300.0 * KMH,
        jerk_limit_mps3=0.5,
        plan_accel_mps2=0.5,
        plan_decel_mps2=0.5,
        max_lateral_accel_mps2=1.0,
        gauge="standard",
    ),
}

__all__ = ["G_MPS2", "KMH", "TRAIN_PRESETS", "TrainSpec"]
