"""The compiled hypothesis bank (radical_rt/fdi/fdi_hypotheses.py, kernels in radical_rt/fdi/fdi_bank.py)
against the Python bank it replaced (tests/oracles/fdi_bank_py.py), on seeded fault scenarios.

Each scenario (2006216, seed 1, cold start, one gyro fault) runs twice through the batch
engine's stream processor:

* **lockstep**: every bank the monitor starts is a pair, the compiled bank driving and the oracle
  fed the same buffers at the same windows. After every tracker sample both banks' log-likelihoods
  and NIS sums, and the sample's NIS, are recorded; at every window both decisions are recorded.
* **oracle only**: the monitor runs the Python bank alone.

Required: the same decisions at every window; ll, nis and the per-sample NIS within 1e-9 relative
(the log-likelihood *ratios*, which decide, within 1e-6 absolute over thousands of samples); the
alarms, the isolated gyro and the isolation time identical between the two runs; the final
estimates within 1e-9 relative. The compiled bank composes the transition between tracker samples
in one run and factors S by Cholesky instead of LU, so the two agree to rounding, not bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from perf.fdi_cases import fault_toml, synth
from radical_rt.apps.batch import make_processor
from radical_rt.fdi.fdi_bank import BK_SLOTS
from radical_rt.fdi.fdi_bank_pack import PACKED, views
from radical_rt.fdi.fdi_hypotheses import HypothesisBank, idle_kernel_args
from radical_rt.fdi.monitor import FaultMonitor
from tests.oracles.fdi_bank_py import PythonHypothesisBank

SCENARIOS = {  # name → (fault, duration [s]); gyro 0..3 = A..D, times from the cold start
    "bias 5 deg/hr B": ({"kind": "bias_step", "gyro": 1, "start_s": 120.0, "bias_deg_hr": 5.0},
                        160.0),
    "noise burst A": ({"kind": "noise_burst", "gyro": 0, "start_s": 150.0, "sigma_arcsec": 0.1},
                      190.0),
    "stuck C": ({"kind": "stuck", "gyro": 2, "start_s": 150.0}, 200.0),
    # the long bank: isolated 170 s after the onset, 3442 tracker samples (engine of 2026-12-02)
    "zero output D": ({"kind": "zero", "gyro": 3, "start_s": 40.0}, 290.0),
}
ISOLATED = {"bias 5 deg/hr B": 1, "noise burst A": 0, "stuck C": 2, "zero output D": 3}


class _TracedNew(HypothesisBank):
    def update_trackers(self, eng, gbuf, batch):
        for item in batch:  # one sample per kernel call, to trace each (test_batch_... below)
            nis0 = self.nis.copy()
            super().update_trackers(eng, gbuf, [item])
            self.trace.append((item[1], self.ll.copy(), self.nis.copy(), self.nis - nis0))


class _TracedRef(PythonHypothesisBank):
    def update_tracker(self, eng, j, t_epoch, q_meas, n_stars):
        nis0 = self.nis.copy()
        super().update_tracker(eng, j, t_epoch, q_meas, n_stars)
        self.trace.append((t_epoch, self.ll.copy(), self.nis.copy(), self.nis - nis0))


class LockstepBank:
    """The compiled bank driving, the oracle beside it on the same inputs (docstring above)."""

    banks: list[LockstepBank] = []
    in_release = False  # the hook drives both banks (FaultMonitor.kernel_bank)

    def __init__(self, eng, snap, t_alarm: float) -> None:
        self.new, self.ref = _TracedNew(eng, snap, t_alarm), _TracedRef(eng, snap, t_alarm)
        self.new.trace, self.ref.trace, self.decisions = [], [], []
        LockstepBank.banks.append(self)

    def __getattr__(self, name):  # everything the monitor reads comes from the compiled bank
        return getattr(self.new, name)

    def advance(self, eng, gbuf, trk, t_upto: float) -> None:
        self.new.advance(eng, gbuf, trk, t_upto)
        self.ref.advance(eng, gbuf, trk, t_upto)

    def decision(self, llr_min: float):
        d_new, d_ref = self.new.decision(llr_min), self.ref.decision(llr_min)
        self.decisions.append((d_new, d_ref))
        return d_new

    def final_state(self, eng, gbuf, h: int):
        out = self.new.final_state(eng, gbuf, h)
        self.final = (tuple(np.copy(x) for x in out), self.ref.final_state(eng, gbuf, h))
        return out


def _run(path, bank_type, monkeypatch):
    from radical_rt.io.archive import ArchiveReader
    monkeypatch.setattr(FaultMonitor, "bank_type", bank_type)
    sp = make_processor()
    with ArchiveReader(str(path)) as r:
        for topic, _ns, data in r.iter_raw(topics=["/siru", "/st1", "/st2", "/temp"]):
            sp.feed(topic[1:], data)
    sp.end_stream(None)
    return sp


def _rel(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1.0)))


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_compiled_bank_matches_the_python_bank(name, tmp_path, monkeypatch):
    fault, duration = SCENARIOS[name]
    path = synth(fault_toml(fault, duration=duration), tmp_path / "fault.mcap")
    LockstepBank.banks = []
    lock = _run(path, LockstepBank, monkeypatch)
    banks = LockstepBank.banks
    assert banks, "no bank ran"
    n_samples = 0
    worst = {"ll": 0.0, "nis": 0.0, "nis_k": 0.0, "llr": 0.0}
    for b in banks:
        assert len(b.new.trace) == len(b.ref.trace) == b.new.k == b.ref.k > 0
        for (t1, ll1, ns1, nk1), (t2, ll2, ns2, nk2) in zip(b.new.trace, b.ref.trace, strict=True):
            assert t1 == t2
            worst["ll"] = max(worst["ll"], _rel(ll1, ll2))
            worst["nis"] = max(worst["nis"], _rel(ns1, ns2))
            worst["nis_k"] = max(worst["nis_k"], _rel(nk1, nk2))
            worst["llr"] = max(worst["llr"], float(np.max(np.abs((ll1 - ll1[0]) - (ll2 - ll2[0])))))
        n_samples += len(b.new.trace)
        # the same decision at every window (margins to rounding)
        for (v1, g1, m1), (v2, g2, m2) in b.decisions:
            assert (v1, g1) == (v2, g2)
            assert m1 == pytest.approx(m2, rel=1e-9, abs=1e-6)
        assert b.new.undetermined.sum() == 0 and b.ref.undetermined.sum() == 0
    assert worst["ll"] < 1e-9 and worst["nis"] < 1e-9 and worst["nis_k"] < 1e-9, worst
    assert worst["llr"] < 1e-6, worst
    # the hand-over at the isolation: attitude, rate and covariance blocks of the winner
    (q1, w1, P1, C1), (q2, w2, P2, C2) = banks[-1].final
    assert _rel(q1, q2) < 1e-12 and _rel(w1, w2) < 1e-12
    assert np.max(np.abs(P1 - P2)) <= 1e-9 * np.max(np.abs(P2))
    assert np.max(np.abs(C1 - C2)) <= 1e-9 * np.max(np.abs(C2))

    ref = _run(path, PythonHypothesisBank, monkeypatch)
    f_new, f_ref = lock.engine.fdi, ref.engine.fdi
    assert [(a["t_alarm"], a["test"], a["t_snapshot"]) for a in f_new.alarms] == [
        (a["t_alarm"], a["test"], a["t_snapshot"]) for a in f_ref.alarms]
    iso_new = [(i["gyro"], i["t_isolated"], i["trackers"]) for i in f_new.isolations]
    assert iso_new == [(i["gyro"], i["t_isolated"], i["trackers"]) for i in f_ref.isolations]
    assert [i[0] for i in iso_new] == [ISOLATED[name]]
    assert f_new.isolations[0]["llr_margin"] == pytest.approx(f_ref.isolations[0]["llr_margin"],
                                                              rel=1e-9)
    assert lock.flag_names() == ref.flag_names() and lock.engine.mode == ref.engine.mode
    e1, e2 = lock.engine, ref.engine
    for g, v in e1.estimates().items():
        assert _rel(v, e2.estimates()[g]) < 1e-9, g
    assert math.isfinite(e1.t) and e1.t == e2.t
    print(f"{name}: {n_samples} tracker samples; max relative ll {worst['ll']:.1e}, nis "
          f"{worst['nis']:.1e}, per-sample NIS {worst['nis_k']:.1e}; max |Δ llr| {worst['llr']:.1e}")


def _bank_calls(path, monkeypatch, in_kernel: bool):
    """A run with the compiled bank, run inside the compiled release (in_kernel) or, as before,
    by the window hook after every tracker sample; returns (processor, [(engine time, bank.k) of
    every window hook while a bank runs], number of tracker samples the kernel ran the bank on)."""
    calls, steps = [], [0]
    orig_window, orig_done = FaultMonitor.on_window, HypothesisBank.kernel_done

    def on_window(self, eng, t):
        if self.bank is not None:
            calls.append((float(eng.t), self.bank.k))
        return orig_window(self, eng, t)

    def kernel_done(self):
        n = orig_done(self)
        steps[0] += n
        return n

    monkeypatch.setattr(FaultMonitor, "on_window", on_window)
    monkeypatch.setattr(HypothesisBank, "kernel_done", kernel_done)
    if not in_kernel:
        monkeypatch.setattr(HypothesisBank, "in_release", False)
    sp = _run(path, HypothesisBank, monkeypatch)
    monkeypatch.undo()
    return sp, calls, steps[0]


@pytest.mark.parametrize("name", ["stuck C", "zero output D"])
def test_bank_in_the_compiled_release_decides_at_the_same_sample(name, tmp_path, monkeypatch):
    """The compiled release runs the bank on its tracker samples and hands over only when the
    decision is due (docs/fdi.md §1, §7): the same alarms, isolation (gyro, time, tracker count,
    margin to the bit), flags, mode and final estimates (bit for bit) as the window hook running it
    after every tracker sample, with far fewer window hooks while the bank runs."""
    fault, duration = SCENARIOS[name]
    path = synth(fault_toml(fault, duration=duration), tmp_path / "fault.mcap")
    kinds = set()  # (rank, dtype) of every array of the bank tuples the release was given
    kernel_args = HypothesisBank.kernel_args

    def recorded(self, *a):
        bk = kernel_args(self, *a)
        kinds.add(tuple((x.ndim, str(x.dtype), x.flags.c_contiguous) for x in views(bk).values()))
        return bk

    monkeypatch.setattr(HypothesisBank, "kernel_args", recorded)
    sp_k, calls_k, steps_k = _bank_calls(path, monkeypatch, in_kernel=True)
    monkeypatch.setattr(HypothesisBank, "kernel_args", kernel_args)
    # the packed arrays follow their one declaration (fdi_bank.BK_SLOTS, but the history blocks),
    # as the idle stand-in's do
    assert BK_SLOTS[3:] == PACKED
    declared = tuple((nd, dt, True) for _name, nd, dt in PACKED)
    idle = tuple((x.ndim, str(x.dtype), x.flags.c_contiguous)
                 for x in views(idle_kernel_args()).values())
    assert kinds == {declared} and idle == declared, kinds
    sp_p, calls_p, steps_p = _bank_calls(path, monkeypatch, in_kernel=False)
    f_k, f_p = sp_k.engine.fdi, sp_p.engine.fdi
    assert steps_p == 0 and steps_k > 0
    assert f_k.alarms == f_p.alarms and f_k.counts == f_p.counts
    assert len(f_k.isolations) == 1 and f_k.isolations[0]["gyro"] == ISOLATED[name]
    assert f_k.isolations == f_p.isolations  # every field, margin and bank summary included
    assert sp_k.flag_names() == sp_p.flag_names() and sp_k.engine.mode == sp_p.engine.mode
    e_k, e_p = sp_k.engine, sp_p.engine
    assert e_k.t == e_p.t and np.array_equal(e_k.q, e_p.q) and np.array_equal(e_k.xp, e_p.xp)
    assert np.array_equal(e_k.U, e_p.U) and np.array_equal(e_k.d, e_p.d)
    assert e_k.counters == e_p.counters
    iso = f_k.isolations[0]
    span = iso["t_isolated"] - f_k.alarms[0]["t_alarm"]
    # the kernel ran the bank on most samples (the hook: the catch-up from the snapshot at the
    # alarm's window, and samples at which the flags change); the hook ran at the parity sums,
    # the bank's time checks (5-s snapshots) and the decision, not after every tracker sample
    assert steps_k >= 0.75 * iso["trackers"], (steps_k, iso["trackers"])
    print(f"{name}: bank on {iso['trackers']} tracker samples, {steps_k} in the kernel; window "
          f"hooks while it ran {len(calls_k)} (hook running the bank: {len(calls_p)})")
    # (about two per second: the close of each parity sum and its lagged update, as in a nominal
    # run, and the windows at which the engine's flags change, e.g. edited tracker samples)
    assert len(calls_k) <= 3.0 * span + 10 < 0.2 * len(calls_p), (len(calls_k), len(calls_p), span)
    # the deciding hook: the kernel had run the bank on the deciding sample; the hook-driven bank
    # runs it inside that hook (k is recorded before)
    assert calls_k[-1][1] == iso["trackers"] == calls_p[-1][1] + 1


def test_fast_path_hands_over_at_tracker_samples_only_while_a_bank_runs(tmp_path, monkeypatch):
    """While a bank runs that the compiled release does not run itself, the window hook runs
    after every tracker sample and at the bank's time checks, not at the 10-Hz gyro window closes
    (docs/fdi.md §1); the decision times are those of the reference path (tests/radical_rt/engine/test_fastpath.py
    compares the outputs byte for byte)."""
    fault, duration = SCENARIOS["stuck C"]
    path = synth(fault_toml(fault, duration=duration), tmp_path / "fault.mcap")
    calls = []
    orig = FaultMonitor.on_window

    def on_window(self, eng, t):
        if self.bank is not None:
            calls.append((float(eng.t), self.bank.k))
        return orig(self, eng, t)

    monkeypatch.setattr(FaultMonitor, "on_window", on_window)
    monkeypatch.setattr(HypothesisBank, "in_release", False)  # the hook runs the bank
    sp = _run(path, HypothesisBank, monkeypatch)
    iso = sp.engine.fdi.isolations[0]
    t = np.array([c[0] for c in calls])
    k = np.array([c[1] for c in calls])
    span = iso["t_isolated"] - sp.engine.fdi.alarms[0]["t_alarm"]
    live = iso["trackers"] - k[1]  # the first call caught up with the samples since the snapshot
    windows = 10.0 * span + live  # gyro window closes (10 Hz) and tracker epochs
    # after every tracker sample (the decision is checked at each), plus parity sums and the
    # bank's time checks, far fewer than one per window close
    assert k[0] == 0 and k[1] > 0 and np.all(np.diff(k[1:]) <= 1) and np.all(np.diff(k) >= 0)
    assert live <= len(calls) <= live + 1.5 * span + 10, (len(calls), live, span)
    assert len(calls) < 0.8 * windows
    assert np.all(np.diff(t) >= 0.0)


class _OneByOne(HypothesisBank):
    """The bank with every tracker sample of a catch-up in its own kernel call."""

    def update_trackers(self, eng, gbuf, batch):
        for item in batch:
            super().update_trackers(eng, gbuf, [item])


def test_batched_catch_up_equals_one_sample_per_call(tmp_path, monkeypatch):
    """HypothesisBank.advance hands a whole catch-up (the samples since the snapshot the bank
    starts from) to one kernel call (fdi_bank.bank_run): bit for bit the run of one call per
    sample (isolation, margin, bank summary, engine state)."""
    fault, duration = SCENARIOS["stuck C"]
    path = synth(fault_toml(fault, duration=duration), tmp_path / "fault.mcap")
    batches = []
    orig = HypothesisBank.update_trackers

    def spy(self, eng, gbuf, batch):
        batches.append(len(batch))
        return orig(self, eng, gbuf, batch)

    monkeypatch.setattr(HypothesisBank, "update_trackers", spy)
    sp_b = _run(path, HypothesisBank, monkeypatch)
    monkeypatch.undo()
    assert max(batches) > 20  # a real catch-up went through one call
    sp_1 = _run(path, _OneByOne, monkeypatch)
    f_b, f_1 = sp_b.engine.fdi, sp_1.engine.fdi
    assert len(f_b.isolations) == 1 and f_b.isolations == f_1.isolations
    e_b, e_1 = sp_b.engine, sp_1.engine
    assert e_b.t == e_1.t and np.array_equal(e_b.q, e_1.q) and np.array_equal(e_b.xp, e_1.xp)
    assert np.array_equal(e_b.U, e_1.U) and np.array_equal(e_b.d, e_1.d)
