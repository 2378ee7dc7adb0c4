"""Keeps perf/bench_router.py from rotting: the smoke profile (direct, one router, two chained
routers; a short 100 Hz latency run and two throughput steps each), checked for shape and counts,
never for speed."""

from __future__ import annotations

import json
import math

import pytest

from perf import bench_router

pytestmark = pytest.mark.zenoh


def _check_latency(lat: dict) -> None:
    q = lat["one_way_ms"]
    assert lat["received"] == lat["sent"] == lat["distinct"] == q["n"]  # reliable, no duplicates
    assert all(math.isfinite(q[k]) and q[k] > 0 for k in ("p50", "p99", "p99_9", "max"))
    assert q["p50"] <= q["p99"] <= q["p99_9"] <= q["max"]


def test_bench_router_smoke(tmp_path):
    res = bench_router.run("smoke", out_dir=tmp_path)
    data = json.loads((tmp_path / "router_smoke.json").read_text())
    assert data["schema"] == "radical.bench.router/1"
    assert set(data["topologies"]) == {"direct", "one", "two"}
    for name, topo in data["topologies"].items():
        assert topo["routers"] == {"direct": 0, "one": 1, "two": 2}[name]
        _check_latency(topo["latency"])
        assert [s["target_hz"] for s in topo["throughput"]] == data["rates"]
        for s in topo["throughput"]:
            assert 0 < s["received"] <= s["sent"]
            assert 0 < s["delivered_hz"] <= s["sent_hz"]
            assert s["one_way_ms"]["p50"] <= s["one_way_ms"]["max"]
            assert len([k for k in s["cpu_pct"] if k.startswith("router")]) == topo["routers"]
        assert len(topo["idle_cpu_pct"]) == topo["routers"]
    assert set(data["overhead_ms"]) == {"one_vs_direct", "two_vs_direct", "two_vs_one"}
    assert "direct" in bench_router.markdown(res)
