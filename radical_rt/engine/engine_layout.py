"""Layout of the engine's packed state, declared once: which arrays the compiled release reads
and writes, in which buffer, with which rank.

:class:`radical_rt.engine.engine_state.EngineState` keeps these arrays in three flat buffers (float64
``fb``, int64 ``ib``, bool ``bb``) plus a layout array ``lay`` (k, 4) of offset, rows, columns and
buffer per array, so that a compiled call takes four arguments instead of 46. From :data:`SLOTS`
follow: the packing order and the dtype and rank checks (``EngineState._pack``), the position of
each array in the tuple ``E`` of :mod:`radical_rt.engine.loop` (:data:`E_INDEX`, ``E_*`` constants),
and the compiled :func:`unpack` itself, whose source is generated from the table (one ``_v1`` or
``_v2`` view per slot), so that no position is written by hand; likewise the propagation's work
arrays (:func:`propagation_work`, slots ``pw.*``).
"""

from __future__ import annotations

from typing import NamedTuple

from radical_rt._jit import inline_kernel
from radical_rt.kernels.flat_views import view1, view2
from radical_rt.kernels.propagate import SampleWork

FLOAT, INT, BOOL = 0, 1, 2  # buffer codes: fb, ib, bb
BUFFER_DTYPES = ("float64", "int64", "bool")


class Slot(NamedTuple):
    """One packed array: ``owner`` ("" the engine, "ws" its UD workspace, "geo" its copy of the
    nominal triads, "pw" the propagation's work arrays, radical_rt.kernels.propagate.SampleWork), attribute ``name``, ``buffer`` (FLOAT, INT, BOOL) and rank ``ndim`` (1, 2)."""

    owner: str
    name: str
    buffer: int
    ndim: int

    @property
    def key(self) -> str:
        return f"{self.owner}.{self.name}" if self.owner else self.name


def _slots(spec: str) -> tuple[Slot, ...]:
    out = []
    for item in spec.split():
        path, code = item.split(":")
        owner, _, name = path.rpartition(".")
        out.append(Slot(owner, name, "fib".index(code[0]), int(code[1])))
    return tuple(out)


#: every packed array as owner.name:<buffer f|i|b><rank>, in packing order (E's order)
SLOTS = _slots("""
    excluded:b1 xp:f1 q:f1 A:f2 geo.W:f2 geo.U:f2 geo.V:f2 Minv:f2 Gp:f2 N:f2 Phi_aa:f2
    Phi_ap:f2 Q_aa:f2 par_y:f2 par_t:f2 acc_i:i1 acc_f:f1 th_acc:f1 omega:f1 U:f2 d:f1 dx:f1
    q_params:f1 param_idx:i1 q_dt:f1 ws.struct:f2 ws.a:f1 ws.var:f1 conv_var:f1 kappa_last:f1
    Hbuf:f2 r3:f1 H_att:f2 H_phi:f2 Fbuf:f2 Sbuf:f2 innov:f1 sig:f1 ws.f:f1 ws.v:f1 ws.k:f1
    st_sigma:f1 gyro_mask:b1 Hwbuf:f2 zwbuf:f1 Lbuf:f2 p0:f1 scale_mask:b1 pq:f2 pq_i:i1
    par_innov:f1 par_sig:f1 z_par:f1 H_par:f2 theta_par:f1 Phi_par:f2 fdi_z:f1 fdi_H:f2
    fdi_th:f1 fdi_Phi:f2 fdi_h:f1
    pw.c:f1 pw.sg:f1 pw.s:f1 pw.gh:f1 pw.th:f1 pw.F:f2 pw.work4:f1 pw.dq:f1 pw.active:b1 pw.R:f2
    pw.T:f2 pw.Gm:f2 pw.Mm:f2
""")

#: "owner.name" (or "name") → position in E
E_INDEX = {s.key: i for i, s in enumerate(SLOTS)}


def slot_problems(slot: Slot, array) -> list[str]:
    """Why ``array`` cannot be packed into ``slot`` (empty when it can): dtype and rank."""
    want = BUFFER_DTYPES[slot.buffer]
    probs = []
    if str(array.dtype) != want:
        probs.append(f"{slot.key}: dtype {array.dtype}, layout says {want}")
    if array.ndim != slot.ndim:
        probs.append(f"{slot.key}: rank {array.ndim}, layout says {slot.ndim}")
    return probs



def _unpack_source() -> str:
    views = ", ".join(f"_v{s.ndim}({('fb', 'ib', 'bb')[s.buffer]}, lay, {i})"
                      for i, s in enumerate(SLOTS))
    return f"def unpack(fb, ib, bb, lay):\n    return ({views},)\n"


def _generated_unpack():
    namespace = {"_v1": view1, "_v2": view2}
    exec(compile(_unpack_source(), __file__, "exec"), namespace)  # noqa: S102 (source: SLOTS)
    fn = namespace["unpack"]
    fn.__doc__ = ("The array tuple E (one view per entry of SLOTS) from the engine's packed "
                  "buffers fb (float64), ib (int64), bb (bool) and layout lay (k, 4).")
    return fn


unpack = inline_kernel(_generated_unpack())


#: the slots of the propagation's work arrays, in SampleWork's field order
_PW_SLOTS = [s for s in SLOTS if s.owner == "pw"]
assert tuple(s.name for s in _PW_SLOTS) == tuple(SampleWork.__annotations__), "pw.* slots"


def _generated_work():
    items = ", ".join(f"E[{E_INDEX[s.key]}]" for s in _PW_SLOTS)
    namespace = {"SampleWork": SampleWork}
    source = f"def propagation_work(E):\n    return SampleWork({items})\n"
    exec(compile(source, __file__, "exec"), namespace)  # noqa: S102 (source: SLOTS)
    fn = namespace["propagation_work"]
    fn.__doc__ = ("The propagation's work arrays (radical_rt.kernels.propagate.SampleWork) from "
                  "the engine's tuple E: its slots pw.<field>.")
    return fn


propagation_work = inline_kernel(_generated_work())
