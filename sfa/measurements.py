"""The filter's own measurement types, dated in sensor-set time (seconds).

The listener maps decoded wire messages to these; the filter never sees the wire format.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class ImuMeas:
    """6-axis IMU sample, FRD body frame."""

    t_s: float  #: sampling time [s]
    f_mps2: tuple[float, float, float]  #: specific force (ax, ay, az) [m/s^2]; at rest ~ (0, 0, -9.81)
    w_radps: tuple[float, float, float]  #: angular rate (gx, gy, gz) [rad/s]


@dataclass(frozen=True, slots=True)
class OdoMeas:
    """Odometer / radar speed sample."""

    t_s: float  #: sampling time [s]
    speed_mps: float  #: signed speed, positive forward [m/s]
    sigma_mps: float  #: the sample's 1-sigma [m/s], > 0


@dataclass(frozen=True, slots=True)
class GpsMeas:
    """GNSS fix."""

    t_s: float  #: fix time [s]
    lat_deg: float  #: WGS84 latitude [deg]
    lon_deg: float  #: WGS84 longitude [deg]
    alt_m: float  #: altitude above MSL [m] (not used by the along-track filter)
    sigma_h_m: float | None = None  #: reported 1-sigma per horizontal axis [m]; None: not reported
    fix_quality: int | None = None  #: NMEA GGA quality; 0 = no fix; None: not reported
    num_sv: int | None = None  #: satellites used; None: not reported


@dataclass(frozen=True, slots=True)
class InitMeas:
    """GROUND TRUTH: (re)initialises arc length and speed, and picks the line."""

    t_s: float  #: time [s]
    arc_length_m: float  #: arc length on the line [m]
    speed_mps: float  #: speed in the train's forward direction (GROUND TRUTH's body vx) [m/s]
    line_id: int | None = None  #: line of the database; None: the database's default line
    direction: int | None = None  #: +1 forward is increasing arc length, -1 decreasing; None: unknown
    #: (the filter then keeps both senses as hypotheses until GNSS tells them apart)


Measurement = ImuMeas | OdoMeas | GpsMeas | InitMeas
