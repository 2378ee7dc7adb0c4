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
    assert res["end_to_end"]["x_realtime"] > 0  # radical process as a new process
    assert "× real time" in bench_engine.markdown(res)
    assert res["wall_s_runs"] == [res["wall_s"]]  # (one pass in the smoke profile)
    runs = {"wall_s_runs": [2.5, 2.4, 2.6]}
    assert bench_engine._spread(runs) == " (2.40–2.60, 3 runs)" and bench_engine._spread({}) == ""


def test_outside_compiled_share_reads_native_stacks():
    """Samples whose frames below the innermost Python frame include Numba's unresolved machine
    code (``0x… (?)``, also when it called malloc) count as compiled; the others do not."""
    py = "main (radical_rt/apps/cli.py:1);release (radical_rt/engine/shell.py:75)"
    collapsed = "\n".join([
        f"{py};0x7f00 (?) 6",  # in a kernel
        f"{py};0x7f00 (?);nrt_allocate (numba/core/runtime/nrt.cpp:1);malloc (libc.so.6) 2",
        f"{py};_trackers_taken (radical_rt/engine/shell.py:116) 1",  # Python
        f"{py};array_dealloc (numpy/_core/x.so) 1",  # numpy called from Python
        "0x7f0 (libc.so.6);gc_collect_main (libpython3.11.so.1.0) 2",
    ])
    assert bench_engine.outside_share(collapsed) == 1.0 - 8 / 12
    assert bench_engine.outside_share("") is None


def test_bench_driver_writes_summary(tmp_path):
    import argparse
    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args(["--profile", "smoke", "--only", "engine", "--out", str(tmp_path)])
    assert run(args) == 0
    summary = json.loads((tmp_path / "summary_smoke.json").read_text())
    assert summary["engine"]["telemetry_s"] == 30.0
    assert (tmp_path / "summary_smoke.md").read_text().startswith("# radical bench")
