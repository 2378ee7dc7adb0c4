"""The engine's per-event loop, compiled: one call runs a whole release of the stream processor.

:func:`run_release` takes the gyro samples and tracker samples the stream processor releases, in
time order, and runs every step of the filter on them: propagation, the window close (time update,
lock latch, parity sums queued with their FDI statistic, lagged parity updates), attitude
initialization, gyro gaps (warm start), tracker updates (all cases of docs/engine.md §3.4:
plain, whitened with the clock's timing term, with the calibration considered), the correction
fold, numeric-fault recovery, flags and counters, and the FDI hypothesis bank on its tracker
samples. The steps themselves are in :mod:`radical_rt.engine.steps`; they exist once.

A call returns to Python only for the window hook (``R_ON_WINDOW``), the Python collaborators'
turn at a close: the flags differ from those at the start of the call or would change (stale
trackers, convergence), the mode would change, the event time reached ``wake_t`` (a window
packet or diag due) or the engine time ``wake_e`` (an INPUT_REJECTED hold ending) or
``wake_fdi`` (the FDI's bookkeeping), a parity sum was queued that the FDI does not take in the
loop (an alarm, a snapshot or an excitation step due, :mod:`radical_rt.fdi.fdi_quiet`), with
io[IO_WAKE_EVERY] set after every tracker sample (an FDI bank the kernel does not run itself),
or after a tracker sample at which
the bank the kernel runs (argument ``bk``) has its decision due. Python then runs
``Engine.on_window`` and calls again from where this call stopped. :func:`engine_event` runs a
step for Python (commands, checks, the end of a stream) on the same state.

``E``: tuple of the engine's arrays (:func:`radical_rt.engine.engine_layout.unpack` of the
engine's three flat buffers, one argument each instead of one per array; all updated in place).
``cfg``, ``io``, ``cnt``: the engine's scalar configuration (float64), its scalar state, kept
there between calls, with the outputs of a tracker update (float64), and its flags, counters and
status codes (int64; the counters accumulate until Python takes them), declared in
:mod:`radical_rt.engine.loop_layout` (``CFG_*``, ``IO_*``, ``CNT_*``; docs/engine.md lists them).
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import inline_kernel, kernel
from radical_rt.contract.flags import Flag
from radical_rt.engine.engine_layout import E_INDEX, propagation_work, unpack
from radical_rt.engine.events import begin_call
from radical_rt.engine.gyro_queue import predict_pending
from radical_rt.engine.handover import window_due
from radical_rt.engine.loop_layout import (
    CFG_ARW_VAR,
    CFG_EDIT,
    CFG_GATE_NIS,
    CFG_GYRO_GAP,
    CFG_LAT_COL,
    CFG_LAT_P,
    CFG_PHI_COL,
    CFG_PHI_P,
    CFG_PROP_WINDOW,
    CFG_ST_MIN_STARS,
    CFG_ST_REF_STARS,
    CFG_TIMING_CONSIDER,
    CNT_CONSIDER,
    CNT_CONSIDER_ST,
    CNT_DIAG_ST,
    CNT_EDITED,
    CNT_EDITED_ST,
    CNT_FIRST_UPDATED,
    CNT_FIRST_VALID,
    CNT_FLAGS,
    CNT_GAPS,
    CNT_INVALID_ST,
    CNT_LOCKED_ST,
    CNT_MASKED,
    CNT_PRE_INIT,
    CNT_STATUS,
    CNT_TRK_ADDED,
    CNT_UNDETERMINED,
    CNT_UPDATED,
    CNT_USED,
    CNT_USED_ST,
    IO_ATT_VALID,
    IO_DIAG_ST1,
    IO_DIAG_ST2,
    IO_LAST_ST,
    IO_NIS,
    IO_NIS_LOCKED_ST,
    IO_NIS_SUM_ST,
    IO_SIG_T,
    IO_T,
    IO_TRK_SEQ0,
    IO_WAKE_EVERY,
)
from radical_rt.engine.steps import (
    close_window,
    fold,
    init_attitude,
    numeric_fault,
    warm_reset,
)
from radical_rt.fdi.fdi_bank_pack import bank_on, bank_sample_packed
from radical_rt.fdi.fdi_bank_propagate import append_rows
from radical_rt.kernels.flat_views import borrow
from radical_rt.kernels.propagate import PROP_MASKED, PROP_UNDETERMINED, propagate_window
from radical_rt.kernels.tracker_model import tracker_rows
from radical_rt.kernels.ud import decorrelate
from radical_rt.kernels.updates import (
    gated_update,
    gated_update_consider,
    timing_noise,
    unwhiten_diagnostics,
)

R_DONE, R_ON_WINDOW = 0, 1  # the reasons a call returns: all done; the window hook has work

_ST1_STALE, _ST2_STALE = int(Flag.ST1_STALE), int(Flag.ST2_STALE)
_ST1_EDITED, _ST2_EDITED = int(Flag.ST1_EDITED), int(Flag.ST2_EDITED)
_NOT_CONVERGED, _NUMERIC = int(Flag.NOT_CONVERGED), int(Flag.NUMERIC)
_GYRO_GAP = int(Flag.GYRO_GAP)
_TIMING_RATIO = 1e-4  # the timing term is negligible below this share of the tracker variance

# positions in E of its arrays, by key (engine_layout.SLOTS declares the order once)
_EXCLUDED, _XP = E_INDEX["excluded"], E_INDEX["xp"]
_Q, _A = E_INDEX["q"], E_INDEX["A"]
_W, _UAX = E_INDEX["geo.W"], E_INDEX["geo.U"]
_VAX, _MINV = E_INDEX["geo.V"], E_INDEX["Minv"]
_GP, _N = E_INDEX["Gp"], E_INDEX["N"]
_PHI_AA, _PHI_AP = E_INDEX["Phi_aa"], E_INDEX["Phi_ap"]
_Q_AA, _PAR_Y = E_INDEX["Q_aa"], E_INDEX["par_y"]
_PAR_T, _ACC_I = E_INDEX["par_t"], E_INDEX["acc_i"]
_ACC_F, _TH_ACC = E_INDEX["acc_f"], E_INDEX["th_acc"]
_PQ_I = E_INDEX["pq_i"]
_OMEGA, _U = E_INDEX["omega"], E_INDEX["U"]
_D, _DX = E_INDEX["d"], E_INDEX["dx"]
_Q_PARAMS, _PARAM_IDX = E_INDEX["q_params"], E_INDEX["param_idx"]
_Q_DT, _STRUCT_W = E_INDEX["q_dt"], E_INDEX["ws.struct"]
_A_W, _VAR_W = E_INDEX["ws.a"], E_INDEX["ws.var"]
_CONV_VAR, _KAPPA_LAST = E_INDEX["conv_var"], E_INDEX["kappa_last"]
_HBUF, _R3 = E_INDEX["Hbuf"], E_INDEX["r3"]
_H_ATT, _H_PHI = E_INDEX["H_att"], E_INDEX["H_phi"]
_FBUF, _SBUF = E_INDEX["Fbuf"], E_INDEX["Sbuf"]
_INNOV, _SIG = E_INDEX["innov"], E_INDEX["sig"]
_F_W, _V_W = E_INDEX["ws.f"], E_INDEX["ws.v"]
_K_W, _ST_SIGMA = E_INDEX["ws.k"], E_INDEX["st_sigma"]
_GYRO_MASK, _HWBUF = E_INDEX["gyro_mask"], E_INDEX["Hwbuf"]
_ZWBUF, _LBUF = E_INDEX["zwbuf"], E_INDEX["Lbuf"]


@inline_kernel
def _gyro_step(t, dt, dth, status, bridged, var_extra, k, upto, E, cfg, io, cnt, fq, work):
    """Samples k..upto−1 of the gyro arrays (t, dt (m,) [s], dth (m, n) [rad], status (m,) int
    bits, bridged (m,) bool, var_extra (m,) [rad²]; work: the propagation's
    radical_rt.kernels.propagate.SampleWork): before an attitude exists only counted; a
    gap (dt > gyro_gap) loses the attitude (GYRO_GAP, warm start without bump); otherwise
    propagated window by window, closing each full window (close, correction fold). Returns
    (R_DONE, upto), or (R_ON_WINDOW, next sample) when the window hook has work after a close."""
    excluded, xp, q, A, W, U_ax, V_ax = E[_EXCLUDED], E[_XP], E[_Q], E[_A], E[_W], E[_UAX], E[_VAX]
    Minv, Gp, N, Phi_aa, Phi_ap = E[_MINV], E[_GP], E[_N], E[_PHI_AA], E[_PHI_AP]
    Q_aa, par_y, par_t, acc_i, acc_f = E[_Q_AA], E[_PAR_Y], E[_PAR_T], E[_ACC_I], E[_ACC_F]
    th_acc, omega = E[_TH_ACC], E[_OMEGA]
    window, arw, gap_s = int(cfg[CFG_PROP_WINDOW]), cfg[CFG_ARW_VAR], cfg[CFG_GYRO_GAP]
    while k < upto:
        if io[IO_ATT_VALID] == 0.0:  # waiting for the first tracker: nothing to propagate
            cnt[CNT_PRE_INIT] += upto - k
            io[IO_T] = t[upto - 1]
            return R_DONE, upto
        if dt[k] > gap_s:  # the attitude is lost; resume at the next tracker sample
            cnt[CNT_FLAGS] |= _GYRO_GAP
            cnt[CNT_GAPS] += 1
            warm_reset(E, io, cnt)
            io[IO_T] = t[k]
            k += 1
            continue
        stop = k + 1
        while stop < upto and not dt[stop] > gap_s:
            stop += 1
        while k < stop and io[IO_ATT_VALID] != 0.0:
            k_next, pflags = propagate_window(
                dth, dt, status, bridged, var_extra, k, stop, excluded, xp, q, A, W, U_ax, V_ax,
                Minv, Gp, N, Phi_aa, Phi_ap, Q_aa, par_y, par_t, acc_i, acc_f, th_acc, window, arw,
                omega, work)
            cnt[CNT_USED] += k_next - k
            if pflags & PROP_UNDETERMINED:
                cnt[CNT_UNDETERMINED] += 1
            cnt[CNT_MASKED] = 1 if pflags & PROP_MASKED else 0
            io[IO_T] = t[k_next - 1]
            k = k_next
            if acc_i[0] >= window:
                close_window(E, cfg, io, cnt)
                fold(E, io, cnt)
                if window_due(E, cfg, io, cnt, fq, io[IO_T], 0):
                    return R_ON_WINDOW, k
    return R_DONE, k


@inline_kernel
def _tracker_step(j, t_epoch, q_meas, n_stars, valid, R_nom, use_phi, E, cfg, io, cnt, fq):
    """A tracker j (1 or 2) sample at t_epoch [s, gyro time line], q_meas (4,)
    q_st_from_inertial, n_stars, valid, mounting R_nom (3, 3), use_phi (ST2). An invalid sample
    (not valid, or too few stars) is only counted, cnt[CNT_INVALID_ST + j] += 1, with
    cnt[CNT_UPDATED] = −1; otherwise io[IO_LAST_ST + j] (last valid epoch) ← t_epoch, then
    without an attitude its initialization (steps.init_attitude; CNT_UPDATED 0), else the window
    close, the residual and rows, the gated update (whitened with the clock's timing term when
    that is not negligible; the gyro calibration considered while the time line is not locked),
    the ST<j>_EDITED flag, the fold and the window test. Returns R_DONE or R_ON_WINDOW."""
    xp, q, omega, U, d, dx = E[_XP], E[_Q], E[_OMEGA], E[_U], E[_D], E[_DX]
    a_w, Hbuf, r3, H_att, H_phi = E[_A_W], E[_HBUF], E[_R3], E[_H_ATT], E[_H_PHI]
    Fbuf, Sbuf, innov, sig = E[_FBUF], E[_SBUF], E[_INNOV], E[_SIG]
    f_w, v_w, k_w, st_sigma, gyro_mask = E[_F_W], E[_V_W], E[_K_W], E[_ST_SIGMA], E[_GYRO_MASK]
    Hwbuf, zwbuf, Lbuf = E[_HWBUF], E[_ZWBUF], E[_LBUF]
    cnt[CNT_UPDATED], cnt[CNT_CONSIDER] = 0, 0
    if not valid or n_stars < cfg[CFG_ST_MIN_STARS]:  # counted, nothing else
        cnt[CNT_INVALID_ST + j] += 1
        cnt[CNT_UPDATED] = -1
        return R_DONE
    io[IO_LAST_ST + j] = t_epoch
    if io[IO_ATT_VALID] == 0.0:
        init_attitude(j, t_epoch, q_meas, n_stars, R_nom, use_phi, E, cfg, io, cnt)
        return R_DONE
    close_window(E, cfg, io, cnt)
    phi_col, lat_col = int(cfg[CFG_PHI_COL]), int(cfg[CFG_LAT_COL])
    phi_p, lat_p = int(cfg[CFG_PHI_P]), int(cfg[CFG_LAT_P])
    H = Hbuf[:3]
    rate2 = tracker_rows(q_meas, q, omega, t_epoch - xp[lat_p] - io[IO_T], R_nom,
                         xp[phi_p:phi_p + 3], use_phi, phi_col, lat_col, r3, H_att, H_phi, H)
    scale = math.sqrt(cfg[CFG_ST_REF_STARS] / max(n_stars, 1))
    rdiag = np.empty(3)
    for r in range(3):
        s = st_sigma[r] * scale
        rdiag[r] = s * s
    sig_t = io[IO_SIG_T]
    gate, edit = cfg[CFG_GATE_NIS], cfg[CFG_EDIT] != 0.0
    if sig_t * sig_t * rate2 / rdiag.min() > _TIMING_RATIO:  # the clock's timing term
        # Epoch error δt of the gyro time line → attitude error R ω̂ δt (rank one in tracker
        # axes): a slowly varying bias while the clock is not locked, so the tracker then keeps
        # the attitude (and φ2) but does not calibrate the gyros (Schmidt consider)
        Rm = np.empty((3, 3))
        timing_noise(R_nom, omega, rdiag, sig_t, Rm)
        Hw, zw, L = Hwbuf[:3], zwbuf[:3], Lbuf[:3, :3]
        st = decorrelate(H, r3, Rm, Hw, zw, L)
        if st != 0:
            numeric_fault(E, io, cnt, st)
        ones = np.ones(3)
        if sig_t > cfg[CFG_TIMING_CONSIDER]:
            cnt[CNT_CONSIDER] = 1
            status, nis, edited = gated_update_consider(
                U, d, dx, Hw, zw, ones, gate, edit, gyro_mask, Fbuf[:3], Sbuf[:3, :3], innov[:3],
                sig[:3], f_w, v_w, k_w, a_w)
        else:
            status, nis, edited = gated_update(U, d, dx, Hw, zw, ones, gate, edit, Fbuf[:3],
                                               Sbuf[:3, :3], innov[:3], sig[:3], f_w, v_w, k_w)
        iw = innov[:3].copy()
        unwhiten_diagnostics(L, iw, Sbuf[:3, :3], innov[:3], sig[:3])
    else:
        status, nis, edited = gated_update(U, d, dx, H, r3, rdiag, gate, edit, Fbuf[:3],
                                           Sbuf[:3, :3], innov[:3], sig[:3], f_w, v_w, k_w)
    cnt[CNT_STATUS], cnt[CNT_EDITED], cnt[CNT_UPDATED] = status, 1 if edited else 0, 1
    io[IO_NIS] = nis
    if status != 0:
        numeric_fault(E, io, cnt, status)
    bit = _ST1_EDITED if j == 1 else _ST2_EDITED
    cnt[CNT_FLAGS] = (cnt[CNT_FLAGS] & ~bit) | (bit if edited else 0)
    fold(E, io, cnt)
    if io[IO_WAKE_EVERY] != 0.0 or window_due(E, cfg, io, cnt, fq, t_epoch, 1):
        return R_ON_WINDOW
    return R_DONE


@inline_kernel
def _book_tracker(j, epoch, q_meas, n_stars, E, cfg, io, cnt, trk_f, trk_i, trk_end, trk_seq0):
    """The bookkeeping of a tracker j sample the kernel completed (nothing for an invalid one,
    cnt[CNT_UPDATED] < 0): appended to the FDI's tracker history (trk_f (cap, 5) epoch [s],
    q_st_from_inertial (4,); trk_i (cap, 3) seq, j, n_stars; rows from trk_end, numbered from
    trk_seq0 + 1; trk_end < 0: no FDI), then, for an update that ran, the counters of its kind
    (used or edited, considered, used while locked), its NIS added to the sums IO_NIS_SUM_ST
    and (time line locked: σ_t ≤ timing_consider) IO_NIS_LOCKED_ST, and its NIS, innovation
    and σ kept as the kind's last diagnostics (IO_DIAG_ST<j>). CNT_FIRST_VALID and
    CNT_FIRST_UPDATED name the call's first valid and first updated tracker (Python keeps its
    maps in that order)."""
    upd = cnt[CNT_UPDATED]
    if upd < 0:
        return
    if cnt[CNT_FIRST_VALID] == 0:
        cnt[CNT_FIRST_VALID] = j
    if trk_end >= 0:
        r = trk_end + cnt[CNT_TRK_ADDED]
        trk_f[r, 0] = epoch
        for c in range(4):
            trk_f[r, 1 + c] = q_meas[c]
        cnt[CNT_TRK_ADDED] += 1
        trk_i[r, 0], trk_i[r, 1], trk_i[r, 2] = trk_seq0 + cnt[CNT_TRK_ADDED], j, n_stars
    if upd == 0:
        return
    k = j - 1
    if cnt[CNT_FIRST_UPDATED] == 0:
        cnt[CNT_FIRST_UPDATED] = j
    cnt[CNT_DIAG_ST + k] = 1
    base = IO_DIAG_ST1 if j == 1 else IO_DIAG_ST2
    innov, sig = E[_INNOV], E[_SIG]
    io[base] = io[IO_NIS]
    for r in range(3):
        io[base + 1 + r] = innov[r]
        io[base + 4 + r] = sig[r]
    if cnt[CNT_CONSIDER]:
        cnt[CNT_CONSIDER_ST + k] += 1
    if cnt[CNT_EDITED]:
        cnt[CNT_EDITED_ST + k] += 1
        return
    cnt[CNT_USED_ST + k] += 1
    io[IO_NIS_SUM_ST + k] += io[IO_NIS]
    if io[IO_SIG_T] <= cfg[CFG_TIMING_CONSIDER]:
        cnt[CNT_LOCKED_ST + k] += 1
        io[IO_NIS_LOCKED_ST + k] += io[IO_NIS]


@kernel
def run_release(t, dt, dth, status, bridged, var_extra, k, z, ev_f, ev_i, e, n_ev, R1, R2, fb,
                 ib, bb, lay, cfg, io, cnt, g_f, g_i, g_b, g_end, pred, q_end,
                 clock_I, clock_F, bfb, bib, bbb, blay, sig_t, wake_t, wake_e, wake_fdi, fq, trk_f,
                 trk_i, trk_end, trk_seq0):
    """A whole release of the stream processor in one call: for each tracker event e..n_ev−1
    (ev_f (E, 5): epoch [s], q_st_from_inertial (4,); ev_i (E, 3): tracker 1|2, n_stars, valid;
    epochs in order), the gyro samples up to its epoch then the sample; then the gyro samples up
    to z. R1, R2: ST1 and nominal ST2 mountings (3, 3). Every tracker event completed is booked
    in io and cnt (:func:`_book_tracker`) for Python's bookkeeping. Returns (reason, next
    sample, event, stage): R_DONE with event == n_ev when everything is done; R_ON_WINDOW when
    the window hook has work, stage 0 after a close of the gyro part before event e (or before z
    when e == n_ev), 1 after tracker event e itself. g_end ≥ 0: first copy
    samples k..z−1 to the FDI history blocks g_f, g_i, g_b from row g_end
    (radical_rt.fdi.fdi_history.SampleBuffer, room already made; its owner advances its end).
    pred (9,): with pred[0] = 1 and
    pred[1] = t_now [s], a release that ends here (R_DONE) also makes the prediction of
    sample-triggered telemetry from its final state (:func:`radical_rt.engine.gyro_queue.predict_pending`
    through the queue's samples z..q_end−1 and the clock's held-back read, clock state
    clock_I, clock_F): pred[0] ← 2, pred[1] ← its time, pred[2:6] ← q, pred[6:9] ← ω.
    bfb, bib, bbb, blay: the running FDI hypothesis bank's buffers (radical_rt.fdi.fdi_hypotheses.
    HypothesisBank.kernel_args, radical_rt.fdi.fdi_bank_pack; idle_kernel_args with bi[BI_ON] = 0
    when none runs here), its gyro history the blocks g_f, g_i, g_b: each tracker event the
    kernel completes goes through :func:`radical_rt.fdi.fdi_bank.bank_sample` as well, and when
    the bank's decision is due the event hands over with R_ON_WINDOW (stage 1), so that Python
    takes the decision at that sample.
    sig_t: σ of the time line [s]; wake_t, wake_e, wake_fdi: see the module docstring
    (:func:`begin_call`; the engine's other scalar state stays in io and cnt between calls);
    fq: the FDI's array for the parity sums it takes without the hook
    (:mod:`radical_rt.fdi.fdi_quiet`; zeros when there is no FDI). Every tracker sample
    completed is booked by :func:`_book_tracker` (trk_f, trk_i, trk_end, trk_seq0: the FDI's
    tracker history there). The array arguments are used as views that own no memory
    (:func:`radical_rt.kernels.flat_views.borrow`: no reference counting in the inlined steps)."""
    t, dt, dth, status, bridged = borrow(t), borrow(dt), borrow(dth), borrow(status), borrow(bridged)
    var_extra, ev_f, ev_i, R1, R2 = borrow(var_extra), borrow(ev_f), borrow(ev_i), borrow(R1), borrow(R2)
    cfg, io, cnt, g_f, g_i, g_b = borrow(cfg), borrow(io), borrow(cnt), borrow(g_f), borrow(g_i), borrow(g_b)
    pred, clock_I, clock_F, trk_f, trk_i = (borrow(pred), borrow(clock_I), borrow(clock_F),
                                            borrow(trk_f), borrow(trk_i))
    fq = borrow(fq)
    begin_call(io, cnt, sig_t, wake_t, wake_e, wake_fdi)
    io[IO_TRK_SEQ0] = trk_seq0
    if g_end >= 0:
        append_rows(g_f, g_i, g_b, g_end, t, dt, var_extra, dth, status, bridged, k, z)
    E = unpack(fb, ib, bb, lay)
    work = propagation_work(E)  # the propagation's work arrays (engine state)
    bank = bank_on(bib, blay)  # a bank runs (its control bi[BI_ON])
    while e < n_ev:
        epoch = ev_f[e, 0]
        up = k
        while up < z and t[up] <= epoch:
            up += 1
        reason, k = _gyro_step(t, dt, dth, status, bridged, var_extra, k, up, E, cfg, io, cnt,
                               fq, work)
        if reason != R_DONE:
            return reason, k, e, 0
        j = ev_i[e, 0]
        reason = _tracker_step(j, epoch, ev_f[e, 1:5], ev_i[e, 1], ev_i[e, 2] != 0,
                               R1 if j == 1 else R2, j == 2, E, cfg, io, cnt, fq)
        _book_tracker(j, epoch, ev_f[e, 1:5], ev_i[e, 1], E, cfg, io, cnt, trk_f, trk_i, trk_end,
                      trk_seq0)
        # the bank takes every sample whose update the kernel completed, also one after which
        # the window hook has work (R_ON_WINDOW: Python then finds the bank caught up)
        if (reason == R_DONE or reason == R_ON_WINDOW) and cnt[CNT_UPDATED] >= 0 and bank \
                and bank_sample_packed(g_f, g_i, g_b, bfb, bib, bbb, blay, ev_f[e, 1:5],
                                       ev_i[e, 1], epoch, R1 if j == 1 else R2, j == 2,
                                       io[IO_SIG_T], E[_W], E[_UAX], E[_VAX]):
            reason = R_ON_WINDOW  # the bank's decision is due: Python takes it (on_window)
        if reason != R_DONE:
            return reason, k, e, 1
        e += 1
    reason, k = _gyro_step(t, dt, dth, status, bridged, var_extra, k, z, E, cfg, io, cnt, fq,
                           work)
    if reason == R_DONE and pred[0] == 1.0 and io[IO_ATT_VALID] != 0.0:  # else now() does it
        q, omega = E[_Q], E[_OMEGA]
        q_p, omega_p = pred[2:6], pred[6:9]
        for c in range(4):
            q_p[c] = q[c]
        for c in range(3):
            omega_p[c] = omega[c]
        pred[1] = predict_pending(dth, dt, status, z, q_end, pred[1], clock_I, clock_F,
                                  E[_EXCLUDED], E[_XP], E[_A], E[_GP], q_p, omega_p, work)
        pred[0] = 2.0
    return reason, k, e, 0
