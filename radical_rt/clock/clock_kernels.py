"""Numba kernels of the SIRU clock: the per-read loop (sequence, repair, release). See docs/clock.md.

All state lives in the two arrays laid out in :mod:`radical_rt.clock.clock_layout` (``I`` int64, ``F``
float64); kernels mutate them in place, never allocate per read, never raise. Released samples go
to ``OF`` (float rows: t, dt, var_extra, dtheta...) and ``OI`` (int rows: status, bridged, tt).
One read is held back (look-ahead of one read) so that a glitch can be told from a counter reset
or a clock jump by the read that follows it. Timing: :mod:`radical_rt.clock.clock_timing`.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import kernel
from radical_rt.clock import clock_layout as L
from radical_rt.clock.clock_line import period, raise_anomaly
from radical_rt.clock.clock_timing import NO_TIMING, REACQUIRE, TIMING, line_time, time_read

# columns of the output arrays
O_T = 0
O_DT = 1
O_VAR = 2
O_DTH = 3  # OF[:, 3:3+n]
O_ST = 0
O_BR = 1
O_TT = 2


@kernel
def _emit(I, F, OF, m, t_rec, t_naive, k):
    """Time and interval of released sample k (t clamped to slew small corrections)."""
    t0 = F[L.P_T]
    dk = k - I[L.I_K_OUT] if I[L.I_HAVE_OUT] else 1
    nominal = period(F) * dk
    if F[L.P_NAIVE] > 0.5:
        t = t_naive
        dt = t - F[L.F_T_OUT] if I[L.I_HAVE_OUT] else t0
        if not dt > 0.0:
            dt = t0 * dk
    else:
        t = t_rec
        if I[L.I_HAVE_OUT]:
            dt = t - F[L.F_T_OUT]
            if abs(dt - nominal) <= t0:
                dt = min(max(dt, 0.5 * nominal), 1.5 * nominal)
                t = F[L.F_T_OUT] + dt
            else:  # the time line was re-anchored: t jumps, dt is the true interval
                dt = nominal
        else:
            dt = nominal
    OF[m, O_T] = t
    OF[m, O_DT] = dt
    F[L.F_T_OUT] = t
    I[L.I_HAVE_OUT] = 1
    I[L.I_K_OUT] = k


@kernel
def _release_bridges(I, F, OF, OI, m, n, k):
    """Bridge samples k-n+1 .. k-1 by interpolating the neighbouring increments."""
    ng = I[L.I_NG]
    da = L.DA
    dp = L.DA + ng
    b = period(F)
    t_a = F[L.F_TAU_A_FIRST]
    tau = F[L.F_TAU_P]
    for i in range(1, n):
        w = i / n
        for g in range(ng):
            OF[m, O_DTH + g] = (1.0 - w) * F[da + g] + w * F[dp + g]
        OF[m, O_VAR] = (F[L.P_SIG_ALPHA] * b * b * min(i, n - i)) ** 2
        OI[m, O_ST] = I[L.I_ST_A] | I[L.I_ST_P]
        OI[m, O_BR] = 1
        OI[m, O_TT] = -1
        _emit(I, F, OF, m, line_time(I, F, k - n + i), t_a + (tau - t_a) * w, k - n + i)
        m += 1
        I[L.C_BRIDGED] += 1
    return m


@kernel
def _accept(I, F, OF, OI, n, mode, wrapped, m):
    """Accept the pending read as sample k_A + n (n = 0: a repeat). Returns the output count."""
    ng = I[L.I_NG]
    da = L.DA
    dp = L.DA + ng
    tau = F[L.F_TAU_P]
    first = I[L.I_HAVE_A] == 0
    if first:
        n = 1
    k = I[L.I_K_A] + n
    event = not first and (n == 0 or n >= 2)
    if mode != NO_TIMING:  # repeats and misses are judged by the spate tracker (clock_line)
        time_read(I, F, tau, k, mode)
    if wrapped:
        I[L.C_WRAPS] += 1
    if event and n <= 2:  # sawtooth wraps: one repeat (or one miss) net each; gaps do not count
        I[L.I_NET] += 1 if n == 0 else -1
        I[L.I_NET_HI] = max(I[L.I_NET_HI], I[L.I_NET])
        I[L.I_NET_LO] = min(I[L.I_NET_LO], I[L.I_NET])
    if n == 0:
        I[L.C_REPEATED] += 1
        F[L.F_TAU_A_LAST] = tau
        for g in range(ng):
            if F[dp + g] != F[da + g]:
                I[L.C_REPEAT_MISMATCH] += 1
                raise_anomaly(I, F, tau)
                break
        return m
    if n >= 2:
        I[L.C_MISSING] += n - 1
        if n - 1 <= F[L.P_MAX_BRIDGE]:
            m = _release_bridges(I, F, OF, OI, m, n, k)
        else:  # a dropout consistent in tt and bus time: the engine flags GYRO_GAP from dt
            I[L.C_GAPS] += 1
    for g in range(ng):
        OF[m, O_DTH + g] = F[dp + g]
        F[da + g] = F[dp + g]
    OF[m, O_VAR] = 0.0
    OI[m, O_ST] = I[L.I_ST_P]
    OI[m, O_BR] = 0
    OI[m, O_TT] = I[L.I_TT_P]
    F[L.F_T_LINE] = line_time(I, F, k)
    _emit(I, F, OF, m, F[L.F_T_LINE], tau, k)
    I[L.C_SAMPLES] += 1
    I[L.I_HAVE_A] = 1
    I[L.I_K_A] = k
    I[L.I_TT_A] = I[L.I_TT_P]
    I[L.I_ST_A] = I[L.I_ST_P]
    F[L.F_TAU_A_FIRST] = tau
    F[L.F_TAU_A_LAST] = tau
    return m + 1


@kernel
def _tt_step(F, tt_from, tt_to):
    """``(ok, n)``: tt_to is n samples after tt_from (mod the wrap), n <= the largest jump."""
    d = tt_to - tt_from
    ticks = np.int64(F[L.P_TICKS])
    if d < 0:
        d += np.int64(F[L.P_WRAP])
    if d % ticks != 0:
        return False, np.int64(0)
    n = d // ticks
    return n <= F[L.P_MAX_JUMP], n


@kernel
def _time_ok(F, tau_from, tau_to, n):
    """Bus times of two reads n samples apart agree with the clock model (sawtooth within T)."""
    if not tau_to > tau_from:
        return False
    y_span = F[L.F_Y_HI] - F[L.F_Y_LO]
    dev = (tau_to - tau_from) - n * period(F)
    return abs(dev) < F[L.P_T] + F[L.P_TIME_TOL] + n * y_span / F[L.P_NS]


@kernel
def _reg_ok(F, tau_from, tau_to):
    """Two reads fall on the bus's read ticks (a whole number >= 1 of bus periods apart), within
    max(read_tol, 8 x the running RMS tick deviation)."""
    if F[L.P_CHECK_TICKS] < 0.5:
        return True
    q = (tau_to - tau_from) / F[L.P_BUS_T]
    r = np.floor(q + 0.5)
    tol = max(F[L.P_READ_TOL], 8.0 * math.sqrt(F[L.F_RJ2]))
    return r >= 1.0 and abs(q - r) * F[L.P_BUS_T] <= tol


@kernel
def _track_ticks(F, tau_from, tau_to):
    """Update the running mean square of the read-tick deviation (from accepted reads)."""
    q = (tau_to - tau_from) / F[L.P_BUS_T]
    dev = (q - np.floor(q + 0.5)) * F[L.P_BUS_T]
    F[L.F_RJ2] += (dev * dev - F[L.F_RJ2]) * (1.0 / 256.0)


@kernel
def _consistent(F, tt_from, tau_from, tt_to, tau_to):
    ok, n = _tt_step(F, tt_from, tt_to)
    ok = ok and _time_ok(F, tau_from, tau_to, n) and _reg_ok(F, tau_from, tau_to)
    return ok, n


@kernel
def _n_from_time(I, F, tau):
    """Samples after k_A up to the read at tau, from the time line (at least 1)."""
    n = np.floor((tau - line_time(I, F, I[L.I_K_A])) / period(F))
    return np.int64(max(n, 1.0))


@kernel
def _process(I, F, OF, OI, has_n, tau_n, tt_n, m):
    """Classify the pending read P against the last accepted sample A and the next read N."""
    I[L.I_HAVE_P] = 0
    if I[L.I_HAVE_A] == 0:
        return _accept(I, F, OF, OI, 1, TIMING, False, m)
    tt_a = I[L.I_TT_A]
    tt_p = I[L.I_TT_P]
    tau_a = F[L.F_TAU_A_LAST]
    tau_p = F[L.F_TAU_P]
    tick = np.int64(F[L.P_TICKS])
    ok_tt, n = _tt_step(F, tt_a, tt_p)
    ok_time = ok_tt and _time_ok(F, tau_a, tau_p, n)
    ok_reg = _reg_ok(F, tau_a, tau_p)
    wrapped = ok_tt and tt_a + n * tick >= np.int64(F[L.P_WRAP])
    if ok_tt and ok_time and ok_reg:
        _track_ticks(F, tau_a, tau_p)
        return _accept(I, F, OF, OI, n, TIMING, wrapped, m)
    ok_an = False
    n_an = np.int64(0)
    ok_pn = False
    if has_n:
        ok_an, n_an = _consistent(F, tt_a, tau_a, tt_n, tau_n)
        ok_pn, _ = _consistent(F, tt_p, tau_p, tt_n, tau_n)
    if ok_tt:
        if ok_an and n <= n_an:  # P's bus time is the outlier: keep the sample, not the timing,
            I[L.C_TBUS_GLITCHES] += 1  # and tag it as read at the bus tick before N
            raise_anomaly(I, F, tau_p)
            F[L.F_TAU_P] = tau_n - F[L.P_BUS_T]
            return _accept(I, F, OF, OI, n, NO_TIMING, wrapped, m)
        if ok_an:  # P's tt runs ahead of the next read's: a tt glitch
            I[L.C_TT_GLITCHES] += 1
            raise_anomaly(I, F, tau_p)
            return m
        if ok_pn and not ok_reg:  # the bus clock jumped: same samples, new time line
            I[L.C_TIME_JUMPS] += 1
            raise_anomaly(I, F, tau_p)
            return _accept(I, F, OF, OI, n, REACQUIRE, wrapped, m)
        if not ok_pn:  # unresolved: trust the sequence number, not the time
            I[L.C_TBUS_GLITCHES] += 1
            raise_anomaly(I, F, tau_p)
            F[L.F_TAU_P] = tau_a + F[L.P_BUS_T] * max(n, 1)
            return _accept(I, F, OF, OI, n, NO_TIMING, wrapped, m)
    elif ok_an or not ok_pn:  # a read whose tt fits neither neighbour: drop it
        I[L.C_TT_GLITCHES] += 1
        raise_anomaly(I, F, tau_p)
        return m
    # the tt sequence restarts at P (counter reset or jump): re-anchor the index from time
    n = _n_from_time(I, F, tau_p)
    if tt_p < F[L.P_RESET_TICKS] and (tt_p < tt_a or not ok_tt):
        I[L.C_RESETS] += 1
        n = max(n, tt_p // tick + 1)
    else:
        I[L.C_TT_JUMPS] += 1
    raise_anomaly(I, F, tau_p)
    mode = TIMING if ok_reg and tau_p > tau_a else REACQUIRE
    return _accept(I, F, OF, OI, n, mode, False, m)


@kernel
def _next(I, F, OF, OI, tau_n, tt_n, m):
    """Dispose of the pending read given the next one: the usual case (the next sample, with
    consistent times) goes straight to :func:`_accept`, everything else through :func:`_process`."""
    if I[L.I_HAVE_A]:
        ok, n = _tt_step(F, I[L.I_TT_A], I[L.I_TT_P])
        if (ok and n == 1 and I[L.I_TT_A] + np.int64(F[L.P_TICKS]) < np.int64(F[L.P_WRAP])
                and _time_ok(F, F[L.F_TAU_A_LAST], F[L.F_TAU_P], n)
                and _reg_ok(F, F[L.F_TAU_A_LAST], F[L.F_TAU_P])):
            I[L.I_HAVE_P] = 0
            _track_ticks(F, F[L.F_TAU_A_LAST], F[L.F_TAU_P])
            return _accept(I, F, OF, OI, n, TIMING, False, m)
    return _process(I, F, OF, OI, True, tau_n, tt_n, m)


@kernel
def clock_run(I, F, t_bus, tt, dth, status, j0, final, OF, OI):
    """Process reads ``j0, j0 + 1, ...`` in order (one held back); ``final`` then releases the held
    one. Stops early when OF/OI (rows of released samples) could overflow. Returns ``(m, j)``: rows
    written and the next read to process, ``len(t_bus) + 1`` once the final step is done."""
    m = 0
    ng = I[L.I_NG]
    dp = L.DA + ng
    wrap = np.int64(F[L.P_WRAP])
    room = np.int64(F[L.P_MAX_BRIDGE]) + 1
    cap = OF.shape[0]
    nr = t_bus.shape[0]
    for j in range(j0, nr):
        if m + room > cap:
            return m, j
        tau = t_bus[j]
        q = tt[j]
        if not np.isfinite(tau) or q < 0 or q >= wrap:
            I[L.C_REJECTED] += 1
            raise_anomaly(I, F, F[L.F_TAU_NOW])
            continue
        if I[L.I_HAVE_P]:
            m = _next(I, F, OF, OI, tau, q, m)
        F[L.F_TAU_P] = tau
        F[L.F_TAU_NOW] = max(F[L.F_TAU_NOW], tau)
        I[L.I_TT_P] = q
        s = status[j]
        for g in range(ng):
            v = dth[j, g]
            if np.isfinite(v):
                F[dp + g] = v
            else:
                F[dp + g] = 0.0
                s |= np.int64(1) << g
        I[L.I_ST_P] = s
        I[L.I_HAVE_P] = 1
    if not final:
        return m, nr
    if m + room > cap:
        return m, nr
    if I[L.I_HAVE_P]:
        m = _process(I, F, OF, OI, False, 0.0, np.int64(0), m)
    return m, nr + 1


@kernel
def append_rows(of, oi, m, end, t, dt, dtheta, status, bridged, var_extra):
    """Copy rows 0..m−1 of the output blocks (of, oi; columns O_*) into the sample arrays t, dt,
    dtheta (·, n), status, bridged, var_extra (a :class:`radical_rt.engine.gyro_queue.GyroQueue`) from
    index end (the caller made room)."""
    n = dtheta.shape[1]
    for r in range(m):
        k = end + r
        t[k], dt[k], var_extra[k] = of[r, O_T], of[r, O_DT], of[r, O_VAR]
        for i in range(n):
            dtheta[k, i] = of[r, O_DTH + i]
        status[k], bridged[k] = oi[r, O_ST], oi[r, O_BR] != 0


@kernel
def clock_push_rows(I, F, t_bus, tt, dth, status, chunk, OF, OI, end, t, dt, dtheta, st, bridged,
                    var_extra, tags):
    """All reads of one message through :func:`clock_run` (``chunk`` reads per pass through the
    output blocks OF/OI), the released samples appended to the sample arrays from index end (as
    :func:`append_rows`) and their time tags to tags (−1: bridged). The caller made room for
    len(t_bus)·(max_bridge + 1) rows (the most the reads can release). Returns the rows appended."""
    k = t_bus.shape[0]
    j, total = 0, 0
    while j < k:
        stop = min(j + chunk, k)
        m, j = clock_run(I, F, t_bus[:stop], tt[:stop], dth[:stop], status[:stop], j, False, OF, OI)
        append_rows(OF, OI, m, end + total, t, dt, dtheta, st, bridged, var_extra)
        for r in range(m):
            tags[total + r] = OI[r, O_TT]
        total += m
    return total
