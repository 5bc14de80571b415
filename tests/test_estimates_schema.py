"""tools.estimates_schema: the data dictionary, the Parquet file and its metadata, docs/replay.md."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from sfa.layout import REASON_NAMES, FilterStatus
from tools.estimates_schema import (
    COLUMNS,
    REASON_BITS,
    REASONS_COLUMN,
    STATUS_CODES,
    reason_bits,
    write_estimates_parquet,
)
from tools.replay import ESTIMATE_COLUMNS, ReplayResult

DOC = Path(__file__).resolve().parents[1] / "docs" / "replay.md"


def test_dictionary_covers_the_csv_columns_in_order():
    assert tuple(c.name for c in COLUMNS) == ESTIMATE_COLUMNS
    assert set(STATUS_CODES) == {int(s) for s in FilterStatus}
    assert REASON_BITS == {int(b): n for b, n in REASON_NAMES.items()}
    assert reason_bits(("standstill", "gnss_step")) == sum(b for b, n in REASON_BITS.items()
                                                          if n in ("standstill", "gnss_step"))  # fmt: skip


def test_docs_data_dictionary_matches():
    text = DOC.read_text()
    section = text[text.index("## Data dictionary") :]
    for c in (*COLUMNS, REASONS_COLUMN):
        assert re.search(rf"^\| `{c.name}` \| {re.escape(c.unit)} \|", section, re.M), c.name
    for code, (name, _) in STATUS_CODES.items():
        assert re.search(rf"^\| {code} \| {name} \|", section, re.M), name
    for bit, name in REASON_BITS.items():
        assert re.search(rf"^\| {bit} \| `{name}` \|", section, re.M), name


def _result(reasons):
    rng = np.random.default_rng(3)
    n = 50
    est = {c.name: (rng.integers(0, 4, n) if c.dtype == "int64" else rng.normal(size=n)) for c in COLUMNS}
    est = {k: np.asarray(v, dtype=next(c.dtype for c in COLUMNS if c.name == k)) for k, v in est.items()}
    return ReplayResult("x", est, {}, {}, {}, n, 0, reasons=reasons)


@pytest.mark.parametrize("with_reasons", [True, False])
def test_parquet_has_the_csv_columns_units_and_codes(tmp_path, with_reasons):
    pq = pytest.importorskip("pyarrow.parquet")
    reasons = np.arange(50, dtype=np.int64) * 3 if with_reasons else None
    res = _result(reasons)
    path = write_estimates_parquet(res, tmp_path / "e.parquet")
    table = pq.read_table(path)
    assert table.column_names == [*ESTIMATE_COLUMNS, "reasons"]
    for c in COLUMNS:
        assert table.column(c.name).to_numpy().tolist() == res.estimates[c.name].tolist()  # exact
        meta = table.schema.field(c.name).metadata
        assert meta[b"unit"].decode() == c.unit and meta[b"description"].decode() == c.description
    got = table.column("reasons").to_pylist()
    assert got == (reasons.tolist() if with_reasons else [None] * 50)
    md = table.schema.metadata
    assert json.loads(md[b"sfa.status_codes"])["2"]["name"] == "DEGRADED"
    assert json.loads(md[b"sfa.reason_bits"])[str(1 << 10)] == "standstill"
    assert json.loads(md[b"sfa.columns"])["speed"]["unit"] == "m/s"
