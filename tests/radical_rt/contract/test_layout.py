"""Flat-array layouts declared once (radical_rt.contract.layout.Fields): the helper itself, and every
layout module's constants against its table (a constant edited by hand, a field inserted without
its constant, or overlapping parts of one array fail here)."""

from __future__ import annotations

import numpy as np
import pytest

from radical_rt.clock import clock_layout
from radical_rt.contract.layout import Fields
from radical_rt.engine import loop_layout
from radical_rt.stream import stream_layout


def test_offsets_follow_the_declaration_order():
    f = Fields("demo", "float64")
    assert (f.add("a"), f.add("v", 3, unit="rad"), f.add("b")) == (0, 1, 4)
    g = f.freeze().follow("demo tail")
    assert g.add("c") == 5 and g.freeze().end == 6 and f.size == 5
    with pytest.raises(RuntimeError):
        f.add("late")
    assert f.name_at(2) == "v[1]" and f.name_at(4) == "b"
    with pytest.raises(IndexError):
        f.name_at(5)
    with pytest.raises(KeyError, match="fields: a, v, b"):
        f["nope"]


def test_pack_requires_every_field_with_its_size():
    f = Fields("demo", "int64")
    f.add("n")
    f.add("pair", 2)
    f.freeze()
    a = f.pack({"n": 7, "pair": [1, 2]})
    assert a.dtype == np.int64 and a.tolist() == [7, 1, 2]
    assert f.unpack(a)["n"] == 7 and f.unpack(a)["pair"].tolist() == [1, 2]
    with pytest.raises(ValueError, match="missing"):
        f.pack({"n": 1})
    with pytest.raises(ValueError, match="needs 2"):
        f.pack({"n": 1, "pair": [1, 2, 3]})
    with pytest.raises(ValueError, match="unknown"):
        f.pack({"n": 1, "pair": [1, 2], "x": 0})
    assert f.check(a) == []
    assert f.check(np.zeros(3)) and f.check(np.zeros(2, np.int64)) and f.check([1, 2, 3])
    g = Fields("d")
    g.add("x")
    with pytest.raises(ValueError, match="twice"):
        g.add("x")


def _constants(module, prefix: str, layout: Fields) -> None:
    """Every field of ``layout`` has its module constant prefix + NAME at its offset."""
    for f in layout.fields:
        name = prefix + f.name.upper()
        assert getattr(module, name) == f.offset, (layout.name, name)


def test_clock_layout_constants_are_the_table():
    L = clock_layout
    _constants(L, "P_", L.PRM)
    _constants(L, "F_", L.STATE)
    for f in L.INT.fields:
        if f.name == "counters":
            assert f.offset == L.C0 and f.size == len(L.COUNTER_NAMES)
        else:
            assert getattr(L, "I_" + f.name.upper()) == f.offset
    for i, c in enumerate(L.COUNTER_NAMES):
        short = {"crossings_rejected": "cross_rejected"}.get(c, c)
        assert getattr(L, "C_" + short.upper()) == L.C0 + i
    # one F array: parameters, state, polygon, then the held increments, without overlap
    assert L.PRM.start == 0 and L.STATE.start == L.PRM.end and L.WORK.start == L.STATE.end
    assert (L.NPRM, L.NF, L.NI, L.DA) == (L.PRM.size, L.STATE.size, L.INT.end, L.WORK.end)
    assert L.f_size(4) == L.DA + 8


def test_clock_params_fill_every_parameter():
    from radical_rt.clock.clock_config import ClockConfig
    p = ClockConfig().params()
    assert p.shape == (clock_layout.NPRM,) and p[clock_layout.P_T] == 0.01
    assert p[clock_layout.P_WRAP] == 2.0**32 and np.isfinite(p).all()


def test_stream_layout_constants_are_the_table():
    S = stream_layout
    _constants(S, "SS_", S.SS)
    _constants(S, "SI_", S.SI)
    assert S.SS_LAST + 1 == S.SS_LAST_ST1 and S.SS_LAST + 2 == S.SS_LAST_ST2
    from radical_rt.stream.tracker_queue import TrackerQueue
    tq = TrackerQueue()
    assert tq.ss.shape == (S.SS.end,) and tq.si.shape == (S.SI.end,)


def test_loop_layout_constants_are_the_table():
    F = loop_layout
    _constants(F, "CFG_", F.CFG)
    _constants(F, "IO_", F.IO)
    _constants(F, "CNT_", F.CNT)
    assert F.IO_LAST_ST + 1 == F.IO_LAST_ST1 and F.IO_LAST_ST + 2 == F.IO_LAST_ST2
    from radical_rt.engine.filter import Engine
    eng = Engine()
    assert not F.CFG.check(eng._cfg) and eng._cfg.shape == (F.CFG.end,)
    assert not F.IO.check(eng._io) and not F.CNT.check(eng._cnt)
    cfg = F.CFG.unpack(eng._cfg)
    assert cfg["n_gyro"] == eng.n_gyro and cfg["prop_window"] == eng.si.prop_window
    assert cfg["phi_p"] == cfg["phi_col"] - 3 and cfg["lat_p"] == cfg["lat_col"] - 3


def test_engine_layout_packs_every_slot_as_declared():
    """The packed engine state against its table: every slot's view has the declared buffer and
    rank, views do not overlap, and the compiled unpack returns the same arrays (values and
    shapes) as the engine's attributes."""
    from radical_rt.engine import engine_layout as EL
    from radical_rt.engine.filter import Engine

    eng = Engine()
    bufs = (eng._fb, eng._ib, eng._bb)
    seen = [np.zeros(b.size, bool) for b in bufs]
    for i, s in enumerate(EL.SLOTS):
        o, r, c, kind = (int(x) for x in eng._lay[i])
        assert kind == s.buffer and (c > 0) == (s.ndim == 2), s.key
        n = r * max(c, 1)
        assert not seen[kind][o:o + n].any(), f"{s.key} overlaps another slot"
        seen[kind][o:o + n] = True
    assert all(m.all() for m in seen)  # no unused element either
    E = EL.unpack.py_func(eng._fb, eng._ib, eng._bb, eng._lay)
    assert len(E) == len(EL.SLOTS)
    for s, view in zip(EL.SLOTS, E, strict=True):
        owner = eng if s.owner == "" else getattr(eng, s.owner)
        attr = getattr(eng, "_geo_" + s.name) if s.owner == "geo" else getattr(owner, s.name)
        assert view.shape == attr.shape and np.shares_memory(view, attr), s.key
    work = EL.propagation_work.py_func(E)  # the propagation's work arrays: the engine's pw.*
    for name, arr in zip(work._fields, work, strict=True):
        assert arr is E[EL.E_INDEX["pw." + name]] and np.shares_memory(arr, getattr(eng.pw, name))
    assert work.Gm.shape == (3, eng.n_gyro) and work.active.dtype == np.bool_
    bad = np.zeros((3, 3), np.int64)
    assert EL.slot_problems(EL.SLOTS[EL.E_INDEX["U"]], bad) == [
        "U: dtype int64, layout says float64"]
