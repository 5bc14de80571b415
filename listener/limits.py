"""Physical and wire ranges the codec enforces, one named constant per bound (SI units, degrees for lat/lon).

Every bound is inclusive unless the name says otherwise. The table in docs/protocol.md ("Ranges")
is generated from the same numbers and checked by tests/test_codec.py, so the two cannot drift.
"""

STANDARD_GRAVITY_MPS2 = 9.80665  #: m/s^2, ISO 80000-3 standard gravity

LAT_MIN_DEG, LAT_MAX_DEG = -90.0, 90.0  #: WGS84 latitude
LON_MIN_DEG, LON_MAX_DEG = -180.0, 180.0  #: WGS84 longitude
ALT_MIN_M, ALT_MAX_M = -500.0, 9000.0  #: altitude above MSL: below the Dead Sea shore .. above any railway

ACCEL_MAX_MPS2 = 16.0 * STANDARD_GRAVITY_MPS2  #: |a| per axis: the widest common MEMS range (+-16 g)
RATE_MAX_RADPS = 35.0  #: |w| per axis: 35 rad/s ~ 2005 deg/s, the widest common MEMS gyro range (+-2000 dps)
SPEED_MAX_MPS = 150.0  #: |v| (odometer speed, each ground-truth velocity axis): 540 km/h, above any train
ODO_SIGMA_MAX_MPS = 50.0  #: odometer 1-sigma upper bound (a sigma above this carries no information)
GPS_SIGMA_H_MAX_M = 100_000.0  #: GPS horizontal 1-sigma upper bound (100 km: "no usable fix")
FIX_QUALITY_MIN, FIX_QUALITY_MAX = 0, 8  #: NMEA GGA fix quality 0..8
NUM_SV_MIN, NUM_SV_MAX = 0, 255  #: satellites used
LINE_ID_MIN, LINE_ID_MAX = 0, 2**31 - 1  #: track database line id (int32, non-negative)
ARC_LENGTH_MIN_M, ARC_LENGTH_MAX_M = -1.0e3, 1.0e8  #: arc length: just before the line start .. 1e5 km
EPOCH_MIN_S, EPOCH_MAX_S = 0.0, 1.0e10  #: sensor-set time (epoch, STROBE timestamp): >= 0, before year 2286

SEQ_MIN, SEQ_MAX = 0, 0xFFFF  #: uint16 sequence numbers (INPUT, OUTPUT, ACK)
