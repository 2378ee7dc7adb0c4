"""Keeps perf/bench_fleet_capacity.py from rotting: the smoke profile (a router, two workers,
two vehicles at real rate), checked for shape and completeness, never for speed."""

from __future__ import annotations

import json

import pytest

from perf import bench_fleet_capacity

pytestmark = pytest.mark.zenoh


def test_bench_fleet_capacity_smoke(tmp_path):
    res = bench_fleet_capacity.run("smoke", out_dir=tmp_path)
    data = json.loads((tmp_path / "fleet_capacity_smoke_w2_b1.json").read_text())
    assert data["schema"] == "radical.bench.fleet_capacity/1" and data["workers"] == 2
    r = data["steps"]["2"]
    # every published message has exactly one record in the workers' merged timing
    assert r["node_timing_complete"] and r["records"] == r["messages_published"] > 0
    assert r["node_exit_code"] == 0
    assert r["service_misses"]["n"] > 0 and r["service_ms"]["p50"] > 0
    assert set(r["cpu_pct"]) == {"router", "worker0", "worker1", "driver"}
    assert r["cpu_pct"]["driver"] is not None and r["cpu_pct"]["driver"] > 0
    assert "| 2 |" in bench_fleet_capacity.markdown(res)
