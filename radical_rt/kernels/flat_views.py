"""Views into flat buffers, for layouts that pack many arrays into a few (the engine's state,
the FDI bank): slot ``i`` of a layout ``lay`` (int64 rows ``offset, dims...``) as a 1-, 2- or
3-dimensional view of ``buf``. Inlined into the kernels whose unpacking code is generated from
the layout tables (:mod:`radical_rt.engine.engine_layout`, :mod:`radical_rt.fdi.fdi_bank_pack`).
"""

from __future__ import annotations

from radical_rt._jit import inline_kernel


@inline_kernel
def view1(buf, lay, i):
    """buf[offset : offset + n], lay[i] = (offset, n, ...)."""
    return buf[lay[i, 0]:lay[i, 0] + lay[i, 1]]


@inline_kernel
def view2(buf, lay, i):
    """(r, c) view, lay[i] = (offset, r, c, ...)."""
    o, r, c = lay[i, 0], lay[i, 1], lay[i, 2]
    return buf[o:o + r * c].reshape((r, c))


@inline_kernel
def view3(buf, lay, i):
    """(a, r, c) view, lay[i] = (offset, a, r, c)."""
    o, a, r, c = lay[i, 0], lay[i, 1], lay[i, 2], lay[i, 3]
    return buf[o:o + a * r * c].reshape((a, r, c))
