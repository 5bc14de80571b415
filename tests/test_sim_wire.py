"""The bulk packer produces exactly the bytes of listener.codec for any in-range values."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from interface_modules.errors import SimError
from interface_modules.wirepack import pack_stream
from listener.codec import GpsFix, ImuSample, OdometerSample, decode_input, encode_input

seqs = st.integers(0, 65535)
acc = st.floats(-150.0, 150.0, allow_nan=False)
rate = st.floats(-30.0, 30.0, allow_nan=False)
epoch = st.one_of(st.none(), st.floats(0.0, 1e10, allow_nan=False))


@given(st.lists(st.tuples(seqs, acc, acc, acc, rate, rate, rate), min_size=1, max_size=20), epoch)
def test_imu_rows_match_the_codec(rows, ep):
    cols = list(zip(*rows, strict=True))
    names = ("ax", "ay", "az", "gx", "gy", "gz")
    values = {n: np.array(cols[i + 1]) for i, n in enumerate(names)}
    epochs = None if ep is None else np.full(len(rows), ep)
    out = pack_stream("imu", np.array(cols[0]), values, epochs)
    for row, data in zip(rows, out, strict=True):
        assert data == encode_input(ImuSample(*row, epoch=ep))


@given(seqs, st.floats(-100.0, 100.0), st.floats(1e-6, 40.0), epoch)
def test_odometer_rows_match_the_codec(seq, speed, sigma, ep):
    out = pack_stream(
        "odometer",
        np.array([seq]),
        {"speed": np.array([speed]), "sigma": np.array([sigma])},
        None if ep is None else np.array([ep]),
    )
    assert out[0] == encode_input(OdometerSample(seq, speed, sigma, ep))


@given(
    seqs,
    st.floats(-90.0, 90.0),
    st.floats(-180.0, 180.0),
    st.floats(-400.0, 8000.0),
    st.integers(0, 8),
    st.integers(0, 255),
    st.floats(1e-3, 1e4),
    epoch,
)
def test_gps_rows_match_the_codec(seq, lat, lon, alt, fq, nsv, sigma_h, ep):
    values = {
        "lat": np.array([lat]),
        "lon": np.array([lon]),
        "alt": np.array([alt]),
        "fix_quality": np.array([fq]),
        "num_sv": np.array([nsv]),
        "sigma_h": np.array([sigma_h]),
    }
    out = pack_stream("gps", np.array([seq]), values, None if ep is None else np.array([ep]))
    assert out[0] == encode_input(GpsFix(seq, lat, lon, alt, fq, nsv, sigma_h, ep))
    assert decode_input(out[0]).seq == seq


def test_values_the_codec_would_refuse_are_an_error():
    values = {"speed": np.array([1.0, np.nan]), "sigma": np.array([0.1, 0.1])}
    with pytest.raises(SimError, match="odometer.speed"):
        pack_stream("odometer", np.array([1, 2]), values, None)
    values = {"speed": np.array([1.0]), "sigma": np.array([0.0])}
    with pytest.raises(SimError, match="outside the wire range"):
        pack_stream("odometer", np.array([1]), values, None)
    with pytest.raises(SimError, match="sequence number"):
        pack_stream("odometer", np.array([70000]), {"speed": np.array([1.0]), "sigma": np.array([1.0])}, None)
