"""Vectorised INPUT_PROTOCOL packing of whole sensor streams (the bulk path of offline generation).

``listener.codec`` is the project's codec and the reference: this module lays out exactly the same
bytes (header ``<BHBB``, then int32s, then float64s, little-endian, wire protocol section
"INPUT_PROTOCOL") with one numpy structured array per stream instead of one Python object per
datagram, which is what makes a 1-hour scenario fast. tests/test_sim_wire.py checks, datagram by
datagram, that the bytes equal ``listener.codec.encode_input`` of the decoded message, and before
packing the values are checked against the codec's own ranges (``listener.limits``), so a datagram
the codec would refuse is never produced.
"""

from __future__ import annotations

import numpy as np

from .errors import SimError

#: wire field order per stream kind: (sensor type, int fields, double fields)
LAYOUTS = {
    "imu": (1, (), ("ax", "ay", "az", "gx", "gy", "gz")),
    "odometer": (2, (), ("speed", "sigma")),
    "gps": (3, ("fix_quality", "num_sv"), ("lat", "lon", "alt", "sigma_h")),
}


def _ranges() -> dict[str, tuple[float, float]]:
    from listener import limits as L

    return {
        "ax": (-L.ACCEL_MAX_MPS2, L.ACCEL_MAX_MPS2),
        "ay": (-L.ACCEL_MAX_MPS2, L.ACCEL_MAX_MPS2),
        "az": (-L.ACCEL_MAX_MPS2, L.ACCEL_MAX_MPS2),
        "gx": (-L.RATE_MAX_RADPS, L.RATE_MAX_RADPS),
        "gy": (-L.RATE_MAX_RADPS, L.RATE_MAX_RADPS),
        "gz": (-L.RATE_MAX_RADPS, L.RATE_MAX_RADPS),
        "speed": (-L.SPEED_MAX_MPS, L.SPEED_MAX_MPS),
        "sigma": (np.nextafter(0.0, 1.0), L.ODO_SIGMA_MAX_MPS),
        "lat": (L.LAT_MIN_DEG, L.LAT_MAX_DEG),
        "lon": (L.LON_MIN_DEG, L.LON_MAX_DEG),
        "alt": (L.ALT_MIN_M, L.ALT_MAX_M),
        "sigma_h": (np.nextafter(0.0, 1.0), L.GPS_SIGMA_H_MAX_M),
        "fix_quality": (L.FIX_QUALITY_MIN, L.FIX_QUALITY_MAX),
        "num_sv": (L.NUM_SV_MIN, L.NUM_SV_MAX),
        "epoch": (L.EPOCH_MIN_S, L.EPOCH_MAX_S),
    }


def pack_stream(
    kind: str, seq: np.ndarray, values: dict[str, np.ndarray], epoch: np.ndarray | None
) -> list[bytes]:
    """One datagram per row: ``seq`` (0..65535), the layout's fields, and ``epoch`` if given (last double)."""
    if kind not in LAYOUTS:
        raise SimError(f"no bulk layout for {kind!r}")
    sensor_type, ints, doubles = LAYOUTS[kind]
    n = int(seq.size)
    names = list(doubles) + (["epoch"] if epoch is not None else [])
    columns = {**values, **({"epoch": epoch} if epoch is not None else {})}
    ranges = _ranges()
    for name in list(ints) + names:
        col = np.asarray(columns[name])
        if col.shape != (n,):
            raise SimError(f"{kind}.{name}: {col.shape} values for {n} datagrams")
        lo, hi = ranges[name]
        if not np.all(np.isfinite(col)) or np.any(col < lo) or np.any(col > hi):
            bad = int(np.flatnonzero(~np.isfinite(col) | (col < lo) | (col > hi))[0])
            raise SimError(
                f"{kind}.{name} = {col[bad]!r} at datagram {bad} is outside the wire range {lo}..{hi}"
            )
    if np.any((seq < 0) | (seq > 0xFFFF)):
        raise SimError(f"{kind}: sequence number outside 0..65535")
    fields = [("type", "u1"), ("seq", "<u2"), ("n_int", "u1"), ("n_double", "u1")]
    fields += [(f"i_{name}", "<i4") for name in ints] + [(f"d_{name}", "<f8") for name in names]
    dtype = np.dtype(fields)
    rec = np.empty(n, dtype=dtype)
    rec["type"] = sensor_type
    rec["seq"] = seq
    rec["n_int"] = len(ints)
    rec["n_double"] = len(names)
    for name in ints:
        rec[f"i_{name}"] = columns[name]
    for name in names:
        rec[f"d_{name}"] = columns[name]
    size = dtype.itemsize
    buf = rec.tobytes()
    return [buf[i : i + size] for i in range(0, n * size, size)]
