"""Per-sample gyro propagation and window accumulation (the 100 Hz hot loop, one Numba call).

Between two time-update window closes (≤ ``window`` samples, or a tracker epoch) the engine
accumulates, for the structured UD time update (notes §7, §11.5), the attitude transition
``Phi_aa`` (3, 3), the attitude-parameter coupling ``Phi_ap`` (3, 5n+3; the φ2 columns stay zero),
the attitude process noise ``Q_aa`` (3, 3) and ``th_acc`` (3,) the sum of the estimated body
increments θ̂ (the regressor of the λ, μ, du, dv columns, see
:meth:`radical_rt.engine.filter.Engine._regressor_reliability`). Independently, over a longer parity sum (it
may span several time-update windows and tracker epochs; the engine closes it), it accumulates the
sufficient statistics of the parity measurement: ``par_y`` (2, n) the raw increments and ``par_t``
(2, n) the sample intervals, split by the sign of the corrected increment
(:func:`radical_rt.kernels.model.parity_from_stats`).
``acc_i`` (int64[4]) holds (samples in the time-update window, parity samples, parity segments —
contiguous runs of parity samples, each adds one quantization term to the noise because the
quantization of the accumulated angle telescopes only over contiguous samples —, 1 if the previous
sample entered the parity sum) and ``acc_f`` (float64[3]) holds (time-update window duration [s],
ARW variance of the parity sum [rad²], parity-sum duration [s]).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from radical_rt._jit import inline_kernel, kernel
from radical_rt.kernels.flat_views import borrow
from radical_rt.kernels.model import correct_increment_lin, jacobian_gyro, masked_pinv
from radical_rt.kernels.rotation import (
    apply_body_quat,
    apply_body_rotation,
    quat_to_dcm_into,
    rotvec_to_quat_into,
)

#: propagate_window return flags (bit set in the second return value)
PROP_MASKED = 1  # some samples used fewer than all gyros
PROP_UNDETERMINED = 2  # some samples had fewer than 3 usable gyros (not propagated)


@kernel
def propagate_window(dtheta, dt, status, bridged, var_extra, i0, stop, excluded, xp, q, A, W,
                     U_ax, V_ax, Minv, Gp, N, Phi_aa, Phi_ap, Q_aa, par_y, par_t, acc_i, acc_f,
                     th_acc, window, arw_var, omega, work):
    """Propagate samples i0..stop−1 of a gyro batch until the window holds ``window`` samples.

    dtheta (m, n) [rad], dt (m,) [s], status (m,) int bits (gyro invalid), bridged (m,) bool,
    var_extra (m,) [rad²]; excluded (n,) bool (commanded exclusions); xp internal parameters
    (:mod:`radical_rt.kernels.model`, linear parametrization); A (3, n) estimated scaled axes, W, U_ax, V_ax
    (3, n) nominal triads, Minv, Gp, N from :func:`model.refresh_axes`; q (4,)
    q_body_from_inertial, propagated in place; omega (3,) [rad/s] receives the last body rate.
    work: a :class:`SampleWork` for n gyros (the caller's, allocated once for many calls; used
    here through views that own no memory, :func:`work_views`).
    Returns (index of the next unprocessed sample, flags PROP_*).
    """
    n = dtheta.shape[1]
    m = min(stop, dtheta.shape[0])
    wk = work_views(work)
    Gm, Mm = wk.Gm, wk.Mm
    flags = 0
    k = i0
    have = -1  # active-gyro bit pattern whose masked pseudo-inverse Gm, Mm hold (−1: none)
    have_ok = False
    h_last = 0.0  # interval of the last sample propagated [s]
    moved = False
    while k < m and acc_i[0] < window:
        n_act, bits = active_gyros(excluded, status[k], wk.active)
        G, Mi = Gp, Minv
        if n_act < n:
            flags |= PROP_MASKED
            if bits != have:  # A is constant over the call: one pseudo-inverse per pattern
                have, have_ok = bits, masked_pinv(A, wk.active, Mm, Gm) >= 0
            if not have_ok:
                flags |= PROP_UNDETERMINED
                k += 1
                continue
            G, Mi = Gm, Mm
        correct_increment_lin(dtheta[k], dt[k], xp, wk.active, wk.c, wk.sg, wk.s)
        propagate_sample(dtheta[k], dt[k], var_extra[k], n_act == n and not bridged[k], q, A, W,
                         U_ax, V_ax, Mi, G, N, Phi_aa, Phi_ap, Q_aa, par_y, par_t, acc_i, acc_f,
                         th_acc, arw_var, wk)
        h_last, moved = dt[k], True
        k += 1
    if moved:  # the body rate of the last sample propagated
        for r in range(3):
            omega[r] = wk.th[r] / h_last
    return k, flags


class SampleWork(NamedTuple):
    """Work arrays of :func:`propagate_sample` (:func:`sample_work`; each is written before it is
    read): the corrected increments c, their signs sg and scale s (n,) of
    :func:`radical_rt.kernels.model.correct_increment_lin`, gh = Aᵀθ̂ (n,), θ̂ th (3,) [rad, body],
    one gyro's Jacobian columns F (3, 5), work4 and dq (4,), the active gyros (n,) bool, R(θ̂) and
    a product T (3, 3), and a masked pseudo-inverse Gm (3, n) with its (AAᵀ)⁻¹ Mm (3, 3)
    (:func:`radical_rt.kernels.model.masked_pinv`, for :func:`propagate_window`)."""

    c: np.ndarray
    sg: np.ndarray
    s: np.ndarray
    gh: np.ndarray
    th: np.ndarray
    F: np.ndarray
    work4: np.ndarray
    dq: np.ndarray
    active: np.ndarray
    R: np.ndarray
    T: np.ndarray
    Gm: np.ndarray
    Mm: np.ndarray


@kernel
def sample_work(n):
    """A :class:`SampleWork` for n gyros."""
    return SampleWork(np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(3),
                      np.empty((3, 5)), np.empty(4), np.empty(4), np.empty(n, dtype=np.bool_),
                      np.empty((3, 3)), np.empty((3, 3)), np.empty((3, n)), np.empty((3, 3)))


@inline_kernel
def sample_work_size(n):
    """Floats of the flat buffer of :func:`sample_work_in` for n gyros."""
    return 7 * n + 53


@inline_kernel
def sample_work_in(wf, wb, n):
    """A :class:`SampleWork` for n gyros whose arrays are consecutive pieces of wf
    (≥ :func:`sample_work_size` (n),) float64 and wb (≥ n,) bool (views: borrowed ones when wf
    and wb are): two allocations where :func:`sample_work` makes thirteen, for a caller that
    needs the work arrays for one call only (the FDI bank, per tracker sample)."""
    o = 4 * n
    th, F = wf[o:o + 3], wf[o + 3:o + 18].reshape((3, 5))
    work4, dq = wf[o + 18:o + 22], wf[o + 22:o + 26]
    R, T = wf[o + 26:o + 35].reshape((3, 3)), wf[o + 35:o + 44].reshape((3, 3))
    Gm, Mm = wf[o + 44:o + 44 + 3 * n].reshape((3, n)), wf[o + 44 + 3 * n:o + 53 + 3 * n].reshape((3, 3))
    return SampleWork(wf[0:n], wf[n:2 * n], wf[2 * n:3 * n], wf[3 * n:o], th, F, work4, dq,
                      wb[0:n], R, T, Gm, Mm)


@inline_kernel
def work_views(wk):
    """The arrays of the :class:`SampleWork` wk as views that own no memory
    (:func:`radical_rt.kernels.flat_views.borrow`): a kernel that takes wk as an argument (alive
    for its whole call) unpacks them in its per-sample loop without atomic reference counting."""
    return SampleWork(borrow(wk.c), borrow(wk.sg), borrow(wk.s), borrow(wk.gh), borrow(wk.th),
                      borrow(wk.F), borrow(wk.work4), borrow(wk.dq), borrow(wk.active),
                      borrow(wk.R), borrow(wk.T), borrow(wk.Gm), borrow(wk.Mm))


@inline_kernel
def body_increment(G, c, th):
    """th (3,) ← θ̂ = G c [rad, body]: the body increment of one sample from the corrected
    increments c (n,) through the pseudo-inverse G (3, n), summed gyro by gyro in order."""
    n = c.shape[0]
    for r in range(3):
        th[r] = G[r, 0] * c[0]
        for i in range(1, n):
            th[r] += G[r, i] * c[i]


@inline_kernel
def rotate_columns(R, P, m):
    """P[:, :m] ← Rᵀ P[:, :m] (R (3, 3), P (3, ≥ m)), column by column with the entries of R held
    in registers: the loop over the columns compiles to vector instructions (the same products
    and sums, in the same order, as one column at a time)."""
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    for c in range(m):
        x0, x1, x2 = P[0, c], P[1, c], P[2, c]
        P[0, c] = r00 * x0 + r10 * x1 + r20 * x2
        P[1, c] = r01 * x0 + r11 * x1 + r21 * x2
        P[2, c] = r02 * x0 + r12 * x1 + r22 * x2


@inline_kernel
def active_gyros(excluded, status_k, active):
    """active (n,) ← the gyros neither excluded (n,) bool nor flagged invalid in the status bits
    status_k of one sample. Returns (their number, their bit pattern)."""
    n_act = 0
    bits = 0
    for i in range(excluded.shape[0]):
        active[i] = (not excluded[i]) and ((status_k >> i) & 1) == 0
        if active[i]:
            n_act += 1
            bits |= 1 << i
    return n_act, bits


@inline_kernel
def propagate_sample(dth_k, h, var_k, parity, q, A, W, U_ax, V_ax, Mi, G, N, Phi_aa, Phi_ap,
                     Q_aa, par_y, par_t, acc_i, acc_f, th_acc, arw_var, wk):
    """One gyro sample (dth_k (n,) [rad] over h [s], extra variance var_k [rad²]) over the active
    gyros wk.active, whose corrected increments wk.c, wk.sg, wk.s the caller has computed
    (:func:`radical_rt.kernels.model.correct_increment_lin`) and whose pseudo-inverse is G (3, n)
    and (AAᵀ)⁻¹ Mi (3, 3): θ̂ = G c (left in wk.th; the caller takes the body rate θ̂/h of the last
    sample of a run from it), the attitude q, the window accumulators (module docstring), and when
    ``parity`` (all gyros, not bridged) the parity statistics. wk: a :class:`SampleWork`."""
    c, sg, s, gh, th, F, work4, dq, active, R, T = wk[:11]
    n = dth_k.shape[0]
    body_increment(G, c, th)
    for i in range(n):
        gh[i] = (A[0, i] * th[0] + A[1, i] * th[1] + A[2, i] * th[2]) if active[i] else 0.0
    rotvec_to_quat_into(th, dq)  # the quaternion of R(θ̂), used twice below
    quat_to_dcm_into(dq, R)
    # Phi_aa ← Rᵀ Phi_aa; Phi_ap ← Rᵀ Phi_ap + F; Q_aa ← Rᵀ Q_aa R + arw·h·Minv + var_extra·I
    rotate_columns(R, Phi_aa, 3)
    rotate_columns(R, Phi_ap, 5 * n)  # the gyro columns (the φ2 and τ ones stay zero)
    for i in range(n):  # F = ∂θ̂/∂p̂ one gyro (five columns k·n + i) at a time
        jacobian_gyro(i, gh, sg, s, h, th, W, U_ax, V_ax, G, active, F)
        for k in range(5):
            j = k * n + i
            for r in range(3):
                Phi_ap[r, j] += F[r, k]
    for j in range(3):
        x0, x1, x2 = Q_aa[0, j], Q_aa[1, j], Q_aa[2, j]
        for r in range(3):
            T[r, j] = R[0, r] * x0 + R[1, r] * x1 + R[2, r] * x2
    qn = arw_var * h
    for r in range(3):
        for j in range(3):
            Q_aa[r, j] = T[r, 0] * R[0, j] + T[r, 1] * R[1, j] + T[r, 2] * R[2, j] + qn * Mi[r, j]
        Q_aa[r, r] += var_k
    apply_body_quat(q, dq, work4)
    if parity and N.shape[1] > 0:
        for i in range(n):  # sufficient statistics of the parity sum (model.parity_from_stats)
            row = 0 if sg[i] > 0.0 else 1
            par_y[row, i] += dth_k[i]
            par_t[row, i] += h
        if acc_i[3] == 0:
            acc_i[2] += 1  # a new contiguous run: one more quantization endpoint pair
        acc_i[1] += 1
        acc_i[3] = 1
        acc_f[1] += arw_var * h
        acc_f[2] += h
    else:
        acc_i[3] = 0
    for r in range(3):
        th_acc[r] += th[r]
    acc_i[0] += 1
    acc_f[0] += h


@kernel
def predict_attitude(dtheta, dt, status, a, b, excluded, xp, A, Gp, q, omega, work):
    """Propagate the attitude only (no covariance, no accumulators) through samples a..b−1 not
    yet given to the filter: the low-latency "now" attitude of sample-triggered telemetry.

    dtheta (m, n) [rad], dt (m,) [s], status (m,) gyro-invalid bits, excluded (n,) bool; xp, A, Gp
    the engine's current calibration (internal parameters, scaled axes, pseudo-inverse). q (4,)
    q_body_from_inertial, propagated in place; omega (3,) receives the last body rate [rad/s].
    work: a :class:`SampleWork` (scratch; the engine's own after its propagation). Samples with
    fewer than three usable gyros are skipped. Returns the number of samples used.
    """
    wk = work_views(work)
    used = 0
    for k in range(a, b):
        if _predict_sample(dtheta[k], dt[k], status[k], excluded, xp, A, Gp, q, omega, wk):
            used += 1
    return used


@inline_kernel
def _predict_sample(dth_k, h, status_k, excluded, xp, A, Gp, q, omega, wk):
    """One sample of :func:`predict_attitude` (dth_k (n,) [rad] over h [s], its gyro-invalid
    bits status_k; wk: :class:`SampleWork` views). False: fewer than three usable gyros."""
    n = dth_k.shape[0]
    active, c, th = wk.active, wk.c, wk.th
    n_act, _bits = active_gyros(excluded, status_k, active)
    G = Gp
    if n_act < n:
        if masked_pinv(A, active, wk.Mm, wk.Gm) < 0:
            return False
        G = wk.Gm
    correct_increment_lin(dth_k, h, xp, active, c, wk.sg, wk.s)
    body_increment(G, c, th)
    if h > 0.0:
        for r in range(3):
            omega[r] = th[r] / h
    apply_body_rotation(q, th, wk.work4, wk.dq)
    return True


@kernel
def predict_now(dtheta, dt, status, a, b, pend_dth, pend_status, pend_dt, use_pend, excluded, xp,
                A, Gp, q, omega, work):
    """:func:`predict_attitude` through samples a..b−1 of the pending arrays (dtheta (m, n), dt,
    status), then, if use_pend, through one more read (pend_dth (n,), pend_status, interval
    pend_dt [s]): the attitude of sample-triggered telemetry in one call. q, omega in place;
    work: a :class:`SampleWork` (scratch)."""
    if b > a:
        predict_attitude(dtheta, dt, status, a, b, excluded, xp, A, Gp, q, omega, work)
    if use_pend:
        _predict_sample(pend_dth, pend_dt, pend_status, excluded, xp, A, Gp, q, omega,
                        work_views(work))
