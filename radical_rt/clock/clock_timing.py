"""Numba kernels of the SIRU clock's timing: the coarse polygon and the choice of the line in use.

The feasible lines ``t_k = a + b k`` form a convex polygon (:mod:`radical_rt.clock.clock_poly`) in
``(x, y)``: ``x`` [s] is the offset from the nominal line ``tau_anchor + T (k - k_anchor)`` at the
reference sample ``k_ref``, ``y`` [s per N_s samples] the slope deviation. Each read of sample k
at bus time tau adds ``t_k <= tau + delta`` and ``t_{k+1} >= tau - delta``, with a margin delta
wide enough for the read jitter (reads are tagged with their bus cycle, not their instant). The
polygon is the coarse estimate: it gives the line before the first sawtooth crossing and the prior
slope at it. From the first crossing on, the fine line of :mod:`radical_rt.clock.clock_line` (a Kalman
filter on the crossings) is the line in use. See docs/clock.md. State layout:
:mod:`radical_rt.clock.clock_layout`.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import kernel
from radical_rt.clock import clock_layout as L
from radical_rt.clock.clock_line import (
    CROSSING,
    base_time,
    line_crossing,
    line_lose_phase,
    line_select,
    line_shear,
    line_var,
    period,
    raise_anomaly,
    spate_read,
)
from radical_rt.clock.clock_poly import (
    poly_box,
    poly_centroid,
    poly_clip2,
    poly_extent,
    poly_inflate,
)

# timing modes of the read being accepted
NO_TIMING = 0
TIMING = 1
REACQUIRE = 2
#: the polygon's reference sample is moved at least every REREF samples
REREF = 1000


@kernel
def line_time(I, F, k):
    """Reconstructed true time of sample k on the bus time line (the line in use) [s]."""
    d = k - I[L.I_K_REF]
    return base_time(I, F, I[L.I_K_REF]) + F[L.F_CX] + (F[L.F_CY] / F[L.P_NS] + F[L.P_T]) * d


@kernel
def tag_sigma(I, F):
    """1-sigma reconstructed-time uncertainty of the last accepted sample [s]: the fine line's once
    it has a phase; before, uniform over the polygon's core (its extent at that sample less the two
    jitter margins) plus a jitter floor; T/sqrt(12) before acquisition."""
    if I[L.I_ACQ] == 0:
        return F[L.P_T] / math.sqrt(12.0)
    if I[L.I_KAL]:
        return math.sqrt(line_var(I, F, I[L.I_K_A], F[L.F_TAU_NOW]))
    g = (I[L.I_K_A] - I[L.I_K_REF]) / F[L.P_NS]
    lo = np.inf
    hi = -np.inf
    for i in range(I[L.I_NV]):
        v = F[L.OX + i] + g * F[L.OY + i]
        lo = min(lo, v)
        hi = max(hi, v)
    core = max(hi - lo - 2.0 * F[L.F_DELTA], 0.0)
    return math.sqrt(core * core / 12.0 + (0.25 * F[L.F_DELTA]) ** 2)


@kernel
def _centroid(I, F):
    cx, cy = poly_centroid(F, L.OX, L.OY, I[L.I_NV])
    F[L.F_PCX] = cx
    F[L.F_PCY] = cy
    lo, hi = poly_extent(F, L.OY, I[L.I_NV])
    F[L.F_Y_LO] = lo
    F[L.F_Y_HI] = hi
    line_select(I, F)


@kernel
def _acquire(I, F, tau, k):
    """Start (or restart) the phase: sample k was read at tau; the slope range (and the fine
    line's frequency) is kept."""
    line_lose_phase(I, F, 0.0)
    t = F[L.P_T]
    F[L.F_DELTA] = F[L.P_DELTA]  # a margin widened for the old phase starts afresh
    d = F[L.F_DELTA]
    I[L.I_K_ANCHOR] = k
    I[L.I_K_REF] = k
    F[L.F_TAU_ANCHOR] = tau - 0.5 * t
    I[L.I_NV] = poly_box(F, L.OX, L.OY, -t - d, t + d, F[L.F_Y_LO], F[L.F_Y_HI])
    I[L.I_ACQ] = 1
    I[L.I_CONSEC_REJ] = 0
    F[L.F_LAST_INFL] = tau
    _centroid(I, F)


@kernel
def _inflate(I, F, tau):
    dtau = tau - F[L.F_LAST_INFL]
    qx = F[L.P_PHASE_WANDER] * dtau
    qy = F[L.P_FREQ_WANDER] * dtau * F[L.P_T] * F[L.P_NS]
    I[L.I_NV] = poly_inflate(F, L.OX, L.OY, I[L.I_NV], qx, qy, L.WX, L.WY)
    F[L.F_LAST_INFL] = tau
    _centroid(I, F)


@kernel
def _recentre(I, F, k):
    """Move the polygon's reference sample to k (a shear; the centroid moves with it)."""
    d = k - I[L.I_K_REF]
    if d == 0:
        return
    dx = (base_time(I, F, I[L.I_K_REF]) - base_time(I, F, k)) + F[L.P_T] * d
    g = d / F[L.P_NS]
    for i in range(I[L.I_NV]):
        F[L.OX + i] += dx + g * F[L.OY + i]
    F[L.F_PCX] += dx + g * F[L.F_PCY]
    line_shear(I, F, dx, g)
    I[L.I_K_REF] = k
    line_select(I, F)


@kernel
def _constrain(I, F, tau, k):
    """Sample k was taken at or before tau, sample k + 1 after it (each within the jitter margin).
    Returns the violation [s] of a constraint that would empty the polygon (0 if none); such a
    constraint is not applied."""
    _recentre(I, F, k)
    d = F[L.F_DELTA]
    r0 = tau - base_time(I, F, k)
    nv, c1, v1, c2, v2 = poly_clip2(F, L.OX, L.OY, I[L.I_NV], r0 + d, 1.0 / F[L.P_NS],
                                    F[L.P_T] - r0 + d, L.WX, L.WY)
    I[L.I_NV] = nv
    if c1 == 1 or c2 == 1:
        _centroid(I, F)
    return max(v1, v2)


@kernel
def time_read(I, F, tau, k, mode):
    """Fold one read (sample k at bus time tau) into the timing polygon and the spate tracker of
    the fine line. The common case (both constraints redundant, no spate) is one scan of the
    vertices; the reference sample moves only when the polygon is cut or every REREF samples."""
    if mode == REACQUIRE or I[L.I_ACQ] == 0:
        _acquire(I, F, tau, k)
    if k - I[L.I_K_REF] > REREF or k < I[L.I_K_REF]:
        _recentre(I, F, k)
    if tau - F[L.F_LAST_INFL] >= F[L.P_INFL_DT]:
        _inflate(I, F, tau)
    elif tau < F[L.F_LAST_INFL]:
        F[L.F_LAST_INFL] = tau
    r0 = tau - base_time(I, F, k)
    g = (k - I[L.I_K_REF]) / F[L.P_NS]
    g1 = g + 1.0 / F[L.P_NS]
    m1 = -np.inf
    m2 = -np.inf
    for i in range(I[L.I_NV]):
        x = F[L.OX + i]
        y = F[L.OY + i]
        m1 = max(m1, x + g * y)
        m2 = max(m2, -x - g1 * y)
    cut = m1 > r0 + F[L.F_DELTA] or m2 > F[L.P_T] - r0 + F[L.F_DELTA]
    viol = _constrain(I, F, tau, k) if cut else 0.0
    if viol > 0.0 and viol <= F[L.P_DELTA_MAX] and F[L.F_DELTA] < F[L.P_DELTA_MAX]:
        # a read just outside the margin: the jitter is larger than assumed. Widen the margin
        # and loosen the polygon by as much (as if the wider margin had been used all along).
        grow = min(2.0 * viol, F[L.P_DELTA_MAX] - F[L.F_DELTA])
        F[L.F_DELTA] += grow
        I[L.C_MARGIN_GROWS] += 1
        I[L.I_NV] = poly_inflate(F, L.OX, L.OY, I[L.I_NV], grow, 0.0, L.WX, L.WY)
        _centroid(I, F)
        viol = _constrain(I, F, tau, k)
    if viol > 0.0:
        I[L.C_TIMING_OUTLIERS] += 1
        I[L.I_CONSEC_REJ] += 1
        F[L.F_MAX_VIOL] = max(F[L.F_MAX_VIOL], viol)
        if viol > F[L.P_GROSS]:
            raise_anomaly(I, F, tau)
        if I[L.I_CONSEC_REJ] >= F[L.P_RELOCK]:
            I[L.C_RELOCKS] += 1
            raise_anomaly(I, F, tau)
            _acquire(I, F, tau, k)
            _constrain(I, F, tau, k)
    else:
        I[L.I_CONSEC_REJ] = 0
    code, k_star, t_star, var_z = spate_read(I, F, tau, k)
    if code == CROSSING:
        line_crossing(I, F, k_star, t_star, var_z)
    F[L.F_E_LAST] = tau - line_time(I, F, k)


@kernel
def pending_read(I, F):
    """(has, status, period): whether the read held back for look-ahead is probably the next
    sample (SiruClock.pending), its status bits, and the estimated sample period [s]."""
    has = I[L.I_HAVE_P] != 0 and not (I[L.I_HAVE_A] != 0 and I[L.I_TT_P] == I[L.I_TT_A])
    return has, I[L.I_ST_P], period(F)
