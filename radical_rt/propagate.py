"""Per-sample gyro propagation and window accumulation (the 100 Hz hot loop, one Numba call).

Between two window closes (≤ ``window`` samples, or a tracker epoch) the engine accumulates, for the
structured UD time update (notes §7, §11.5), the attitude transition ``Phi_aa`` (3, 3), the
attitude-parameter coupling ``Phi_ap`` (3, 5n+3; the φ2 columns stay zero), the attitude process
noise ``Q_aa`` (3, 3), and the parity window sum ``z_par`` (n−3,) with its rows ``H_par``
(n−3, 5n+3). ``acc_i`` (int64[2]) holds (samples in window, parity samples in window) and ``acc_f``
(float64[2]) holds (window duration [s], variance of the parity noise [rad²] accumulated).
"""

from __future__ import annotations

import numpy as np

from ._jit import kernel
from .model import (
    apply_body_rotation,
    correct_increment,
    increment_jacobian,
    masked_pinv,
    parity_rows,
)
from .rotation import rotvec_to_dcm

#: propagate_window return flags (bit set in the second return value)
PROP_MASKED = 1  # some samples used fewer than all gyros
PROP_UNDETERMINED = 2  # some samples had fewer than 3 usable gyros (not propagated)


@kernel
def propagate_window(dtheta, dt, status, bridged, var_extra, i0, excluded, xp, q, Wt, dWdu, dWdv,
                     Minv, Gp, N, Phi_aa, Phi_ap, Q_aa, z_par, H_par, acc_i, acc_f, window,
                     arw_var, omega):
    """Propagate samples i0.. of a gyro batch until the window holds ``window`` samples.

    dtheta (m, n) [rad], dt (m,) [s], status (m,) int bits (gyro invalid), bridged (m,) bool,
    var_extra (m,) [rad²]; excluded (n,) bool (commanded exclusions); xp parameters; q (4,)
    q_body_from_inertial, propagated in place; omega (3,) [rad/s] receives the last body rate.
    Returns (index of the next unprocessed sample, flags PROP_*).
    """
    m, n = dtheta.shape
    c = np.empty(n)
    sg = np.empty(n)
    s = np.empty(n)
    th = np.empty(3)
    gh = np.empty(n)
    F = np.empty((3, 5 * n))
    work4 = np.empty(4)
    dq = np.empty(4)
    Gm = np.empty((3, n))
    Mm = np.empty((3, 3))
    active = np.empty(n, dtype=np.bool_)
    flags = 0
    k = i0
    while k < m and acc_i[0] < window:
        n_act = 0
        for i in range(n):
            active[i] = (not excluded[i]) and ((status[k] >> i) & 1) == 0
            n_act += 1 if active[i] else 0
        G, Mi = Gp, Minv
        if n_act < n:
            flags |= PROP_MASKED
            if masked_pinv(Wt, active, Mm, Gm) < 0:
                flags |= PROP_UNDETERMINED
                k += 1
                continue
            G, Mi = Gm, Mm
        h = dt[k]
        correct_increment(dtheta[k], h, xp, active, c, sg, s)
        for r in range(3):
            th[r] = G[r, 0] * c[0]
            for i in range(1, n):
                th[r] += G[r, i] * c[i]
        for i in range(n):
            gh[i] = (Wt[0, i] * th[0] + Wt[1, i] * th[1] + Wt[2, i] * th[2]) if active[i] else 0.0
        increment_jacobian(gh, sg, s, h, th, Wt, dWdu, dWdv, Mi, G, active, F)
        Rt = rotvec_to_dcm(th).T
        Phi_aa[:, :] = Rt @ Phi_aa
        Phi_ap[:, :5 * n] = Rt @ Phi_ap[:, :5 * n] + F
        Q_aa[:, :] = Rt @ Q_aa @ Rt.T + (arw_var * h) * Mi
        for r in range(3):
            Q_aa[r, r] += var_extra[k]
            omega[r] = th[r] / h
        apply_body_rotation(q, th, work4, dq)
        if n_act == n and not bridged[k] and N.shape[1] > 0:
            parity_rows(c, gh, sg, s, h, th, N, dWdu, dWdv, z_par, H_par)
            acc_i[1] += 1
            acc_f[1] += arw_var * h
        acc_i[0] += 1
        acc_f[0] += h
        k += 1
    return k, flags
