"""Keeps perf/bench_fleet_discovery.py from rotting: 3 vehicles for 1.5 s per row, checked for
shape and completeness (the discoverer sees every vehicle; the idle one subscribes to nothing),
never for speed."""

from __future__ import annotations

import pytest

from perf import bench_fleet_discovery

pytestmark = pytest.mark.zenoh


def test_bench_fleet_discovery_smoke():
    res = bench_fleet_discovery.run(3, 1.5, ["temp"])
    idle, temp = res["rows"]
    assert idle["topic"] is None and idle["samples"] == 0 and idle["discovered"] == 0
    assert temp["topic"] == "temp" and temp["samples"] > 0 and temp["discovered"] == 3
    assert temp["us_per_msg"] is not None and set(temp) >= {"msgs_per_s", "cpu_pct"}
