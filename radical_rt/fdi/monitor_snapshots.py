"""The FDI monitor's engine snapshots and the trimming of its history.

:class:`SnapshotSteps` is a part of :class:`radical_rt.fdi.monitor.FaultMonitor` (a mixin: it
works on the monitor's own state). Every ``SNAPSHOT_PERIOD_S`` of engine time the monitor keeps a
copy of the engine's state (:class:`radical_rt.fdi.fdi_history.Snapshot`: the bank starts from one
and the rollback returns to one) and drops the history older than ``BUFFER_S``. Its window hook
does that (:meth:`SnapshotSteps._snapshot`); while monitoring, the engine's compiled loop does it
itself at the parity sum where the snapshot is due (:func:`radical_rt.fdi.fdi_quiet.put_snapshot`:
the same state at the same close, copied to a slot after the fields of the monitor's array
``fq``), and :meth:`SnapshotSteps._slot_snapshots` makes the records after the call, in order,
with the same trimming, so that the records are those the hook would have made.
"""

from __future__ import annotations

import numpy as np

from radical_rt.fdi import fdi_quiet as FQ
from radical_rt.fdi.fdi_detect import DTH
from radical_rt.fdi.fdi_history import Snapshot

SNAPSHOT_PERIOD_S = 5.0  # engine snapshots for the rollback and the bank start
BUFFER_S = 600.0  # gyro and tracker history kept for the bank


class SnapshotSteps:
    """Snapshots and history trimming of :class:`radical_rt.fdi.monitor.FaultMonitor` (which
    provides ``snaps``, ``gbuf``, ``trk``, ``trk_seq``, ``gen``, ``bank``, ``det`` and ``fq``)."""

    def _trim(self, t: float) -> None:
        """Drop the snapshots, gyro rows and tracker samples older than BUFFER_S before engine
        time t [s] (or the running bank's start), keeping at least one snapshot."""
        t_min = t - BUFFER_S
        if self.bank is not None:
            t_min = min(t_min, self.bank.t_last)
        while self.snaps and self.snaps[0].t < t_min and len(self.snaps) > 1:
            self.snaps.popleft()
        t_keep = min(t_min, self.snaps[0].t) if self.snaps else t_min
        self.gbuf.drop_before(t_keep)
        keep_seq = self.snaps[0].trk_seq if self.snaps else self.trk_seq
        if self.bank is not None:
            keep_seq = min(keep_seq, self.bank.trk_seq)
        self.trk.drop_through(keep_seq)

    def _snapshot(self, eng) -> None:
        """A snapshot of the engine's state now (none without an attitude)."""
        if not eng.att_valid or not np.isfinite(eng.t):
            return
        self.snaps.append(Snapshot(
            t=float(eng.t), trk_seq=self.trk_seq, gen=self.gen, q=eng.q.copy(),
            omega=eng.omega.copy(), xp=eng.xp.copy(), U=eng.U.copy(), d=eng.d.copy(),
            N=eng.N.copy()))

    def _snapshot_slots(self, eng) -> None:
        """Room in ``fq`` for FQ.SNAP_SLOTS snapshots of this engine's state, made once (the
        array is replaced, its fields kept, the detector's views bound to the new one)."""
        size = int(FQ.snapshot_size(eng.xp.shape[0], eng.d.shape[0], eng.N.size))
        if self.fq[FQ.Q_SNAP_LEN] == size:
            return
        fq = np.zeros(FQ.QF.end + FQ.SNAP_SLOTS * size)
        fq[:FQ.QF.end] = self.fq[:FQ.QF.end]
        fq[FQ.Q_SNAP_LEN], fq[FQ.Q_SNAPS] = size, 0.0
        self.fq = fq
        self._bind_detector()

    def _bind_detector(self) -> None:
        """The detector's statistics and configuration as views of ``fq`` (their values kept),
        which the engine's loop updates."""
        det, fq = self.det, self.fq
        if det is not None:
            fq[FQ.Q_DET:FQ.Q_TH], fq[FQ.Q_TH:FQ.Q_TH + DTH.end] = det.state, det.config
            det.state, det.config = fq[FQ.Q_DET:FQ.Q_TH], fq[FQ.Q_TH:FQ.Q_TH + DTH.end]

    def _slot_snapshots(self, eng) -> None:
        """The snapshots the engine's loop put into ``fq``'s slots since the monitor last
        looked: for each, in order, the history trimmed at its time and its record kept, as
        the window hook of its parity sum would have done."""
        fq = self.fq
        k = int(fq[FQ.Q_SNAPS])
        if not k:
            return
        fq[FQ.Q_SNAPS] = 0.0
        npar, ns, (rows, cols) = eng.xp.shape[0], eng.d.shape[0], eng.N.shape
        for s in range(k):
            head, q, omega, xp, U, d, N = FQ.slot_views(fq, s, npar, ns, rows, cols)
            t, seq = head.tolist()
            self._trim(t)
            self.snaps.append(Snapshot(t=t, trk_seq=int(seq), gen=self.gen, q=q.copy(),
                                       omega=omega.copy(), xp=xp.copy(), U=U.copy(), d=d.copy(),
                                       N=N.copy()))
