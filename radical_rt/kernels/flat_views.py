"""Views into flat buffers, for layouts that pack many arrays into a few (the engine's state,
the FDI bank): slot ``i`` of a layout ``lay`` (int64 rows ``offset, dims...``) as a 1-, 2- or
3-dimensional view of ``buf``. Inlined into the kernels whose unpacking code is generated from
the layout tables (:mod:`radical_rt.engine.engine_layout`, :mod:`radical_rt.fdi.fdi_bank_pack`).

The views do not own their memory (``numba.carray`` over the buffer's data: no reference count),
so a kernel may pass its tuple of dozens of them to inlined helpers without the two atomic
reference-count operations per array and per pass that views of ``buf`` cost (about a third of
the compiled release's time, perf/README.md); and a 2- or 3-dimensional view needs no reshape
call. They are valid while ``buf`` is: a kernel's argument, alive for the whole call. They must
never be returned to Python or stored beyond the call.
"""

from __future__ import annotations

import numba
from numba import types
from numba.extending import intrinsic, overload

from radical_rt._jit import JIT_POLICY


@intrinsic
def _at(typingctx, buf, off):
    """Pointer to element ``off`` of the C-contiguous 1-D array ``buf``."""
    sig = types.CPointer(buf.dtype)(buf, off)

    def codegen(context, builder, signature, args):
        ary = context.make_array(signature.args[0])(context, builder, args[0])
        return builder.gep(ary.data, [args[1]])
    return sig, codegen


# The functions below are the NumPy forms (Python callers, NUMBA_DISABLE_JIT); compiled code
# gets the non-owning forms registered with numba.extending.overload after each.

def view1(buf, lay, i):
    """buf[offset : offset + n], lay[i] = (offset, n, ...)."""
    return buf[lay[i, 0]:lay[i, 0] + lay[i, 1]]


def view2(buf, lay, i):
    """(r, c) view, lay[i] = (offset, r, c, ...)."""
    o, r, c = lay[i, 0], lay[i, 1], lay[i, 2]
    return buf[o:o + r * c].reshape((r, c))


def view3(buf, lay, i):
    """(a, r, c) view, lay[i] = (offset, a, r, c)."""
    o, a, r, c = lay[i, 0], lay[i, 1], lay[i, 2], lay[i, 3]
    return buf[o:o + a * r * c].reshape((a, r, c))


@overload(view1, inline="always", jit_options=JIT_POLICY)
def _view1_compiled(buf, lay, i):
    def impl(buf, lay, i):
        return numba.carray(_at(buf, lay[i, 0]), lay[i, 1])
    return impl


@overload(view2, inline="always", jit_options=JIT_POLICY)
def _view2_compiled(buf, lay, i):
    def impl(buf, lay, i):
        return numba.carray(_at(buf, lay[i, 0]), (lay[i, 1], lay[i, 2]))
    return impl


@overload(view3, inline="always", jit_options=JIT_POLICY)
def _view3_compiled(buf, lay, i):
    def impl(buf, lay, i):
        return numba.carray(_at(buf, lay[i, 0]), (lay[i, 1], lay[i, 2], lay[i, 3]))
    return impl


def borrow(a):
    """``a`` itself (Python callers, NUMBA_DISABLE_JIT); in compiled code a view of the
    C-contiguous array ``a`` that owns no memory (see the module docstring), so that passing
    it on to inlined helpers costs no reference counting. Valid while ``a`` is: a kernel's own
    argument, for the call."""
    return a


@overload(borrow, inline="always", jit_options=JIT_POLICY)
def _borrow_compiled(a):
    if not isinstance(a, types.Array) or a.layout != "C":
        return lambda a: a  # (a strided array is passed on as it is)

    def impl(a):
        return numba.carray(_at(a, 0), a.shape)
    return impl


@intrinsic
def _use(typingctx, x):
    """A use of ``x`` that compiles to nothing (see :func:`keep`)."""
    def codegen(context, builder, signature, args):
        return context.get_dummy_value()

    return types.none(x), codegen


def keep(x):
    """Nothing (Python callers). In compiled code, a last use of ``x``: Numba releases a local
    array after its last use, so a kernel that makes borrowed views (:func:`borrow`) of arrays it
    allocated itself calls ``keep`` on them (or on the tuple holding them) after its last use of
    the views, and the memory stays valid until then."""


@overload(keep, inline="always", jit_options=JIT_POLICY)
def _keep_compiled(x):
    def impl(x):
        _use(x)

    return impl
