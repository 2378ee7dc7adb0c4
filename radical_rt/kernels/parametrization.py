"""Exact conversions between the engine's internal linear gyro parameters and the contract's.

The engine estimates, per gyro, the scaled axis a_i = (1 + λ'_i) w_i − du'_i v_i − dv'_i u_i and
μ' = μ/(1 + λ) (internal form, :mod:`radical_rt.kernels.model`, docs/engine.md §2); the contract
(CONTRACT §1.5) uses (λ, μ, du, dv). Parameter vectors ``xp`` (5n+3,) in state order: b (rad/s),
the four scale/misalignment groups (dimensionless, per gyro), φ2 (rad, body axes). This module
owns the maps both ways, the Jacobian ∂contract/∂internal and the contract-parameter 1σ taken
straight from the UD factors.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import kernel
from radical_rt.kernels.ud import variances


def contract_from_internal(xp, n):
    """Contract parameters (CONTRACT §1.5, SI) and the Jacobian ∂contract/∂internal.

    xp (5n+3,) internal (b, λ', μ', du', dv', φ2). Per gyro, with a = (1+λ')w − du'v − dv'u:
    1 + λ = |a| = √((1+λ')² + du'² + dv'²), du = du'/(1+λ'), dv = dv'/(1+λ'), μ = μ'(1+λ).
    Returns (xp_contract (5n+3,), J (5n+3, 5n+3)).
    """
    xp = np.ascontiguousarray(xp, dtype=float)
    J = np.eye(xp.size)
    return contract_values(xp, n, J), J


def contract_values(xp, n, J_work):
    """The contract parameters (5n+3,) of :func:`contract_from_internal`: xp (5n+3,) float64
    internal; the per-gyro entries of the Jacobian are written into J_work (5n+3, 5n+3) (the
    identity elsewhere is left as it is; nothing in J_work is read)."""
    out = xp.copy()
    _contract_from_internal(xp, int(n), out, J_work)
    return out


@kernel
def output_numbers(xp, n, U, d, J, est, sig, var):
    """The numbers of the telemetry fields est, sigma, att_sigma and latency in one call: est
    (npar,) ← :func:`contract_values`, sig (npar,) ← :func:`contract_sigma_ud`, var (ns,) ←
    the diagonal of P (:func:`radical_rt.kernels.ud.variances`); xp (npar,) internal, n gyros,
    U (ns, ns), d (ns,), J (npar, npar) work. The same operations, in the same order, as the
    three calls."""
    for i in range(xp.shape[0]):
        est[i] = xp[i]
    _contract_from_internal(xp, n, est, J)
    contract_sigma_ud(xp, n, U, d, J, sig)
    variances(U, d, var)


@kernel
def contract_sigma_ud(xp, n, U, d, J, sig):
    """1σ (npar,) of the contract parameters into sig, straight from the UD factors: σ_i² =
    Σ_l d_l (J U_pp)²_il over the parameter block (U (ns, ns) unit upper, d (ns,), parameters
    from state 3), with J = ∂contract/∂internal of :func:`contract_from_internal` (written into
    the work matrix J (npar, npar)); J has at most four entries per row, so the product is taken
    over a row's nonzero entries only (P and J P Jᵀ are never formed)."""
    npar = xp.shape[0]
    for r in range(npar):
        for c in range(npar):
            J[r, c] = 1.0 if r == c else 0.0
    _contract_from_internal(xp, n, np.empty(npar), J)
    cols = np.empty(npar, np.int64)
    vals = np.empty(npar)
    for i in range(npar):
        m = 0
        for k in range(npar):
            if J[i, k] != 0.0:
                cols[m], vals[m] = k, J[i, k]
                m += 1
        if m == 0:
            sig[i] = 0.0
            continue
        acc = 0.0
        lo = cols[0]  # U is upper triangular: row k of U_pp is zero left of column k
        for col in range(lo, npar):
            f = 0.0
            for a in range(m):
                f += vals[a] * U[3 + cols[a], 3 + col]
            acc += d[3 + col] * f * f
        sig[i] = np.sqrt(max(acc, 0.0))


@kernel
def _contract_from_internal(xp, n, out, J):
    """The per-gyro part of :func:`contract_from_internal` into out (copy of xp) and J (= I)."""
    for i in range(n):
        il, im, iu, iv = n + i, 2 * n + i, 3 * n + i, 4 * n + i
        sl, mu, du, dv = 1.0 + xp[il], xp[im], xp[iu], xp[iv]
        na = math.sqrt(sl * sl + du * du + dv * dv)
        out[il] = na - 1.0
        out[im] = mu * na
        out[iu] = du / sl
        out[iv] = dv / sl
        J[il, il], J[il, iu], J[il, iv] = sl / na, du / na, dv / na
        J[im, im] = na
        J[im, il], J[im, iu], J[im, iv] = mu * sl / na, mu * du / na, mu * dv / na
        J[iu, iu], J[iu, il] = 1.0 / sl, -du / (sl * sl)
        J[iv, iv], J[iv, il] = 1.0 / sl, -dv / (sl * sl)


def internal_from_contract(xp_c, n):
    """Inverse of :func:`contract_from_internal` (exact): contract (b, λ, μ, du, dv, φ2) → internal."""
    xp_c = np.asarray(xp_c, dtype=float)
    out = xp_c.copy()
    for i in range(n):
        il, im, iu, iv = n + i, 2 * n + i, 3 * n + i, 4 * n + i
        lam, mu, du, dv = xp_c[il], xp_c[im], xp_c[iu], xp_c[iv]
        sl = (1.0 + lam) / math.sqrt(1.0 + du * du + dv * dv)
        out[il] = sl - 1.0
        out[im] = mu / (1.0 + lam)
        out[iu] = du * sl
        out[iv] = dv * sl
    return out
