"""The engine's shell around its compiled loop (:mod:`radical_rt.engine.loop`).

:class:`LoopShell` is the part of :class:`radical_rt.engine.filter.Engine` that hands one whole
release of the stream processor to :func:`radical_rt.engine.loop.run_release`, runs the
window hook where the kernel stops for it, and keeps the bookkeeping the kernel reports: the
tracker samples it completed (FDI history, diagnostics, counters), the counters of the call, and
the scalar state it loads and hands back (:meth:`_loop_begin`, :meth:`_loop_end`).
:meth:`_event` runs one of the engine's compiled steps for Python (commands, checks, the end of a
stream) on the same state. No filter step is written here.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt.contract.flags import Flag
from radical_rt.engine import loop as lp
from radical_rt.engine import loop_layout as FL
from radical_rt.engine import steps
from radical_rt.engine.engine_state import EDITED_KEY, USED_KEY
from radical_rt.engine.events import EV_WINDOW_STATE, engine_event
from radical_rt.engine.steps import NUMERIC_GEOMETRY
from radical_rt.fdi.fdi_hypotheses import idle_kernel_args

ST_KIND = {1: "st1", 2: "st2"}
ST_CONSIDER = {1: "st1_consider", 2: "st2_consider"}  # counter of considered updates
ST_EDITED_BIT = {1: int(Flag.ST1_EDITED), 2: int(Flag.ST2_EDITED)}
MODE_CODE = {"init": steps.MODE_INIT, "converging": steps.MODE_CONVERGING,
             "converged": steps.MODE_CONVERGED, "degraded": steps.MODE_DEGRADED}  # IO_MODE
_MODE_NAME = {v: k for k, v in MODE_CODE.items()}
_NO_SUM = None  # no parity sum waiting for the window hook


def numeric_reason(code: int) -> str:
    """The text of a numeric fault the kernel reported with ``code`` (CNT_NUMERIC_CODE)."""
    return "sense-axis geometry singular" if code == NUMERIC_GEOMETRY else f"UD kernel status {code}"


class LoopShell:
    """Mixin of :class:`radical_rt.engine.filter.Engine`: :meth:`release` and its bookkeeping."""

    def release(self, arrays, a: int, z: int, events, predict=None) -> None:
        """One release of the stream processor: for each tracker event (j, t_epoch, q_meas,
        n_stars, valid) in epoch order, the gyro samples up to its epoch, then the sample; then
        the samples up to z. arrays: (t, dt, dtheta, status, bridged, var_extra), samples a..z−1
        (the stream's :class:`~radical_rt.engine.gyro_queue.GyroQueue`), first copied to the FDI's
        history by the kernel. events: a :class:`radical_rt.stream.tracker_queue.EventBlock` (rows
        of the stream's tracker queue, which the kernel reads in place). predict: None, or (pred,
        q_end, clock_I, clock_F) for the kernel's prediction of sample-triggered telemetry at the
        end of a release it completes (see run_release; pred[0] = 1 asks for it, 2 says it was
        made). Runs :meth:`on_window` wherever the kernel stops for the window hook."""
        fdi = self.fdi
        if fdi is not None and z > a:  # the kernel's first call copies a..z−1 to the history
            gbuf = fdi.gbuf
            gbuf.reserve(z - a, self.n_gyro)
            g_f, g_i, g_b, _i0, g_end = gbuf.blocks()
        else:
            g_f, g_i, g_b, g_end = self._no_hist, self._no_hist_i, self._no_hist_b, -1
        pred, q_end, clock_I, clock_F = predict or (self._no_pred, 0, self._no_clock_I,
                                                     self._no_clock_F)
        ev_f, ev_i = events.f, events.i
        n_ev = events.stop  # row numbers of the tracker queue: events.start..n_ev−1
        # the kernel appends the valid tracker samples to the FDI's history (room made per call:
        # the window hook may have cleared it)
        trk, trk_f, trk_i = (None, self._no_trk_f, self._no_trk_i) if fdi is None else (
            fdi.trk, None, None)
        t, dt, dtheta, status, bridged, var_extra = arrays
        R1, R2 = self.geo.R_st1_from_body, self.geo.R_st2_from_body_nom
        io, cnt, run = self._io, self._cnt, lp.run_release
        k, e = a, events.start
        while k < z or e < n_ev:
            bank = None if fdi is None else fdi.kernel_bank()
            if bank is None:
                bk = self._no_bank
            else:  # the kernel runs the bank on its valid tracker samples (FaultMonitor.kernel_bank)
                hist = fdi.gbuf
                bk = bank.kernel_args(self, hist, hist.end + (z - a if g_end >= 0 else 0),
                                      n_ev - e, fdi.llr_threshold(self))
                # the bank reads the FDI history (the copy's blocks above when there is one)
                g_f, g_i, g_b = hist.blocks()[:3]
            if trk is not None:
                trk_f, trk_i = trk.reserve(n_ev - e)
            b = self._loop_begin()
            reason, k, e_stop, stage = run(
                t, dt, dtheta, status, bridged, var_extra, k, z, ev_f, ev_i, e, n_ev, R1, R2,
                self._fb, self._ib, self._bb, self._lay, self._cfg, io, cnt, g_f, g_i, g_b,
                g_end, pred, q_end, clock_I, clock_F, bk[0], bk[1], bk[2], bk[3],
                b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7], b[8], b[9], b[10], b[11], b[12],
                b[13], b[14], trk_f, trk_i, -1 if trk is None else trk.end,
                0 if trk is None else fdi.trk_seq)
            if bank is not None:
                bank.kernel_done()
            if g_end >= 0:
                gbuf.end += z - a
                g_end = -1
            self._loop_end()  # (with the bookkeeping of the tracker events it completed)
            e = e_stop
            if stage == 1:  # the hook after tracker event e
                t_hook = float(ev_f[e, 0])
                e += 1
                self.on_window(t_hook)
            elif reason == lp.R_ON_WINDOW:
                self.on_window(self.t)

    # stand-ins for the FDI history blocks of loop.run_release when there is no history
    _no_hist, _no_hist_i, _no_hist_b = np.zeros((0, 7)), np.zeros(0, np.int64), np.zeros(0, np.bool_)
    # ... and for the FDI bank when none runs in the kernel
    _no_bank = idle_kernel_args()
    # ... and for its prediction when none is asked for (pred[0] = 0)
    _no_pred, _no_clock_I, _no_clock_F = np.zeros(9), np.zeros(0, np.int64), np.zeros(0)
    # ... and for the FDI's tracker history when there is no FDI
    _no_trk_f, _no_trk_i = np.zeros((0, 5)), np.zeros((0, 3), np.int64)

    # ---------------------------------------------------------------- kernel state
    def _loop_begin(self) -> tuple:
        """The scalar state the kernel loads into its io arrays at the start of a call (the last
        eleven arguments of :func:`loop.run_release`; :meth:`_loop_end` takes it back): t,
        locked_since, σ of the time line, wake_t, wake_e, attitude valid, last valid epochs of
        ST1 and ST2, mode code, flags, sum of the parity NIS. It also sets the configuration
        that follows the collaborators: IO_WAKE_EVERY (the window hook after every tracker sample,
        for a bank the kernel cannot run), CFG_FDI_ON and CFG_HOOK_SUM."""
        last, fdi = self.last_valid_st, self.fdi
        wake_t, wake_e = self.hooks.wake()  # the hooks' (the stream's packets and flags)
        if fdi is not None:
            wake_e = min(wake_e, fdi.wake_time())
        self._io[FL.IO_WAKE_EVERY] = 1.0 if fdi is not None and fdi.wake_on_tracker() else 0.0
        cfg = self._cfg
        cfg[FL.CFG_FDI_ON] = 1.0 if fdi is not None and fdi.enabled(self) else 0.0
        cfg[FL.CFG_HOOK_SUM] = 1.0 if fdi is not None or self.excitation is not None else 0.0
        sig_t = self.timing_sigma()
        self.locked = sig_t <= self.si.timing_consider_s  # for the NIS statistics of this call
        nis, locked = self.nis_sum, self.nis_locked
        return (self.t, self.locked_since, sig_t, wake_t, wake_e,
                1.0 if self.att_valid else 0.0, last.get(1, -math.inf), last.get(2, -math.inf),
                MODE_CODE[self.mode], int(self.flags), nis.get("parity", 0.0), nis.get("st1", 0.0),
                nis.get("st2", 0.0), locked["st1"][1], locked["st2"][1])

    def _loop_end(self) -> None:
        """The scalar state and the counters of a call back from the io arrays."""
        v, c = self._io.tolist(), self._cnt.tolist()  # (plain floats and ints: one read each)
        self.t, self.locked_since = v[FL.IO_T], v[FL.IO_LOCKED_SINCE]
        self.att_valid = v[FL.IO_ATT_VALID] != 0.0
        self.mode = _MODE_NAME[v[FL.IO_MODE]]
        self.flags = c[FL.CNT_FLAGS]
        counters = self.counters
        for name, i in self._COUNTED:
            if c[i]:
                counters[name] += c[i]
        if c[FL.CNT_MASKED] >= 0:
            self.masked = c[FL.CNT_MASKED] != 0
        if c[FL.CNT_GAPS]:
            counters["warm_starts"] += c[FL.CNT_GAPS]
        if c[FL.CNT_RESETS] and self.excitation is not None:
            self.excitation.clear()
        if c[FL.CNT_NUMERIC]:
            self.last_numeric = numeric_reason(c[FL.CNT_NUMERIC_CODE])
        if c[FL.CNT_PAR_USED] or c[FL.CNT_PAR_EDITED]:
            self._parity_done(c[FL.CNT_PAR_USED], v[FL.IO_NIS_SUM_PAR])
        if c[FL.CNT_PAR_SUMS]:
            self._sum_pending = ((v[FL.IO_PAR_NU], v[FL.IO_PAR_RHO], v[FL.IO_PAR_T0],
                                  v[FL.IO_PAR_Z]) if c[FL.CNT_PAR_STAT] else ())
        if c[FL.CNT_FIRST_VALID]:
            self._trackers_done(v, c)

    def _trackers_done(self, v: list, c: list) -> None:
        """The bookkeeping of the tracker samples a call completed (:func:`loop._book_tracker`;
        v, c: the io and cnt arrays as lists): last valid epochs, the FDI history's new rows,
        and per tracker kind the last diagnostics, the counters and NIS sums. New keys of these
        maps are added in the order of the samples, as sample-by-sample bookkeeping would."""
        first = c[FL.CNT_FIRST_VALID]
        last = self.last_valid_st
        for j in (first, 3 - first):
            t_last = v[FL.IO_LAST_ST + j]
            if t_last != last.get(j, -math.inf):
                last[j] = t_last
        added = c[FL.CNT_TRK_ADDED]
        if added and self.fdi is not None:
            self.fdi.trk.end += added
            self.fdi.trk_seq += added
        first = c[FL.CNT_FIRST_UPDATED]
        if not first:
            return
        counters = self.counters
        for j in (first, 3 - first):
            k = j - 1
            if not c[FL.CNT_DIAG_ST + k]:
                continue
            kind, d = ST_KIND[j], (FL.IO_DIAG_ST1 if j == 1 else FL.IO_DIAG_ST2)
            self.diag_last[kind] = (v[d + 1:d + 4], v[d + 4:d + 7], v[d])  # (lists: read once)
            if c[FL.CNT_CONSIDER_ST + k]:
                counters[ST_CONSIDER[j]] += c[FL.CNT_CONSIDER_ST + k]
            if c[FL.CNT_EDITED_ST + k]:
                counters[EDITED_KEY[kind]] += c[FL.CNT_EDITED_ST + k]
            used = c[FL.CNT_USED_ST + k]
            if used:
                counters[USED_KEY[kind]] += used
                self.nis_sum[kind] = v[FL.IO_NIS_SUM_ST + k]
            if c[FL.CNT_LOCKED_ST + k]:
                rec = self.nis_locked[kind]
                rec[0] += c[FL.CNT_LOCKED_ST + k]
                rec[1] = v[FL.IO_NIS_LOCKED_ST + k]

    #: (counter, CNT field) added after every call
    _COUNTED = (("siru_used", FL.CNT_USED), ("siru_undetermined", FL.CNT_UNDETERMINED),
                ("st1_invalid", FL.CNT_INVALID_ST1), ("st2_invalid", FL.CNT_INVALID_ST2),
                ("siru_pre_init", FL.CNT_PRE_INIT), ("gyro_gaps", FL.CNT_GAPS),
                ("att_inits", FL.CNT_ATT_INITS), ("numeric_faults", FL.CNT_NUMERIC),
                ("parity_used", FL.CNT_PAR_USED), ("parity_edited", FL.CNT_PAR_EDITED),
                ("parity_early", FL.CNT_PAR_EARLY))

    _sum_pending = _NO_SUM  # the FDI statistic of a parity sum queued since the last hook

    def _parity_done(self, used: int, nis_sum: float) -> None:
        """Diagnostics of the parity updates of a call: the last one's innovation, σ and NIS,
        the running NIS sum, and the NIS of the used ones while the time line was locked."""
        self.diag_last["parity"] = (self.par_innov.copy(), self.par_sig.copy(),
                                    float(self._io[FL.IO_PAR_NIS]))
        if used:
            if self.locked:
                self.nis_locked["parity"][0] += used
                self.nis_locked["parity"][1] += nis_sum - self.nis_sum.get("parity", 0.0)
            self.nis_sum["parity"] = nis_sum

    def _event(self, code: int, arg: int = 0, t: float = 0.0) -> None:
        """Run :func:`radical_rt.engine.events.engine_event` ``code`` (EV_*; int ``arg``, time
        ``t`` [s]) on the engine's state."""
        b = self._loop_begin()
        engine_event(code, arg, t, self._fb, self._ib, self._bb, self._lay, self._cfg,
                        self._io, self._cnt, b[0], b[1], b[2], b[5], b[6], b[7],
                        b[8], b[9], b[10])
        self._loop_end()

    def _window_state(self, t: float) -> None:
        """:meth:`_event` EV_WINDOW_STATE (the flags and the mode after a close at event time t
        [s], steps.window_state) for the window hook, without the wake times, the collaborators'
        settings and the read-back of every counter: the step reads the attitude flag, the last
        valid epochs, the flags and the factors, and changes only the flags and the mode. The
        other scalars are loaded as they stand (σ_t as the last call left it)."""
        last, io, cnt = self.last_valid_st, self._io, self._cnt
        engine_event(EV_WINDOW_STATE, 0, t, self._fb, self._ib, self._bb, self._lay, self._cfg,
                     io, cnt, self.t, self.locked_since, float(io[FL.IO_SIG_T]),
                     1.0 if self.att_valid else 0.0, last.get(1, -math.inf),
                     last.get(2, -math.inf), MODE_CODE[self.mode], int(self.flags),
                     self.nis_sum.get("parity", 0.0))
        self.flags = int(cnt[FL.CNT_FLAGS])
        self.mode = _MODE_NAME[float(io[FL.IO_MODE])]

    def _loop_config(self) -> None:
        """Scalar parameters and io arrays of the kernel (after every parameter change)."""
        si = self.si
        self._cfg = FL.CFG.pack({
            "prop_window": si.prop_window, "arw_var": si.arw_var_per_s, "quant_var": si.quant_var,
            "regressor_k": si.regressor_k_sigma, "parity_window": si.parity_window,
            "gyro_gap": si.gyro_gap_s, "parity_lag": si.parity_lag_s,
            "st_stale": si.st_stale_s, "timing_consider": si.timing_consider_s,
            "n_gyro": self.n_gyro, "st_ref_stars": si.st_ref_stars,
            "gate_nis": si.gate_st_nis, "edit": 1.0 if si.edit_enabled else 0.0,
            "phi_col": self._phi_col, "lat_col": self._lat_col, "phi_p": self._phi_col - 3,
            "lat_p": self._lat_col - 3, "st_min_stars": si.st_min_stars,
            "gate_parity": si.gate_parity_nis, "att_init_scale": si.att_init_scale,
            "fdi_on": 0.0, "hook_sum": 0.0})
        self._io = np.zeros(FL.IO.end)
        self._cnt = np.zeros(FL.CNT.end, np.int64)
