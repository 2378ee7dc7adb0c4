"""Keeps perf/bench_kernels.py from rotting: a tiny run, checked for shape, never for speed."""

from __future__ import annotations

import json
import math

import pytest

from perf import bench_kernels

CASES = {"bierman_update", "bierman_update_sparse_st", "structured_time_update",
         "mwgs_time_update_r3", "mwgs_time_update_r26", "agee_turner", "add_diagonal_noise_23"}
TIMING_KEYS = {"best_us", "median_us", "p50_us", "p99_us", "max_us"}


def positive(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x) and x > 0


def check_timing(t) -> None:
    assert set(t) == TIMING_KEYS
    assert all(positive(t[k]) for k in TIMING_KEYS), t


def test_bench_kernels_smoke(tmp_path):
    report = bench_kernels.run("smoke", out_dir=tmp_path)
    path = tmp_path / "kernels_smoke.json"
    assert report["json_path"] == str(path)
    data = json.loads(path.read_text())
    assert data["schema"] == "radical.bench.kernels/1" and data["profile"] == "smoke"
    assert data["n"] == 26
    assert set(data["results"]) == CASES
    for name, row in data["results"].items():
        check_timing(row["ud"])
        check_timing(row["dense_numpy"])
        assert row["check_max_err"] < 1e-8, name
        if row["filterpy"] is not None:
            check_timing(row["filterpy"])
    fp_rows = [data["results"][k]["filterpy"] for k in ("bierman_update", "structured_time_update")]
    assert all(r is not None for r in fp_rows) or data["machine"]["filterpy_error"]
    jit = data["jit"]
    assert positive(jit["cold_compile_s"]) and positive(jit["cache_load_s"])
    assert positive(jit["import_numba_s"])
    for phase in ("cold", "cache"):
        assert set(jit[phase]["first_call_s"]) >= {"bierman_update", "structured_time_update",
                                                   "mwgs_time_update", "agee_turner",
                                                   "add_diagonal_noise"}
        assert all(positive(v) for v in jit[phase]["first_call_s"].values())
    table = bench_kernels.markdown(report)
    assert table.count("\n| ") == len(CASES) + 1 and "cold compile" in table


def test_bench_rejects_unknown_profile(tmp_path):
    with pytest.raises(ValueError, match="profile"):
        bench_kernels.run("huge", out_dir=tmp_path)
