"""Keeps perf/bench_fdi_bank.py from rotting: the smoke profile, checked for shape, never for speed."""

from __future__ import annotations

import json

from perf import bench_fdi_bank


def test_bench_fdi_bank_smoke(tmp_path):
    res = bench_fdi_bank.run("smoke", out_dir=tmp_path)
    assert json.loads((tmp_path / "fdi_bank_smoke.json").read_text())["profile"] == "smoke"
    names = [r["name"] for r in res["rows"]]
    assert names[:2] == ["nominal", "compiled bank"] and "no-op bank" in names
    assert res["gyro"] == 1 and res["bank_trackers"] > 0
    comp = res["rows"][1]
    assert comp["ms_per_s"] > 0.0
    assert any((r.get("us_per_tracker") or 0.0) > 0.0 for r in res["rows"])
    assert res["checks"][0]["ok"] is None  # too short to judge the speed
    assert res["process"]["nominal_s"] > 0.0 and res["process"]["fault_s"] > 0.0
    x = res["process"]["interval_x_nominal"]  # (None when the interval is within one block)
    assert x is None or (x > 0.0 and len(res["process"]["interval_x_nominal_per_rep"]) >= 3)
    alone = res["bank_alone"]  # the bank's recorded samples replayed: the same numbers, bit for bit
    assert alone["replay_equal"] is True and alone["trackers"] == res["bank_trackers"]
    assert alone["decisions_due"] >= 1 and alone["us_per_tracker"] > 0.0
    md = bench_fdi_bank.markdown(res)
    assert "× nominal" in md and "`radical process`" in md and "Bank alone" in md
