"""The running FDI bank's arrays in three flat buffers, as the engine's compiled release takes them.

The tuple ``bk`` of :func:`radical_rt.fdi.fdi_bank.bank_sample` holds the 36 arrays that
:data:`radical_rt.fdi.fdi_bank.BK_SLOTS` declares. Passed to the release as a tuple, Numba's
dispatch unboxed every one of them at each call, about 2 µs, also when no bank runs
(perf/README.md). The bank therefore keeps all of them but the gyro history's blocks (``f``,
``st``, ``br``, which the release receives anyway as its history arguments) as views of three
flat buffers ``bfb`` (float64), ``bib`` (int64), ``bbb`` (bool) with a layout ``blay`` (k, 5):
offset, three dimensions (trailing ones 0 below the rank) and buffer per array, in BK_SLOTS
order (:func:`pack_bank`). The release rebuilds ``bk`` with :func:`bank_unpack` only at the
samples it gives a running bank (:func:`bank_sample_packed`); :func:`bank_on` reads the bank's
BI_ON control from the buffers.
"""

from __future__ import annotations

import numpy as np

from radical_rt._jit import inline_kernel, kernel
from radical_rt.fdi.fdi_bank import BI_END, BI_ON, BK_SLOTS, bank_sample
from radical_rt.kernels.flat_views import view1, view2, view3

#: the packed slots: every entry of BK_SLOTS but the history blocks, in BK_SLOTS order
PACKED = BK_SLOTS[3:]
assert tuple(name for name, _nd, _dt in BK_SLOTS[:3]) == ("f", "st", "br")
_BUFFERS = ("float64", "int64", "bool")
_BI_ROW = [name for name, _nd, _dt in PACKED].index("bi")  # row of the controls bi in blay


def views(buffers: tuple) -> dict[str, np.ndarray]:
    """The packed arrays by name: views of ``buffers`` = (bfb, bib, bbb, blay)."""
    blay = buffers[3]
    out = {}
    for i, (name, nd, _dt) in enumerate(PACKED):
        o, d0, d1, d2, b = (int(v) for v in blay[i])
        shape = (d0, d1, d2)[:nd]
        out[name] = buffers[b][o:o + int(np.prod(shape))].reshape(shape)
    return out


def pack_bank(arrays: dict[str, np.ndarray]) -> tuple[tuple, dict[str, np.ndarray]]:
    """Copy ``arrays`` (name → array of every PACKED slot, with its declared rank and dtype) into
    new flat buffers. Returns the buffers (bfb, bib, bbb, blay) and the views of them by name
    (:func:`views`), which the bank takes as its arrays from then on."""
    sizes = [0, 0, 0]
    blay = np.zeros((len(PACKED), 5), np.int64)
    for i, (name, nd, dt) in enumerate(PACKED):
        a = arrays[name]
        if a.ndim != nd or str(a.dtype) != dt:  # a programming error
            raise TypeError(f"FDI bank array {name}: {a.ndim}-d {a.dtype}, BK_SLOTS says {nd}-d {dt}")
        b = _BUFFERS.index(dt)
        blay[i, :4] = sizes[b], *(a.shape + (0, 0))[:3]
        blay[i, 4] = b
        sizes[b] += a.size
    buffers = (np.zeros(sizes[0]), np.zeros(sizes[1], np.int64), np.zeros(sizes[2], np.bool_), blay)
    out = views(buffers)
    for name, v in out.items():
        v[...] = arrays[name]
    return buffers, out


def idle_buffers() -> tuple:
    """The buffers of no running bank: every array empty but the controls bi (8,) and bf (5,),
    with BI_ON = 0."""
    sizes = {"bi": 8, "bf": 5}
    return pack_bank({name: np.zeros((sizes[name],) if name in sizes else (0,) * nd, dt)
                      for name, nd, dt in PACKED})[0]


def _unpack_source() -> str:
    bufs = {"float64": "bfb", "int64": "bib", "bool": "bbb"}
    items = ", ".join(f"_w{nd}({bufs[dt]}, blay, {i})" for i, (_n, nd, dt) in enumerate(PACKED))
    return f"def bank_unpack(f, st, br, bfb, bib, bbb, blay):\n    return (f, st, br, {items})\n"


def _generated_unpack():
    namespace = {"_w1": view1, "_w2": view2, "_w3": view3}
    exec(compile(_unpack_source(), __file__, "exec"), namespace)  # noqa: S102 (source: BK_SLOTS)
    fn = namespace["bank_unpack"]
    fn.__doc__ = ("The tuple bk of fdi_bank.bank_sample (BK_SLOTS order) from the history blocks "
                  "f, st, br and the bank's buffers bfb, bib, bbb with layout blay.")
    return fn


bank_unpack = inline_kernel(_generated_unpack())


@inline_kernel
def bank_on(bib, blay):
    """Whether a bank runs in the release: its control bi[BI_ON] in the int64 buffer."""
    return bib[blay[_BI_ROW, 0] + BI_ON] != 0


@inline_kernel
def bank_set_end(bib, blay, end):
    """The running bank's history end (control bi[BI_END]: rows in use up to end−1) in the int64
    buffer: a kernel that makes several releases in one call (the stream's block intake) sets
    it before each, after the rows that release appends."""
    bib[blay[_BI_ROW, 0] + BI_END] = end


@kernel
def bank_sample_packed(f, st, br, bfb, bib, bbb, blay, q_meas, n_stars, epoch, R_nom, use_phi,
                       sig_t, W, U_ax, V_ax):
    """:func:`radical_rt.fdi.fdi_bank.bank_sample` with the bank's arrays from the history blocks
    f, st, br and the bank's buffers (:func:`bank_unpack`); the other arguments are its own."""
    return bank_sample(bank_unpack(f, st, br, bfb, bib, bbb, blay), q_meas, n_stars, epoch, R_nom,
                       use_phi, sig_t, W, U_ax, V_ax)
