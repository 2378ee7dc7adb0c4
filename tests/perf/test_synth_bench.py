"""Smoke run of perf/bench_synth.py so that the benchmark does not rot."""

from __future__ import annotations

from perf import bench_synth


def test_bench_synth_smoke(tmp_path):
    r = bench_synth.run("smoke", out_dir=tmp_path)
    assert r["profile"] == "smoke" and r["sim_s"] == 60.0
    assert r["wall_s"] > 0 and r["size_bytes"] > 0 and r["messages"] > 0
    assert (tmp_path / "synth_2006216_smoke.mcap").exists()
    row = bench_synth.markdown_row(r)
    assert row.startswith("| smoke | 60 |")
