"""The engine's shell around its compiled fast path (:mod:`radical_rt.engine.fastpath`).

:class:`FastRelease` is the part of :class:`radical_rt.engine.filter.Engine` that hands one whole
release of the stream processor to :func:`radical_rt.engine.fastpath.fast_release` and does, in Python,
what the kernel hands back: the bookkeeping of the tracker samples it completed, the reference
steps from a handover point on (:meth:`_window_done`, :meth:`_tracker_done`), and the loading
and unloading of the scalar state it reads and writes (:meth:`_fast_begin`, and the end of each
kernel call in :meth:`release`).
The reference path itself (``Engine.gyro``, ``Engine.tracker`` and their helpers) stays in
:mod:`radical_rt.engine.filter`; docs/engine.md §1.1 describes both.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from radical_rt.contract.flags import Flag
from radical_rt.engine import fastpath as fp
from radical_rt.engine import fastpath_layout as FL
from radical_rt.fdi.fdi_hypotheses import idle_kernel_args

ST_KIND = {1: "st1", 2: "st2"}
ST_EDITED_BIT = {1: int(Flag.ST1_EDITED), 2: int(Flag.ST2_EDITED)}
_MODE_CODE = {"converging": fp.MODE_CONVERGING, "converged": fp.MODE_CONVERGED,
              "degraded": fp.MODE_DEGRADED}  # IO_MODE of radical_rt.engine.fastpath_layout ("init": −1)


def _span(arrays, a: int, b: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                            np.ndarray, np.ndarray]:
    """Samples a..b−1 of gyro arrays (t, dt, dtheta, status, bridged, var_extra), as views."""
    t, dt, dtheta, status, bridged, var_extra = arrays
    return t[a:b], dt[a:b], dtheta[a:b], status[a:b], bridged[a:b], var_extra[a:b]


class FastRelease:
    """Mixin of :class:`radical_rt.engine.filter.Engine`: :meth:`release` and its fast-path glue."""

    def release(self, arrays, a: int, z: int, events, predict=None) -> None:
        """One release of the stream processor: for each tracker event (j, t_epoch, q_meas,
        n_stars, valid) in epoch order, the gyro samples up to its epoch, then the sample; then
        the samples up to z. arrays: (t, dt, dtheta, status, bridged, var_extra), samples a..z−1
        (the stream's :class:`~radical_rt.engine.gyro_queue.GyroQueue`), first given to the FDI's
        history (:meth:`radical_rt.fdi.monitor.FaultMonitor.on_gyro_rows`, or the kernel's own copy).
        events: a :class:`radical_rt.stream.tracker_queue.EventBlock` (rows of the stream's tracker
        queue, which the kernel reads in place). predict: None, or (pred, q_end, clock_I,
        clock_F) for the kernel's prediction of sample-triggered telemetry at the end of a release
        it completes (see fast_release; pred[0] = 1 asks for it, 2 says it was made). The same as
        the reference calls, run by :func:`fastpath.fast_release` while it applies."""
        fdi = self.fdi
        if not (self.fast and self.att_valid):
            if fdi is not None and z > a:
                fdi.on_gyro_rows(arrays, a, z)
            self._release_ref(arrays, a, z, events)
            return
        if fdi is not None and z > a:  # the kernel's first call copies a..z−1 to the history
            gbuf = fdi.gbuf
            gbuf.reserve(z - a, self.n_gyro)
            g_f, g_i, g_b, _i0, g_end = gbuf.blocks()
        else:
            g_f, g_i, g_b, g_end = self._no_hist, self._no_hist_i, self._no_hist_b, -1
        pred, q_end, clock_I, clock_F = predict or (self._no_pred, 0, self._no_clock_I,
                                                     self._no_clock_F)
        ev_f, ev_i, evo_f, evo_i = events.f, events.i, events.out_f, events.out_i
        n_ev = events.stop  # row numbers of the tracker queue: events.start..n_ev−1
        t, dt, dtheta, status, bridged, var_extra = arrays
        R1, R2 = self.geo.R_st1_from_body, self.geo.R_st2_from_body_nom
        io, cnt, run = self._fast_io, self._fast_cnt, fp.fast_release
        k, e = a, events.start
        while k < z or e < n_ev:
            if not self.att_valid:
                self._release_ref(arrays, k, z, events.after(e))
                return
            bank = None if fdi is None else fdi.kernel_bank()
            if bank is None:
                bk = self._no_bank
            else:  # the kernel runs the bank on its valid tracker samples (FaultMonitor.kernel_bank)
                hist = fdi.gbuf
                bk = bank.kernel_args(self, hist, hist.end + (z - a if g_end >= 0 else 0),
                                      n_ev - e, fdi.llr_threshold(self))
            reason, k, e_stop, stage = run(
                t, dt, dtheta, status, bridged, var_extra, k, z, ev_f, ev_i, e, n_ev, R1, R2,
                self._fb, self._ib, self._bb, self._lay, self._fast_cfg, io, cnt, evo_f, evo_i,
                g_f, g_i, g_b, g_end, pred, q_end, clock_I, clock_F, bk, *self._fast_begin())
            if bank is not None:
                bank.kernel_done()
            if g_end >= 0:
                gbuf.end += z - a
                g_end = -1
            # _fast_end: the scalar state back from the io arrays
            self.t, self.locked_since = float(io[FL.IO_T]), float(io[FL.IO_LOCKED_SINCE])
            self.flags, used = int(cnt[FL.CNT_FLAGS]), int(cnt[FL.CNT_USED])
            undetermined, masked = int(cnt[FL.CNT_UNDETERMINED]), int(cnt[FL.CNT_MASKED])
            inv1, inv2 = int(cnt[FL.CNT_INVALID_ST1]), int(cnt[FL.CNT_INVALID_ST2])
            if inv1:
                self.counters["st1_invalid"] += inv1
            if inv2:
                self.counters["st2_invalid"] += inv2
            if used:
                self.counters["siru_used"] += used
            if undetermined:
                self.counters["siru_undetermined"] += undetermined
            if masked >= 0:
                self.masked = masked != 0
            if e_stop > e:  # events the kernel completed
                self._trackers_taken(events, e, e_stop)
            e = e_stop
            if stage == 1:
                self._tracker_done(reason, events, e)
                e += 1
                continue
            if reason == fp.R_DONE:
                continue
            # the reference path to the next event (or to z); the kernel then takes the event
            seg = z if e >= n_ev else k + int(np.searchsorted(t[k:z], ev_f[e, 0], side="right"))
            if reason == fp.R_SLOW:  # a gap at sample k
                self._gyro_body(*_span(arrays, k, seg), 0)
                k = seg
            else:
                self._window_done(reason)
                if not self.att_valid and k < seg:
                    self._gyro_resume(*_span(arrays, k, seg))
                    k = seg

    def _release_ref(self, arrays, a: int, z: int, events) -> None:
        """The reference path of :meth:`release` (the FDI history already has the samples)."""
        t = arrays[0]
        k = a
        for ev in events:
            up = k + int(np.searchsorted(t[k:z], ev[1], side="right"))
            if up > k:
                self._gyro_body(*_span(arrays, k, up), 0)
            k = up
            self.tracker(*ev)
        if z > k:
            self._gyro_body(*_span(arrays, k, z), 0)

    # stand-ins for the FDI history blocks of fastpath.fast_release when there is no history
    _no_hist, _no_hist_i, _no_hist_b = np.zeros((0, 7)), np.zeros(0, np.int64), np.zeros(0, np.bool_)
    # ... and for the FDI bank when none runs in the kernel
    _no_bank = idle_kernel_args()
    # ... and for its prediction when none is asked for (pred[0] = 0)
    _no_pred, _no_clock_I, _no_clock_F = np.zeros(9), np.zeros(0, np.int64), np.zeros(0)

    def _trackers_taken(self, events, e: int, e_stop: int) -> bool:
        """The reference path's bookkeeping of the rows e..e_stop−1 of an event block the kernel
        completed (valid tracker samples; an invalid one it only counted is skipped): last valid epoch, FDI hook and, where the update ran,
        status check, diagnostics and counters, read from the block's arrays in one pass (no event
        tuples; the FDI's quaternions and the diagnostics are rows of one copy each). Returns
        whether the last row's update was used."""
        f = events.f
        heads, epochs = events.i[e:e_stop].tolist(), f[e:e_stop, 0].tolist()
        quats, outs_f = f[e:e_stop, 1:5].copy(), events.out_f[e:e_stop].copy()
        outs_i = events.out_i[e:e_stop].tolist()
        last, fdi = self.last_valid_st, self.fdi
        used = False
        for r, head in enumerate(heads):
            status, edited, updated, consider = outs_i[r]
            used = False
            if updated < 0:  # an invalid sample: the kernel counted it, nothing else to do
                continue
            j, t_epoch = head[0], epochs[r]
            last[j] = t_epoch
            if fdi is not None:
                fdi.on_tracker(j, t_epoch, quats[r], head[1])
            if not updated:
                continue
            kind = ST_KIND[j]
            if consider:
                self.counters[kind + "_consider"] += 1
            if status:
                self._check(status)
            out_f = outs_f[r]
            used = self._update_done(kind, out_f[1:4], out_f[4:7], float(out_f[0]), edited != 0)
        return used

    def _window_done(self, reason: int) -> None:
        """Python's share of a window close the gyro fast path handed over."""
        if reason == fp.R_CLOSE_TAIL:
            self._check(int(self._fast_cnt[FL.CNT_STATUS]))
            self._close_tail()
            self._apply_correction()
        elif reason == fp.R_NUMERIC_FOLD:
            self._numeric("sense-axis geometry singular")
        self.on_window(self.t)

    # ---------------------------------------------------------------- fast-path glue
    fast = True  # use radical_rt.engine.fastpath (the dense reference of perf/ turns it off)

    def _fast_begin(self) -> tuple:
        """The scalar state the fast path loads into its io arrays at the start of a call (the
        last ten arguments of :func:`fastpath.fast_release`; :meth:`release` takes it back after
        each call): t, locked_since, σ of the time line, wake_t, wake_e, epoch of the oldest
        queued parity sum, last valid epochs of ST1 and ST2, mode code, flags. It also sets
        IO_WAKE_EVERY (the window hook after every tracker sample) from the FDI (a bank that the kernel
        cannot run itself)."""
        last, pq, fdi, src = self.last_valid_st, self.parity_queue, self.fdi, self.wake_source
        wake_e = math.inf if fdi is None else fdi.wake_time()
        # the FDI's bank wants the window hook after every tracker sample
        self._fast_io[FL.IO_WAKE_EVERY] = 1.0 if fdi is not None and fdi.wake_on_tracker() else 0.0
        if src is None:
            wake_t = math.inf
        else:  # the listener's (the stream's packets and flags)
            wake_t, e = src()
            wake_e = min(wake_e, e)
        return (self.t, self.locked_since, self.timing_sigma(), wake_t, wake_e,
                pq[0][0] if pq else math.inf, last.get(1, -math.inf), last.get(2, -math.inf),
                _MODE_CODE.get(self.mode, -1.0), int(self.flags))

    def _fast_config(self) -> None:
        """Scalar parameters and io arrays of the fast path (after every parameter change)."""
        si = self.si
        self._fast_cfg = FL.CFG.pack({
            "prop_window": si.prop_window, "arw_var": si.arw_var_per_s, "quant_var": si.quant_var,
            "regressor_k": si.regressor_k_sigma, "parity_window": si.parity_window,
            "gyro_gap": si.gyro_gap_s, "parity_lag": si.parity_lag_s,
            "st_stale": si.st_stale_s, "timing_consider": si.timing_consider_s,
            "n_gyro": self.n_gyro, "st_ref_stars": si.st_ref_stars,
            "gate_nis": si.gate_st_nis, "edit": 1.0 if si.edit_enabled else 0.0,
            "phi_col": self._phi_col, "lat_col": self._lat_col, "phi_p": self._phi_col - 3,
            "lat_p": self._lat_col - 3, "st_min_stars": si.st_min_stars})
        self._fast_io = np.zeros(FL.IO.end)
        self._fast_cnt = np.zeros(FL.CNT.end, np.int64)

    # callable() → (wake_t, wake_e) of the listener (the stream's packets): the event time and
    # the engine time from which on_window has work although the flags stay the same (−inf: at
    # once); _fast_begin combines it with the FDI's wake_time()
    wake_source: Callable[[], tuple[float, float]] | None = None

    def _tracker_done(self, reason: int, events, e: int) -> None:
        """Row e of the event block, at which :func:`radical_rt.engine.fastpath.fast_release` handed
        over: the bookkeeping of what the kernel did, then the reference steps from there."""
        ev = events.event(e)
        used = self._trackers_taken(events, e, e + 1)
        j, t_epoch, q_meas, n_stars, _valid = ev
        if reason == fp.R_CLOSE_TAIL or reason == fp.R_TRACKER_SLOW:
            if reason == fp.R_CLOSE_TAIL:
                self._check(int(events.out_i[e, 0]))
                self._close_tail()
            self._tracker_update(j, t_epoch, q_meas, n_stars)
            self._apply_correction()
        elif reason == fp.R_VEC_STATUS:
            bit = ST_EDITED_BIT[j]
            self.flags = (self.flags & ~bit) | (0 if used else bit)
            self._apply_correction()
        elif reason == fp.R_NUMERIC_FOLD:
            self._numeric("sense-axis geometry singular")
        self.on_window(t_epoch)
