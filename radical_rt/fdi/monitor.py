"""Gyro fault detection, isolation and reconfiguration (FDI) from the parity vector and the trackers.

With four gyros the parity space is one-dimensional: the calibrated parity innovation tells *that*
the four increments disagree, never *which* gyro is wrong (notes/rimu.md §12.2). The monitor
therefore works in three stages (design and thresholds: docs/fdi.md):

1. **Detection** on the calibrated parity innovation ν = z/σ of every 1-s sum as it closes (z from
   the current calibration, σ² = hPhᵀ + R with the calibration uncertainty): an instantaneous
   χ²(1) test, a persistence test (m consecutive χ² exceedances) and a two-sided CUSUM for small
   or slowly growing faults. The thresholds follow from one design false-alarm rate per hour.
   A convergence-aware guard holds
   the sequential tests and raises the instantaneous threshold while the calibration part of σ²
   dominates the measurement noise (cold start, covariance bumps).
2. **Isolation** by a bank of attitude hypotheses started from a snapshot of the engine taken
   before the estimated fault onset: H0 (all four gyros) and H_i (gyro i left out), each an
   attitude propagation through the buffered gyro samples with the snapshot calibration, and a
   Schmidt (consider) attitude filter on the buffered tracker samples whose considered states are
   the snapshot's calibration, ST2 misalignment and latency. A fault in gyro i drives every
   hypothesis that contains it along its own direction and leaves H_i consistent; the
   log-likelihood ratio of the tracker innovations decides.
3. **Reconfiguration** when H_i wins: gyro i is excluded (the engine's three-gyro path, no parity),
   the calibration and its covariance are rolled back to the pre-fault snapshot (plus the
   parameter process noise since), the attitude and its cross-covariance come from the winning
   hypothesis filter, GYRO_<i>_FAILED is set and PARITY_ALARM cleared.

The engine calls :class:`FaultMonitor` through four hooks (``on_gyro``, ``on_tracker``,
``on_parity_sum``, ``on_window``); all decisions are made in ``on_window``, a deterministic point
after the correction is folded in, so batch and streaming runs take identical decisions.
This module owns the hooks, the detection and the bookkeeping (history, snapshots, restarts);
the alarm/isolation/reconfiguration steps are in :mod:`radical_rt.fdi.monitor_isolation`, the
checkpoint state and the detail in :mod:`radical_rt.fdi.monitor_state`.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from radical_rt.contract.conventions import SIRU_PERIOD_S
from radical_rt.contract.flags import GYRO_FAILED, Flag
from radical_rt.fdi import fdi_quiet as FQ
from radical_rt.fdi.fdi_detect import (
    CUSUM_SHIFT,
    DTH,
    PERSIST_M,
    ParityDetector,
    Thresholds,
    chi2_1_isf,
    chi2_isf,
    cusum_arl0,
    cusum_threshold,
    thresholds,
)
from radical_rt.fdi.fdi_history import SampleBuffer, Snapshot, TrackerBuffer
from radical_rt.fdi.fdi_hypotheses import CONSISTENCY_P, NIS_CAP, HypothesisBank
from radical_rt.fdi.monitor_isolation import IsolationSteps
from radical_rt.fdi.monitor_snapshots import BUFFER_S, SNAPSHOT_PERIOD_S, SnapshotSteps
from radical_rt.fdi.monitor_state import MonitorState

# Fixed design constants (tuning that is not in the parameter table; docs/fdi.md §5).
BANK_MAX_S = 300.0  # a bank that has not decided after this long (from the alarm) is stopped
# outside an alarm the bookkeeping runs at each parity sum, and at the latest this long after the last
CHECK_MAX_S = 2.0
QUIET_SUMS = 60  # parity sums without any exceedance before PARITY_ALARM clears
WAKE_EARLY_S = 1e-6  # the compiled loop wakes the hook this much before a time-gated bank check


_ALL_FAILED = int(Flag.GYRO_A_FAILED | Flag.GYRO_B_FAILED | Flag.GYRO_C_FAILED | Flag.GYRO_D_FAILED)

# ----------------------------------------------------------------------------- the monitor
class FaultMonitor(IsolationSteps, MonitorState, SnapshotSteps):
    """The engine's FDI object (``Engine.fdi``). Parameters come from the engine's active table
    (``fdi_*``, :mod:`radical_rt.contract.params`); defaults apply when a name is missing. The
    alarm/isolation steps come from :class:`radical_rt.fdi.monitor_isolation.IsolationSteps`, the
    checkpoint state and the detail from :class:`radical_rt.fdi.monitor_state.MonitorState`, the
    snapshots and the history's trimming from
    :class:`radical_rt.fdi.monitor_snapshots.SnapshotSteps`."""

    #: the bank of an alarm: (engine, Snapshot, t_alarm) → bank (tests/radical_rt/fdi/test_fdi_bank.py and
    #: perf/bench_fdi_bank.py put the Python oracle of tests/oracles here)
    bank_type = HypothesisBank

    def __init__(self) -> None:
        self._th_key = None
        self.det: ParityDetector | None = None
        # what the engine's compiled loop needs to take parity sums itself (radical_rt.fdi.
        # fdi_quiet; the detector's statistics live there)
        self.fq = np.zeros(FQ.QF.end)
        self.fq[FQ.Q_SNAP_PERIOD], self.fq[FQ.Q_CHECK_S] = SNAPSHOT_PERIOD_S, CHECK_MAX_S
        self.gbuf = SampleBuffer()
        self.trk = TrackerBuffer()  # the valid tracker samples since the oldest snapshot
        self.trk_seq = 0
        self.snaps: deque[Snapshot] = deque()
        self.bank: HypothesisBank | None = None
        self.state = "waiting"
        self.gen = None
        self.alarm: dict[str, Any] | None = None
        self.last_nu = math.nan
        self.last_rho = math.nan
        self.alarms: list[dict[str, Any]] = []  # every alarm raised (time, test, onset estimate)
        self.isolations: list[dict[str, Any]] = []  # every isolation decision
        self.parity_log: deque = deque()  # (t0, z) of recent sums, for the fault-size estimate
        self._next_check = -math.inf
        self._sum_seen = False  # a parity sum closed since the last bookkeeping
        self._t_decided = -math.inf  # engine time of the running bank's last decision
        self._llr: tuple = (None, 0.0)  # (fdi_isolation_error_prob, llr_threshold) last computed
        self.failed_by_fdi: set[int] = set()
        self.flagged_only: set[int] = set()  # isolated without exclusion (fdi_auto_exclude false)
        self.counts = {"sums": 0, "alarms": 0, "isolations": 0, "banks": 0, "unconfirmed": 0,
                       "timeouts": 0}

    # ------------------------------------------------------------------ configuration
    @staticmethod
    def _p(eng, name: str, default):
        return getattr(eng.table.active, "fdi_" + name, default)

    def enabled(self, eng) -> bool:
        return bool(self._p(eng, "enabled", True))

    def detector(self, eng) -> ParityDetector:
        """The detector of the current table (a new one, with fresh statistics, when its
        thresholds changed)."""
        key = self._detector_key(eng)
        if key != self._th_key or self.det is None:
            fq = self.fq
            self.det = ParityDetector(thresholds(key[0], 3600.0 / key[1]), key[2],
                                      fq[FQ.Q_DET:FQ.Q_TH], fq[FQ.Q_TH:FQ.Q_TH + DTH.end])
            self._th_key = key
        return self.det

    def _detector_key(self, eng) -> tuple[float, float, float]:
        """(false-alarm rate [1/h], parity sum duration [s], guard ratio) of the current table."""
        return (float(self._p(eng, "false_alarm_per_hr", 1e-3)),
                eng.si.parity_window * SIRU_PERIOD_S, float(self._p(eng, "guard_ratio", 4.0)))

    def llr_threshold(self, eng) -> float:
        """The bank's decision margin: −ln(fdi_isolation_error_prob) (cached by value)."""
        p = self._p(eng, "isolation_error_prob", 1e-6)
        if p != self._llr[0]:
            self._llr = (p, -math.log(max(min(float(p), 0.5), 1e-300)))
        return self._llr[1]

    # ------------------------------------------------------------------ hooks (engine → FDI)
    def on_gyro(self, t, dt, dtheta, status, bridged, var_extra) -> None:
        """Every gyro batch the engine receives (before propagation)."""
        self.gbuf.append((t, dt, dtheta, status, bridged, var_extra))

    def on_gyro_rows(self, arrays, a: int, z: int) -> None:
        """:meth:`on_gyro` of rows a..z−1 of the sample arrays (t, dt, dθ, status, bridged,
        var_extra), without views (the stream processor's gyro queue)."""
        self.gbuf.append(arrays, a, z)

    def on_tracker(self, j: int, t_epoch: float, q_meas, n_stars: int) -> None:
        """Every valid tracker sample the engine receives (before its update)."""
        self.trk_seq += 1
        self.trk.append(self.trk_seq, t_epoch, j, q_meas, n_stars)

    def on_parity_sum(self, eng, stat: tuple) -> None:
        """Every closed parity sum, at the window hook of its close: its statistic ``stat`` =
        (ν, ρ, t0, z), computed by the engine's compiled close when the sum was queued
        (radical_rt.engine.steps.parity_statistic: the calibrated innovation z = Nᵀĉ − h·dx with
        the estimate of that time, σ² = h P hᵀ + R from the UD factors, ν = z/σ, ρ = σ²/R, t0 the
        sum's first sample [s]), or () when it was not computed (FDI disabled, not finite). Runs
        the detector; the bookkeeping follows in :meth:`on_window`."""
        self._sum_seen = True
        if not stat or not self.enabled(eng):
            return
        nu, rho, t0, z = stat
        det = self.detector(eng)
        t1 = float(eng.t)
        self.counts["sums"] += 1
        self.last_nu, self.last_rho = nu, rho
        self.parity_log.append((t0, z))
        while self.parity_log and self.parity_log[0][0] < t1 - BUFFER_S:
            self.parity_log.popleft()
        hit = det.update(nu, rho, t0)
        if hit is not None and self.bank is None and self.state in ("monitoring", "alarm"):
            self._raise_alarm(eng, hit[0], hit[1], nu, rho)

    def on_include(self, eng, gyro: int) -> None:
        """The operator's include_gyro: the gyro is trusted again (its GYRO_<i>_FAILED clears now;
        monitoring resumes at the next window with fresh statistics)."""
        eng.flags &= ~int(GYRO_FAILED[gyro])
        self.failed_by_fdi.discard(int(gyro))
        self.flagged_only.discard(int(gyro))

    def wake_time(self) -> float:
        """Engine time from which :meth:`on_window` has work: the engine's compiled loop
        skips the hook before it (radical_rt.engine.loop). −inf after a parity sum, or during an
        alarm without a bank. While a bank runs, its decision changes only with a tracker sample
        (:meth:`wake_on_tracker`) or at the times of :meth:`_bank_wake`."""
        if self._sum_seen or (self.state == "alarm" and self.bank is None):
            return -math.inf
        return self._bank_wake() if self.state == "alarm" else self._next_check

    def wake_on_tracker(self) -> bool:
        """Whether :meth:`on_window` has work after every tracker sample: a bank is running that
        the compiled release cannot run itself (:meth:`kernel_bank`)."""
        return self.state == "alarm" and self.bank is not None and self.kernel_bank() is None

    def release_inputs(self, eng) -> tuple[HypothesisBank | None, float, bool, bool]:
        """What a compiled call of the engine needs from the FDI, in one call: (the bank it runs,
        :meth:`kernel_bank`; :meth:`wake_time`; :meth:`wake_on_tracker`; :meth:`enabled`), and
        the array :attr:`fq` set for it (:meth:`_quiet_setup`)."""
        enabled, bank = self.enabled(eng), self.kernel_bank()
        self._quiet_setup(eng, enabled, bank)
        return bank, self.wake_time(), self.wake_on_tracker(), enabled

    def _quiet_setup(self, eng, enabled: bool, bank: HypothesisBank | None) -> None:
        """Whether the compiled loop may take parity sums without the window hook
        (radical_rt.fdi.fdi_quiet): while monitoring (TAKE_QUIET) or during an alarm whose bank
        the loop runs (TAKE_ALARM: ``bank``, :meth:`kernel_bank`), with no bookkeeping pending,
        the current thresholds, a snapshot, no failed gyro and the generation the monitor has seen
        (the loop checks that it stays so); with the newest snapshot's time. It never makes
        the detector: the hook of a sum does, as before. While monitoring ``fq`` has room for
        the snapshots the loop may take (:meth:`_snapshot_slots`)."""
        mode = FQ.TAKE_NONE
        if (enabled and not self._sum_seen and self.snaps and not self.failed_by_fdi
                and not self.flagged_only and not int(eng.flags) & _ALL_FAILED):
            if self.state == "monitoring" and self.bank is None:
                mode = FQ.TAKE_QUIET
            elif self.state == "alarm" and bank is not None:
                mode = FQ.TAKE_ALARM
        if mode != FQ.TAKE_NONE and (self.det is None or self._detector_key(eng) != self._th_key
                                  or eng.generation() != self.gen):
            mode = FQ.TAKE_NONE  # (the hook makes the detector of the current table first)
        if mode == FQ.TAKE_QUIET:
            self._snapshot_slots(eng)
        fq = self.fq
        fq[FQ.Q_ON] = mode
        if mode != FQ.TAKE_NONE:
            fq[FQ.Q_SNAP_T] = self.snaps[-1].t

    def sums_taken(self, eng) -> None:
        """The records of the parity sums the compiled loop took (radical_rt.fdi.fdi_quiet), as
        :meth:`on_parity_sum` and the bookkeeping of :meth:`on_window` keep them: the count,
        the last ν and ρ, the parity log, the time of the next bookkeeping and the snapshots
        the loop took (:meth:`_slot_snapshots`)."""
        v = self.fq[:FQ.QF_END].tolist()
        n = int(v[FQ.Q_TAKEN])
        if not n:
            return
        self.fq[FQ.Q_TAKEN] = 0.0
        self.counts["sums"] += n
        self.last_nu, self.last_rho, t1 = v[FQ.Q_LAST:FQ.Q_LAST + 3]
        log = self.parity_log
        for k in range(n):
            log.append((v[FQ.Q_RING + 2 * k], v[FQ.Q_RING + 2 * k + 1]))
        while log and log[0][0] < t1 - BUFFER_S:  # (trimmed at t1 once: t0 and t1 increase)
            log.popleft()
        self._next_check = t1 + CHECK_MAX_S
        if v[FQ.Q_ON] == FQ.TAKE_ALARM:  # (the hook decides at every window during an alarm)
            self._t_decided = t1
        self._slot_snapshots(eng)

    def kernel_bank(self) -> HypothesisBank | None:
        """The running bank when the engine's compiled release may run it on its valid tracker
        samples and hand over only when its decision is due (radical_rt.engine.loop; docs/fdi.md
        §7): a compiled bank, caught up with the tracker buffer, past the window of its alarm
        (where the decision is held); ``in_release`` False on a bank class
        keeps it in the hook (the oracle, the benchmark's rows). Between two tracker samples :meth:`on_window` then only
        repeats the decision it took at the last one, except at the :meth:`_bank_wake` times."""
        b = self.bank
        if (self.state != "alarm" or not getattr(b, "in_release", False)
                or b.trk_seq != self.trk_seq or self._t_decided <= b.t_alarm):
            return None
        return b

    def _bank_wake(self) -> float:
        """While a bank runs, the engine time from which a window without a new tracker sample
        has work: the first window after the alarm's own (the decision is held there), the next
        snapshot and the bank's timeout (a little early: a hook that finds nothing is harmless)."""
        b = self.bank
        if self._t_decided <= b.t_alarm:
            return b.t_alarm
        w = b.t_alarm + BANK_MAX_S - WAKE_EARLY_S
        return min(w, self.snaps[-1].t + SNAPSHOT_PERIOD_S - WAKE_EARLY_S) if self.snaps else -math.inf

    def on_window(self, eng, t: float) -> None:
        """After every window close: bookkeeping, snapshots, the bank and the decisions. Outside
        an alarm the bookkeeping (it only watches for restarts, exclusions and the snapshot
        period) runs at the window close of each parity sum (1 s by default; the engine's
        compiled path stops there anyway), and at the latest CHECK_MAX_S of engine time after
        the last one (no sums: three gyros, FDI disabled, invalid samples)."""
        if self.state != "alarm" and not self._sum_seen and eng.t < self._next_check:
            return
        self._sum_seen = False
        self._next_check = eng.t + CHECK_MAX_S
        self._check_gen(eng)
        self._sync_failed_flags(eng)
        if not self.enabled(eng):
            self._stop(eng, "disabled")
            self.state = "disabled"
            self.gbuf.clear()  # nothing is kept while disabled
            self.trk.clear()
            self.snaps.clear()
            return
        if True in eng.excluded.tolist():  # (a list: ndarray.any costs µs here)
            if self.state != "three-gyro":
                self._stop(eng, "three-gyro")
            self.state = "three-gyro"  # no parity with three gyros
        elif self.state in ("three-gyro", "waiting", "disabled") or (
                self.state == "flagged" and not self.flagged_only):
            self.state = "monitoring"
            if self.det is not None:
                self.det.reset()
        if not self.snaps or eng.t - self.snaps[-1].t >= SNAPSHOT_PERIOD_S:
            self._trim(float(eng.t))
            self._snapshot(eng)
        if self.state != "alarm":
            return
        if self.bank is not None:
            self.bank.advance(eng, self.gbuf, self.trk, t)
            verdict, gyro, margin = self.bank.decision(self.llr_threshold(eng))
            self._t_decided = float(eng.t)
            if eng.t <= self.bank.t_alarm:
                verdict = "wait"  # PARITY_ALARM is published for at least one window first
            if verdict == "isolate":
                self._isolate(eng, gyro, margin)
                return
            ended = None
            if verdict == "none":
                ended = "unconfirmed"  # the trackers agree with all four gyros
            elif eng.t - self.bank.t_alarm > BANK_MAX_S:
                ended = "timeout"
            if ended is not None:
                self.counts[ended if ended == "unconfirmed" else "timeouts"] += 1
                self.alarm["bank"] = ended
                self.alarm["bank_summary"] = self.bank.summary()
                self.bank = None
                self.det.reset()  # a new bank needs fresh evidence (and a new onset estimate)
        if self.bank is None and self.det is not None and self.det.quiet >= QUIET_SUMS:
            eng.flags &= ~int(Flag.PARITY_ALARM)
            self.alarm["t_cleared"] = float(eng.t)
            self.state = "monitoring"

    # ------------------------------------------------------------------ internals
    def _check_gen(self, eng) -> None:
        gen = eng.generation()
        if gen != self.gen:  # a new attitude (start, gap): history and hypotheses are void
            self._restart(eng, gen)

    def _restart(self, eng, gen) -> None:
        self.gen = gen
        self.snaps.clear()
        self.bank = None
        # samples after the engine's time are the new history (a caller may have given the FDI
        # the samples of a whole release before the engine processed them)
        self.gbuf.drop_before(float(eng.t))
        self.trk.clear()
        if self.det is not None:
            self.det.reset()
        eng.flags &= ~int(Flag.PARITY_ALARM)
        self.state = "monitoring" if eng.att_valid else "waiting"

    def _stop(self, eng, why: str) -> None:
        if self.bank is not None and self.alarm is not None:
            self.alarm["bank"] = why
        self.bank = None
        eng.flags &= ~int(Flag.PARITY_ALARM)

    def _sync_failed_flags(self, eng) -> None:
        """GYRO_<i>_FAILED follows the exclusion: an operator's include_gyro clears it."""
        if not (int(eng.flags) & _ALL_FAILED or self.flagged_only or self.failed_by_fdi):
            return
        for i, bit in enumerate(GYRO_FAILED[:eng.n_gyro]):
            if eng.excluded[i]:
                self.flagged_only.discard(i)
            if eng.flags & bit and not eng.excluded[i] and i not in self.flagged_only:
                eng.flags &= ~int(bit)
                self.failed_by_fdi.discard(i)
            elif eng.flags & bit:
                self.failed_by_fdi.add(i)  # e.g. restored from a checkpoint


__all__ = ["CONSISTENCY_P", "CUSUM_SHIFT", "NIS_CAP", "PERSIST_M", "FaultMonitor", "HypothesisBank",
           "ParityDetector", "SampleBuffer", "Snapshot", "Thresholds", "chi2_1_isf", "chi2_isf", "cusum_arl0",
           "cusum_threshold", "thresholds"]
