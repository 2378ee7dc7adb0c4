"""Gated vector measurement update on UD factors (one Numba call per tracker or parity update).

For m measurement rows with diagonal noise: the innovation covariance S = H P Hᵀ + R is formed from
the UD factors (F = H U, S = F D Fᵀ + R; P itself is never formed), the normalized innovation
squared NIS = νᵀS⁻¹ν is tested against the gate, and if accepted the rows are applied as m
sequential scalar Bierman updates, each with the innovation recomputed from the updated correction
dx (error-state form, notes §11.3).
"""

from __future__ import annotations

import numpy as np

from ._jit import kernel
from .ud import bierman_update

UPDATE_ACCEPTED = 0
UPDATE_EDITED = 1


@kernel
def gated_update(U, d, dx, H, z, rdiag, gate, edit_enabled, F, S, innov, sig, f, v, k):
    """Apply rows H (m, n) with measurements z (m,) and noise variances rdiag (m,) to (U, d, dx).

    Writes innov (m,) = z − H dx (before the update) and sig (m,) = sqrt(diag S).
    Returns (kernel status, NIS, UPDATE_ACCEPTED or UPDATE_EDITED).
    """
    m, n = H.shape
    for a in range(m):
        s = 0.0
        for j in range(n):
            s += H[a, j] * dx[j]
        innov[a] = z[a] - s
        for j in range(n):  # F[a] = Uᵀ h_a  (U unit upper triangular)
            acc = H[a, j]
            for i in range(j):
                acc += U[i, j] * H[a, i]
            F[a, j] = acc
    for a in range(m):
        for b in range(m):
            acc = rdiag[a] if a == b else 0.0
            for j in range(n):
                acc += F[a, j] * d[j] * F[b, j]
            S[a, b] = acc
        sig[a] = np.sqrt(S[a, a]) if S[a, a] > 0 else 0.0
    nis = innov @ np.linalg.solve(S, innov)
    if edit_enabled and not (nis <= gate):
        return 0, nis, UPDATE_EDITED
    for a in range(m):
        s = 0.0
        for j in range(n):
            s += H[a, j] * dx[j]
        res = z[a] - s
        status, _alpha = bierman_update(U, d, H[a], rdiag[a], k, f, v)
        if status != 0:
            return status, nis, UPDATE_ACCEPTED
        for j in range(n):
            dx[j] += k[j] * res
    return 0, nis, UPDATE_ACCEPTED
