"""Smoke test of the engine benchmark and the `radical bench` driver (tiny workload; no timing asserted)."""

import json
import math

from perf import bench_engine
from perf.cli import add_arguments, run


def test_engine_bench_reports_finite_figures(tmp_path):
    res = bench_engine.run("smoke", tmp_path)
    for key in ("wall_s", "x_realtime", "us_per_gyro_sample", "warmup_s"):
        assert math.isfinite(res[key]) and res[key] > 0, key
    assert res["siru_samples"] > 2500  # 30 s at 100 Hz, less repeats/misses
    assert json.loads((tmp_path / "engine_smoke.json").read_text())["bench"] == "engine"
    assert "× real time" in bench_engine.markdown(res)


def test_bench_driver_writes_summary(tmp_path):
    import argparse
    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args(["--profile", "smoke", "--only", "engine", "--out", str(tmp_path)])
    assert run(args) == 0
    summary = json.loads((tmp_path / "summary_smoke.json").read_text())
    assert summary["engine"]["telemetry_s"] == 30.0
    assert (tmp_path / "summary_smoke.md").read_text().startswith("# radical bench")
