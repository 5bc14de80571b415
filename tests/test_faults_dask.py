"""The campaign's optional Dask executor on a real (in-process) Dask cluster: same rows as the local one.

Needs the optional extra ``dask`` (``pip install -e '.[dask]'``); skipped with that reason otherwise.
"""

from __future__ import annotations

import pytest
from test_faults_campaign import campaign

from tools.faults.campaign import run_campaign

distributed = pytest.importorskip("distributed", reason="optional extra: pip install -e '.[dask]'")


def _stable(row: dict) -> dict:
    return {k: v for k, v in row.items() if k != "wall_s"}


def test_dask_executor_gives_the_local_rows(tmp_path):
    c = campaign(
        {"name": "clean", "expect": {"crashes": 0, "losses_match": True}},
        {"name": "lossy", "input_link": {"loss": 0.1, "duplicate": 0.02}, "expect": {"losses_match": True}},
        duration_s=8.0,
    )
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
    ) as cluster:
        rows = run_campaign(
            c, "replay", tmp_path / "dask", executor="dask", scheduler=cluster.scheduler_address
        )
    local = run_campaign(c, "replay", tmp_path / "local", jobs=2)
    assert [r["scenario"] for r in rows] == ["clean", "lossy"]
    assert [r["verdict"] for r in rows] == ["PASS", "PASS"], rows
    assert rows[1]["lost_inj"] == rows[1]["lost_det"] > 0
    assert [_stable(r) for r in rows] == [_stable(r) for r in local]  # deterministic: executor-independent
    assert (tmp_path / "dask" / "results.md").exists() and (
        tmp_path / "dask" / "lossy" / "trace.json"
    ).exists()


def test_dask_executor_reports_a_stalled_row(tmp_path):
    # 60 simulated seconds take several wall seconds on the replay path, warm caches or not
    c = campaign({"name": "stalls", "timeout_s": 0.5}, duration_s=60.0)
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        rows = run_campaign(c, "replay", tmp_path, executor="dask", scheduler=cluster.scheduler_address)
    assert rows[0]["verdict"] == "FAIL" and rows[0]["crashes"] == 1
    assert "stalled" in rows[0]["notes"]
