"""Numba kernels of the SIRU clock's fine time line: sawtooth crossings and a Kalman line filter.

The bus reads the SIRU at its 100 Hz ticks ``j``; read j returns the latest sample ``k_j``. The
level ``d_j = k_j − j`` is constant while the tag error (the sawtooth) stays inside one period and
steps by ±1 where it wraps. Near a wrap the read jitter (of the read instant against its tag, or of
the tags themselves) makes the level flicker between its two values: a spate of repeats and misses.
With ``p_j`` the probability that read j still sees the old level, the crossing of the boundary
lies at ``j_c = j_0 − 1/2 + Σ_j p_j`` for any jitter distribution that is symmetric about its mean
(notes: the integral of a symmetric CDF's complement about its centre). The sum is estimated by
counting the reads of the spate on the old level: one O(1) step per read, exact without any
model of the jitter, and a constant mean of the jitter (a read offset before the tag) moves every
crossing alike, so it shifts the whole line and goes to the tracker-latency state.

Each crossing says: the sample-time line passes through ``(k*, t*) = (j_c + n_c, grid(j_c))``.
These points feed a two-state Kalman filter (offset and slope of the line, random-walk drift),
which gives the fine line and its honest 1σ. Before the first crossing the coarse polygon of
:mod:`radical_rt.clock.clock_timing` provides the line. Coordinates are the polygon's: ``x`` [s] is the
offset from the nominal line at the reference sample ``k_ref``, ``y`` [s per N_s samples] the
slope deviation. State layout: :mod:`radical_rt.clock.clock_layout`; method: docs/clock.md.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import kernel
from radical_rt.clock import clock_layout as L

#: spate status codes returned by :func:`spate_read`
NOTHING = 0
CROSSING = 1
#: tick holes longer than this inside a spate abandon it (shorter ones repeat the last level)
MAX_HOLE = 3


@kernel
def base_time(I, F, k):
    """Nominal line at sample k [s] (the polygon's and the fine line's x is relative to it)."""
    return F[L.F_TAU_ANCHOR] + F[L.P_T] * (k - I[L.I_K_ANCHOR])


@kernel
def period(F):
    """Estimated true sample period [s] (slope of the line in use)."""
    return F[L.P_T] + F[L.F_CY] / F[L.P_NS]


@kernel
def raise_anomaly(I, F, tau):
    """Count an anomaly event and hold CLOCK_ANOMALY for the configured time after bus time tau."""
    I[L.C_ANOMALIES] += 1
    F[L.F_ANOM_UNTIL] = max(F[L.F_ANOM_UNTIL], tau + F[L.P_HOLD])


@kernel
def line_select(I, F):
    """The line in use (F_CX, F_CY): the fine line once it has a phase, else the centroid."""
    if I[L.I_KAL]:
        F[L.F_CX] = F[L.F_KX]
        F[L.F_CY] = F[L.F_KY]
    else:
        F[L.F_CX] = F[L.F_PCX]
        F[L.F_CY] = F[L.F_PCY]


@kernel
def line_shear(I, F, dx, g):
    """The reference sample moved by g·N_s samples (x' = x + dx + g y): the fine line and its
    covariance follow (C' = G C Gᵀ, G = [[1, g], [0, 1]])."""
    if I[L.I_KAL] == 0:
        return
    F[L.F_KX] += dx + g * F[L.F_KY]
    cxy, cyy = F[L.F_KCXY], F[L.F_KCYY]
    F[L.F_KCXX] += 2.0 * g * cxy + g * g * cyy
    F[L.F_KCXY] = cxy + g * cyy


@kernel
def line_var(I, F, k, tau):
    """Variance [s²] of the fine line at sample k, with the drift up to bus time tau."""
    g = (k - I[L.I_K_REF]) / F[L.P_NS]
    dt = max(tau - F[L.F_KTAU], 0.0)
    cxx = F[L.F_KCXX] + F[L.P_LINE_QX] * dt
    cyy = F[L.F_KCYY] + F[L.P_LINE_QY] * dt
    return cxx + 2.0 * g * F[L.F_KCXY] + g * g * cyy + F[L.P_LINE_FLOOR] ** 2


@kernel
def _predict(F, tau):
    dt = tau - F[L.F_KTAU]
    if dt > 0.0:
        F[L.F_KCXX] += F[L.P_LINE_QX] * dt
        F[L.F_KCYY] += F[L.P_LINE_QY] * dt
        F[L.F_KTAU] = tau


@kernel
def _line_init(I, F, g, r_base, var_z, tau):
    """Phase from one crossing; the slope from the kept frequency, else from the polygon."""
    if I[L.I_KMEM] == 0:
        F[L.F_KY] = F[L.F_PCY]
        F[L.F_KCYY] = (F[L.F_Y_HI] - F[L.F_Y_LO]) ** 2 / 12.0
        I[L.I_KMEM] = 1
    cyy = F[L.F_KCYY]
    F[L.F_KX] = r_base - g * F[L.F_KY]
    F[L.F_KCXX] = var_z + g * g * cyy
    F[L.F_KCXY] = -g * cyy
    F[L.F_KTAU] = tau
    I[L.I_KAL] = 1
    I[L.I_NCROSS] = 1


@kernel
def line_crossing(I, F, k_star, t_star, var_z):
    """Fold a crossing: the line passes through (k_star, t_star [s]) with variance var_z [s²].
    The first crossing after a phase loss initialises the phase. A crossing beyond the gate is a
    loss of lock: the phase restarts from it (frequency kept, its variance quadrupled). Returns
    1 folded or initialised, 0 rejected (and re-initialised)."""
    tau = F[L.F_TAU_NOW]
    k_ref = I[L.I_K_REF]
    g = (k_star - k_ref) / F[L.P_NS]
    # t_star minus the nominal line at k_star: the x + g y the line must have
    r_base = t_star - base_time(I, F, k_ref) - F[L.P_T] * (k_star - k_ref)
    I[L.C_CROSSINGS] += 1
    if I[L.I_KAL] == 0:
        _line_init(I, F, g, r_base, var_z, tau)
        line_select(I, F)
        _note_lock(I, F, tau)
        return 1
    _predict(F, tau)
    cxx, cxy, cyy = F[L.F_KCXX], F[L.F_KCXY], F[L.F_KCYY]
    r = r_base - F[L.F_KX] - g * F[L.F_KY]
    hp_x = cxx + g * cxy
    hp_y = cxy + g * cyy
    s = hp_x + g * hp_y + var_z
    gate = F[L.P_LINE_GATE]
    if not r * r <= gate * gate * s:
        I[L.C_CROSS_REJECTED] += 1
        I[L.C_UNEXPLAINED] += 1
        I[L.C_RELOCKS] += 1
        raise_anomaly(I, F, tau)
        F[L.F_KCYY] *= 4.0
        _line_init(I, F, g, r_base, var_z, tau)
        line_select(I, F)
        return 0
    kx = hp_x / s
    ky = hp_y / s
    F[L.F_KX] += kx * r
    F[L.F_KY] += ky * r
    F[L.F_KCXX] = cxx - kx * hp_x
    F[L.F_KCXY] = cxy - kx * hp_y
    F[L.F_KCYY] = cyy - ky * hp_y
    I[L.I_NCROSS] += 1
    line_select(I, F)
    _note_lock(I, F, tau)
    return 1


@kernel
def _note_lock(I, F, tau):
    """Remember the bus time of the first lock that holds: σ of the line below the lock threshold
    with the slope from two crossings (right after the first one σ can dip below it briefly)."""
    if (F[L.F_T_LOCK] == -np.inf and I[L.I_NCROSS] >= 2
            and line_var(I, F, I[L.I_K_A], tau) < F[L.P_LOCK_SIGMA] ** 2):
        F[L.F_T_LOCK] = tau


@kernel
def line_lose_phase(I, F, widen_y):
    """Forget the fine line's phase (stream break, bus clock jump, re-acquisition); keep its
    frequency with widen_y [y units, 1σ] added in quadrature, and restart the tick grid."""
    if I[L.I_KAL]:
        I[L.I_KAL] = 0
        F[L.F_KCYY] += widen_y * widen_y
    I[L.I_GRID] = 0
    I[L.I_SP_ON] = 0
    line_select(I, F)


@kernel
def _spate_end(I, F):
    """A spate settled on a level: a crossing (returns its k*, t*, var_z) or a transient."""
    d_after = I[L.I_SP_RV]
    delta = I[L.I_SP_DB] - d_after
    I[L.I_SP_ON] = 0
    I[L.I_LEVEL] = d_after
    if delta == 0:  # the level came back: a late or early read (or a few), not a wrap
        I[L.C_READ_GLITCHES] += 1
        return NOTHING, 0.0, 0.0, 0.0
    n0 = I[L.I_SP_N0]
    j_c = I[L.I_SP_J0] - 0.5 + n0 + I[L.I_SP_A0] / delta
    rate = abs(F[L.P_BUS_T] - period(F))  # tag-error change per tick [s]
    var_j = n0 / 8.0 + 1.0 / 12.0  # counting variance (at most n0/4; spates are ~ Gaussian)
    sig_read = n0 * rate / 6.0  # the spate spans about ±3σ of the jitter
    F[L.F_SIG_READ] += (sig_read - F[L.F_SIG_READ]) * 0.25
    k_star = j_c + max(I[L.I_SP_DB], d_after)
    t_star = F[L.F_GRID0] + F[L.F_GRID_DEV] + j_c * F[L.P_BUS_T]
    return CROSSING, k_star, t_star, var_j * rate * rate


@kernel
def _spate_step(I, F, d):
    """One tick inside a spate at level d (ends it once a run of one level is long enough)."""
    if d != I[L.I_SP_RV]:
        I[L.I_SP_N0] = I[L.I_SP_N]
        I[L.I_SP_A0] = I[L.I_SP_A]
        I[L.I_SP_RV] = d
        I[L.I_SP_RL] = 0
    I[L.I_SP_N] += 1
    I[L.I_SP_A] += d - I[L.I_SP_DB]
    I[L.I_SP_RL] += 1
    if abs(d - I[L.I_SP_DB]) > 1 or I[L.I_SP_N] > F[L.P_SPATE_MAX]:
        I[L.C_UNEXPLAINED] += 1  # wider than one level, or never settles: not a wrap
        I[L.I_SP_ON] = 0
        I[L.I_LEVEL] = d
        return NOTHING, 0.0, 0.0, 0.0
    if I[L.I_SP_RL] >= max(F[L.P_SPATE_WMIN], I[L.I_SP_N0]):
        return _spate_end(I, F)
    return NOTHING, 0.0, 0.0, 0.0


@kernel
def _grid_read(I, F, tau):
    """Tick index of a read at bus time tau; folds its deviation from the grid into the mean."""
    j = np.int64(math.floor((tau - F[L.F_GRID0]) / F[L.P_BUS_T] + 0.5))
    dev = tau - F[L.F_GRID0] - j * F[L.P_BUS_T]
    n = I[L.I_GRID_N] + 1
    I[L.I_GRID_N] = n
    F[L.F_GRID_DEV] += (dev - F[L.F_GRID_DEV]) * max(1.0 / n, 1.0 / 4096.0)
    return j


@kernel
def spate_read(I, F, tau, k):
    """One timed read: sample k at bus time tau. Returns ``(code, k*, t*, var_z)``; code CROSSING
    when a spate just ended in a crossing of the line through (k*, t* [s]), variance var_z [s²]."""
    if I[L.I_GRID] == 0:
        F[L.F_GRID0] = tau
        F[L.F_GRID_DEV] = 0.0
        I[L.I_GRID_N] = 0
        I[L.I_GRID] = 1
        I[L.I_J_PREV] = 0
        I[L.I_D_PREV] = k
        I[L.I_LEVEL] = k
        I[L.I_SP_ON] = 0
        return NOTHING, 0.0, 0.0, 0.0
    j = _grid_read(I, F, tau)
    if j <= I[L.I_J_PREV]:
        return NOTHING, 0.0, 0.0, 0.0
    d = k - j
    hole = j - I[L.I_J_PREV] - 1
    d_prev = I[L.I_D_PREV]
    I[L.I_J_PREV] = j
    I[L.I_D_PREV] = d
    if I[L.I_SP_ON] and hole > MAX_HOLE:
        I[L.I_SP_ON] = 0  # a dropout inside a spate: its count is incomplete
        I[L.I_LEVEL] = d
        return NOTHING, 0.0, 0.0, 0.0
    if I[L.I_SP_ON]:
        for _ in range(hole):  # a missing read or two: hold the level of the last one
            code, ks, ts, vz = _spate_step(I, F, d_prev)
            if code == CROSSING or I[L.I_SP_ON] == 0:
                I[L.I_LEVEL] = d
                return code, ks, ts, vz
        return _spate_step(I, F, d)
    if d == I[L.I_LEVEL]:
        return NOTHING, 0.0, 0.0, 0.0
    if abs(d - I[L.I_LEVEL]) > 1 or hole > MAX_HOLE:
        I[L.I_LEVEL] = d  # a re-anchored index or a dropout: a new level, no crossing
        return NOTHING, 0.0, 0.0, 0.0
    I[L.I_SP_ON] = 1
    I[L.I_SP_J0] = j
    I[L.I_SP_N] = 0
    I[L.I_SP_A] = 0
    I[L.I_SP_N0] = 0
    I[L.I_SP_A0] = 0
    I[L.I_SP_DB] = I[L.I_LEVEL]
    I[L.I_SP_RV] = I[L.I_LEVEL]
    I[L.I_SP_RL] = 0
    return _spate_step(I, F, d)
