"""The engine's shell around its compiled loop (:mod:`radical_rt.engine.loop`).

:class:`LoopShell` is the part of :class:`radical_rt.engine.filter.Engine` that hands one whole
release of the stream processor to :func:`radical_rt.engine.loop.run_release`, runs the
window hook where the kernel stops for it, and takes the bookkeeping the kernel counts: the
tracker samples it completed (diagnostics, counters, NIS sums), the parity updates and sums, the
numeric faults (:meth:`_drain`, when Python reads them; the FDI's tracker history after every
call, :meth:`_call_done`). The scalar state stays in the kernel's io and cnt arrays between calls
(the engine's attributes are views of them, :mod:`radical_rt.engine.engine_state`).
:meth:`_event` runs one of the engine's compiled steps for Python (commands, checks, the end of a
stream) on the same state. No filter step is written here.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt.contract.flags import Flag
from radical_rt.engine import loop as lp
from radical_rt.engine import loop_layout as FL
from radical_rt.engine.engine_state import EDITED_KEY, USED_KEY
from radical_rt.engine.events import EV_WINDOW_STATE, engine_event
from radical_rt.engine.steps import NUMERIC_GEOMETRY
from radical_rt.fdi.fdi_hypotheses import idle_kernel_args
from radical_rt.fdi.fdi_quiet import Q_TAKEN, QF

ST_KIND = {1: "st1", 2: "st2"}
ST_CONSIDER = {1: "st1_consider", 2: "st2_consider"}  # counter of considered updates
ST_EDITED_BIT = {1: int(Flag.ST1_EDITED), 2: int(Flag.ST2_EDITED)}


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
            g_end = gbuf.blocks()[4]
        else:
            g_end = -1
        self._calls(arrays, a, z, events.f, events.i, events.start, events.stop, g_end, predict)

    def hook_after(self, reason: int, stage: int, e: int, ev_f) -> int:
        """After a compiled call another kernel made for a release (the stream's block intake,
        radical_rt.stream.intake_block, with this shell's inputs) returned (reason, ·, e, stage):
        the bookkeeping after a call (:meth:`_call_done`) and the window hook where it stopped for
        it (ev_f: the tracker queue's rows). Returns the next tracker row of the release."""
        self._undrained = True
        self._call_done()
        return self._after_call(reason, stage, e, ev_f)

    def continue_release(self, arrays, k: int, z: int, ev_f, ev_i, e: int, n_ev: int,
                         predict) -> None:
        """The rest of such a release (after :meth:`hook_after`): gyro samples k..z−1, tracker
        rows e..n_ev−1, arguments as in :meth:`release`."""
        self._calls(arrays, k, z, ev_f, ev_i, e, n_ev, -1, predict)

    def _calls(self, arrays, a: int, z: int, ev_f, ev_i, e: int, n_ev: int, g_end: int,
               predict) -> None:
        """The compiled calls of a release from sample a and tracker row e (g_end ≥ 0: the first
        call copies a..z−1 to the FDI's history from that row), with the window hook where a
        call stops for it."""
        fdi = self.fdi
        if g_end >= 0:
            g_f, g_i, g_b = fdi.gbuf.blocks()[:3]
        else:
            g_f, g_i, g_b = self._no_hist, self._no_hist_i, self._no_hist_b
        pred, q_end, clock_I, clock_F = predict or (self._no_pred, 0, self._no_clock_I,
                                                     self._no_clock_F)
        # the kernel appends the valid tracker samples to the FDI's history (room made per call:
        # the window hook may have cleared it)
        trk, trk_f, trk_i = (None, self._no_trk_f, self._no_trk_i) if fdi is None else (
            fdi.trk, None, None)
        t, dt, dtheta, status, bridged, var_extra = arrays
        R1, R2 = self.geo.R_st1_from_body, self.geo.R_st2_from_body_nom
        io, cnt, run = self._io, self._cnt, lp.run_release
        k = a
        while k < z or e < n_ev:
            bank, wake_fdi, every, fdi_on = self._fdi_release_inputs()
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
            sig_t, wake_t, wake_e = self._call_inputs(every, fdi_on)
            reason, k, e_stop, stage = run(
                t, dt, dtheta, status, bridged, var_extra, k, z, ev_f, ev_i, e, n_ev, R1, R2,
                self._fb, self._ib, self._bb, self._lay, self._cfg, io, cnt, g_f, g_i, g_b,
                g_end, pred, q_end, clock_I, clock_F, bk[0], bk[1], bk[2], bk[3], sig_t, wake_t,
                wake_e, wake_fdi, self._no_fq if fdi is None else fdi.fq, trk_f, trk_i,
                -1 if trk is None else trk.end, 0 if trk is None else fdi.trk_seq)
            self._undrained = True  # the counters of the call: taken when Python reads them
            if bank is not None:
                bank.kernel_done()
            if g_end >= 0:
                fdi.gbuf.end += z - a
                g_end = -1
            self._call_done()
            e = self._after_call(reason, stage, e_stop, ev_f)

    def _after_call(self, reason: int, stage: int, e: int, ev_f) -> int:
        """The window hook where a compiled call stopped for it (stage 1: after tracker row e,
        at its epoch); returns the next tracker row."""
        if stage == 1:  # the hook after tracker event e
            t_hook = float(ev_f[e, 0])
            e += 1
            self.on_window(t_hook)
        elif reason == lp.R_ON_WINDOW:
            self.on_window(self.t)
        return e

    # ---------------------------------------------------------------- calls made by another kernel
    def outside_calls(self, samples: int, trackers: int) -> tuple | None:
        """What a kernel that calls :func:`radical_rt.engine.loop.run_release` itself (the
        stream's block intake) needs for up to ``samples`` gyro samples and ``trackers`` tracker
        samples released, with room made in the FDI's histories; None when those calls must be
        this shell's (the FDI's window hook has work after every tracker sample). Sets the
        configuration that follows the collaborators (:meth:`_call_inputs`). Returns (wake_fdi
        [s], the FDI's array of the sums it takes in the loop (radical_rt.fdi.fdi_quiet), R1,
        R2, fb, ib, bb, lay, cfg, io, cnt, the bank's four buffers (the running bank's,
        FaultMonitor.kernel_bank, with its history end as of now: the kernel sets it before each
        release, fdi_bank_pack.bank_set_end; else the idle bank's), g_f, g_i, g_b, g_end, trk_f,
        trk_i, trk_end, trk_seq); g_end, trk_end −1: no FDI. :meth:`outside_done` takes the ends
        and the bank's steps back."""
        bank, wake_fdi, every, fdi_on = self._fdi_release_inputs()
        if every:
            return None
        fdi = self.fdi
        bk = self._no_bank
        if fdi is None:
            hist = (self._no_hist, self._no_hist_i, self._no_hist_b, -1, self._no_trk_f,
                    self._no_trk_i, -1, 0)
        else:
            fdi.gbuf.reserve(samples, self.n_gyro)
            g_f, g_i, g_b, _i0, g_end = fdi.gbuf.blocks()
            trk_f, trk_i = fdi.trk.reserve(trackers)
            hist = (g_f, g_i, g_b, g_end, trk_f, trk_i, fdi.trk.end, fdi.trk_seq)
            if bank is not None:  # (after the reserve: its rows may have moved)
                bk = bank.kernel_args(self, fdi.gbuf, g_end, trackers, fdi.llr_threshold(self))
        self._outside_bank = bank
        self._set_collaborators(every, fdi_on)  # (last: IO_GEN0 as of the call)
        fq = self._no_fq if fdi is None else fdi.fq
        return (wake_fdi, fq, self.geo.R_st1_from_body, self.geo.R_st2_from_body_nom, self._fb,
                self._ib, self._bb, self._lay, self._cfg, self._io, self._cnt, *bk) + hist

    def outside_done(self, g_end: int, trk_end: int, trk_seq: int, called: bool) -> None:
        """After a kernel's own calls (:meth:`outside_calls`): the FDI histories' new ends and
        sequence number; ``called``: whether it made any (their counts are taken when read;
        an attitude reset among them clears the excitation monitor, :meth:`_call_done`)."""
        bank, self._outside_bank = self._outside_bank, None
        if bank is not None:
            bank.kernel_done()
        fdi = self.fdi
        if fdi is not None:
            fdi.gbuf.end, fdi.trk.end, fdi.trk_seq = g_end, trk_end, trk_seq
        if called:
            self._undrained = True
            self._call_done()

    _outside_bank = None  # the bank handed to the kernel of the last outside_calls
    # stand-ins for the FDI history blocks of loop.run_release when there is no history
    _no_hist, _no_hist_i, _no_hist_b = np.zeros((0, 7)), np.zeros(0, np.int64), np.zeros(0, np.bool_)
    # ... and for the FDI bank when none runs in the kernel
    _no_bank = idle_kernel_args()
    # ... and for its prediction when none is asked for (pred[0] = 0)
    _no_pred, _no_clock_I, _no_clock_F = np.zeros(9), np.zeros(0, np.int64), np.zeros(0)
    # ... and for the FDI's tracker history when there is no FDI
    _no_trk_f, _no_trk_i = np.zeros((0, 5)), np.zeros((0, 3), np.int64)
    # ... and for the FDI's array of the sums it takes in the loop (never on)
    _no_fq = np.zeros(QF.end)

    # ---------------------------------------------------------------- kernel state
    def _call_inputs(self, every: bool, fdi_on: bool) -> tuple[float, float, float]:
        """The collaborators' inputs of a compiled call: σ of the time line [s] and the wake
        times wake_t, wake_e [s] (the hooks': the stream's packets and flags; the FDI's
        ``wake_fdi``). Also sets the configuration that follows the collaborators:
        IO_WAKE_EVERY (``every``: the window hook after every tracker sample, for a bank the
        kernel cannot run), CFG_FDI_ON (``fdi_on``) and CFG_HOOK_SUM (a parity sum wakes the
        hook: an FDI or an excitation monitor). The FDI's figures come from
        :meth:`radical_rt.fdi.monitor.FaultMonitor.release_inputs` (without FDI: inf, False,
        False). The rest of the scalar state stays in io and cnt between calls."""
        wake_t, wake_e = self.hooks.wake()
        self._set_collaborators(every, fdi_on)
        return self.timing_sigma(), wake_t, wake_e

    def _fdi_release_inputs(self) -> tuple:
        """:meth:`radical_rt.fdi.monitor.FaultMonitor.release_inputs` (bank, wake time, window
        hook after every tracker sample, enabled); without FDI (None, inf, False, False)."""
        fdi = self.fdi
        return (None, math.inf, False, False) if fdi is None else fdi.release_inputs(self)

    def _set_collaborators(self, every: bool, fdi_on: bool) -> None:
        """The configuration that follows the collaborators (see :meth:`_call_inputs`), and
        for the parity sums the FDI may take in the loop (handover.take_sum_here) the excitation
        monitor's next step (IO_EX_NEXT) and the restarts counted as the FDI saw them
        (IO_GEN0: right before the call, the counters not taken since)."""
        io, cnt, ex = self._io, self._cnt, self.excitation
        io[FL.IO_WAKE_EVERY] = 1.0 if every else 0.0
        io[FL.IO_EX_NEXT] = math.inf if ex is None else ex.next_step()
        io[FL.IO_GEN0] = cnt.item(FL.CNT_GAPS) + cnt.item(FL.CNT_ATT_INITS)
        cfg = self._cfg
        cfg[FL.CFG_FDI_ON] = 1.0 if fdi_on else 0.0
        cfg[FL.CFG_HOOK_SUM] = 1.0 if self.fdi is not None or self.excitation is not None else 0.0

    def _call_done(self) -> None:
        """After a compiled call, what cannot wait until Python reads the bookkeeping: the FDI's
        tracker history grows by the rows the kernel appended, the FDI keeps the records of the
        parity sums it took in the loop, and an attitude reset clears the excitation monitor."""
        cnt = self._cnt
        if self.fdi is not None and self.fdi.fq.item(Q_TAKEN):
            self.fdi.sums_taken(self)
        added = cnt.item(FL.CNT_TRK_ADDED)
        if added:
            cnt[FL.CNT_TRK_ADDED] = 0
            self.fdi.trk.end += added
            self.fdi.trk_seq += added
        if cnt.item(FL.CNT_RESETS):
            cnt[FL.CNT_RESETS] = 0
            if self.excitation is not None:
                self.excitation.clear()

    def _drain(self) -> None:
        """Take what the compiled calls counted since Python last looked (cnt from CNT_USED on,
        then back to 0, CNT_MASKED to −1) into the bookkeeping: counters, the parity and tracker
        diagnostics and NIS sums, the last valid tracker epochs, the masked flag, the last
        numeric fault and the FDI statistic of a queued parity sum. New keys of the maps are
        added in the order of the samples, as sample-by-sample bookkeeping would."""
        self._undrained = False
        io, cnt = self._io, self._cnt
        v, c = io.tolist(), cnt.tolist()  # (plain floats and ints: one read each)
        cnt[FL.CNT_USED:FL.CNT_END] = 0
        cnt[FL.CNT_MASKED] = -1
        counters = self._b_counters
        for name, i in self._COUNTED:
            if c[i]:
                counters[name] += c[i]
        if c[FL.CNT_MASKED] >= 0:
            self._b_masked = c[FL.CNT_MASKED] != 0
        if c[FL.CNT_GAPS]:
            counters["warm_starts"] += c[FL.CNT_GAPS]
        if c[FL.CNT_NUMERIC]:
            self._b_last_numeric = numeric_reason(c[FL.CNT_NUMERIC_CODE])
        if c[FL.CNT_PAR_USED] or c[FL.CNT_PAR_EDITED]:
            self._parity_done(v, c)
        if c[FL.CNT_PAR_SUMS]:
            self._b_sum_pending = ((v[FL.IO_PAR_NU], v[FL.IO_PAR_RHO], v[FL.IO_PAR_T0],
                                    v[FL.IO_PAR_Z]) if c[FL.CNT_PAR_STAT] else ())
        if c[FL.CNT_FIRST_VALID]:
            self._trackers_done(v, c)

    def _trackers_done(self, v: list, c: list) -> None:
        """The bookkeeping of the tracker samples the kernel completed (:func:`loop._book_tracker`;
        v, c: the io and cnt arrays as lists): last valid epochs, and per tracker kind the last
        diagnostics, the counters and NIS sums. New keys of these maps are added in the order
        of the samples, as sample-by-sample bookkeeping would."""
        first = c[FL.CNT_FIRST_VALID]
        last = self._b_last_valid_st
        for j in (first, 3 - first):
            t_last = v[FL.IO_LAST_ST + j]
            if t_last != last.get(j, -math.inf):
                last[j] = t_last
        first = c[FL.CNT_FIRST_UPDATED]
        if not first:
            return
        counters = self._b_counters
        for j in (first, 3 - first):
            k = j - 1
            if not c[FL.CNT_DIAG_ST + k]:
                continue
            kind, d = ST_KIND[j], (FL.IO_DIAG_ST1 if j == 1 else FL.IO_DIAG_ST2)
            self._b_diag_last[kind] = (v[d + 1:d + 4], v[d + 4:d + 7], v[d])  # (lists: read once)
            if c[FL.CNT_CONSIDER_ST + k]:
                counters[ST_CONSIDER[j]] += c[FL.CNT_CONSIDER_ST + k]
            if c[FL.CNT_EDITED_ST + k]:
                counters[EDITED_KEY[kind]] += c[FL.CNT_EDITED_ST + k]
            used = c[FL.CNT_USED_ST + k]
            if used:
                counters[USED_KEY[kind]] += used
                self._b_nis_sum[kind] = v[FL.IO_NIS_SUM_ST + k]
            if c[FL.CNT_LOCKED_ST + k]:
                rec = self._b_nis_locked[kind]
                rec[0] += c[FL.CNT_LOCKED_ST + k]
                rec[1] = v[FL.IO_NIS_LOCKED_ST + k]

    def gyro_gaps(self) -> int:
        """``counters["gyro_gaps"]`` (the key made as that read makes it) without taking the
        rest of what the compiled calls counted (the stream's flags read it at every packet)."""
        return self._b_counters["gyro_gaps"] + self._cnt.item(FL.CNT_GAPS)

    def generation(self) -> tuple[int, int, int]:
        """(cold starts, warm starts, attitude initializations) as ``counters`` has them, without
        taking the rest of what the compiled calls counted (the FDI's restart test reads them at
        every window hook); the first read goes through ``counters`` (which makes the keys)."""
        b = self._b_counters
        if "cold_starts" in b and "warm_starts" in b and "att_inits" in b:
            cnt = self._cnt
            return (b["cold_starts"], b["warm_starts"] + cnt.item(FL.CNT_GAPS),
                    b["att_inits"] + cnt.item(FL.CNT_ATT_INITS))
        c = self.counters
        return c["cold_starts"], c["warm_starts"], c["att_inits"]

    def _load_bookkeeping(self) -> None:
        """The bookkeeping the compiled calls continue (last valid tracker epochs, NIS sums) from
        the Python maps into io, after Python replaced them (a checkpoint restored; the Python
        oracle of the tests, which keeps them itself, before each compiled step)."""
        io, last, nis, lk = self._io, self.last_valid_st, self.nis_sum, self.nis_locked
        io[FL.IO_LAST_ST1], io[FL.IO_LAST_ST2] = last.get(1, -math.inf), last.get(2, -math.inf)
        io[FL.IO_NIS_SUM_PAR] = nis.get("parity", 0.0)
        io[FL.IO_NIS_SUM_ST], io[FL.IO_NIS_SUM_ST + 1] = nis.get("st1", 0.0), nis.get("st2", 0.0)
        io[FL.IO_NIS_LOCKED_ST], io[FL.IO_NIS_LOCKED_ST + 1] = lk["st1"][1], lk["st2"][1]
        io[FL.IO_NIS_LOCKED_PAR] = lk["parity"][1]

    #: (counter, CNT field) added after every call
    _COUNTED = (("siru_used", FL.CNT_USED), ("siru_undetermined", FL.CNT_UNDETERMINED),
                ("st1_invalid", FL.CNT_INVALID_ST1), ("st2_invalid", FL.CNT_INVALID_ST2),
                ("siru_pre_init", FL.CNT_PRE_INIT), ("gyro_gaps", FL.CNT_GAPS),
                ("att_inits", FL.CNT_ATT_INITS), ("numeric_faults", FL.CNT_NUMERIC),
                ("parity_used", FL.CNT_PAR_USED), ("parity_edited", FL.CNT_PAR_EDITED),
                ("parity_early", FL.CNT_PAR_EARLY))

    def _parity_done(self, v: list, c: list) -> None:
        """Diagnostics of the parity updates since Python last looked (v, c: io and cnt as
        lists): the last one's innovation, σ and NIS, the running NIS sum, and the count and
        NIS sum of the used ones while the time line was locked."""
        self._b_diag_last["parity"] = (self.par_innov.copy(), self.par_sig.copy(),
                                       v[FL.IO_PAR_NIS])
        if c[FL.CNT_PAR_USED]:
            self._b_nis_sum["parity"] = v[FL.IO_NIS_SUM_PAR]
        if c[FL.CNT_LOCKED_PAR]:
            rec = self._b_nis_locked["parity"]
            rec[0] += c[FL.CNT_LOCKED_PAR]
            rec[1] = v[FL.IO_NIS_LOCKED_PAR]

    def _event(self, code: int, arg: int = 0, t: float = 0.0) -> None:
        """Run :func:`radical_rt.engine.events.engine_event` ``code`` (EV_*; int ``arg``, time
        ``t`` [s]) on the engine's state."""
        _bank, _wake, every, fdi_on = self._fdi_release_inputs()
        self._set_collaborators(every, fdi_on)
        engine_event(code, arg, t, self._fb, self._ib, self._bb, self._lay, self._cfg,
                     self._io, self._cnt, self.timing_sigma())
        self._undrained = True
        self._call_done()

    def _window_state(self, t: float) -> None:
        """:meth:`_event` EV_WINDOW_STATE (the flags and the mode after a close at event time t
        [s], steps.window_state) for the window hook, without the collaborators' inputs: the
        step reads the attitude flag, the last valid epochs, the flags and the factors, and
        changes only the flags and the mode (σ_t as the last call left it)."""
        io = self._io
        engine_event(EV_WINDOW_STATE, 0, t, self._fb, self._ib, self._bb, self._lay, self._cfg,
                     io, self._cnt, io.item(FL.IO_SIG_T))

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
