"""Parity sums the engine's compiled loop takes for the FDI without stopping for its window hook
(radical_rt/fdi/fdi_quiet.py, engine/handover.take_sum_here): a run that lets the loop take them gives the same
outputs, decisions and records, message for message, as one where every sum goes to the hook;
the detector's step (fdi_detect.detector_step) gives the same bits compiled and uncompiled."""

from __future__ import annotations

import math

import numpy as np
import pytest

from radical_rt.apps.batch import process
from radical_rt.fdi.fdi_detect import DET, DTH, HIT_NONE, ParityDetector, detector_step, thresholds
from radical_rt.fdi.fdi_quiet import Q_ON, Q_SNAPS, Q_TAKEN
from radical_rt.fdi.monitor import FaultMonitor
from radical_rt.io.archive import ArchiveReader
from tests.support.fdi_records import record_snapshots


def _run(path, out, take: bool):
    """``radical process`` of path to out; take=False: the loop never takes a sum. Returns the
    summary, every output message, the engine times of the sums the hook ran the detector on,
    the number of sums the loop took, every snapshot record made and the number of those the
    loop took."""
    hooked, taken, slotted = [], [], []
    orig_sum, orig_taken = FaultMonitor.on_parity_sum, FaultMonitor.sums_taken
    orig_setup = FaultMonitor._quiet_setup

    def on_sum(self, eng, stat):
        hooked.append(float(eng.t))
        return orig_sum(self, eng, stat)

    def sums_taken(self, eng):
        taken.append(int(self.fq[Q_TAKEN]))
        slotted.append(int(self.fq[Q_SNAPS]))
        return orig_taken(self, eng)

    def setup(self, eng, *args):
        orig_setup(self, eng, *args)
        if not take:
            self.fq[Q_ON] = 0.0

    with pytest.MonkeyPatch.context() as m:
        m.setattr(FaultMonitor, "on_parity_sum", on_sum)
        m.setattr(FaultMonitor, "sums_taken", sums_taken)
        m.setattr(FaultMonitor, "_quiet_setup", setup)
        snaps = record_snapshots(m)
        summary = process([str(path)], str(out))
    with ArchiveReader(out) as r:
        msgs = list(r.iter_messages())
    return summary, msgs, hooked, sum(taken), snaps, sum(slotted)


def test_sums_taken_in_the_loop_change_nothing(short_fault, tmp_path):
    s_hook, m_hook, hooked_all, taken_none, snaps_hook, slotted_none = _run(
        short_fault, tmp_path / "hook.mcap", False)
    s_loop, m_loop, hooked, taken, snaps_loop, slotted = _run(short_fault, tmp_path / "loop.mcap",
                                                              True)
    assert taken_none == 0 and slotted_none == 0 and "GYRO_B_FAILED" in s_hook["flags"]
    # most sums before the alarm are taken in the loop, those with a snapshot due too; the
    # alarm's sum goes to the hook
    assert taken > 0.8 * len(hooked_all) and len(hooked) + taken == len(hooked_all)
    # the snapshot records from the loop's slots are those the hook made, bit for bit (here the
    # loop takes those before the alarm: the bank and the three gyros after it leave it to the hook)
    assert len(snaps_hook) > 20 and slotted > 0.2 * len(snaps_hook) and snaps_loop == snaps_hook
    assert s_loop == s_hook
    assert len(m_loop) == len(m_hook)
    diags = 0
    for a, b in zip(m_loop, m_hook, strict=True):
        assert a == b
        diags += a[0] == "/diag"
    assert diags > 350  # (the FDI's counts, last ν, CUSUMs and alarm are in every diag)
    last = [m for topic, _ns, m in m_loop if topic == "/diag"][-1]["fdi"]
    assert last["counts"]["sums"] >= taken and last["counts"]["isolations"] == 1


def test_detector_step_compiled_and_uncompiled_agree():
    """The compiled step and its Python source on the same sequence (quiet, guarded, drifting,
    spikes): the same verdicts, onsets and statistics, bit for bit; ParityDetector reads them."""
    th = thresholds(1e-3, 3600.0)
    det = ParityDetector(th, 4.0)
    rng = np.random.default_rng(7)
    s_c, s_p = np.zeros(DET.end), np.zeros(DET.end)
    s_c[:] = s_p[:] = det.state
    cfg = det.config.copy()
    assert cfg.shape == (DTH.end,)
    hits = 0
    for k in range(3000):
        nu = rng.standard_normal() + (0.9 if 1000 <= k < 1300 else 0.0)
        nu += 8.0 if k in (500, 2500) else 0.0
        rho = 6.0 if 1800 <= k < 1900 else 1.0 + 0.5 * rng.random()
        a = detector_step(s_c, cfg, nu, rho, float(k))
        b = detector_step.py_func(s_p, cfg, nu, rho, float(k))
        assert a[0] == b[0] and (a[1] == b[1] or math.isnan(a[1]) and math.isnan(b[1]))
        assert s_c.tobytes() == s_p.tobytes()
        hits += a[0] != HIT_NONE
        hit = det.update(nu, rho, float(k))
        assert (hit is None) == (a[0] == HIT_NONE)
    assert hits > 2
    assert det.state.tobytes() == s_c.tobytes()
    st = det.get_state()
    assert isinstance(st["run"], int) and isinstance(st["quiet"], int)
    assert isinstance(st["guarded"], bool)


def test_copies_keep_the_detector_in_the_loops_array():
    """A copied monitor (Run.fork's deepcopy, pickle) keeps its detector's statistics and
    configuration as views of its own array: what the loop writes there, the detector reads."""
    import copy
    import pickle

    from radical_rt.engine.filter import Engine
    from radical_rt.fdi.fdi_quiet import Q_DET, Q_TH

    m = FaultMonitor()
    det = m.detector(Engine())
    det.update(3.0, 1.0, 10.0)
    for m2 in (copy.deepcopy(m), pickle.loads(pickle.dumps(m))):
        d2 = m2.det
        assert np.shares_memory(d2.state, m2.fq) and np.shares_memory(d2.config, m2.fq)
        assert not np.shares_memory(m2.fq, m.fq)
        assert d2.get_state() == det.get_state() and d2.config.tobytes() == det.config.tobytes()
        m2.fq[Q_DET] = 7.5  # (the loop's write)
        assert d2.s_pos == 7.5 and det.s_pos != 7.5
        assert m2.fq[Q_TH:Q_TH + DTH.end].tobytes() == d2.config.tobytes()


def test_snapshots_the_same_fed_message_by_message(short_fault):
    """The shell's path (message by message, as the node feeds; LoopShell._calls) takes
    snapshots in the loop too, with the same records, bit for bit, as the block intake's."""
    from radical_rt.engine.filter import Engine
    from tests.oracles.dense_engine import make_processor, run_archive

    slotted = []
    orig_taken = FaultMonitor.sums_taken

    def sums_taken(self, eng):
        slotted.append(int(self.fq[Q_SNAPS]))
        return orig_taken(self, eng)

    with pytest.MonkeyPatch.context() as m:
        m.setattr(FaultMonitor, "sums_taken", sums_taken)
        by_block = record_snapshots(m)
        process([str(short_fault)], None)
    n_block, slotted[:] = sum(slotted), []
    with pytest.MonkeyPatch.context() as m:
        m.setattr(FaultMonitor, "sums_taken", sums_taken)
        by_message = record_snapshots(m)
        run_archive(make_processor(Engine), short_fault)
    assert len(by_block) > 20 and by_message == by_block
    assert n_block > 0 and sum(slotted) > 0
