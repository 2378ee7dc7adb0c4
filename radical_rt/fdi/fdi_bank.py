"""Compiled kernels of the FDI hypothesis bank (docs/fdi.md §3): every hypothesis in one call.

The bank (:class:`radical_rt.fdi.fdi_hypotheses.HypothesisBank`) keeps the state of its nh hypotheses
(H0 with all gyros, H_i with gyro i left out) in stacked arrays:

* ``q`` (nh, 4) q_body_from_inertial (scalar last), ``omega`` (nh, 3) last body rate [rad/s, body];
* ``Ptt`` (nh, 3, 3) covariance of the attitude error δθ [rad², body axes], ``Ptp`` (nh, 3, npar)
  its cross-covariance with the considered parameters (internal units of :mod:`radical_rt.kernels.model`),
  ``Ppp`` (npar, npar) the snapshot's parameter covariance (shared: the parameters are considered,
  never estimated);
* ``ll`` (nh,) robust log-likelihood (up to a common constant), ``nis`` (nh,) capped NIS sums.

The propagation between tracker samples (the gyro history's rows, :func:`bank_propagate`,
:func:`bank_flush`: the engine's own propagation kernel with the hypothesis's exclusion mask and
the snapshot calibration, then the Schmidt time update of the covariance blocks) is in
:mod:`radical_rt.fdi.fdi_bank_propagate`. This module owns the measurement side:
:func:`bank_tracker` applies one star-tracker sample to all hypotheses: the engine's tracker model
(:func:`radical_rt.kernels.tracker_model.tracker_residual`, noise with the time-line term
:func:`radical_rt.kernels.updates.timing_noise`), the innovation covariance S (3, 3), its Cholesky factor
(:func:`radical_rt.kernels.ud.cholesky_lower`; no LAPACK), NIS and ln det S, the gated log-likelihood and
the Schmidt (consider) gain and correction of the attitude states only (Schmidt 1966; the
considered-state form of Bierman 1977 ch. VIII). Kernels never raise: a hypothesis whose S is not
positive definite gets ll = −inf and no correction, and the count of such hypotheses is returned.
:func:`bank_step` / :func:`bank_run` chain propagation, flush and tracker update for one / m
tracker samples; :func:`decide` is the decision rule and :func:`bank_sample` the entry of the
compiled release.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import OK, inline_kernel, kernel
from radical_rt.fdi.fdi_bank_propagate import bank_flush, bank_propagate, transition_clear
from radical_rt.kernels.flat_views import borrow
from radical_rt.kernels.rotation import apply_body_rotation, quat_mul_into, rotvec_to_quat_into
from radical_rt.kernels.tracker_model import tracker_error, tracker_geometry
from radical_rt.kernels.ud import cholesky_lower
from radical_rt.kernels.updates import timing_noise


@inline_kernel
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
    q_meas, R_nom, phi, st_sigma = borrow(q_meas), borrow(R_nom), borrow(phi), borrow(st_sigma)
    q, omega, Ptt, Ptp, Ppp = borrow(q), borrow(omega), borrow(Ptt), borrow(Ptp), borrow(Ppp)
    ll, nis, nis_k, logdet_k = borrow(ll), borrow(nis), borrow(nis_k), borrow(logdet_k)
    W33, W3p, W4 = borrow(W33), borrow(W3p), borrow(W4)
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
    W33, W3p = borrow(W33), borrow(W3p)
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


#: bank_sample's integer and float controls (the entries "bi" and "bf" of the bank's tuple)
BI_ON, BI_I0, BI_END, BI_PHI_COL, BI_LAT_COL, BI_K, BI_STEPS, BI_BAD = range(8)
BF_TAU, BF_REF_STARS, BF_GATE, BF_LLR_MIN, BF_ARW = range(5)

#: the bank's arrays as the compiled release takes them (the tuple bk of :func:`bank_sample`,
#: built by radical_rt.fdi.fdi_hypotheses.HypothesisBank.kernel_args, its idle stand-in by
#: idle_kernel_args), declared once: name, rank, dtype, in tuple order. The gyro history's
#: blocks f, st, br; the stacked hypotheses' state and work; phi (3,), st_sigma (3,), the
#: consistency thresholds thr (K,); the controls bi (BI_*), bf (BF_*).
BK_SLOTS = tuple((name, int(spec[0]), {"f": "float64", "i": "int64", "b": "bool"}[spec[1]])
                 for name, spec in (item.split(":") for item in """
    f:2f st:1i br:1b masks:2b xp:1f A:2f Minv:2f Gp:2f N_none:2f q:2f omega:2f tlast:1f
    undetermined:1i Phi_aa:3f Phi_ap:3f Q_aa:3f Ptt:3f Ptp:3f Ppp:2f ll:1f nis:1f nis_k:1f
    logdet_k:1f par_y:2f par_t:2f acc_i:1i acc_f:1f th_acc:1f W33:3f W3p:3f W4:2f phi:1f
    st_sigma:1f thr:1f bi:1i bf:1f""".split()))
BK_INDEX = {name: i for i, (name, _nd, _dt) in enumerate(BK_SLOTS)}  # name → position in bk
BK_F, BK_ST, BK_BR, BK_SIG, BK_BI, BK_BF = (BK_INDEX[n] for n in ("f", "st", "br", "st_sigma",
                                                                 "bi", "bf"))


@inline_kernel
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


@inline_kernel
def decision_due(ll, nis, thr, k, llr_min):
    """Whether HypothesisBank.decision(llr_min) would say anything but "wait" after k ≥ 1 tracker
    samples (:func:`decide`; a table too short answers True, a harmless handover)."""
    return decide(ll, nis, thr, k, llr_min)[0] != 0


# positions in bk of its arrays, by name (BK_SLOTS declares the order once)
(_F, _ST, _BR, _MASKS, _XP, _A, _MINV, _GP, _N_NONE, _Q, _OMEGA, _TLAST, _UNDET, _PHI_AA, _PHI_AP,
 _Q_AA, _PTT, _PTP, _PPP, _LL, _NIS, _NIS_K, _LOGDET_K, _PAR_Y, _PAR_T, _ACC_I, _ACC_F, _TH_ACC,
 _W33, _W3P, _W4, _PHI, _SIG, _THR, _BI, _BF) = (BK_INDEX[n] for n in (
    "f", "st", "br", "masks", "xp", "A", "Minv", "Gp", "N_none", "q", "omega", "tlast",
    "undetermined", "Phi_aa", "Phi_ap", "Q_aa", "Ptt", "Ptp", "Ppp", "ll", "nis", "nis_k",
    "logdet_k", "par_y", "par_t", "acc_i", "acc_f", "th_acc", "W33", "W3p", "W4", "phi",
    "st_sigma", "thr", "bi", "bf"))


@kernel
def bank_sample(bk, q_meas, n_stars, epoch, R_nom, use_phi, sig_t, W, U_ax, V_ax):
    """One valid tracker sample (q_meas (4,) q_st_from_inertial, n_stars, epoch [s], mounting
    R_nom (3, 3), use_phi (ST2), σ_t [s] of the time line) for the running bank inside the
    compiled release (radical_rt.engine.loop.run_release): :func:`bank_step` with the bank's
    arrays bk (HypothesisBank.kernel_args: the gyro history blocks, the bank state and work,
    phi (3,), st_sigma (3,), thr (K,), bi int64 (8,) BI_*, bf float64 (5,) BF_*) and the engine's
    geometry W, U_ax, V_ax; bi[BI_K] and bi[BI_STEPS] += 1, bi[BI_BAD] += the hypotheses whose S
    was not positive definite. Returns :func:`decision_due` (True: hand over to Python)."""
    f, st, br, masks, xp, A = bk[_F], bk[_ST], bk[_BR], bk[_MASKS], bk[_XP], bk[_A]
    Minv, Gp, N_none, q, omega = bk[_MINV], bk[_GP], bk[_N_NONE], bk[_Q], bk[_OMEGA]
    tlast, undetermined, Phi_aa, Phi_ap = bk[_TLAST], bk[_UNDET], bk[_PHI_AA], bk[_PHI_AP]
    Q_aa, Ptt, Ptp, Ppp, ll, nis = bk[_Q_AA], bk[_PTT], bk[_PTP], bk[_PPP], bk[_LL], bk[_NIS]
    nis_k, logdet_k, par_y, par_t = bk[_NIS_K], bk[_LOGDET_K], bk[_PAR_Y], bk[_PAR_T]
    acc_i, acc_f, th_acc, W33, W3p = bk[_ACC_I], bk[_ACC_F], bk[_TH_ACC], bk[_W33], bk[_W3P]
    W4, phi, st_sigma, thr, bi, bf = bk[_W4], bk[_PHI], bk[_SIG], bk[_THR], bk[_BI], bk[_BF]
    bad = bank_step(f, st, br, bi[BI_I0], bi[BI_END], q_meas, n_stars, epoch, R_nom, use_phi, phi,
                    bi[BI_PHI_COL], bi[BI_LAT_COL], bf[BF_TAU], st_sigma, bf[BF_REF_STARS], sig_t,
                    bf[BF_GATE], masks, xp, A, W, U_ax, V_ax, Minv, Gp, N_none, bf[BF_ARW], q,
                    omega, tlast, undetermined, Phi_aa, Phi_ap, Q_aa, Ptt, Ptp, Ppp, ll, nis,
                    nis_k, logdet_k, par_y, par_t, acc_i, acc_f, th_acc, W33, W3p, W4)
    bi[BI_BAD] += bad
    bi[BI_STEPS] += 1
    bi[BI_K] += 1
    return decision_due(ll, nis, thr, bi[BI_K], bf[BF_LLR_MIN])
