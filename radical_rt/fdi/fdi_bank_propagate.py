"""Compiled kernels of the FDI hypothesis bank, time side (docs/fdi.md §3): the gyro history's
rows and the propagation of every hypothesis between tracker samples.

The gyro history (:class:`radical_rt.fdi.fdi_history.SampleBuffer`) keeps its samples in a float
block f (m, 3 + n) with columns COL_T, COL_DT [s], COL_VAR [rad²], COL_DTH.. (dθ (n) [rad]), an
int64 block of gyro-invalid bits and a bool block (bridged); :func:`append_rows` fills it and
:func:`rows_after` finds a time range. :func:`bank_propagate` takes all hypotheses (stacked arrays
of :mod:`radical_rt.fdi.fdi_bank`) through a run of buffered gyro samples with the engine's own
propagation (:func:`radical_rt.kernels.propagate.propagate_window` with the hypothesis's exclusion
mask as the commanded exclusions, the snapshot calibration in the internal units of
:mod:`radical_rt.kernels.model`, no parity sums)
and composes each hypothesis's transition; :func:`bank_flush` applies it to the covariance blocks
(Schmidt time update; Schmidt 1966, Bierman 1977 ch. VIII) and :func:`transition_clear` tells
when that would change nothing. The tracker update, the per-sample step and the decision are in
:mod:`radical_rt.fdi.fdi_bank`.
"""

from __future__ import annotations

import numpy as np

from radical_rt._jit import inline_kernel, kernel
from radical_rt.kernels.flat_views import borrow, keep
from radical_rt.kernels.propagate import (
    PROP_UNDETERMINED,
    propagate_window,
    sample_work_in,
    sample_work_size,
)

#: columns of the gyro history's float block (radical_rt.fdi.fdi_history.SampleBuffer): t, dt, var_extra, dθ
COL_T, COL_DT, COL_VAR, COL_DTH = 0, 1, 2, 3


@kernel
def append_rows(f, i_blk, b_blk, end, t, dt, var_extra, dth, status, bridged, a, z):
    """The gyro history's append (radical_rt.fdi.fdi_history.SampleBuffer, and the compiled release
    itself): source rows a..z−1 of t, dt [s], var_extra [rad²], dθ (m, n) [rad], status (int
    bits), bridged (bool) to rows end.. of the float block f (columns COL_T, COL_DT, COL_VAR,
    COL_DTH.., room already made), the int block i_blk and the bool block b_blk."""
    n = dth.shape[1]
    for r in range(a, z):
        k = end + r - a
        f[k, 0], f[k, 1], f[k, 2] = t[r], dt[r], var_extra[r]
        for c in range(n):
            f[k, 3 + c] = dth[r, c]
        i_blk[k], b_blk[k] = status[r], bridged[r]


@inline_kernel
def rows_after(f, i0, end, t_after, t_upto):
    """Rows a..z−1 of the float block f (time in column COL_T, ascending over rows i0..end−1)
    with t_after < t ≤ t_upto: (a, z), z ≤ a when there are none (np.searchsorted, side right)."""
    return _search_right(f, i0, end, t_after), _search_right(f, i0, end, t_upto)


@inline_kernel
def _search_right(f, lo, hi, x):
    while lo < hi:
        mid = (lo + hi) // 2
        if f[mid, COL_T] <= x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@inline_kernel
def bank_propagate(f, st, br, i0, end, t_end, masks, xp, A, W, U_ax, V_ax, Minv, Gp, N_none,
                   arw_var, q, omega, tlast, undetermined, Phi_aa, Phi_ap, Q_aa, par_y, par_t, acc_i,
                   acc_f, th_acc):
    """Propagate every hypothesis through the buffered gyro samples with tlast[0] < t ≤ t_end.

    f (m, 3 + n) float block of the gyro history (t [s], dt [s], var_extra [rad²], dθ (n) [rad])
    whose rows i0..end−1 are in use, st (m,) int64 gyro-invalid bits, br (m,) bool bridged;
    masks (nh, n) bool: the gyros each hypothesis leaves out; xp, A, W, U_ax, V_ax, Minv, Gp the
    snapshot calibration and geometry (:func:`radical_rt.kernels.model.refresh_axes`), N_none (n, 0) (no
    parity sums); arw_var [rad²/s]. In place: q (nh, 4), omega (nh, 3) [rad/s], tlast (1,) [s]
    the time of the last sample propagated, and per hypothesis the transition accumulated since
    the last :func:`bank_flush`: Phi_aa (nh, 3, 3), Phi_ap (nh, 3, npar) = ∂θ/∂p, Q_aa (nh, 3, 3)
    (propagate_window composes them sample by sample). undetermined (nh,) int64 += 1 for a call in
    which a hypothesis met samples with fewer than three usable gyros (skipped). Work, scratch of
    propagate_window: par_y, par_t (2, n), acc_i int64 (4,), acc_f, th_acc (3,). Returns the
    number of gyro samples in the run.
    """
    # views that own no memory (flat_views.borrow): no atomic reference count per view taken
    f, st, br, masks, xp = borrow(f), borrow(st), borrow(br), borrow(masks), borrow(xp)
    A, W, U_ax, V_ax, Minv = borrow(A), borrow(W), borrow(U_ax), borrow(V_ax), borrow(Minv)
    Gp, N_none, q, omega = borrow(Gp), borrow(N_none), borrow(q), borrow(omega)
    tlast = borrow(tlast)
    undetermined, Phi_aa, Phi_ap = borrow(undetermined), borrow(Phi_aa), borrow(Phi_ap)
    Q_aa, par_y, par_t, acc_i = borrow(Q_aa), borrow(par_y), borrow(par_t), borrow(acc_i)
    acc_f, th_acc = borrow(acc_f), borrow(th_acc)
    a, z = rows_after(f, i0, end, tlast[0], t_end)
    if z <= a:
        return 0
    nh, n = masks.shape
    # one set of work arrays for every hypothesis, in two allocations, used as borrowed views
    wf, wb = np.empty(sample_work_size(n)), np.empty(n, np.bool_)
    work = sample_work_in(borrow(wf), borrow(wb), n)
    dth, dt, var = f[:, COL_DTH:], f[:, COL_DT], f[:, COL_VAR]
    for h in range(nh):  # hypothesis by hypothesis, each through the engine's own propagation
        acc_i[0] = 0  # the window count: z − a + 1 never stops the run
        _, flags = propagate_window(dth, dt, st, br, var, a, z, masks[h], xp, q[h], A, W, U_ax,
                                    V_ax, Minv, Gp, N_none, Phi_aa[h], Phi_ap[h], Q_aa[h], par_y,
                                    par_t, acc_i, acc_f, th_acc, z - a + 1, arw_var, omega[h],
                                    work)
        if flags & PROP_UNDETERMINED:
            undetermined[h] += 1
    tlast[0] = f[z - 1, COL_T]
    keep(wf)  # (alive until here: the views own no memory)
    keep(wb)
    return z - a


@inline_kernel
def bank_flush(Phi_aa, Phi_ap, Q_aa, Ptt, Ptp, Ppp, FPtp, GPpp, T):
    """Schmidt time update of every hypothesis with its accumulated transition, then the
    accumulators reset (Phi_aa = I, Phi_ap = 0, Q_aa = 0):

        Ptt ← Φ Ptt Φᵀ + Φ Ptp Γᵀ + Γ (Φ Ptp)ᵀ + Γ Ppp Γᵀ + Q (symmetrized),   Ptp ← Φ Ptp + Γ Ppp

    with Φ = Phi_aa[h], Γ = Phi_ap[h], Q = Q_aa[h] (shapes of :func:`bank_propagate`); Ptt
    (nh, 3, 3), Ptp (nh, 3, npar), Ppp (npar, npar). Work: FPtp, GPpp (3, npar), T (3, 3)."""
    Phi_aa, Phi_ap, Q_aa = borrow(Phi_aa), borrow(Phi_ap), borrow(Q_aa)
    Ptt, Ptp = borrow(Ptt), borrow(Ptp)
    Ppp, FPtp, GPpp, T = borrow(Ppp), borrow(FPtp), borrow(GPpp), borrow(T)
    npar = Ppp.shape[0]
    for h in range(Ptt.shape[0]):
        F, G, Q, P, C = Phi_aa[h], Phi_ap[h], Q_aa[h], Ptt[h], Ptp[h]
        for r in range(3):  # FPtp = Φ Ptp, GPpp = Γ Ppp (rows of Γ are sparse: φ2, τ, left-out gyro)
            for c in range(npar):
                FPtp[r, c] = F[r, 0] * C[0, c] + F[r, 1] * C[1, c] + F[r, 2] * C[2, c]
                GPpp[r, c] = 0.0
            for k in range(npar):
                g = G[r, k]
                if g != 0.0:
                    for c in range(npar):
                        GPpp[r, c] += g * Ppp[k, c]
        for r in range(3):
            for c in range(3):
                fpf = 0.0
                for k in range(3):
                    fp = 0.0
                    for j in range(3):
                        fp += F[r, j] * P[j, k]
                    fpf += fp * F[c, k]
                x1 = 0.0
                x2 = 0.0
                x3 = 0.0
                for k in range(npar):
                    x1 += FPtp[r, k] * G[c, k]
                    x2 += G[r, k] * FPtp[c, k]
                    x3 += GPpp[r, k] * G[c, k]
                T[r, c] = fpf + x1 + x2 + x3 + Q[r, c]
        for r in range(3):
            for c in range(3):
                P[r, c] = 0.5 * (T[r, c] + T[c, r])
                F[r, c] = 1.0 if r == c else 0.0
                Q[r, c] = 0.0
            for c in range(npar):
                C[r, c] = FPtp[r, c] + GPpp[r, c]
                G[r, c] = 0.0


@inline_kernel
def transition_clear(Phi_aa, Phi_ap, Q_aa, Ptt):
    """Whether every hypothesis's accumulated transition is the identity (Phi_aa = I, Phi_ap = 0,
    Q_aa = 0; shapes of :func:`bank_propagate`) and its Ptt (nh, 3, 3) exactly symmetric:
    :func:`bank_flush` would then leave Ptt and Ptp as they are, bit for bit (a second tracker
    at the same epoch: about half of the bank's samples)."""
    for h in range(Phi_aa.shape[0]):
        for r in range(3):
            for c in range(3):
                if (Phi_aa[h, r, c] != (1.0 if r == c else 0.0) or Q_aa[h, r, c] != 0.0
                        or Ptt[h, r, c] != Ptt[h, c, r]):
                    return False
            for c in range(Phi_ap.shape[2]):
                if Phi_ap[h, r, c] != 0.0:
                    return False
    return True
