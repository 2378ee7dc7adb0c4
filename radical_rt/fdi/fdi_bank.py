"""Compiled kernels of the FDI hypothesis bank (docs/fdi.md §3): every hypothesis in one call.

The bank (:class:`radical_rt.fdi.fdi_hypotheses.HypothesisBank`) keeps the state of its nh hypotheses
(H0 with all gyros, H_i with gyro i left out) in stacked arrays:

* ``q`` (nh, 4) q_body_from_inertial (scalar last), ``omega`` (nh, 3) last body rate [rad/s, body];
* ``Ptt`` (nh, 3, 3) covariance of the attitude error δθ [rad², body axes], ``Ptp`` (nh, 3, npar)
  its cross-covariance with the considered parameters (internal units of :mod:`radical_rt.kernels.model`),
  ``Ppp`` (npar, npar) the snapshot's parameter covariance (shared: the parameters are considered,
  never estimated);
* ``ll`` (nh,) robust log-likelihood (up to a common constant), ``nis`` (nh,) capped NIS sums.

:func:`bank_propagate` takes all hypotheses through a run of buffered gyro samples with the engine's
own propagation kernel (:func:`radical_rt.kernels.propagate.propagate_window`, the hypothesis's exclusion
mask, the snapshot calibration) and propagates the covariance blocks (Schmidt time update).
:func:`bank_tracker` applies one star-tracker sample to all hypotheses: the engine's tracker model
(:func:`radical_rt.kernels.tracker_model.tracker_residual`, noise with the time-line term
:func:`radical_rt.kernels.updates.timing_noise`), the innovation covariance S (3, 3), its Cholesky factor
(:func:`radical_rt.kernels.ud.cholesky_lower`; no LAPACK), NIS and ln det S, the gated log-likelihood and
the Schmidt (consider) gain and correction of the attitude states only (Schmidt 1966; the
considered-state form of Bierman 1977 ch. VIII). Kernels never raise: a hypothesis whose S is not
positive definite gets ll = −inf and no correction, and the count of such hypotheses is returned.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import OK, kernel
from radical_rt.kernels.model import correct_increment_lin, masked_pinv, select_increments
from radical_rt.kernels.propagate import active_gyros, propagate_sample, sample_work
from radical_rt.kernels.rotation import apply_body_rotation, quat_mul_into, rotvec_to_quat_into
from radical_rt.kernels.tracker_model import tracker_error, tracker_geometry
from radical_rt.kernels.ud import cholesky_lower
from radical_rt.kernels.updates import timing_noise

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


@kernel
def rows_after(f, i0, end, t_after, t_upto):
    """Rows a..z−1 of the float block f (time in column COL_T, ascending over rows i0..end−1)
    with t_after < t ≤ t_upto: (a, z), z ≤ a when there are none (np.searchsorted, side right)."""
    return _search_right(f, i0, end, t_after), _search_right(f, i0, end, t_upto)


@kernel
def _search_right(f, lo, hi, x):
    while lo < hi:
        mid = (lo + hi) // 2
        if f[mid, COL_T] <= x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@kernel
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
    which a hypothesis met samples with fewer than three usable gyros. Work: par_y, par_t (2, n),
    acc_i int64 (4,), acc_f, th_acc (3,). Returns the number of samples propagated.
    """
    a, z = rows_after(f, i0, end, tlast[0], t_end)
    if z <= a:
        return 0
    nh, n = masks.shape
    wk = sample_work(n)  # one set of work arrays for every hypothesis and sample
    Gm = np.empty((nh, 3, n))  # per hypothesis: the masked pseudo-inverse of the pattern `have`
    Mm = np.empty((nh, 3, 3))
    have = np.full(nh, -1, np.int64)
    have_ok = np.zeros(nh, np.bool_)
    undet = np.zeros(nh, np.bool_)
    th_last = np.empty((nh, 3))  # θ̂ [rad] and interval [s] of each hypothesis's last sample
    h_last = np.zeros(nh)
    moved = np.zeros(nh, np.bool_)
    every = sample_work(n)  # the sample corrected once, over every valid gyro
    no_mask = np.zeros(n, np.bool_)
    for k in range(a, z):  # sample by sample, every hypothesis (each has its own state)
        dth_k, h_k = f[k, COL_DTH:], f[k, COL_DT]
        active_gyros(no_mask, st[k], every.active)
        correct_increment_lin(dth_k, h_k, xp, every.active, every.c, every.sg, every.s)
        for h in range(nh):
            n_act, bits = active_gyros(masks[h], st[k], wk.active)
            G, Mi = Gp, Minv
            if n_act < n:
                if bits != have[h]:  # A is constant over the call: one pseudo-inverse per pattern
                    have[h], have_ok[h] = bits, masked_pinv(A, wk.active, Mm[h], Gm[h]) >= 0
                if not have_ok[h]:
                    undet[h] = True
                    continue
                G, Mi = Gm[h], Mm[h]
            select_increments(wk.active, every.c, every.sg, every.s, wk.c, wk.sg, wk.s)
            propagate_sample(dth_k, h_k, f[k, COL_VAR], False, q[h], A, W, U_ax, V_ax, Mi, G,
                             N_none, Phi_aa[h], Phi_ap[h], Q_aa[h], par_y, par_t, acc_i, acc_f,
                             th_acc, arw_var, wk)
            th_last[h, 0], th_last[h, 1], th_last[h, 2] = wk.th[0], wk.th[1], wk.th[2]
            h_last[h], moved[h] = h_k, True
    for h in range(nh):
        if undet[h]:
            undetermined[h] += 1
        if moved[h]:  # the body rate of its last sample
            for r in range(3):
                omega[h, r] = th_last[h, r] / h_last[h]
    tlast[0] = f[z - 1, COL_T]
    return z - a


@kernel
def bank_flush(Phi_aa, Phi_ap, Q_aa, Ptt, Ptp, Ppp, FPtp, GPpp, T):
    """Schmidt time update of every hypothesis with its accumulated transition, then the
    accumulators reset (Phi_aa = I, Phi_ap = 0, Q_aa = 0):

        Ptt ← Φ Ptt Φᵀ + Φ Ptp Γᵀ + Γ (Φ Ptp)ᵀ + Γ Ppp Γᵀ + Q (symmetrized),   Ptp ← Φ Ptp + Γ Ppp

    with Φ = Phi_aa[h], Γ = Phi_ap[h], Q = Q_aa[h] (shapes of :func:`bank_propagate`); Ptt
    (nh, 3, 3), Ptp (nh, 3, npar), Ppp (npar, npar). Work: FPtp, GPpp (3, npar), T (3, 3)."""
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


@kernel
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


@kernel
def bank_tracker(q_meas, n_stars, R_nom, use_phi, phi, phi_col, lat_col, dt_extrap, st_sigma,
                 ref_stars, sig_t, gate, q, omega, Ptt, Ptp, Ppp, ll, nis, nis_k, logdet_k, W33, W3p,
                 W4):
    """Apply one star-tracker sample to every hypothesis (Schmidt attitude filter, docs/fdi.md §3.2).

    q_meas (4,) measured q_st_from_inertial, n_stars its star count; R_nom (3, 3) R_st_from_body
    (nominal); phi (3,) the
    snapshot's φ2 [rad, body] used when use_phi (ST2), whose columns in the parameter vector are
    phi_col..phi_col+2; lat_col the column of the latency state (−1: none); dt_extrap [s] =
    epoch − τ̂ − time of the last propagated gyro sample (the attitude is extrapolated with ω̂);
    st_sigma (3,) the tracker's 1σ noise at ref_stars stars [rad, tracker axes], scaled by
    √(ref_stars/n_stars) to the variances rdiag; sig_t [s] σ of the time line; gate the NIS cap. Per hypothesis: residual r and H_a, H_p (φ2 and τ columns, τ: −H_a ω̂) from the
    engine's model; S = H_a Ptt H_aᵀ + H_a Ptp H_pᵀ + H_p Ptpᵀ H_aᵀ + H_p Ppp H_pᵀ + R (symmetrized),
    R = diag(rdiag) + σ_t² v vᵀ with v = R_nom ω̂; NIS = rᵀS⁻¹r and ln det S from S = L Lᵀ;
    nis += min(NIS, gate), ll −= ½ (min(NIS, gate) + ln det S). If NIS ≤ gate, K = (Ptt H_aᵀ +
    Ptp H_pᵀ) S⁻¹ (3, 3), q ← R(K r)ᵀ ∘ q, Ptt ← Ptt − K (Ptt H_aᵀ + Ptp H_pᵀ)ᵀ (symmetrized),
    Ptp ← Ptp − K (H_a Ptp + H_p Ppp); the parameters are neither corrected nor their covariance
    changed. Outputs nis_k, logdet_k (nh,): this sample's NIS and ln det S (NaN where S is not
    positive definite: ll = −inf, no correction). Work: W33 (12, 3, 3), W3p (3, 3, npar), W4 (4, 4).
    Returns the number of hypotheses whose S was not positive definite.
    """
    nh = q.shape[0]
    npar = Ppp.shape[0]
    Ha, Hphi, R, PHt, S, L, K, Ptt_new = W33[0], W33[1], W33[2], W33[3], W33[4], W33[5], W33[6], W33[7]
    X = W33[8]  # rows 0..2: r, y (= L⁻¹ r), the rotation vector K r
    Hp, HpPpp, Y = W3p[0], W3p[1], W3p[2]
    qe, w4, dq, qc = W4[0], W4[1], W4[2], W4[3]
    r, y, v = X[0], X[1], X[2]
    rdiag = W33[9][0]
    fac = math.sqrt(ref_stars / max(n_stars, 1))
    for i in range(3):
        sg = st_sigma[i] * fac
        rdiag[i] = sg * sg
    # the columns of H_p that can be nonzero (φ2 for ST2, τ), ascending: the sums below run over
    # them only, in the order (and with the zero tests) of a sweep over all npar columns
    cols = np.empty(4, np.int64)
    ncol = 0
    if use_phi:
        for c in range(3):
            cols[ncol] = phi_col + c
            ncol += 1
    if lat_col >= 0 and not (use_phi and phi_col <= lat_col < phi_col + 3):  # (τ overwrites φ2)
        cols[ncol] = lat_col
        ncol += 1
        i = ncol - 1
        while i > 0 and cols[i - 1] > cols[i]:
            cols[i - 1], cols[i] = cols[i], cols[i - 1]
            i -= 1
    bad = 0
    tracker_geometry(R_nom, phi, use_phi, Ha, Hphi)  # the same for every hypothesis
    for h in range(nh):
        for i in range(4):
            qe[i] = q[h, i]
        if dt_extrap != 0.0:
            for i in range(3):
                v[i] = omega[h, i] * dt_extrap
            apply_body_rotation(qe, v, w4, dq)
        tracker_error(q_meas, qe, Ha, r)
        for a in range(3):
            if use_phi:
                for c in range(3):
                    Hp[a, phi_col + c] = Hphi[a, c]
            if lat_col >= 0:
                Hp[a, lat_col] = -(Ha[a, 0] * omega[h, 0] + Ha[a, 1] * omega[h, 1]
                                   + Ha[a, 2] * omega[h, 2])
        timing_noise(R_nom, omega[h], rdiag, sig_t, R)
        P, C = Ptt[h], Ptp[h]
        for a in range(3):  # PHt = cov(δθ, Hx) = Ptt Haᵀ + Ptp Hpᵀ;  HpPpp = Hp Ppp (Hp sparse)
            for b in range(3):
                s1 = P[a, 0] * Ha[b, 0] + P[a, 1] * Ha[b, 1] + P[a, 2] * Ha[b, 2]
                s2 = 0.0
                for ic in range(ncol):
                    c = cols[ic]
                    if Hp[b, c] != 0.0:
                        s2 += C[a, c] * Hp[b, c]
                PHt[a, b] = s1 + s2
            for c in range(npar):
                HpPpp[a, c] = 0.0
            for ic in range(ncol):
                k = cols[ic]
                hk = Hp[a, k]
                if hk != 0.0:
                    for c in range(npar):
                        HpPpp[a, c] += hk * Ppp[k, c]
        for c in range(npar):  # Y (rows) = (Ptpᵀ Haᵀ)ᵀ = Ha Ptp, the cross term of S and Ptp
            for a in range(3):
                Y[a, c] = Ha[a, 0] * C[0, c] + Ha[a, 1] * C[1, c] + Ha[a, 2] * C[2, c]
        for a in range(3):
            for b in range(3):
                s1 = Ha[a, 0] * PHt[0, b] + Ha[a, 1] * PHt[1, b] + Ha[a, 2] * PHt[2, b]
                s2 = 0.0
                s3 = 0.0
                for ic in range(ncol):
                    c = cols[ic]
                    if Hp[a, c] != 0.0:
                        s2 += Hp[a, c] * Y[b, c]
                    if Hp[b, c] != 0.0:
                        s3 += HpPpp[a, c] * Hp[b, c]
                Ptt_new[a, b] = s1 + s2 + s3 + R[a, b]
        for a in range(3):
            for b in range(3):
                S[a, b] = 0.5 * (Ptt_new[a, b] + Ptt_new[b, a])
        if cholesky_lower(S, 3, L) != OK:
            ll[h] = -math.inf
            nis_k[h] = math.nan
            logdet_k[h] = math.nan
            bad += 1
            continue
        e = 0.0
        logdet = 0.0
        for j in range(3):  # y = L⁻¹ r
            t = r[j]
            for k in range(j):
                t -= L[j, k] * y[k]
            y[j] = t / L[j, j]
            e += y[j] * y[j]
            logdet += math.log(L[j, j])
        logdet *= 2.0
        nis_k[h] = e
        logdet_k[h] = logdet
        capped = gate if gate < e else e
        nis[h] += capped
        ll[h] -= 0.5 * (capped + logdet)
        if not e <= gate:
            continue  # edited like the engine would: no correction
        for a in range(3):  # K[a] = S⁻¹ PHt[a]ᵀ (two triangular solves)
            for j in range(3):
                t = PHt[a, j]
                for k in range(j):
                    t -= L[j, k] * K[a, k]
                K[a, j] = t / L[j, j]
            for j in range(2, -1, -1):
                t = K[a, j]
                for k in range(j + 1, 3):
                    t -= L[k, j] * K[a, k]
                K[a, j] = t / L[j, j]
        for a in range(3):
            v[a] = K[a, 0] * r[0] + K[a, 1] * r[1] + K[a, 2] * r[2]
        rotvec_to_quat_into(v, dq)
        dq[0], dq[1], dq[2] = -dq[0], -dq[1], -dq[2]
        for i in range(4):
            qe[i] = q[h, i]
        quat_mul_into(dq, qe, qc)
        nrm = math.sqrt(qc[0] * qc[0] + qc[1] * qc[1] + qc[2] * qc[2] + qc[3] * qc[3])
        if qc[3] < 0.0:
            nrm = -nrm
        for i in range(4):
            q[h, i] = qc[i] / nrm
        for a in range(3):
            for b in range(3):
                Ptt_new[a, b] = P[a, b] - (K[a, 0] * PHt[b, 0] + K[a, 1] * PHt[b, 1]
                                           + K[a, 2] * PHt[b, 2])
        for a in range(3):
            for b in range(3):
                P[a, b] = 0.5 * (Ptt_new[a, b] + Ptt_new[b, a])
        for c in range(npar):
            y0 = Y[0, c] + HpPpp[0, c]
            y1 = Y[1, c] + HpPpp[1, c]
            y2 = Y[2, c] + HpPpp[2, c]
            for a in range(3):
                C[a, c] -= K[a, 0] * y0 + K[a, 1] * y1 + K[a, 2] * y2
    return bad


@kernel
def bank_step(f, st, br, i0, end, q_meas, n_stars, epoch, R_nom, use_phi, phi, phi_col, lat_col,
              tau, st_sigma, ref_stars, sig_t, gate, masks, xp, A, W, U_ax, V_ax, Minv, Gp, N_none,
              arw_var, q, omega, tlast, undetermined, Phi_aa, Phi_ap, Q_aa, Ptt, Ptp, Ppp, ll, nis,
              nis_k, logdet_k, par_y, par_t, acc_i, acc_f, th_acc, W33, W3p, W4):
    """One tracker sample of the bank in one call: :func:`bank_propagate` through the gyro samples
    up to its epoch [s], :func:`bank_flush` (skipped when no transition is pending, which leaves
    Ptt and Ptp bit for bit as the flush would), then :func:`bank_tracker` with the attitude
    extrapolated by epoch − τ̂ − tlast (τ̂ = tau [s], the snapshot's latency). Arguments as in those
    kernels. Returns the number of hypotheses whose S was not positive definite."""
    m = bank_propagate(f, st, br, i0, end, epoch, masks, xp, A, W, U_ax, V_ax, Minv, Gp, N_none,
                       arw_var, q, omega, tlast, undetermined, Phi_aa, Phi_ap, Q_aa, par_y, par_t,
                       acc_i, acc_f, th_acc)
    if m > 0 or not transition_clear(Phi_aa, Phi_ap, Q_aa, Ptt):
        bank_flush(Phi_aa, Phi_ap, Q_aa, Ptt, Ptp, Ppp, W3p[0], W3p[1], W33[10])
    return bank_tracker(q_meas, n_stars, R_nom, use_phi, phi, phi_col, lat_col,
                        epoch - tau - tlast[0], st_sigma, ref_stars, sig_t, gate, q, omega, Ptt,
                        Ptp, Ppp, ll, nis, nis_k, logdet_k, W33, W3p, W4)


@kernel
def bank_run(f, st, br, i0, end, q_meas, n_stars, epoch, st2, R1, R2, phi, phi_col, lat_col, tau,
             st_sigma, ref_stars, sig_t, gate, masks, xp, A, W, U_ax, V_ax, Minv, Gp, N_none,
             arw_var, q, omega, tlast, undetermined, Phi_aa, Phi_ap, Q_aa, Ptt, Ptp, Ppp, ll, nis,
             nis_k, logdet_k, par_y, par_t, acc_i, acc_f, th_acc, W33, W3p, W4):
    """:func:`bank_step` for m tracker samples in epoch order, in one call (the bank's catch-up
    from its snapshot): q_meas (m, 4) q_st_from_inertial, n_stars (m,) int64, epoch (m,) [s],
    st2 (m,) bool (ST2: mounting R2 and the φ2 columns; else ST1 with R1, both (3, 3)
    R_st_from_body nominal); the other arguments as in bank_step. Returns the sum of its counts."""
    bad = 0
    for i in range(q_meas.shape[0]):
        R_nom = R2 if st2[i] else R1
        bad += bank_step(f, st, br, i0, end, q_meas[i], n_stars[i], epoch[i], R_nom, st2[i], phi,
                         phi_col, lat_col, tau, st_sigma, ref_stars, sig_t, gate, masks, xp, A, W,
                         U_ax, V_ax, Minv, Gp, N_none, arw_var, q, omega, tlast, undetermined,
                         Phi_aa, Phi_ap, Q_aa, Ptt, Ptp, Ppp, ll, nis, nis_k, logdet_k, par_y,
                         par_t, acc_i, acc_f, th_acc, W33, W3p, W4)
    return bad


#: bank_sample's integer and float controls (the last two entries of the bank's kernel tuple,
#: radical_rt.fdi.fdi_hypotheses.HypothesisBank.kernel_args)
BI_ON, BI_I0, BI_END, BI_PHI_COL, BI_LAT_COL, BI_K, BI_STEPS, BI_BAD = range(8)
BF_TAU, BF_REF_STARS, BF_GATE, BF_LLR_MIN, BF_ARW = range(5)


@kernel
def decide(ll, nis, thr, k, llr_min):
    """The bank's decision after k ≥ 1 tracker samples (docs/fdi.md §3.3): ll, nis (nh,) as in
    the bank, thr (K,) the consistency thresholds χ²(3k) by k (fdi_hypotheses.consistency_thresholds),
    llr_min the margin. Returns (code, best, margin): the best hypothesis and runner-up (the first
    index on ties), margin = ll[best] − ll[runner-up]; code 0 wait (margin below llr_min, or the
    best hypothesis fails the consistency test), 1 the best hypothesis is chosen, 2 the table is
    too short to tell (k ≥ K)."""
    nh = ll.shape[0]
    best = 0
    for h in range(1, nh):
        if ll[h] > ll[best]:
            best = h
    second = 1 if best == 0 else 0
    for h in range(second + 1, nh):
        if h != best and ll[h] > ll[second]:
            second = h
    margin = ll[best] - ll[second]
    if margin < llr_min:
        return 0, best, margin
    if k >= thr.shape[0]:
        return 2, best, margin
    return (0 if nis[best] > thr[k] else 1), best, margin


@kernel
def decision_due(ll, nis, thr, k, llr_min):
    """Whether HypothesisBank.decision(llr_min) would say anything but "wait" after k ≥ 1 tracker
    samples (:func:`decide`; a table too short answers True, a harmless handover)."""
    return decide(ll, nis, thr, k, llr_min)[0] != 0


@kernel
def bank_sample(bk, q_meas, n_stars, epoch, R_nom, use_phi, sig_t, W, U_ax, V_ax):
    """One valid tracker sample (q_meas (4,) q_st_from_inertial, n_stars, epoch [s], mounting
    R_nom (3, 3), use_phi (ST2), σ_t [s] of the time line) for the running bank inside the
    compiled release (radical_rt.engine.loop.run_release): :func:`bank_step` with the bank's
    arrays bk (HypothesisBank.kernel_args: the gyro history blocks, the bank state and work,
    phi (3,), st_sigma (3,), thr (K,), bi int64 (8,) BI_*, bf float64 (5,) BF_*) and the engine's
    geometry W, U_ax, V_ax; bi[BI_K] and bi[BI_STEPS] += 1, bi[BI_BAD] += the hypotheses whose S
    was not positive definite. Returns :func:`decision_due` (True: hand over to Python)."""
    (f, st, br, masks, xp, A, Minv, Gp, N_none, q, omega, tlast, undetermined, Phi_aa, Phi_ap,
     Q_aa, Ptt, Ptp, Ppp, ll, nis, nis_k, logdet_k, par_y, par_t, acc_i, acc_f, th_acc, W33, W3p,
     W4, phi, st_sigma, thr, bi, bf) = bk
    bad = bank_step(f, st, br, bi[BI_I0], bi[BI_END], q_meas, n_stars, epoch, R_nom, use_phi, phi,
                    bi[BI_PHI_COL], bi[BI_LAT_COL], bf[BF_TAU], st_sigma, bf[BF_REF_STARS], sig_t,
                    bf[BF_GATE], masks, xp, A, W, U_ax, V_ax, Minv, Gp, N_none, bf[BF_ARW], q,
                    omega, tlast, undetermined, Phi_aa, Phi_ap, Q_aa, Ptt, Ptp, Ppp, ll, nis,
                    nis_k, logdet_k, par_y, par_t, acc_i, acc_f, th_acc, W33, W3p, W4)
    bi[BI_BAD] += bad
    bi[BI_STEPS] += 1
    bi[BI_K] += 1
    return decision_due(ll, nis, thr, bi[BI_K], bf[BF_LLR_MIN])
