"""Synthesized archives: round trip, schema validation, log times, metadata, determinism,
chunking invariance, data gaps and split archives, truth channels."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from radical_rt.contract.conventions import DEG_PER_HR
from radical_rt.contract.schemas import validate
from radical_rt.io.archive import ArchiveReader
from replayer.synth import synthesize

FAULTS = [
    {"kind": "bias_step", "gyro": 0, "start_s": 20.0, "end_s": 40.0, "bias_deg_hr": 5.0},
    {"kind": "invalid_status", "gyro": 3, "start_s": 10.0, "end_s": 11.0},
    {"kind": "gap", "start_s": 50.0, "end_s": 57.5},
]
SCEN = {"base": "2006216", "duration_s": 90.0, "faults": FAULTS,
        "siru": {"eps_ppm": 400.0, "tt_reset_s": [70.0]}}


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    path = tmp_path_factory.mktemp("synth") / "a.mcap"
    res = synthesize(SCEN, path)
    return res, list(ArchiveReader(path).iter_messages())


def test_round_trip_and_schemas(archive):
    res, msgs = archive
    errors = [e for topic, _, m in msgs for e in validate(topic, m)]
    assert errors == []
    counts: dict[str, int] = {}
    for topic, _, _ in msgs:
        counts[topic] = counts.get(topic, 0) + 1
    assert counts == res.message_counts
    assert set(counts) == {"/siru", "/st1", "/st2", "/temp", "/truth/attitude", "/truth/params",
                           "/truth/siru_time"}
    assert ArchiveReader(res.path).message_counts == counts


def test_log_times_are_bus_times_in_order(archive):
    _, msgs = archive
    ns = [n for _, n, _ in msgs]
    assert ns == sorted(ns)
    for topic, n, m in msgs:
        t = m.get("t_bus")
        t = t[-1] if isinstance(t, list) else t
        assert n == round(t * 1e9), topic


def test_gap_has_no_messages_and_counts_include_it(archive):
    res, msgs = archive
    assert not any(50e9 <= n < 57.5e9 for _, n, _ in msgs)
    siru_rows = sum(len(m["tt"]) for t, _, m in msgs if t == "/siru")
    truth_rows = sum(len(m["tt"]) for t, _, m in msgs if t == "/truth/siru_time")
    c = res.truth_counts[0]
    assert c["n_reads"] == siru_rows and c["n_samples"] == truth_rows
    assert c["n_missing"] >= 740  # the ~750 samples of the 7.5 s gap were never read
    status = [(t0, s) for t, _, m in msgs if t == "/siru" for t0, s in zip(m["t_bus"], m["status"], strict=True)]
    assert {s for t0, s in status if 10.01 < t0 < 11.0} == {8}
    assert {s for t0, s in status if t0 < 9.99 or t0 > 11.02} == {0}


def test_metadata(archive):
    res, _ = archive
    meta = ArchiveReader(res.path).scenario
    assert meta["name"] == "2006216" and meta["vehicle"] == "messenger"
    assert meta["seed"] == "2006216" and meta["generator"].startswith("radical-rt synth")
    counts = json.loads(meta["truth_counts"])
    assert counts == res.truth_counts[0]
    assert all(meta[k] == str(v) for k, v in counts.items())
    assert json.loads(meta["truth_params_paper_units"])["lam"] == [326.4, -261.4, 602.8, 358.7]
    assert "[siru]" in meta["scenario_toml"]


def test_truth_params_include_faults(archive):
    res, msgs = archive
    par = [m for t, _, m in msgs if t == "/truth/params"]
    b0 = res.scenario.truth["b"][0]
    for m in par:
        step = 5.0 * DEG_PER_HR if 20.0 <= m["t_bus"] < 40.0 else 0.0
        assert m["b"][0] == pytest.approx(b0 + step, abs=1e-10)  # bias walk ≪ 1e-10 rad/s
        assert m["lam"] == pytest.approx(res.scenario.truth["lam"].tolist(), abs=0)
    att = [m for t, _, m in msgs if t == "/truth/attitude"]
    assert len(att) == 10 * (90 - 7.5)


def test_same_seed_same_bytes_other_seed_differs(tmp_path, archive):
    res, _ = archive
    again = synthesize(SCEN, tmp_path / "b.mcap")
    assert Path(res.path).read_bytes() == again.path.read_bytes()
    other = synthesize(SCEN, tmp_path / "c.mcap", seed=7)
    assert other.path.read_bytes() != again.path.read_bytes()


def test_chunk_size_does_not_change_messages(tmp_path, archive):
    res, msgs = archive
    small = synthesize({**SCEN, "output": {"chunk_s": 3.0}}, tmp_path / "s.mcap")
    assert list(ArchiveReader(small.path).iter_messages()) == msgs
    assert small.truth_counts == res.truth_counts


def test_split_at_gaps(tmp_path, archive):
    _, msgs = archive
    res = synthesize({**SCEN, "output": {"split_at_gaps": True}}, tmp_path / "p.mcap")
    assert [p.name for p in res.paths] == ["p.part1.mcap", "p.part2.mcap"]
    parts = [list(ArchiveReader(p).iter_messages()) for p in res.paths]
    assert parts[0][-1][1] < 50e9 <= 57.5e9 <= parts[1][0][1]
    assert parts[0] + parts[1] == msgs  # the same stream, cut in two
    for p, c in zip(res.paths, res.truth_counts, strict=True):
        meta = ArchiveReader(p).scenario
        assert json.loads(meta["truth_counts"]) == c
    assert res.truth_counts[1]["n_missing"] < 5  # counting restarts in each part
    siru2 = {v for t, _, m in parts[1] if t == "/siru" for v in m["tt"]}
    truth2 = {v for t, _, m in parts[1] if t == "/truth/siru_time" for v in m["tt"]}
    assert siru2 <= truth2


def test_truth_channels_can_be_disabled(tmp_path):
    res = synthesize({"base": "2006216", "duration_s": 5.0, "output": {"truth": False},
                      "trackers": {"st2": False}}, tmp_path / "n.mcap")
    assert set(res.message_counts) == {"/siru", "/st1", "/temp"}
    assert np.isfinite(res.file_size) and res.file_size > 0


def test_nonzero_start_time(tmp_path):
    faults = [{"kind": "bias_step", "gyro": 2, "start_s": 5.0, "end_s": 6.0, "bias_deg_hr": 1.0}]
    res = synthesize({"base": "2006216", "duration_s": 12.0, "t_start_s": 1000.0,
                      "faults": faults, "maneuver": {"start_s": 2.0}}, tmp_path / "t.mcap")
    msgs = list(ArchiveReader(res.path).iter_messages())
    assert 1000e9 <= msgs[0][1] and msgs[-1][1] < 1012.01e9
    par = [m for t, _, m in msgs if t == "/truth/params"]
    b0 = res.scenario.truth["b"][2]
    steps = [m["t_bus"] for m in par if abs(m["b"][2] - b0) > 0.5 * DEG_PER_HR]
    assert steps == [1005.0]
    att = [m for t, _, m in msgs if t == "/truth/attitude"]
    w = {round(m["t_bus"], 1): m["omega_body"] for m in att}
    assert w[1001.0] == [0, 0, 0] and w[1010.0][0] > 0  # the +10° x slew starts 2 s in
