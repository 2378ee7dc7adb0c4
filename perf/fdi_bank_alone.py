"""The FDI hypothesis bank's own arithmetic, timed apart from the rest of the run.

:func:`record` feeds the fault archive of :mod:`perf.bench_fdi_bank` once with a bank that the
window hook runs (``in_release = False``) and that records, at each of its catch-ups, the gyro
history rows it propagates through (float, int and bool blocks), the tracker samples it takes
(epoch [s], tracker, measured q_st_from_inertial (4,), stars) with the engine's timing σ [s] of
that moment, a copy of itself as it was before its first sample, and its log-likelihoods after the
last. :func:`time_bank` then replays those tracker samples, from the copy, through the compiled
release's own per-sample entry (:func:`radical_rt.fdi.fdi_bank_pack.bank_sample_packed`) in one
compiled loop: no stream, clock, dispatch or Python between samples, only what the bank computes
(propagation of every hypothesis through the gyro samples, covariance flush, tracker update,
decision test). The replay must end with the recorded log-likelihoods, bit for bit
(``replay_equal``), or the figure is of some other computation.

Used by ``python -m perf.bench_fdi_bank`` (its ``bank_alone`` entry and the budget line of its
table).
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from typing import Any

import numba
import numpy as np

from radical_rt.fdi.fdi_bank_pack import bank_sample_packed


def recording_bank(rec: dict[str, Any]) -> type:
    """A hook-run HypothesisBank class whose instances fill ``rec`` (module docstring)."""
    from radical_rt.fdi.fdi_bank_propagate import rows_after
    from radical_rt.fdi.fdi_hypotheses import HypothesisBank

    class RecordingBank(HypothesisBank):
        in_release = False

        def update_trackers(self, eng, gbuf, batch):
            if "bank" not in rec:
                rec.update(bank=copy.deepcopy(self), si=eng.si, rows=[], trackers=[],
                           geometry=tuple(np.array(a, dtype=np.float64) for a in (
                               eng.geo.R_st1_from_body, eng.geo.R_st2_from_body_nom, eng.geo.W,
                               eng.geo.U, eng.geo.V)))
            f, st, br, i0, end = gbuf.blocks()
            a, z = rows_after(f, i0, end, float(self.tlast[0]), max(s[1] for s in batch))
            rec["rows"].append((f[a:z].copy(), st[a:z].copy(), br[a:z].copy()))
            sig_t = eng.timing_sigma()
            rec["trackers"] += [(t, j == 2, np.array(q, dtype=np.float64), n, sig_t)
                                for _seq, t, j, q, n in batch]
            super().update_trackers(eng, gbuf, batch)
            rec["ll"] = self.ll.copy()

    return RecordingBank


def record(feed: Callable[[Any, type], Any], msgs: Any) -> dict[str, Any]:
    """Feed ``msgs`` with ``feed(msgs, bank_type)`` (perf.bench_fdi_bank's message-by-message
    feed) under a recording bank. Returns the recording (module docstring) and ``llr_min``, the
    monitor's decision margin at the end; raises RuntimeError when no bank ran."""
    rec: dict[str, Any] = {}
    sp = feed(msgs, recording_bank(rec))[0]
    if "bank" not in rec:
        raise RuntimeError("no hypothesis bank ran on the benchmark's fault archive")
    rec["llr_min"] = float(sp.engine.fdi.llr_threshold(sp.engine))
    return rec


class _History:
    """The recorded gyro rows as the history blocks HypothesisBank.kernel_args reads (rows from 0)."""

    def __init__(self, f: np.ndarray, st: np.ndarray, br: np.ndarray) -> None:
        self.f, self.st, self.br = f, st, br

    def blocks(self) -> tuple:
        return self.f, self.st, self.br, 0, self.f.shape[0]


@numba.njit(cache=False)
def _replay(f, st, br, bfb, bib, bbb, blay, q_meas, n_stars, epoch, st2, sig_t, R1, R2, W, U, V):
    """Every tracker sample through the release's bank entry; returns how many said a decision
    was due (shapes: q_meas (m, 4), n_stars (m,) int64, epoch, sig_t (m,) [s], st2 (m,) bool)."""
    due = 0
    for i in range(q_meas.shape[0]):
        R_nom = R2 if st2[i] else R1
        if bank_sample_packed(f, st, br, bfb, bib, bbb, blay, q_meas[i], n_stars[i], epoch[i],
                              R_nom, st2[i], sig_t[i], W, U, V):
            due += 1
    return due


def time_bank(rec: dict[str, Any], repetitions: int) -> dict[str, Any]:
    """Replay the recording ``repetitions`` times (after one untimed replay that compiles the
    loop), each from a fresh copy of the bank. Returns tracker samples, gyro rows, µs per
    tracker sample (min and median), the samples at which a decision was due in the last
    replay, and replay_equal (its log-likelihoods bit-equal to the recorded run's)."""
    f, st, br = (np.ascontiguousarray(np.concatenate(block))
                 for block in zip(*rec["rows"], strict=True))
    trk = rec["trackers"]
    epoch = np.array([s[0] for s in trk])
    st2 = np.array([s[1] for s in trk], dtype=np.bool_)
    q_meas = np.array([s[2] for s in trk])
    n_stars = np.array([s[3] for s in trk], dtype=np.int64)
    sig_t = np.array([s[4] for s in trk])
    hist, m = _History(f, st, br), len(trk)

    class _Eng:  # what HypothesisBank.kernel_args reads of the engine
        si = rec["si"]

    times, due, bank = [], 0, None
    for rep in range(repetitions + 1):
        bank = copy.deepcopy(rec["bank"])
        bufs = bank.kernel_args(_Eng, hist, f.shape[0], m, rec["llr_min"])
        t0 = time.perf_counter()
        due = _replay(f, st, br, *bufs, q_meas, n_stars, epoch, st2, sig_t, *rec["geometry"])
        if rep > 0:
            times.append(time.perf_counter() - t0)
    return {"trackers": m, "gyro_rows": int(f.shape[0]),
            "us_per_tracker_min": 1e6 * min(times) / m,
            "us_per_tracker": 1e6 * float(np.median(times)) / m, "decisions_due": int(due),
            "replay_equal": bool(np.array_equal(bank.ll, rec["ll"]))}
