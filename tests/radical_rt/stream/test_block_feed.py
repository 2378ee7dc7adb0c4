"""StreamProcessor.feed_many (the compiled block intake, radical_rt.stream.intake_block) against
feed message by message: the same output bytes, counters, flags and engine state on streams
outside the common case (damage, a forged second ST1 source, a gap, jumps, a gyro gap) and with
packet configurations that take each of the block's paths (sample packets as rows, decimated,
with a field the rows do not carry, none). The golden records check the same on their cases
(tests/system/test_golden.py, both feeds)."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from radical_rt.apps.batch import make_processor
from radical_rt.stream.telemetry import parse_packets
from tests.support.node import input_messages, make_archive
from tests.support.streams import damaged

ARCSEC = math.pi / 648000


@pytest.fixture(scope="module")
def msgs(tmp_path_factory):
    return input_messages(make_archive(tmp_path_factory.mktemp("bf"), "a60", seed=3, duration=60))


def _forged(data: bytes) -> bytes:
    m = msgpack.unpackb(data)
    q = (Rotation.from_rotvec([20 * ARCSEC, 0.0, 0.0]) * Rotation.from_quat(m["q"])).as_quat()
    return msgpack.packb({"v": 1, "t_bus": m["t_bus"] + 1e-4, "q": [float(x) for x in q],
                          "n_stars": m["n_stars"], "valid": m["valid"]})


def _shift(data: bytes, dt: float) -> bytes:
    m = msgpack.unpackb(data)
    m["t_bus"] = [t + dt for t in m["t_bus"]] if isinstance(m["t_bus"], list) else m["t_bus"] + dt
    return msgpack.packb(m)


def _variant(msgs, name):
    """(topic, payload) of the base stream changed as ``name`` says."""
    base = [(t, d) for t, _ns, d in msgs]
    n = len(base)
    if name == "plain":
        return base
    if name == "damaged":
        return [(t, d) for t, _ns, d in damaged(msgs)]
    if name == "forged_st1":  # a second ST1 source from the middle on: conflict, then its end
        out = []
        for i, (t, d) in enumerate(base):
            out.append((t, d))
            if t == "st1" and n // 3 <= i < n // 2:
                out.append(("st1", _forged(d)))
        return out
    if name == "gaps":  # lost siru batches (input gap), a hole in every input (gyro gap)
        keep = []
        for i, (t, d) in enumerate(base):
            if t == "siru" and n // 4 <= i < n // 4 + 6:
                continue
            if n // 2 <= i < n // 2 + 60:
                continue
            keep.append((t, d))
        return keep
    if name == "jumps":  # one message far ahead, then a confirmed forward jump of 30 s
        out = []
        for i, (t, d) in enumerate(base):
            if i == n // 5:
                out.append((t, _shift(d, 1e6)))
            out.append((t, _shift(d, 30.0) if i >= 2 * n // 3 else d))
        return out
    if name == "temps":  # temp messages the block takes and ones it leaves to Python
        return _odd_temps(base)
    raise ValueError(name)


def _odd_temps(base):
    """The stream with temp messages in every form: fields missing, integer, float32 and
    non-finite values, an unknown key, repeated and backward times, a wrong version, bytes
    after the map, one far ahead (a jump candidate), garbage."""
    out, k = [], 0
    for t, d in base:
        out.append((t, d))
        if t != "temp":
            continue
        m = msgpack.unpackb(d)
        k += 1
        form = k % 12
        odd = dict(m, t_bus=m["t_bus"] + 0.25)
        if form == 1:
            odd.pop("st2_baseplate_C")
        elif form == 2:
            odd = {"t_bus": odd["t_bus"], "v": 1, "siru_C": 31.5}  # keys in another order
        elif form == 3:
            odd["siru_C"] = 20  # an integer
        elif form == 4:
            out.append((t, msgpack.packb(odd, use_single_float=True)))  # float32
            continue
        elif form == 5:
            odd["st1_baseplate_C"] = float("nan")
        elif form == 6:
            odd["heater"] = 1.0  # a key outside the contract
        elif form == 7:
            out.append((t, d))  # the same message again
            continue
        elif form == 8:
            odd["t_bus"] = m["t_bus"] - 3.0  # back in time
        elif form == 9:
            odd["v"] = 2
        elif form == 10:
            out.append((t, msgpack.packb(odd) + b"\x00"))
            continue
        elif form == 11:
            odd["t_bus"] = m["t_bus"] + 1e6  # far ahead
        else:
            out.append((t, b"\x85garbage"))
            continue
        out.append((t, msgpack.packb(odd)))
    return out


PACKETS = {
    "default": None,
    "rows_decimated": {"small": {"decimation": 2, "trigger": "sample",
                                 "fields": ["seq", "t", "q_body_from_inertial", "omega_body",
                                            "flags", "mode"]},
                       "medium": {"period_s": 0.05, "trigger": "sample"}},
    "python_fields": {"small": {"period_s": 0.1, "trigger": "sample",
                                "fields": ["seq", "t", "q_body_from_inertial", "est"]}},
    "no_sample": {"small": {"period_s": 0.1, "trigger": "window"}},
}


def _run(stream, packets, chunk):
    sp = make_processor()
    if packets is not None:
        sp.packets = parse_packets(packets)
    out = []
    if chunk is None:
        for t, d in stream:
            out += sp.feed(t, d)
    else:
        for c in range(0, len(stream), chunk):
            out += sp.feed_many(stream[c:c + chunk])
    out += sp.end_stream(None)
    e = sp.engine
    state = (sp.counters(), dict(sp.rejected), sp.flags, e.mode, e.t, e.q.tobytes(),
             e.U.tobytes(), e.d.tobytes(), e.xp.tobytes(), dict(e.counters),
             list(sp.temps.items()), dict(sp.last_t))
    return [(k, msgpack.packb(m)) for k, m in out], state


@pytest.mark.parametrize("name", ["plain", "damaged", "forged_st1", "gaps", "jumps", "temps"])
def test_streams_same_as_message_by_message(msgs, name):
    stream = _variant(msgs, name)
    ref_out, ref_state = _run(stream, None, None)
    for chunk in (5, 256):
        out, state = _run(stream, None, chunk)
        assert state == ref_state, (name, chunk)
        assert len(out) == len(ref_out) and out == ref_out, (name, chunk)
    assert len(ref_out) > 100


@pytest.mark.parametrize("packets", sorted(PACKETS))
def test_packet_configurations_same_as_message_by_message(msgs, packets):
    stream = _variant(msgs, "damaged")
    ref_out, ref_state = _run(stream, PACKETS[packets], None)
    out, state = _run(stream, PACKETS[packets], 256)
    assert state == ref_state
    assert out == ref_out
    assert sum(k == "tlm/small" for k, _m in out) > 50


def test_feed_many_takes_the_block_path(msgs, monkeypatch):
    """The common case goes through the kernel (not message by message): counted calls."""
    from radical_rt.stream import block_feed
    calls, fed = [0], [0]
    real_call, real_feed = block_feed.BlockFeed._block_call, make_processor().__class__.feed

    def count_call(self, *a):
        calls[0] += 1
        return real_call(self, *a)

    def count_feed(self, *a):
        fed[0] += 1
        return real_feed(self, *a)

    monkeypatch.setattr(block_feed.BlockFeed, "_block_call", count_call)
    sp = make_processor()
    monkeypatch.setattr(type(sp), "feed", count_feed)
    stream = _variant(msgs, "plain")
    for c in range(0, len(stream), 256):
        sp.feed_many(stream[c:c + 256])
    siru = sum(t == "siru" for t, _d in stream)
    assert fed[0] <= 5  # only what Python must take (the stream's first messages) goes through feed
    assert 0 < calls[0] < siru  # several siru messages a call
    assert np.isfinite(sp.engine.t)
