"""SIRU oscillator and bus reads: sawtooth period T/|ε|, repeat/miss spates, counter wrap and
reset, chunking invariance, and the counters of an archive against its own bus stream + truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from radical_rt.io.archive import ArchiveReader
from replayer.synth import load_scenario, synthesize
from replayer.synth.clock import BusReads, SiruClock, latest_sample, read_counts
from replayer.synth.simulator import stream

WRAP = 2**32


def siru_cfg(**over):
    return load_scenario({"base": "2006216", "siru": over}).cfg["siru"]


def simulate(cfg, duration, seed=1, step=None):
    """Bus reads over `duration` s: (samples, tau (n,), index of the sample each read returns)."""
    clock = SiruClock(cfg, 0.0, stream(seed, "clock"))
    reads = BusReads(cfg, 0.0, stream(seed, "reads"))
    n = int(round(duration / cfg["bus_period_s"]))
    step = step or n
    taus, parts = [], []
    for j0 in range(0, n, step):
        tau = reads.times(j0, min(j0 + step, n))
        taus.append(tau)
        parts.append(clock.take_through(float(tau[-1])))
    smp = type(parts[0])(*(np.concatenate(c) for c in zip(*parts, strict=True)))
    tau = np.concatenate(taus)
    return smp, tau, latest_sample(smp.t, tau)


def wrap_times(tau, e, period):
    """Times where the tag error jumps by more than half a period (sawtooth wraps)."""
    return tau[1:][np.abs(np.diff(e)) > period / 2]


@pytest.mark.parametrize("eps_ppm", [40.0, 100.0, -40.0, -250.0])
def test_sawtooth_without_jitter(eps_ppm):
    cfg = siru_cfg(eps_ppm=eps_ppm, sample_jitter_s=0.0, read_jitter_s=0.0)
    smp, tau, pos = simulate(cfg, 1500.0)
    assert np.all(pos >= 0)
    T, eps = 0.01, eps_ppm * 1e-6
    e = tau - smp.t[pos]
    assert np.all((e >= 0) & (e < T * (1 + eps) + 1e-12))
    # slope of the sawtooth: −ε·T per read (ε > 0: the tag error shrinks)
    assert np.median(np.diff(e)) == pytest.approx(-eps * T, abs=1e-12)
    w = wrap_times(tau, e, T)
    # period T(1+ε)/|ε| ≈ T/|ε|, measured on reads 10 ms apart
    assert np.diff(w) == pytest.approx(T * (1 + eps) / abs(eps), abs=0.0101)
    n, rep, miss = read_counts(smp.k[pos], None)
    assert (rep, miss) == ((w.size, 0) if eps > 0 else (0, w.size))


@pytest.mark.parametrize("eps_ppm", [40.0, -60.0])
def test_jitter_gives_spates_at_each_wrap(eps_ppm):
    jit = siru_cfg(eps_ppm=eps_ppm)  # defaults: read jitter 20 µs, sample jitter 1 µs
    smp, tau, pos = simulate(jit, 2000.0)
    quiet = siru_cfg(eps_ppm=eps_ppm, sample_jitter_s=0.0, read_jitter_s=0.0)
    smp0, tau0, pos0 = simulate(quiet, 2000.0)
    nominal = wrap_times(tau0, tau0 - smp0.t[pos0], 0.01)
    k = smp.k[pos]
    n, rep, miss = read_counts(k, None)
    eps = eps_ppm * 1e-6
    assert rep - miss == pytest.approx(2000.0 * eps / 0.01, abs=1.01)  # net = number of wraps
    assert min(rep, miss) > nominal.size  # spates: several repeat/miss pairs per wrap
    d = np.diff(k)
    events = tau[1:][d != 1]
    # every event lies near a nominal wrap (read jitter 20 µs over a drift of |ε| s/s)
    width = 8 * np.hypot(jit["read_jitter_s"] * np.sqrt(2), jit["sample_jitter_s"]) / abs(eps)
    dist = np.min(np.abs(events[:, None] - nominal[None, :]), axis=1)
    assert np.all(dist < width)
    # and every nominal wrap has events
    assert np.all(np.min(np.abs(nominal[:, None] - events[None, :]), axis=1) < width)


def test_counter_wraps_modulo_2_32():
    cfg = siru_cfg(tt0=WRAP - 10000 * 300)
    smp, _, _ = simulate(cfg, 10.0)
    assert smp.tt.min() >= 0 and smp.tt.max() < WRAP
    assert np.all(np.diff(smp.tt) % WRAP == 10000)
    assert np.sum(np.diff(smp.tt) < 0) == 1
    assert smp.tt[smp.k == 300][0] == 0


def test_counter_reset():
    cfg = siru_cfg(tt0=123456, tt_reset_s=[3.0, 7.5])
    smp, _, _ = simulate(cfg, 10.0, step=37)
    assert smp.reset.sum() == 2
    for r in (3.0, 7.5):
        i = int(np.argmax(smp.t >= r))
        assert smp.reset[i] and smp.tt[i] == 0 and smp.t[i - 1] < r
        assert smp.tt[i + 1] == 10000
    assert smp.tt[0] == 123456


def test_chunking_does_not_change_the_clock():
    cfg = siru_cfg(eps_ppm=-80.0, tt_reset_s=[2.345])
    a = simulate(cfg, 20.0)
    b = simulate(cfg, 20.0, step=7)
    for x, y in zip(a[0], b[0], strict=True):
        assert np.array_equal(x, y)
    assert np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])


def _read_archive(path):
    r = ArchiveReader(path)
    siru = [m for _, _, m in r.iter_messages(topics=["/siru"])]
    truth = [m for _, _, m in r.iter_messages(topics=["/truth/siru_time"])]
    cols = {k: np.concatenate([m[k] for m in siru]) for k in ("t_bus", "tt", "dtheta", "status")}
    tr = {k: np.concatenate([m[k] for m in truth]) for k in ("tt", "t_true")}
    return r, cols, tr


def test_archive_counters_match_bus_stream_and_truth(tmp_path):
    siru = {"eps_ppm": 200.0, "read_jitter_s": 5e-5, "tt0": WRAP - 10000 * 4000,
            "tt_reset_s": [150.0]}
    res = synthesize({"base": "2006216", "duration_s": 240.0, "siru": siru}, tmp_path / "c.mcap")
    r, s, tr = _read_archive(res.path)
    meta = r.scenario
    counts = json.loads(meta["truth_counts"])
    assert counts == res.truth_counts[0]
    assert all(meta[k] == str(v) for k, v in counts.items())
    # map each read to its sample: walk the truth sequence (tt repeats after the reset)
    idx = np.empty(s["tt"].size, dtype=int)
    p = 0
    for i, v in enumerate(s["tt"].tolist()):
        while tr["tt"][p] != v:
            p += 1
        idx[i] = p
    n, rep, miss = read_counts(idx, None)
    assert (n, rep, miss) == (counts["n_reads"], counts["n_repeated"], counts["n_missing"])
    assert counts["n_samples"] == tr["tt"].size
    assert counts["n_tt_wraps"] == 1 and counts["n_tt_resets"] == 1
    # a repeat is the same sample: same tt, same data
    same = np.diff(idx) == 0
    assert np.array_equal(s["dtheta"][1:][same], s["dtheta"][:-1][same])
    assert rep > 0 and miss > 0
    # sawtooth from the archive: tag error t_bus − t_true in [0, 10 ms] (± jitter), period T/ε
    e = s["t_bus"] - tr["t_true"][idx]
    assert e.min() > -4 * 5e-5 and e.max() < 0.01 * (1 + 2e-4) + 4 * 5e-5
    jumps = s["t_bus"][1:][np.diff(e) > 0.005]
    clusters = jumps[np.concatenate([[True], np.diff(jumps) > 10.0])]
    assert np.diff(clusters) == pytest.approx(0.01 / 200e-6, abs=2.0)
    # counting from /siru alone: Δtt mod 2**32 handles the wrap; the reset is one odd jump
    dtt = np.diff(s["tt"]) % WRAP
    assert np.sum(dtt == 0) == rep
    assert np.all(dtt % 10000 == 0) or np.sum(dtt % 10000 != 0) == 1
    normal = (dtt > 0) & (dtt < 10**8)
    assert np.sum(~normal & (dtt > 0)) == 1  # the reset
    assert int(np.sum(dtt[normal] // 10000 - 1)) <= miss
