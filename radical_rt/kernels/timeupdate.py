"""Close of a time-update window on the UD factors, in one Numba call (10 Hz hot path).

A window of ``prop_window`` gyro samples (or a shorter one ending at a tracker epoch) leaves its
accumulated transition Φ = [[Φ_aa, Φ_ap], [0, I]], attitude noise Q_aa, and summed body increment
Θ̂ in the engine's accumulators (:func:`radical_rt.kernels.propagate.propagate_window`). Closing it:

1. regressor reliability κ of Θ̂ (errors-in-variables control, docs/engine.md): the λ, μ, du, dv
   columns of Φ_ap are scaled by κ;
2. structured UD time update P ← ΦPΦᵀ + diag(Q_aa, 0) (:func:`radical_rt.kernels.ud_time.structured_time_update`);
3. parameter random-walk noise: diag(q) Δt is accumulated, and P_pp += the accumulated noise
   (:func:`radical_rt.kernels.ud_time.add_diagonal_noise`, 24 rank-one updates, the most expensive step of a
   close) once NOISE_PERIOD_S of windows have passed;
4. the accumulators are reset (Φ_aa = I, Φ_ap = 0, Q_aa = 0, Θ̂ = 0, count and Δt = 0).

Why the noise can wait a second: the parameters are random walks with Φ_pp = I, so
P_pp(t + T) = P_pp(t) + q T exactly, whenever within T it is added; what the wait changes is the
attitude-parameter coupling Φ_ap q τ Φ_apᵀ of the noise not yet added (τ < 1 s), a relative
change of order q T / P_pp (1e-6 for the 2006216 tables) of the covariance, against the ≈ 3 µs
per 0.1 s the rank-one updates cost (perf/README.md). The dense reference of perf/ does the same.

The formula of κ is the one of :meth:`radical_rt.engine.filter.Engine._regressor_reliability`; the dense
reference (tests/oracles/dense_engine.py) computes it from P independently.
"""

from __future__ import annotations

import numpy as np

from radical_rt._jit import kernel
from radical_rt.kernels.ud_time import add_diagonal_noise, structured_time_update

NOISE_PERIOD_S = 1.0  # the accumulated parameter process noise is added once this much has passed
ACC_NOISE_T = 3  # acc_f[ACC_NOISE_T]: time since the noise was last added [s]


@kernel
def regressor_reliability(U, d, g0, theta, Phi_g, Minv, noise_var, k_sigma):
    """κ = max(0, 1 − K² s_∥/|Θ̂|²) ∈ [0, 1] of the summed increment theta (3,) [rad, body].

    s_∥ = (vᵀ P_gg v + noise_var·Θ̂ᵀ Minv Θ̂)/|Θ̂|² with v = Φ_gᵀΘ̂ (5n,), Phi_g (3, 5n) = ∂Θ̂/∂p̂,
    P_gg the covariance block of the 5n gyro parameters starting at state g0, from the UD factors
    (U (ns, ns) unit upper, d (ns,)) without forming P: vᵀP_gg v = Σ_j d_j (Σ_i v_i U[g0+i, j])².
    Minv (3, 3) = (ÂÂᵀ)⁻¹, noise_var [rad²/s·s], k_sigma = K. Returns 0 for Θ̂ = 0.
    """
    th2 = theta[0] * theta[0] + theta[1] * theta[1] + theta[2] * theta[2]
    if th2 <= 0.0:
        return 0.0
    ng = Phi_g.shape[1]
    ns = d.shape[0]
    v = np.empty(ng)
    for c in range(ng):
        v[c] = Phi_g[0, c] * theta[0] + Phi_g[1, c] * theta[1] + Phi_g[2, c] * theta[2]
    quad = 0.0
    for j in range(g0, ns):
        f = 0.0
        for i in range(min(ng, j - g0 + 1)):
            f += v[i] * U[g0 + i, j]
        quad += d[j] * f * f
    m = 0.0
    for r in range(3):
        m += theta[r] * (Minv[r, 0] * theta[0] + Minv[r, 1] * theta[1] + Minv[r, 2] * theta[2])
    s_par = (quad + noise_var * m) / th2
    return max(0.0, 1.0 - k_sigma * k_sigma * s_par / th2)


@kernel
def close_time_window(U, d, Phi_aa, Phi_ap, Q_aa, th_acc, acc_i, acc_f, Minv, n_gyro, noise_var,
                      k_sigma, q_params, param_idx, q_acc, struct_work, a_work):
    """Close the time-update window (steps 1–4 of the module docstring) on (U, d) in place.

    Phi_aa (3, 3), Phi_ap (3, ns−3), Q_aa (3, 3), th_acc (3,), acc_i[0] (sample count) and
    acc_f[0] (window length [s]) are the accumulators; Minv (3, 3); noise_var: the increment noise
    of Θ̂ [rad² per unit of Minv]; q_params (ns−3,) [unit²/s], param_idx (ns−3,) the parameter
    states; q_acc (ns−3,) [unit²] and acc_f[ACC_NOISE_T] [s]: the parameter noise accumulated
    since it was last added and its time (step 3); struct_work (3, ≥ ns+3), a_work (ns,) work.
    The window accumulators are reset whatever the status. Returns (UD kernel status, κ).
    """
    n = n_gyro
    kappa = regressor_reliability(U, d, 3, th_acc, Phi_ap[:, :5 * n], Minv, noise_var, k_sigma)
    if kappa < 1.0:
        for r in range(3):
            for c in range(n, 5 * n):  # λ, μ, du, dv columns
                Phi_ap[r, c] *= kappa
    status = structured_time_update(U, d, 3, Phi_aa, Phi_ap, Q_aa, struct_work)
    if status == 0:
        for k in range(q_params.shape[0]):
            q_acc[k] += q_params[k] * acc_f[0]
        acc_f[ACC_NOISE_T] += acc_f[0]
        if acc_f[ACC_NOISE_T] >= NOISE_PERIOD_S:
            status = add_diagonal_noise(U, d, param_idx, q_acc, a_work)
            q_acc[:] = 0.0
            acc_f[ACC_NOISE_T] = 0.0
    for r in range(3):
        th_acc[r] = 0.0
        for c in range(3):
            Phi_aa[r, c] = 1.0 if r == c else 0.0
            Q_aa[r, c] = 0.0
    Phi_ap[:, :] = 0.0
    acc_i[0] = 0
    acc_f[0] = 0.0
    return status, kappa
