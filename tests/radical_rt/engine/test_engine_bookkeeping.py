"""The engine's scalar state and bookkeeping as the compiled calls keep them (docs/engine.md §0).

* ``t``, ``mode``, ``flags``, ``att_valid``, ``locked_since`` are views of the kernel's ``io``/``cnt``
  arrays (a write from Python is what the next compiled call reads, and the reverse);
* the counters, NIS sums, diagnostics and last tracker epochs are taken from ``cnt``/``io`` when
  Python reads them (``LoopShell._drain``): reading them after every message or only at the end
  gives the same maps, in the same key order where outputs show it;
* a restored checkpoint's epochs and NIS sums reach ``io`` (the next call continues them);
* ``FaultMonitor.release_inputs`` answers what its four separate queries answer, in every FDI
  state of a fault run (no alarm, alarm with the bank, isolation, three gyros).
"""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from radical_rt.apps.batch import make_processor
from radical_rt.contract.flags import Flag
from radical_rt.engine import loop_layout as FL
from radical_rt.engine.engine_state import MODE_CODE
from radical_rt.engine.filter import Engine
from tests.support.streams import bias_step_messages, input_messages, make_archive

BOOK = ("counters", "nis_sum", "nis_locked", "diag_last", "last_valid_st", "masked",
        "last_numeric")


def _feed(messages, read_every: bool):
    sp, out = make_processor(), []
    for topic, _ns, data in messages:
        out += [(t, msgpack.packb(m)) for t, m in sp.feed(topic, data)]
        if read_every:  # the read takes what the calls counted
            assert sp.engine.counters.get("siru_used", 0) >= 0 and not sp.engine._undrained
    out += [(t, msgpack.packb(m)) for t, m in sp.end_stream(None)]
    return sp, out


@pytest.fixture(scope="module")
def stream(tmp_path_factory):
    return input_messages(make_archive(tmp_path_factory.mktemp("book"), "b", seed=5,
                                       duration=150))


def test_bookkeeping_read_late_equals_read_after_every_message(stream):
    every, out_every = _feed(stream, True)
    late, out_late = _feed(stream, False)
    assert out_every == out_late
    e1, e2 = every.engine, late.engine
    for name in BOOK:
        a, b = getattr(e1, name), getattr(e2, name)
        if name == "diag_last":
            assert list(a) == list(b)
            for kind in a:
                for x, y in zip(a[kind], b[kind], strict=True):
                    assert np.array_equal(x, y), kind
        else:
            assert a == b, name
    # the maps the outputs show keep their key order
    for name in ("nis_sum", "last_valid_st", "diag_last"):
        assert list(getattr(e1, name)) == list(getattr(e2, name)), name
    c = e2.counters
    assert c["siru_used"] > 10_000 and c["st1_used"] > 1000 and c["parity_used"] > 50
    assert e2.nis_locked["parity"][0] > 0 and e2.last_valid_st[1] > 100.0


def test_scalar_state_is_a_view_of_the_kernel_arrays():
    e = Engine()
    io, cnt = e._io, e._cnt
    assert e.t == -math.inf and io[FL.IO_T] == -math.inf and e.mode == "init"
    e.t, e.locked_since = 12.5, 3.0
    assert (io[FL.IO_T], io[FL.IO_LOCKED_SINCE]) == (12.5, 3.0)
    e.flags |= int(Flag.GYRO_GAP)
    assert cnt[FL.CNT_FLAGS] & int(Flag.GYRO_GAP) and e.flags & int(Flag.GYRO_GAP)
    for mode, code in MODE_CODE.items():
        e.mode = mode
        assert io[FL.IO_MODE] == code and e.mode == mode
    io[FL.IO_ATT_VALID] = 1.0  # as the kernel writes it
    cnt[FL.CNT_FLAGS] = int(Flag.ST1_STALE)
    assert e.att_valid is True and e.flags == int(Flag.ST1_STALE)
    e.att_valid = False
    assert io[FL.IO_ATT_VALID] == 0.0


def test_counts_wait_in_the_kernel_arrays_until_read():
    e = Engine()
    e._cnt[FL.CNT_USED] = 7  # as a compiled call counts
    e._cnt[FL.CNT_INVALID_ST2] = 2
    e._undrained = True
    assert e.counters["siru_used"] == 7 and e.counters["st2_invalid"] == 2
    assert e._cnt[FL.CNT_USED] == 0 and e._cnt[FL.CNT_MASKED] == -1  # taken, reset
    assert e.counters["siru_used"] == 7  # not counted twice
    e._cnt[FL.CNT_GAPS] = 1  # the stream's flags read the gaps without taking the rest
    e._cnt[FL.CNT_USED] = 3
    e._undrained = True
    assert e.gyro_gaps() == 1 and e._cnt[FL.CNT_USED] == 3
    assert e.counters["gyro_gaps"] == 1 and e.counters["siru_used"] == 10
    assert e.gyro_gaps() == 1


def test_restored_bookkeeping_reaches_the_kernel_arrays():
    src = Engine()
    src.last_valid_st = {2: 40.0}
    src.nis_sum = {"st2": 12.5, "parity": 3.25}
    state = src.get_state()
    e = Engine()
    e.set_state(state)
    io = e._io
    assert io[FL.IO_LAST_ST1] == -math.inf and io[FL.IO_LAST_ST2] == 40.0
    assert io[FL.IO_NIS_SUM_ST] == 0.0 and io[FL.IO_NIS_SUM_ST + 1] == 12.5
    assert io[FL.IO_NIS_SUM_PAR] == 3.25


def test_release_inputs_match_the_separate_queries(tmp_path):
    sp = make_processor()
    fdi = sp.engine.fdi
    states = set()
    for topic, _ns, data in bias_step_messages(tmp_path):
        sp.feed(topic, data)
        eng = sp.engine
        bank, wake, every, on = fdi.release_inputs(eng)
        assert bank is fdi.kernel_bank()
        assert wake == fdi.wake_time() or (math.isnan(wake) and math.isnan(fdi.wake_time()))
        assert every == fdi.wake_on_tracker() and on == fdi.enabled(eng)
        states.add((fdi.state, bank is not None))
    assert ("alarm", True) in states and ("monitoring", False) in states
    assert any(s != "monitoring" and s != "alarm" for s, _b in states)
