"""The data dictionary of ``estimates.csv`` / ``estimates.parquet``: columns, units, status codes, reasons.

One table, used by the Parquet writer (field and schema metadata), the HTML report's dictionary and
docs/replay.md (tests/test_estimates_schema.py checks the page against it). ``estimates.csv`` keeps
its columns and header exactly (docs/replay.md; /interfaces: at least ``epoch,arc_length``); units
live here, not in the header, so existing readers keep working.

Parquet needs pyarrow, an optional extra (``pip install sfa-positioning[parquet]``): the CSV is the
interface and the train never needs Parquet, while pyarrow is a large wheel. Without it the replay
writes the CSV and says that the Parquet file was skipped.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sfa.layout import REASON_NAMES, FilterStatus


@dataclass(frozen=True)
class Column:
    name: str
    unit: str  #: SI unit, "deg" (WGS84), or "-" (a count or a code)
    dtype: str  #: Parquet / numpy type
    description: str


COLUMNS: tuple[Column, ...] = (
    Column("epoch", "s", "float64", "sensor-set time the estimate refers to (OUTPUT EPOCH)"),
    Column("arc_length", "m", "float64", "estimated arc length on line_id (OUTPUT FU_ARC_LEN)"),
    Column("seq", "-", "int64", "OUTPUT SEQ, 0..65535, wraps"),
    Column("retransmit", "-", "int64", "1: a resend of an earlier estimate (same SEQ), 0: a new estimate"),
    Column("arrival", "s", "float64", "capture time at which the listener sent it (listener host clock)"),
    Column("speed", "m/s", "float64", "estimated speed, signed, > 0 in the train's forward direction"),
    Column("sigma", "m", "float64", "1-sigma of arc_length"),
    Column("interval_low", "m", "float64",
           "lower bound of the confidence interval on arc_length (95 %; 99 % while a sensor is faulty)"),
    Column("interval_high", "m", "float64", "upper bound of the confidence interval on arc_length"),
    Column("status", "-", "int64", "filter status code (see status codes)"),
    Column("line_id", "-", "int64", "track database line of the estimate, -1 unknown"),
    Column("lat", "deg", "float64", "WGS84 latitude of the estimate"),
    Column("lon", "deg", "float64", "WGS84 longitude of the estimate"),
)  # fmt: skip
"""The columns of estimates.csv, in its order."""

REASONS_COLUMN = Column(
    "reasons", "-", "uint32",
    "reason bits of the status (see reason bits); null where not recorded",
)  # fmt: skip
"""Parquet only: appended after the CSV's columns."""

STATUS_CODES: dict[int, tuple[str, str]] = {
    int(FilterStatus.INITIALISING): ("INITIALISING", "no GROUND TRUTH (or other initialisation) yet"),
    int(FilterStatus.NOMINAL): ("NOMINAL", "all sensors timely, no fault declared, sigma small"),
    int(FilterStatus.DEGRADED): ("DEGRADED", "usable, but a sensor is missing or faulty, or sigma is high"),
    int(FilterStatus.LOST): ("LOST", "the interval is too wide to be useful, or no motion sensor is left"),
}
REASON_BITS: dict[int, str] = {int(bit): name for bit, name in REASON_NAMES.items()}
_BIT_OF_NAME = {name: bit for bit, name in REASON_BITS.items()}


def reason_bits(names) -> int:
    """The bit mask of reason names (``Estimate.reasons``)."""
    bits = 0
    for name in names:
        bits |= _BIT_OF_NAME.get(name, 0)
    return bits


def dictionary_metadata() -> dict[str, str]:
    """Schema-level metadata of the Parquet file (JSON strings)."""
    return {
        "sfa.columns": json.dumps({c.name: {"unit": c.unit, "description": c.description}
                                   for c in (*COLUMNS, REASONS_COLUMN)}),  # fmt: skip
        "sfa.status_codes": json.dumps(
            {str(k): {"name": n, "meaning": m} for k, (n, m) in STATUS_CODES.items()}
        ),
        "sfa.reason_bits": json.dumps({str(k): v for k, v in REASON_BITS.items()}),
        "sfa.docs": "docs/replay.md, 'Data dictionary'",
    }


def write_estimates_parquet(result, path: str | Path) -> Path | None:
    """Write ``estimates.parquet`` (the CSV's columns, then ``reasons``); None if pyarrow is missing."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None
    est = result.estimates
    arrays, fields = [], []
    for c in COLUMNS:
        arrays.append(pa.array(np.asarray(est[c.name], dtype=c.dtype)))
        fields.append(pa.field(c.name, pa.from_numpy_dtype(np.dtype(c.dtype)),
                               metadata={"unit": c.unit, "description": c.description}))  # fmt: skip
    reasons = getattr(result, "reasons", None)
    n = int(np.asarray(est["epoch"]).size)
    if reasons is None:
        arrays.append(pa.nulls(n, type=pa.uint32()))
    else:
        arrays.append(pa.array(np.asarray(reasons, dtype=np.uint32)))
    c = REASONS_COLUMN
    fields.append(pa.field(c.name, pa.uint32(), metadata={"unit": c.unit, "description": c.description}))
    table = pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata=dictionary_metadata()))
    pq.write_table(table, str(path))
    return Path(path)
