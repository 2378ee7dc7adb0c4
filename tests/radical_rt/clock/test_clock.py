"""SIRU clock (radical_rt.clock.siru_clock): sequence repair, counters, timing, determinism, checkpoints.

The reads come from an independent generator of the CONTRACT §1.5 mechanism (neither
replayer.synth's code nor the engine's; tests/support/clock_reads.py): SIRU sample k at
t0 + k T (1 + ε) + jitter, counter (tt0 + 10000 k) mod 2**32, bus reads at the bus's 100 Hz ticks
(with jitter) that get the latest sample taken at or before them.
"""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radical_rt.clock.clock_config import ClockConfig
from radical_rt.clock.siru_clock import COUNTER_NAMES, GyroBatch, SiruClock
from tests.support.clock_reads import (
    WRAP,
    Reads,
    T,
    assert_counts,
    make_reads,
    run,
    run_tt,
    time_errors,
)


# ---------------------------------------------------------------- counts and repair
@pytest.mark.parametrize("eps_ppm,read_jitter,phase,seed", [
    (40.0, 20e-6, 0.0043, 1), (-60.0, 20e-6, 0.0043, 2), (100.0, 1e-4, 0.0043, 3),
    (-15.0, 0.0, 0.0043, 4), (10.0, 2e-4, 0.0097, 5)])
def test_repeats_and_misses_counted_exactly(eps_ppm, read_jitter, phase, seed):
    r = make_reads(40000, eps_ppm=eps_ppm, read_jitter=read_jitter, phase=phase, seed=seed)
    assert r.repeated > 0 or r.missing > 0
    clock = SiruClock()
    b = run(clock, r)
    c = clock.counters
    assert_counts(c, r)
    assert c["bridged"] == c["missing"] and int(b.bridged.sum()) == c["bridged"]
    assert len(b.t) == r.distinct + r.missing
    assert c["anomalies"] == 0 and c["gaps"] == 0 and c["unexplained"] == 0
    # every distinct sample's increments come out once, in order
    k_first = r.k[np.r_[True, np.diff(r.k) > 0]]
    np.testing.assert_array_equal(b.dtheta[~b.bridged], r.dth_true[k_first])
    # repeats and misses balance to one per sawtooth wrap
    assert c["tag_wraps"] == abs(r.repeated - r.missing)


def test_bridge_interpolates_neighbours():
    cfg = ClockConfig(max_bridge=3, bridge_accel_sigma_rad_s2=2e-3)
    clock = SiruClock(cfg)
    ks = [0, 1, 3, 4, 7, 8]  # one miss (2), then two (5, 6)
    tau = 50.0 + 0.0051 + T * np.array(ks)  # the bus skips ticks
    tt = 10000 * np.array(ks, np.int64)
    dth = np.arange(24, dtype=float).reshape(6, 4) * 1e-6
    status = np.array([0, 1, 2, 0, 4, 0])
    b = run(clock, Reads(tau, tt, dth, status, np.array(ks), np.zeros(9), np.zeros((9, 4))))
    assert list(b.bridged) == [False, False, True, False, False, True, True, False, False]
    np.testing.assert_allclose(b.dtheta[2], 0.5 * (dth[1] + dth[2]), rtol=0, atol=1e-18)
    np.testing.assert_allclose(b.dtheta[5], (2 * dth[3] + dth[4]) / 3, rtol=0, atol=1e-18)
    np.testing.assert_allclose(b.dtheta[6], (dth[3] + 2 * dth[4]) / 3, rtol=0, atol=1e-18)
    assert b.status[2] == 1 | 2 and b.status[5] == 4 and b.status[6] == 4
    v1 = (2e-3 * T * T) ** 2
    np.testing.assert_allclose(b.var_extra[[2, 5, 6]], [v1, v1, v1], rtol=1e-3)
    assert np.all(b.var_extra[~b.bridged] == 0)
    assert clock.counters["missing"] == 3 and clock.counters["bridged"] == 3
    np.testing.assert_allclose(np.diff(b.t), b.dt[1:], rtol=0, atol=1e-12)


def test_long_miss_run_is_a_gap_not_bridged():
    r = make_reads(3000, eps_ppm=0.0, read_jitter=0.0, seed=7)
    keep = np.ones(len(r.t_bus), bool)
    keep[1000:1010] = False  # the bus reads nothing for 0.1 s: 10 samples never received
    r = r.cut(keep)
    clock = SiruClock(ClockConfig(max_bridge=3))
    b, _, flags = run_tt(clock, r)
    c = clock.counters
    assert c["missing"] == 10 and c["gaps"] == 1 and c["bridged"] == 0
    assert not b.bridged.any() and len(b.t) == r.distinct
    i = int(np.argmax(b.dt))
    assert b.dt[i] == pytest.approx(11 * T, abs=1e-5)
    # a dropout consistent in tt and bus time is no clock anomaly: the engine flags GYRO_GAP
    assert c["anomalies"] == 0 and not any(f for _, f in flags)
    assert not flags[-1][1]  # cleared after the hold time


# ---------------------------------------------------------------- counter wrap, reset
def test_tt_counter_wrap():
    r = make_reads(30000, eps_ppm=100.0, tt0=WRAP - 10000 * 12000 - 77, seed=8)
    assert np.any(np.diff(r.tt) < 0)
    clock = SiruClock()
    b = run(clock, r)
    c = clock.counters
    assert_counts(c, r)
    assert c["wraps"] == 1 and c["resets"] == 0 and c["anomalies"] == 0
    err = time_errors(b, r)
    assert np.sqrt(np.mean(err[-10000:] ** 2)) < 10e-6


@pytest.mark.parametrize("reset_at,drop_after_reset", [(150.0037, 0), (150.0037, 2)])
def test_counter_reset(reset_at, drop_after_reset):
    r = make_reads(30000, eps_ppm=-100.0, tt0=123456789, reset_at=reset_at, seed=9)
    if drop_after_reset:  # the first reads after the reset are lost: tt restarts above 0
        i = int(np.flatnonzero(r.tt < 123456789)[0])
        keep = np.ones(len(r.t_bus), bool)
        keep[i:i + drop_after_reset] = False
        r = r.cut(keep)
    clock = SiruClock()
    b, _, flags = run_tt(clock, r)
    c = clock.counters
    assert_counts(c, r)
    assert c["resets"] == 1 and c["wraps"] == 0 and c["tt_glitches"] == 0
    raised = [t for t, f in flags if f]
    assert raised and min(raised) >= 1000 + reset_at and max(raised) < 1000 + reset_at + 1.5
    assert not clock.anomaly
    err = time_errors(b, r)
    assert np.sqrt(np.mean(err[-5000:] ** 2)) < 10e-6


# ---------------------------------------------------------------- glitches and jumps
def test_bus_time_outlier_is_ignored():
    r = make_reads(30000, eps_ppm=80.0, seed=10)
    clean = SiruClock()
    b0 = run(clean, r)
    for j, dt in ((20000, 0.37), (21000, -0.0042), (22000, 3.1e-3)):
        r.t_bus[j] += dt
    clock = SiruClock()
    b, _, flags = run_tt(clock, r)
    c = clock.counters
    assert_counts(c, r)
    assert c["tbus_glitches"] >= 2 and c["anomalies"] >= 2 and any(f for _, f in flags)
    err, err0 = time_errors(b, r), time_errors(b0, r)
    assert np.max(np.abs(err[20000:] - err0[20000:])) < 5e-6  # the fit is not corrupted


def test_tt_glitch_read_is_dropped():
    r = make_reads(30000, eps_ppm=80.0, seed=11)
    j = 25000
    assert r.k[j + 1] == r.k[j] + 1 and r.k[j - 1] == r.k[j] - 1
    r.tt[j] = (r.tt[j] + 1_234_567) % WRAP  # not a whole number of samples
    clock = SiruClock()
    b = run(clock, r)
    c = clock.counters
    assert c["tt_glitches"] == 1 and c["anomalies"] >= 1 and c["resets"] == 0
    # the garbled read's sample was never received: it is bridged
    assert c["missing"] == r.missing + 1 and c["repeated"] == r.repeated
    assert c["samples"] == r.distinct - 1
    err = time_errors(b, r.cut(np.arange(len(r.t_bus)) != j))
    assert np.sqrt(np.mean(err[-4000:] ** 2)) < 10e-6


def test_bus_clock_jump_reacquires():
    r = make_reads(60000, eps_ppm=100.0, seed=12)
    j = 30000
    jump = 0.2537  # not a whole number of bus periods
    r.t_bus[j:] += jump
    t_true = r.t_true.copy()
    t_true[r.k[j]:] += jump  # sample times on the (jumped) bus time line
    r = Reads(r.t_bus, r.tt, r.dtheta, r.status, r.k, t_true, r.dth_true)
    clock = SiruClock()
    b = run(clock, r)
    c = clock.counters
    assert_counts(c, r)
    assert c["time_jumps"] == 1 and c["anomalies"] >= 1
    err = time_errors(b, r)
    assert np.sqrt(np.mean(err[-10000:] ** 2)) < 10e-6  # locked again after the next wraps


def test_skipped_tick_is_nominal_and_a_tick_slip_is_an_anomaly():
    r = make_reads(30000, eps_ppm=100.0, seed=13)
    clock = SiruClock()
    run(clock, r.cut(np.arange(len(r.t_bus)) < 25000))
    assert clock.locked and clock.counters["unexplained"] == 0
    # far from a wrap the bus skips a tick: one sample is missed, consistently in tt and bus time
    e = r.t_bus - r.t_true[r.k]
    j = 25000 + int(np.flatnonzero((e[25000:] > 0.004) & (e[25000:] < 0.006))[0])
    assert np.all((e[j:j + 400] > 0.002) & (e[j:j + 400] < 0.008))
    keep = np.ones(len(r.t_bus), bool)
    keep[:25000] = False
    keep[j] = False
    assert r.k[j + 1] == r.k[j - 1] + 2
    r2 = r.cut(keep)
    i = int(np.searchsorted(r2.t_bus, r.t_bus[j + 300]))
    before = clock.counters
    run(clock, Reads(r2.t_bus[:i], r2.tt[:i], r2.dtheta[:i], r2.status[:i], r2.k[:i], r.t_true,
                     r.dth_true))
    c = clock.counters
    k_seen = np.r_[r.k[24999], r2.k[:i]]
    assert c["anomalies"] == 0 and clock.locked
    assert c["missing"] == before["missing"] + int(np.maximum(np.diff(k_seen) - 1, 0).sum())
    # then a sample is read twice and the tags slip by one bus tick: the time line is broken
    tb = np.insert(r2.t_bus[i:], 1, r2.t_bus[i] + T)
    tb[2:] += T  # keep the bus ticks regular after the inserted read
    clock.push(tb, np.insert(r2.tt[i:], 1, r2.tt[i]), np.insert(r2.dtheta[i:], 1, r2.dtheta[i],
               axis=0), np.insert(r2.status[i:], 1, 0))
    assert clock.counters["anomalies"] >= 1


def test_repeat_with_different_data_is_an_anomaly():
    r = make_reads(8000, eps_ppm=100.0, read_jitter=1e-4, seed=14)
    j = int(np.flatnonzero(np.diff(r.k) == 0)[0]) + 1
    r.dtheta[j, 2] += 1e-7
    clock = SiruClock()
    run(clock, r)
    assert clock.counters["repeat_mismatch"] == 1 and clock.counters["repeated"] == r.repeated


def test_bad_values():
    r = make_reads(3000, eps_ppm=30.0, seed=15)
    r.t_bus[100] = np.nan
    r.dtheta[200, 1] = np.inf
    clock = SiruClock()
    b = run(clock, r)
    c = clock.counters
    assert c["rejected"] == 1
    assert c["samples"] + c["missing"] == len(b.t)
    i = int(np.flatnonzero(b.status)[0])
    assert b.status[i] == 2 and b.dtheta[i, 1] == 0.0 and np.all(np.isfinite(b.dtheta))
    with pytest.raises(ValueError):
        clock.push([1.0, 2.0], [0], np.zeros((2, 4)), [0, 0])
    with pytest.raises(ValueError):
        SiruClock(ClockConfig(mode="fast"))


# ---------------------------------------------------------------- timing
def test_startup_before_first_wrap_is_uniform_then_locks():
    r = make_reads(40000, eps_ppm=50.0, phase=0.003, seed=16)  # first wrap after ~140 s
    clock = SiruClock()
    b0 = clock.push(r.t_bus[:100], r.tt[:100], r.dtheta[:100], r.status[:100])
    tel = clock.telemetry()
    assert not tel["locked"] and tel["tag_error_sigma_s"] == pytest.approx(T / math.sqrt(12), 0.2)
    b1 = run(clock, r.cut(np.arange(len(r.t_bus)) >= 100))
    b = GyroBatch(*(np.concatenate([getattr(b0, f), getattr(b1, f)]) for f in GyroBatch._fields))
    err = time_errors(b, r)
    t = r.t_true[r.k[np.r_[True, np.diff(r.k) > 0]]]
    pre = t < 1000 + 130
    assert np.max(np.abs(err[pre])) <= T / 2 + 1e-4  # the band's middle
    assert np.std(err[pre]) > 1e-3  # not locked: the sawtooth shows through
    assert np.sqrt(np.mean(err[-5000:] ** 2)) < 5e-6  # after the second wrap (at ~340 s)
    tel = clock.telemetry()
    assert tel["locked"] and tel["freq_offset_ppm"] == pytest.approx(50.0, abs=0.05)
    assert tel["tag_error_sigma_s"] < 20e-6
    assert np.all(np.diff(b.t) > 0) and np.all(b.dt > 0)


@pytest.mark.parametrize("eps_ppm", [-100.0, -30.0, 30.0, 100.0])
def test_reconstruction_accuracy_vs_naive(eps_ppm):
    r = make_reads(100000, eps_ppm=eps_ppm, seed=17)
    rec, nai = SiruClock(), SiruClock(ClockConfig(mode="naive"))
    b, bn = run(rec, r), run(nai, r)
    err, err_n = time_errors(b, r), time_errors(bn, r)
    assert 2.6e-3 < np.std(err_n) < 3.2e-3  # the 0–10 ms sawtooth
    late = slice(len(err) - 20000, None)  # locked (at least two wraps in)
    assert np.sqrt(np.mean(err[late] ** 2)) < np.std(err_n) / 50
    assert np.max(np.abs(err[late])) < 20e-6
    # naive and reconstruct differ only in timing
    for f in ("dtheta", "status", "bridged", "var_extra"):
        np.testing.assert_array_equal(getattr(b, f), getattr(bn, f))
    assert rec.counters == nai.counters
    t_first = r.t_bus[np.r_[True, np.diff(r.k) > 0]]
    np.testing.assert_array_equal(bn.t[~bn.bridged], t_first)


def test_naive_dt_never_negative():
    r = make_reads(3000, eps_ppm=40.0, seed=18)
    r.t_bus[1500] = r.t_bus[1499] - 0.001  # a late tag out of order
    clock = SiruClock(ClockConfig(mode="naive"))
    b = run(clock, r)
    assert np.all(b.dt > 0)


# ---------------------------------------------------------------- determinism, checkpoint
def test_batch_split_determinism():
    r = make_reads(20000, eps_ppm=-70.0, read_jitter=5e-5, tt0=WRAP - 10000 * 7000,
                   reset_at=123.4, seed=19)
    r.t_bus[9000] += 0.3
    whole = run(SiruClock(), r)
    rng = np.random.default_rng(0)
    for trial in range(6):
        if trial == 0:
            splits = list(range(1, len(r.t_bus)))  # one read per push
        else:
            splits = sorted(set(rng.integers(0, len(r.t_bus), 20 + 300 * trial).tolist()))
        parts = run(SiruClock(), r, splits)
        for f in GyroBatch._fields:
            assert np.array_equal(getattr(whole, f), getattr(parts, f)), (trial, f)


_BASE = make_reads(6000, eps_ppm=-100.0, read_jitter=1e-4, tt0=WRAP - 10000 * 2000,
                   reset_at=41.3, seed=24)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(splits=st.lists(st.integers(0, len(_BASE.t_bus)), max_size=60),
       glitches=st.lists(st.tuples(st.integers(1, len(_BASE.t_bus) - 2),
                                   st.sampled_from(["tbus", "tt", "drop", "dup"])), max_size=6))
def test_any_split_and_faults_give_identical_output(splits, glitches):
    t_bus, tt = _BASE.t_bus.copy(), _BASE.tt.copy()
    keep = np.ones(len(t_bus), bool)
    for j, kind in glitches:
        if kind == "tbus":
            t_bus[j] += 0.0371
        elif kind == "tt":
            tt[j] = (tt[j] + 77777) % WRAP
        elif kind == "drop":
            keep[j] = False
        else:  # the read before, again
            t_bus[j], tt[j] = t_bus[j - 1] + T, tt[j - 1]
    r = Reads(t_bus[keep], tt[keep], _BASE.dtheta[keep], _BASE.status[keep], _BASE.k[keep],
              _BASE.t_true, _BASE.dth_true)
    whole_clock, split_clock = SiruClock(), SiruClock()
    whole = run(whole_clock, r)
    parts = run(split_clock, r, sorted(set(min(x, len(r.t_bus)) for x in splits)))
    for f in GyroBatch._fields:
        assert np.array_equal(getattr(whole, f), getattr(parts, f)), f
    assert whole_clock.get_state() == split_clock.get_state()
    assert np.all(np.isfinite(whole.t)) and np.all(whole.dt > 0)
    c = whole_clock.counters
    assert c["samples"] + c["bridged"] == len(whole.t)


def test_any_number_of_gyros():
    r = make_reads(3000, eps_ppm=100.0, seed=25)
    dth6 = np.hstack([r.dtheta, r.dtheta[:, :2]])
    clock = SiruClock(n_gyro=6)
    b = clock.push(r.t_bus, r.tt, dth6, r.status)
    assert b.dtheta.shape[1] == 6
    np.testing.assert_array_equal(b.dtheta[~b.bridged][:, 4:], b.dtheta[~b.bridged][:, :2])
    assert clock.counters["repeated"] == r.repeated


def test_checkpoint_round_trip_continues_identically():
    r = make_reads(20000, eps_ppm=45.0, tt0=WRAP - 10000 * 9000, seed=20)
    ref = SiruClock()
    b_ref = run(ref, r)
    first = SiruClock()
    h = 12345
    b1 = first.push(r.t_bus[:h], r.tt[:h], r.dtheta[:h], r.status[:h])
    blob = msgpack.packb(first.get_state())
    second = SiruClock()
    second.set_state(msgpack.unpackb(blob))
    assert second.get_state() == first.get_state()
    b2 = run(second, r.cut(np.arange(len(r.t_bus)) >= h))
    for f in GyroBatch._fields:
        assert np.array_equal(getattr(b_ref, f),
                              np.concatenate([getattr(b1, f), getattr(b2, f)])), f
    assert second.get_state() == ref.get_state()
    with pytest.raises(ValueError):
        second.set_state({"schema": "radical.clock_state/99"})


def test_reset_keeps_frequency_and_counters():
    r = make_reads(40000, eps_ppm=-80.0, seed=21)
    clock = SiruClock()
    run(clock, r)
    c0 = clock.counters
    tel0 = clock.telemetry()
    assert tel0["freq_offset_ppm"] == pytest.approx(-80.0, abs=0.05)
    assert tel0["freq_offset_sigma_ppm"] < 0.05
    clock.reset()
    assert not clock.locked
    r2 = make_reads(2000, eps_ppm=-80.0, phase=0.0071, t_start=5000.0, seed=22)
    b = run(clock, r2)
    tel = clock.telemetry()  # the frequency is kept, a little less certain
    assert tel["freq_offset_ppm"] == pytest.approx(-80.0, abs=0.05)
    assert tel0["freq_offset_sigma_ppm"] < tel["freq_offset_sigma_ppm"] < 0.5
    assert b.dt[0] == pytest.approx(T * (1 - 80e-6), rel=1e-6)
    c = clock.counters
    assert c["samples"] == c0["samples"] + r2.distinct
    assert c["missing"] == c0["missing"] + r2.missing  # nothing counted across the discontinuity


def test_telemetry_and_counters_are_msgpack_able():
    r = make_reads(2000, eps_ppm=30.0, seed=23)
    clock = SiruClock()
    assert msgpack.unpackb(msgpack.packb(clock.telemetry()))["locked"] is False
    run(clock, r)
    tel = msgpack.unpackb(msgpack.packb(clock.telemetry()))
    assert set(tel["counters"]) == set(COUNTER_NAMES) | {"tag_wraps"}
    for key in ("freq_offset_ppm", "offset_s", "tag_error_sigma_s", "locked", "counters"):
        assert key in tel
    assert 0.0 <= tel["offset_s"] < 0.0101
