"""Convex-polygon kernels for the SIRU clock's set-membership line estimate (see docs/clock.md).

The feasible set of sample-time lines ``t(k) = t_base(k_ref) + x + (y / N_s) (k - k_ref)`` is a
convex polygon in the plane ``(x, y)``: ``x`` [s] is the line's offset from the nominal line at the
reference sample, ``y`` [s per N_s samples] its slope deviation. Each bus read adds two half-planes
(the sample it got had been taken, the next one had not). Vertices are stored counter-clockwise in
one float array ``F``: x at ``F[ox:ox+nv]``, y at ``F[oy:oy+nv]``, with a workspace at ``wx``,
``wy`` (offsets, so that the per-read loop passes one array). Kernels work in place, never
allocate, and return the new vertex count.

Algorithms: Sutherland & Hodgman (1974) single-plane clipping; the Minkowski sum of a convex
polygon with a box by normal-cone corners (drift inflation); outer vertex reduction by removing the
edge whose removal (extending its two neighbours) adds the least area.
"""

from __future__ import annotations

import numpy as np

from radical_rt._jit import kernel

#: above VHIGH vertices the polygon is reduced to VCAP (outer approximation; the hysteresis keeps
#: the O(V^2) reduction rare). Storage is clock_layout.VMAX >= 2 * VHIGH + 4 per array.
VCAP = 24
VHIGH = 40


@kernel
def poly_clip(F, ox, oy, nv, a, b, r, wx, wy):
    """Keep ``a x + b y <= r``. Returns ``(nv, code, viol)``: code 0 redundant, 1 clipped, -1 empty
    (polygon unchanged, ``viol = min(a x + b y - r) > 0``)."""
    fmin = np.inf
    fmax = -np.inf
    for i in range(nv):
        f = a * F[ox + i] + b * F[oy + i] - r
        fmin = min(fmin, f)
        fmax = max(fmax, f)
    if fmax <= 0.0:
        return nv, 0, 0.0
    if fmin > 0.0:
        return nv, -1, fmin
    m = 0
    for i in range(nv):
        j = i + 1 if i + 1 < nv else 0
        fi = a * F[ox + i] + b * F[oy + i] - r
        fj = a * F[ox + j] + b * F[oy + j] - r
        if fi <= 0.0:
            F[wx + m] = F[ox + i]
            F[wy + m] = F[oy + i]
            m += 1
        if (fi <= 0.0) != (fj <= 0.0):
            t = fi / (fi - fj)
            F[wx + m] = F[ox + i] + t * (F[ox + j] - F[ox + i])
            F[wy + m] = F[oy + i] + t * (F[oy + j] - F[oy + i])
            m += 1
    for i in range(m):
        F[ox + i] = F[wx + i]
        F[oy + i] = F[wy + i]
    if m > VHIGH:
        m = poly_reduce(F, ox, oy, m, VCAP)
    return m, 1, 0.0


@kernel
def poly_clip2(F, ox, oy, nv, r1, g1, r2, wx, wy):
    """The two constraints of one read at the reference sample: keep ``x <= r1`` and
    ``-x - g1 y <= r2``. One scan decides both in the usual case where neither cuts. Returns
    ``(nv, code1, viol1, code2, viol2)`` with the codes of :func:`poly_clip`."""
    max1 = -np.inf
    max2 = -np.inf
    for i in range(nv):
        max1 = max(max1, F[ox + i] - r1)
        max2 = max(max2, -F[ox + i] - g1 * F[oy + i] - r2)
    c1 = 0
    v1 = 0.0
    c2 = 0
    v2 = 0.0
    if max1 > 0.0:
        nv, c1, v1 = poly_clip(F, ox, oy, nv, 1.0, 0.0, r1, wx, wy)
    if max2 > 0.0 or c1 == 1:
        nv, c2, v2 = poly_clip(F, ox, oy, nv, -1.0, -g1, r2, wx, wy)
    return nv, c1, v1, c2, v2


@kernel
def _remove(F, ox, oy, nv, i):
    for q in range(i, nv - 1):
        F[ox + q] = F[ox + q + 1]
        F[oy + q] = F[oy + q + 1]
    return nv - 1


@kernel
def poly_prune(F, ox, oy, nv):
    """Drop duplicate and collinear vertices (relative tolerance 1e-12 of the extent)."""
    if nv < 4:
        return nv
    xlo, xhi = poly_extent(F, ox, nv)
    ylo, yhi = poly_extent(F, oy, nv)
    tol = 1e-12 * (xhi - xlo) * (yhi - ylo) + 1e-300
    i = 0
    while i < nv and nv > 3:
        ip = i - 1 if i > 0 else nv - 1
        i1 = i + 1 if i + 1 < nv else 0
        cr = ((F[ox + i] - F[ox + ip]) * (F[oy + i1] - F[oy + i])
              - (F[oy + i] - F[oy + ip]) * (F[ox + i1] - F[ox + i]))
        if abs(cr) <= tol:
            nv = _remove(F, ox, oy, nv, i)
        else:
            i += 1
    return nv


@kernel
def poly_reduce(F, ox, oy, nv, cap):
    """Outer approximation with at most ``cap`` vertices (the polygon only grows)."""
    nv = poly_prune(F, ox, oy, nv)
    while nv > cap:
        best = -1
        best_area = np.inf
        bx = 0.0
        by = 0.0
        for i in range(nv):
            ip = i - 1 if i > 0 else nv - 1
            i1 = i + 1 if i + 1 < nv else 0
            i2 = i1 + 1 if i1 + 1 < nv else 0
            d1x = F[ox + i] - F[ox + ip]
            d1y = F[oy + i] - F[oy + ip]
            d2x = F[ox + i2] - F[ox + i1]
            d2y = F[oy + i2] - F[oy + i1]
            den = d1x * d2y - d1y * d2x
            if den <= 0.0:
                continue
            ex = F[ox + i1] - F[ox + i]
            ey = F[oy + i1] - F[oy + i]
            t = (ex * d2y - ey * d2x) / den
            if t < 0.0:
                continue
            xx = F[ox + i] + t * d1x
            xy = F[oy + i] + t * d1y
            area = 0.5 * abs(ex * (xy - F[oy + i]) - ey * (xx - F[ox + i]))
            if area < best_area:
                best_area = area
                best = i
                bx = xx
                by = xy
        if best < 0:
            break
        F[ox + best] = bx
        F[oy + best] = by
        nv = _remove(F, ox, oy, nv, best + 1 if best + 1 < nv else 0)
    return nv


@kernel
def poly_centroid(F, ox, oy, nv):
    """Area centroid ``(cx, cy)`` (vertex mean for a degenerate polygon)."""
    x0 = F[ox]
    y0 = F[oy]
    a2 = 0.0
    sx = 0.0
    sy = 0.0
    for i in range(1, nv - 1):
        ax = F[ox + i] - x0
        ay = F[oy + i] - y0
        bx = F[ox + i + 1] - x0
        by = F[oy + i + 1] - y0
        cr = ax * by - bx * ay
        a2 += cr
        sx += (ax + bx) * cr
        sy += (ay + by) * cr
    if a2 > 0.0:
        return x0 + sx / (3.0 * a2), y0 + sy / (3.0 * a2)
    mx = 0.0
    my = 0.0
    for i in range(nv):
        mx += F[ox + i]
        my += F[oy + i]
    return mx / nv, my / nv


@kernel
def poly_box(F, ox, oy, x0, x1, y0, y1):
    """The axis-aligned box ``[x0, x1] x [y0, y1]`` (counter-clockwise); returns 4."""
    F[ox] = x0
    F[oy] = y0
    F[ox + 1] = x1
    F[oy + 1] = y0
    F[ox + 2] = x1
    F[oy + 2] = y1
    F[ox + 3] = x0
    F[oy + 3] = y1
    return 4


@kernel
def _quadrant(nx, ny):
    """Quadrant 0..3 of a normal direction (counter-clockwise from +x)."""
    if nx > 0.0 and ny >= 0.0:
        return 0
    if nx <= 0.0 and ny > 0.0:
        return 1
    if nx < 0.0 and ny <= 0.0:
        return 2
    return 3


@kernel
def poly_inflate(F, ox, oy, nv, qx, qy, wx, wy):
    """Minkowski sum with the box ``[-qx, qx] x [-qy, qy]`` in O(nv): each vertex is moved to the
    box corner(s) extreme over its normal cone (quadrants of the incoming and outgoing edge
    normals, counter-clockwise), so the result has at most nv + 4 vertices (2 nv if rounding
    makes vertices reflex)."""
    if qx <= 0.0 and qy <= 0.0:
        return nv
    nv = poly_prune(F, ox, oy, nv)
    m = 0
    for i in range(nv):
        ip = i - 1 if i > 0 else nv - 1
        i1 = i + 1 if i + 1 < nv else 0
        ax = F[ox + i] - F[ox + ip]
        ay = F[oy + i] - F[oy + ip]
        bx = F[ox + i1] - F[ox + i]
        by = F[oy + i1] - F[oy + i]
        q = _quadrant(ay, -ax)  # outward normal of the incoming edge
        q1 = _quadrant(by, -bx)  # ... of the outgoing edge
        steps = (q1 - q) % 4
        if ax * by - ay * bx <= 0.0:  # not a left turn (rounding): no corners in between
            steps = 1 if steps else 0
        for s in range(steps + 1):
            F[wx + m] = F[ox + i] + (qx if q == 0 or q == 3 else -qx)
            F[wy + m] = F[oy + i] + (qy if q <= 1 else -qy)
            m += 1
            q = q1 if s + 1 == steps else (q + 1) % 4
    for i in range(m):
        F[ox + i] = F[wx + i]
        F[oy + i] = F[wy + i]
    m = poly_prune(F, ox, oy, m)
    if m > VHIGH:
        m = poly_reduce(F, ox, oy, m, VCAP)
    return m


@kernel
def poly_extent(F, o, nv):
    """``(min, max)`` of ``F[o:o+nv]``."""
    lo = F[o]
    hi = F[o]
    for i in range(1, nv):
        lo = min(lo, F[o + i])
        hi = max(hi, F[o + i])
    return lo, hi
