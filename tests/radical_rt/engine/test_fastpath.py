"""The engine's compiled loop (radical_rt/engine/loop.py) against the Python oracle of its steps
(tests/oracles/reference_engine.py).

The two must give bit-identical results: same output messages byte for byte, same final UD
factors, estimates, counters and diagnostics. Each case runs the same input stream through a
stream processor with the product engine and with the oracle:

* a nominal 2006216 stream (slews, invalid and dropped tracker samples, parity sums, timing
  consider updates while the SIRU clock locks);
* the same stream damaged: a SIRU gap (warm start), malformed payloads, duplicates, time going
  backwards, a NaN tracker quaternion;
* a gyro fault: FDI alarm, isolation bank, exclusion, three-gyro operation (degraded mode).
"""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from radical_rt.apps.batch import make_processor
from radical_rt.contract.params import ParamTable
from radical_rt.engine import loop
from tests.oracles.dense_engine import make_processor as dense_make_processor
from tests.oracles.reference_engine import ReferenceEngine
from tests.support.streams import bias_step_messages, damaged, input_messages, make_archive


def run(messages, fast: bool, params=None):
    """Feed (topic, log_ns, payload) messages through the product engine (fast) or the Python
    oracle; return (output bytes, processor)."""
    table = ParamTable()
    table.set(params or {})
    sp = make_processor(table) if fast else dense_make_processor(ReferenceEngine, table)
    out = []
    for topic, _ns, data in messages:
        out += [(t, msgpack.packb(m)) for t, m in sp.feed(topic, data)]
    out += [(t, msgpack.packb(m)) for t, m in sp.end_stream(None)]
    return out, sp


def assert_same(messages, params=None):
    out_fast, fast = run(messages, True, params)
    out_ref, ref = run(messages, False, params)
    assert len(out_fast) == len(out_ref)
    for i, (a, b) in enumerate(zip(out_fast, out_ref, strict=True)):
        assert a == b, f"output {i} ({a[0]}) differs"
    ef, er = fast.engine, ref.engine
    for name in ("U", "d", "xp", "q", "omega", "N", "excluded", "dx"):
        assert np.array_equal(getattr(ef, name), getattr(er, name)), name
    assert dict(ef.counters) == dict(er.counters)
    assert dict(ef.nis_sum) == dict(er.nis_sum)
    assert ef.nis_locked == er.nis_locked  # (both sum each NIS while the time line is locked)
    assert ef.last_valid_st == er.last_valid_st
    assert list(ef.diag_last) == list(er.diag_last)
    for kind, (innov, sig, nis) in ef.diag_last.items():
        r_innov, r_sig, r_nis = er.diag_last[kind]
        assert np.array_equal(innov, r_innov) and np.array_equal(sig, r_sig) and nis == r_nis, kind
    assert (ef.flags, ef.mode, ef.t, ef.locked_since) == (er.flags, er.mode, er.t, er.locked_since)
    return fast, out_fast


@pytest.fixture(scope="module")
def nominal(tmp_path_factory):
    return input_messages(make_archive(tmp_path_factory.mktemp("fastpath"), "n", seed=3,
                                       duration=400))


@pytest.mark.parametrize("consider", [True, False])
def test_nominal_stream_is_bit_identical(nominal, consider, monkeypatch):
    """The slews after 240 s come while the SIRU clock is still locking: tracker updates with the
    timing term, as Schmidt consider updates (default) or, with the consider threshold raised,
    as plain correlated updates."""
    calls = []
    kernel = loop.run_release
    monkeypatch.setattr(loop, "run_release", lambda *a: (calls.append(1), kernel(*a))[1])
    sp, out = assert_same(nominal, None if consider else {"timing_consider_s": 1.0})
    c = sp.engine.counters
    # the run exercised what the fast path hands back to Python and what it does itself
    assert len(calls) > 1000
    assert c["st1_used"] > 1000 and c["st2_used"] > 1000 and c["parity_used"] > 100
    n_consider = c["st1_consider"] + c["st2_consider"]
    assert (n_consider > 500) if consider else (n_consider == 0)
    assert c["st1_invalid"] + c["st2_invalid"] > 0
    assert sum(t == "tlm/medium" for t, _ in out) >= 350


def test_damaged_stream_is_bit_identical(nominal):
    sp, _ = assert_same(damaged(nominal))
    assert sp.engine.counters["gyro_gaps"] >= 1
    assert sum(sp.rejected.values()) >= 5


@pytest.fixture(scope="module")
def fault(tmp_path_factory):
    """300 s, gyro B bias step of 5 deg/hr at 120 s (FDI alarm, isolation, exclusion)."""
    return bias_step_messages(tmp_path_factory.mktemp("fastpath_fault"))


def test_fault_isolation_is_bit_identical(fault):
    sp, _ = assert_same(fault)
    e = sp.engine
    assert e.fdi.counts["alarms"] >= 1 and e.fdi.counts["isolations"] >= 1
    assert e.excluded[1] and e.mode == "degraded"


def test_deep_copy_continues_bit_identically(nominal):
    """A copy (copy.deepcopy, as perf/fdi_table.py forks runs) re-packs its arrays: the copy and
    the original continue identically, and the copy's kernels write the copy's attributes."""
    import copy

    half = len(nominal) // 2
    _, sp = run(nominal[:half], True)
    twin = copy.deepcopy(sp)
    e, t = sp.engine, twin.engine
    assert not np.shares_memory(e.U, t.U) and np.shares_memory(t.U, t._fb)
    for topic, _ns, data in nominal[half:]:
        a, b = sp.feed(topic, data), twin.feed(topic, data)
        assert [msgpack.packb(m) for _, m in a] == [msgpack.packb(m) for _, m in b]
    assert np.array_equal(e.U, t.U) and np.array_equal(e.xp, t.xp)
    assert dict(e.counters) == dict(t.counters)


def test_compiled_intake_equals_the_general_decoding(nominal, monkeypatch):
    """The damaged stream fed as msgpack bytes (siru and tracker messages decoded, checked and
    queued by the compiled intakes, radical_rt.stream.siru_wire / tracker_queue) and as decoded maps
    (msgpack, decode_siru / decode_tracker and the same checks): the same outputs byte for
    byte, the same rejections, the same final state."""
    from radical_rt.stream import processor as stream
    msgs = damaged(nominal)
    as_maps = [(t, ns, msgpack.unpackb(d) if d[:1] != b"\xc1" else d) for t, ns, d in msgs]
    general = []
    for name in ("decode_siru", "decode_tracker"):
        f = getattr(stream, name)
        monkeypatch.setattr(stream, name, lambda *a, f=f: (general.append(1), f(*a))[1])
    out_b, sp_b = run(msgs, True)
    n_general_bytes = len(general)
    out_m, sp_m = run(as_maps, True)
    assert n_general_bytes < 20 < len(general) - n_general_bytes  # the bytes took the kernels
    assert out_b == out_m
    assert dict(sp_b.rejected) == dict(sp_m.rejected) and sum(sp_b.rejected.values()) >= 5
    assert {"duplicate", "time_backwards", "nonfinite"} <= set(sp_b.rejected)
    assert sp_b.late_dropped == sp_m.late_dropped and sp_b.counters() == sp_m.counters()
    for name in ("U", "d", "xp", "q"):
        assert np.array_equal(getattr(sp_b.engine, name), getattr(sp_m.engine, name)), name


def test_packet_change_mid_stream_is_bit_identical(nominal):
    """New packets mid-stream (as set_packets does: a new map): the fast path's cached packet
    schedule follows, so both paths emit the same packets, decimated ones included."""
    from radical_rt.stream.telemetry import parse_packets
    half = len(nominal) // 2

    def switched(fast: bool):
        sp = make_processor(ParamTable()) if fast else dense_make_processor(ReferenceEngine)
        out = []
        for i, (topic, _ns, data) in enumerate(nominal):
            if i == half:
                sp.packets = parse_packets({"medium": {"decimation": 3},
                                            "large": {"period_s": 0.5}})
            out += [(t, msgpack.packb(m)) for t, m in sp.feed(topic, data)]
        return out

    out_fast, out_ref = switched(True), switched(False)
    assert out_fast == out_ref
    late = [t for t, _ in out_fast[len(out_fast) // 2:]]
    assert late.count("tlm/medium") > 2 * late.count("tlm/large") > 0
