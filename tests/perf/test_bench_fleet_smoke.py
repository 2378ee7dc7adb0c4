"""Keeps perf/bench_fleet.py from rotting: the smoke profile (a router, two workers, two
vehicles, one kill and one join), checked for shape, never for speed."""

from __future__ import annotations

import json
import math

import pytest

from perf import bench_fleet

pytestmark = pytest.mark.zenoh


def test_bench_fleet_smoke(tmp_path):
    res = bench_fleet.run("smoke", out_dir=tmp_path)
    data = json.loads((tmp_path / "fleet_smoke.json").read_text())
    assert data["schema"] == "radical.bench.fleet/1" and data["vehicles"] == 2
    assert data["failover_s"]["n"] >= 1
    # one gap per vehicle the joiner took (rendezvous hashing may give it none of the two)
    assert data["handover_gap_s"]["n"] == data["moved_to_joiners"]
    for key in ("failover_s", "handover_gap_s"):
        if data[key]["n"]:
            assert math.isfinite(data[key]["max"]) and data[key]["max"] > 0
    assert data["lost_s"]["n"] == data["failover_s"]["n"]  # every crash takeover counted a loss
    assert "failover" in bench_fleet.markdown(res)
