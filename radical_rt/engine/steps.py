"""The engine's compiled steps on the packed state: starts and resets, attitude initialization,
numeric-fault recovery, the window close with its parity sums, and the correction fold.

Every function takes the array tuple ``E`` (:func:`radical_rt.engine.engine_layout.unpack`) and
the small arrays ``cfg``, ``io``, ``cnt`` of :mod:`radical_rt.engine.loop_layout`, and is
called by the release loop of :mod:`radical_rt.engine.loop` (and by
:func:`radical_rt.engine.events.engine_event`, through which Python runs the same steps for
commands). The small ones are inlined; the rare or long ones (a close at 10 Hz, a parity sum a
second, resets) are compiled once as functions of their own, which keeps the loop's compile time
short. These are the only implementations of these steps; docs/engine.md §2 lists them.
All quantities SI; attitude error states first (body axes, rad), then the parameters xp.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import inline_kernel, kernel
from radical_rt.contract.flags import Flag
from radical_rt.engine.engine_layout import E_INDEX
from radical_rt.engine.loop_layout import (
    CFG_ARW_VAR,
    CFG_ATT_INIT_SCALE,
    CFG_EDIT,
    CFG_FDI_ON,
    CFG_GATE_PARITY,
    CFG_N_GYRO,
    CFG_PARITY_LAG,
    CFG_PARITY_WINDOW,
    CFG_PHI_COL,
    CFG_QUANT_VAR,
    CFG_REGRESSOR_K,
    CFG_ST_REF_STARS,
    CFG_ST_STALE,
    CFG_TIMING_CONSIDER,
    CNT_ATT_INITS,
    CNT_FLAGS,
    CNT_LOCKED_PAR,
    CNT_NUMERIC,
    CNT_NUMERIC_CODE,
    CNT_PAR_EARLY,
    CNT_PAR_EDITED,
    CNT_PAR_STAT,
    CNT_PAR_SUMS,
    CNT_PAR_USED,
    CNT_RESETS,
    IO_ATT_VALID,
    IO_LAST_ST1,
    IO_LAST_ST2,
    IO_LOCKED_SINCE,
    IO_MODE,
    IO_NIS_LOCKED_PAR,
    IO_NIS_SUM_PAR,
    IO_PAR_NIS,
    IO_PAR_NU,
    IO_PAR_RHO,
    IO_PAR_T0,
    IO_PAR_Z,
    IO_SIG_T,
    IO_T,
)
from radical_rt.kernels.model import fold_correction, parity_from_stats
from radical_rt.kernels.timeupdate import close_time_window, regressor_reliability
from radical_rt.kernels.tracker_model import quat_from_tracker
from radical_rt.kernels.ud import variances, variances_within
from radical_rt.kernels.ud_time import reset_leading_block
from radical_rt.kernels.updates import gated_update, gated_update_consider

NUMERIC_GEOMETRY = -1  # cnt[CNT_NUMERIC_CODE] of a singular sense-axis geometry (else a UD status)
# io[IO_MODE]: the engine's mode ("init", "converging", "converged", "degraded")
MODE_INIT, MODE_CONVERGING, MODE_CONVERGED, MODE_DEGRADED = -1.0, 0.0, 1.0, 2.0
_NUMERIC, _GYRO_GAP = int(Flag.NUMERIC), int(Flag.GYRO_GAP)
_ST1_STALE, _ST2_STALE = int(Flag.ST1_STALE), int(Flag.ST2_STALE)
_NOT_CONVERGED = int(Flag.NOT_CONVERGED)

_EXCLUDED, _XP, _Q, _A = E_INDEX["excluded"], E_INDEX["xp"], E_INDEX["q"], E_INDEX["A"]
_W, _UAX, _VAX = E_INDEX["geo.W"], E_INDEX["geo.U"], E_INDEX["geo.V"]
_MINV, _GP, _N = E_INDEX["Minv"], E_INDEX["Gp"], E_INDEX["N"]
_PHI_AA, _PHI_AP, _Q_AA = E_INDEX["Phi_aa"], E_INDEX["Phi_ap"], E_INDEX["Q_aa"]
_PAR_Y, _PAR_T = E_INDEX["par_y"], E_INDEX["par_t"]
_ACC_I, _ACC_F, _TH_ACC = E_INDEX["acc_i"], E_INDEX["acc_f"], E_INDEX["th_acc"]
_U, _D, _DX = E_INDEX["U"], E_INDEX["d"], E_INDEX["dx"]
_Q_PARAMS, _PARAM_IDX, _Q_DT = E_INDEX["q_params"], E_INDEX["param_idx"], E_INDEX["q_dt"]
_STRUCT_W, _A_W, _VAR_W = E_INDEX["ws.struct"], E_INDEX["ws.a"], E_INDEX["ws.var"]
_KAPPA_LAST, _HBUF = E_INDEX["kappa_last"], E_INDEX["Hbuf"]
_FBUF, _SBUF, _INNOV, _SIG = E_INDEX["Fbuf"], E_INDEX["Sbuf"], E_INDEX["innov"], E_INDEX["sig"]
_F_W, _V_W, _K_W = E_INDEX["ws.f"], E_INDEX["ws.v"], E_INDEX["ws.k"]
_ST_SIGMA, _P0, _SCALE_MASK = E_INDEX["st_sigma"], E_INDEX["p0"], E_INDEX["scale_mask"]
_CONV_VAR = E_INDEX["conv_var"]
_PQ, _PQ_I = E_INDEX["pq"], E_INDEX["pq_i"]
_PAR_INNOV, _PAR_SIG = E_INDEX["par_innov"], E_INDEX["par_sig"]
_Z_PAR, _H_PAR = E_INDEX["z_par"], E_INDEX["H_par"]
_THETA_PAR, _PHI_PAR = E_INDEX["theta_par"], E_INDEX["Phi_par"]
_FDI_Z, _FDI_H, _FDI_TH = E_INDEX["fdi_z"], E_INDEX["fdi_H"], E_INDEX["fdi_th"]
_FDI_PHI, _FDI_HV = E_INDEX["fdi_Phi"], E_INDEX["fdi_h"]


# ------------------------------------------------------------------------------ resets
@inline_kernel
def reset_time_window(E):
    """Time-update accumulators to an empty window: Φ_aa ← I, Φ_ap, Q_aa, Σθ̂ ← 0."""
    Phi_aa, Phi_ap, Q_aa = E[_PHI_AA], E[_PHI_AP], E[_Q_AA]
    acc_i, acc_f, th_acc = E[_ACC_I], E[_ACC_F], E[_TH_ACC]
    Phi_aa[:, :] = 0.0
    for i in range(3):
        Phi_aa[i, i] = 1.0
    Phi_ap[:, :] = 0.0
    Q_aa[:, :] = 0.0
    acc_i[0] = 0
    acc_f[0] = 0.0
    th_acc[:] = 0.0


@inline_kernel
def reset_parity(E):
    """Parity-sum statistics and their counts to an empty sum."""
    acc_i, acc_f = E[_ACC_I], E[_ACC_F]
    E[_PAR_Y][:, :] = 0.0
    E[_PAR_T][:, :] = 0.0
    for i in range(1, acc_i.shape[0]):
        acc_i[i] = 0
    acc_f[1] = 0.0
    acc_f[2] = 0.0


@inline_kernel
def begin_attitude_init(E, io, cnt):
    """The attitude is lost: wait for the next valid tracker sample (mode init, windows empty)."""
    io[IO_MODE] = MODE_INIT
    io[IO_ATT_VALID] = 0.0
    reset_time_window(E)
    reset_parity(E)
    cnt[CNT_RESETS] += 1


@kernel
def numeric_fault(E, io, cnt, code):
    """Numerical-integrity failure ``code`` (a UD status, or NUMERIC_GEOMETRY): flag NUMERIC,
    count it; if the factors or the parameters are no longer usable (d not finite and > 0, xp not
    finite), reset them (non-finite parameters to 0, U ← I, d_p ← p0) and restart the attitude."""
    cnt[CNT_FLAGS] |= _NUMERIC
    cnt[CNT_NUMERIC] += 1
    cnt[CNT_NUMERIC_CODE] = code
    U, d, xp, p0 = E[_U], E[_D], E[_XP], E[_P0]
    ok = True
    for i in range(d.shape[0]):
        if not (math.isfinite(d[i]) and d[i] > 0.0):
            ok = False
    for i in range(xp.shape[0]):
        if not math.isfinite(xp[i]):
            ok = False
    if ok:
        return
    for i in range(xp.shape[0]):
        if not math.isfinite(xp[i]):
            xp[i] = 0.0
    U[:, :] = 0.0
    for i in range(U.shape[0]):
        U[i, i] = 1.0
    for i in range(p0.shape[0]):
        d[3 + i] = p0[i]
    begin_attitude_init(E, io, cnt)


@kernel
def warm_reset(E, io, cnt):
    """Warm start without bump: attitude covariance ← I, its cross-covariances ← 0, the
    parameters and their factors kept; then wait for the next tracker sample."""
    status = reset_leading_block(E[_U], E[_D], 3, np.eye(3), E[_STRUCT_W])
    if status != 0:
        numeric_fault(E, io, cnt, status)
    begin_attitude_init(E, io, cnt)


@kernel
def init_attitude(j, t_epoch, q_meas, n_stars, R_nom, use_phi, E, cfg, io, cnt):
    """Attitude from tracker j's sample (q_meas (4,) q_st_from_inertial, n_stars, mounting R_nom
    (3, 3)) while none is valid: q_body_from_inertial through the mounting (and φ̂2 for ST2), the
    attitude covariance from the tracker noise × att_init_scale mapped to body axes (+ P_φ2 for
    ST2), cross-covariances 0. ST2 is not used while ST1 is alive (last valid ST1 epoch within
    st_stale). Returns True when the attitude was initialized."""
    if j == 2 and t_epoch - io[IO_LAST_ST1] < cfg[CFG_ST_STALE]:
        return False
    xp, q = E[_XP], E[_Q]
    phi_col = int(cfg[CFG_PHI_COL])
    phi = xp[phi_col - 3:phi_col]
    q[:] = quat_from_tracker(q_meas, R_nom, phi, use_phi)
    scale = math.sqrt(cfg[CFG_ST_REF_STARS] / max(n_stars, 1))
    s = E[_ST_SIGMA] * scale * cfg[CFG_ATT_INIT_SCALE]
    sig_body = np.abs(R_nom.T) @ s  # the BLAS product of the reference (same bits)
    P0 = np.zeros((3, 3))
    for i in range(3):
        P0[i, i] = sig_body[i] ** 2
    if use_phi:
        var = E[_VAR_W]
        variances(E[_U], E[_D], var)
        for i in range(3):
            P0[i, i] += var[phi_col + i]
    status = reset_leading_block(E[_U], E[_D], 3, P0, E[_STRUCT_W])
    if status != 0:
        numeric_fault(E, io, cnt, status)
    io[IO_ATT_VALID] = 1.0
    io[IO_T] = t_epoch
    io[IO_MODE] = MODE_CONVERGING
    cnt[CNT_FLAGS] &= ~_GYRO_GAP
    reset_time_window(E)
    reset_parity(E)
    cnt[CNT_ATT_INITS] += 1
    return True


# ------------------------------------------------------------------------------ window close
@inline_kernel
def fold(E, io, cnt):
    """Fold the correction dx into q and xp and rebuild the geometry (dx ← 0); a singular
    geometry is a numeric fault."""
    if fold_correction(E[_DX], E[_Q], E[_XP], E[_W], E[_UAX], E[_VAX], E[_A], E[_MINV],
                       E[_GP], E[_N]) > 0:
        numeric_fault(E, io, cnt, NUMERIC_GEOMETRY)


@inline_kernel
def close_window(E, cfg, io, cnt):
    """Close the time-update window on its accumulators (nothing when it is empty): κ scaling,
    P ← ΦPΦᵀ + Q_aa, parameter noise (radical_rt.kernels.timeupdate); then the lock latch and
    the parity sums (:func:`close_tail`)."""
    acc_i, acc_f = E[_ACC_I], E[_ACC_F]
    if acc_i[0] == 0:
        return
    noise_var = cfg[CFG_ARW_VAR] * acc_f[0] + cfg[CFG_QUANT_VAR]
    status, kappa = close_time_window(
        E[_U], E[_D], E[_PHI_AA], E[_PHI_AP], E[_Q_AA], E[_TH_ACC], acc_i, acc_f, E[_MINV],
        int(cfg[CFG_N_GYRO]), noise_var, cfg[CFG_REGRESSOR_K], E[_Q_PARAMS], E[_PARAM_IDX],
        E[_Q_DT], E[_STRUCT_W], E[_A_W])
    E[_KAPPA_LAST][0] = kappa
    if status != 0:
        numeric_fault(E, io, cnt, status)
    close_tail(E, cfg, io, cnt)


@inline_kernel
def close_tail(E, cfg, io, cnt):
    """After the covariance: the lock latch (start of the current run of closes with a locked time
    line, σ_t ≤ timing_consider; inf while unlocked), the parity sum when complete (queued), and
    the update of every queued sum that has waited parity_lag."""
    t = io[IO_T]
    if io[IO_SIG_T] > cfg[CFG_TIMING_CONSIDER]:
        io[IO_LOCKED_SINCE] = math.inf
    elif io[IO_LOCKED_SINCE] == math.inf:
        io[IO_LOCKED_SINCE] = t
    if E[_ACC_I][1] >= cfg[CFG_PARITY_WINDOW]:
        queue_parity(E, cfg, io, cnt)
    pq, pq_i = E[_PQ], E[_PQ_I]
    while pq_i[1] > 0 and pq[pq_i[0], 0] <= t - cfg[CFG_PARITY_LAG]:
        pop_parity(E, cfg, io, cnt)


@inline_kernel
def any_excluded(E):
    excluded = E[_EXCLUDED]
    for i in range(excluded.shape[0]):
        if excluded[i]:
            return True
    return False


@kernel
def queue_parity(E, cfg, io, cnt):
    """Queue the closed parity sum (statistics par_y, par_t (2, n), its noise variance [rad²]) for
    its lagged update, with four gyros in use; with cfg[CFG_FDI_ON], its FDI statistic first
    (:func:`parity_statistic`). The sum's accumulators are reset either way."""
    acc_i, acc_f = E[_ACC_I], E[_ACC_F]
    if acc_i[1] > 0 and not any_excluded(E):
        noise = acc_f[1] + acc_i[2] * cfg[CFG_QUANT_VAR]
        pq, pq_i = E[_PQ], E[_PQ_I]
        if pq_i[1] == pq.shape[0]:  # full (a lag longer than the queue was sized for)
            cnt[CNT_PAR_EARLY] += 1
            pop_parity(E, cfg, io, cnt)
        row = pq[(pq_i[0] + pq_i[1]) % pq.shape[0]]
        n = E[_PAR_Y].shape[1]
        row[0], row[1] = io[IO_T], noise
        row[2:2 + 2 * n] = E[_PAR_Y].ravel()
        row[2 + 2 * n:2 + 4 * n] = E[_PAR_T].ravel()
        pq_i[1] += 1
        cnt[CNT_PAR_SUMS] += 1
        cnt[CNT_PAR_STAT] = 0
        if cfg[CFG_FDI_ON] != 0.0:
            parity_statistic(E, io, cnt, noise)
    reset_parity(E)


@inline_kernel
def parity_statistic(E, io, cnt, noise):
    """The FDI's statistic of the sum in par_y, par_t (docs/fdi.md §2): its calibrated innovation
    z = Nᵀĉ − h·dx with the current estimate and σ² = hPhᵀ + R from the UD factors (all states),
    into io: ν = z/σ (IO_PAR_NU), ρ = σ²/R (IO_PAR_RHO), the sum's first sample time (IO_PAR_T0)
    and z (IO_PAR_Z); cnt[CNT_PAR_STAT] = 1 when they are finite and positive."""
    z1, H1, h = E[_FDI_Z], E[_FDI_H], E[_FDI_HV]
    parity_from_stats(E[_PAR_Y], E[_PAR_T], E[_XP], E[_A], E[_GP], E[_N], E[_W], E[_UAX],
                      E[_VAX], z1, H1, E[_FDI_TH], E[_FDI_PHI])
    h[:3] = 0.0
    h[3:] = H1[0]
    f = E[_U].T @ h  # the BLAS products of the reference (same bits)
    s2 = E[_D] @ (f * f) + noise
    z = z1[0] - h @ E[_DX]
    if not (s2 > 0.0 and noise > 0.0 and math.isfinite(z)):
        return
    io[IO_PAR_NU], io[IO_PAR_RHO] = z / math.sqrt(s2), s2 / noise
    io[IO_PAR_T0], io[IO_PAR_Z] = io[IO_T] - E[_ACC_F][2], z
    cnt[CNT_PAR_STAT] = 1


@kernel
def pop_parity(E, cfg, io, cnt):
    """Take the oldest queued sum off the queue and run its update (:func:`parity_update`)."""
    pq, pq_i = E[_PQ], E[_PQ_I]
    row = pq[pq_i[0]]
    pq_i[0] = (pq_i[0] + 1) % pq.shape[0]
    pq_i[1] -= 1
    n = E[_PAR_Y].shape[1]
    par_y = row[2:2 + 2 * n].copy().reshape((2, n))
    par_t = row[2 + 2 * n:2 + 4 * n].copy().reshape((2, n))
    parity_update(par_y, par_t, row[1], E, cfg, io, cnt)


@inline_kernel
def parity_update(par_y, par_t, noise, E, cfg, io, cnt):
    """Parity update of one closed sum (par_y, par_t (2, n), noise [rad²]) linearized about the
    current estimate (docs/engine.md §3.5): rows on the parameters only, the λ, μ, du, dv columns
    scaled by the regressor reliability κ, the scale and misalignment states considered while
    the time line has not been locked for parity_lag. None with a gyro excluded."""
    if any_excluded(E):
        return
    n = int(cfg[CFG_N_GYRO])
    H_par, theta, Phi = E[_H_PAR], E[_THETA_PAR], E[_PHI_PAR]
    nr = H_par.shape[0]
    parity_from_stats(par_y, par_t, E[_XP], E[_A], E[_GP], E[_N], E[_W], E[_UAX], E[_VAX],
                      E[_Z_PAR], H_par, theta, Phi)
    Hbuf = E[_HBUF]
    H = Hbuf[:nr]
    H[:, :] = 0.0
    H[:, 3:] = H_par
    kappa = regressor_reliability(E[_U], E[_D], 3, theta, Phi, E[_MINV], noise,
                                  cfg[CFG_REGRESSOR_K])
    E[_KAPPA_LAST][1] = kappa
    if kappa < 1.0:
        H[:, 3 + n:3 + 5 * n] *= kappa
    rdiag = np.full(nr, noise)
    innov, sig = E[_INNOV][:nr], E[_SIG][:nr]
    F, S = E[_FBUF][:nr], E[_SBUF][:nr, :nr]
    gate, edit = cfg[CFG_GATE_PARITY], cfg[CFG_EDIT] != 0.0
    if io[IO_T] - io[IO_LOCKED_SINCE] < cfg[CFG_PARITY_LAG]:
        status, nis, edited = gated_update_consider(
            E[_U], E[_D], E[_DX], H, E[_Z_PAR], rdiag, gate, edit, E[_SCALE_MASK], F, S, innov,
            sig, E[_F_W], E[_V_W], E[_K_W], E[_A_W])
    else:
        status, nis, edited = gated_update(E[_U], E[_D], E[_DX], H, E[_Z_PAR], rdiag, gate,
                                           edit, F, S, innov, sig, E[_F_W], E[_V_W], E[_K_W])
    if status != 0:
        numeric_fault(E, io, cnt, status)
    E[_PAR_INNOV][:] = innov
    E[_PAR_SIG][:] = sig
    io[IO_PAR_NIS] = nis
    if edited:
        cnt[CNT_PAR_EDITED] += 1
    else:
        cnt[CNT_PAR_USED] += 1
        io[IO_NIS_SUM_PAR] += nis
        if io[IO_SIG_T] <= cfg[CFG_TIMING_CONSIDER]:  # the time line locked: calibrating
            cnt[CNT_LOCKED_PAR] += 1
            io[IO_NIS_LOCKED_PAR] += nis


@inline_kernel
def window_state(E, cfg, io, cnt, t_event):
    """The flags and the mode code after a close at event time t_event [s]: ST<j>_STALE when
    tracker j's last valid sample is older than st_stale; without an attitude mode init;
    otherwise NOT_CONVERGED unless every parameter variance is within its threshold (UD
    variances), and the mode degraded (NUMERIC, or a gyro excluded), converging or converged.
    Returns (flags, mode); the loop compares them (its window test), the window hook applies
    them (EV_WINDOW_STATE)."""
    f = cnt[CNT_FLAGS]
    f = (f | _ST1_STALE) if t_event - io[IO_LAST_ST1] > cfg[CFG_ST_STALE] else (f & ~_ST1_STALE)
    f = (f | _ST2_STALE) if t_event - io[IO_LAST_ST2] > cfg[CFG_ST_STALE] else (f & ~_ST2_STALE)
    if io[IO_ATT_VALID] == 0.0:
        return f, MODE_INIT
    if variances_within(E[_U], E[_D], E[_VAR_W], E[_CONV_VAR], 3):
        f &= ~_NOT_CONVERGED
    else:
        f |= _NOT_CONVERGED
    if f & _NUMERIC or any_excluded(E):
        return f, MODE_DEGRADED
    return f, (MODE_CONVERGING if f & _NOT_CONVERGED else MODE_CONVERGED)
