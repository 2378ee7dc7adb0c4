"""The compiled siru decoder (radical_rt.stream.siru_wire) against the general path (msgpack +
decode_siru): the same columns for every message it accepts, and a fallback for everything the
general path rejects or that is not in the plain layout."""

from __future__ import annotations

import math
import struct

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radical_rt.stream.packets import InputError, decode_siru, unpack
from radical_rt.stream.processor import StreamProcessor
from radical_rt.stream.siru_wire import SiruWire

KEYS = ("v", "t_bus", "tt", "dtheta", "status")


def _general(payload: bytes):
    """The general path: columns, or the InputError reason."""
    try:
        return decode_siru(unpack(payload), 4)
    except InputError as exc:
        return exc.reason


def _same(fast, general) -> None:
    assert not isinstance(general, str), general
    for a, b in zip(fast, general, strict=True):
        assert a.dtype == b.dtype and a.shape == b.shape
        assert np.array_equal(a, b)
        assert a.flags.c_contiguous


@st.composite
def siru_maps(draw):
    """Valid siru maps with mixed number encodings and a random key order."""
    k = draw(st.integers(1, 40))
    t0 = draw(st.floats(-1e6, 1e6, allow_nan=False))
    steps = draw(st.lists(st.floats(0.0, 1.0, allow_nan=False), min_size=k, max_size=k))
    t_bus = list(np.cumsum([t0] + steps[:-1]).tolist())
    if draw(st.booleans()):  # integer times are numbers too
        t_bus = [int(math.floor(x)) for x in sorted(t_bus)]
    # valid increments: |dθ| ≤ MAX_DTHETA_RAD (1 rad), integers and float32 included
    num = st.one_of(st.floats(-1e-2, 1e-2, allow_nan=False), st.integers(-1, 1),
                    st.floats(-1.0, 1.0, allow_nan=False))
    dtheta = [draw(st.lists(num, min_size=4, max_size=4)) for _ in range(k)]
    tt = draw(st.lists(st.integers(0, 2**32 - 1), min_size=k, max_size=k))
    status = draw(st.lists(st.integers(0, 2**40), min_size=k, max_size=k))
    msg = {"v": 1, "t_bus": t_bus, "tt": tt, "dtheta": dtheta, "status": status}
    order = draw(st.permutations(KEYS))
    return {key: msg[key] for key in order}, draw(st.booleans())


@settings(max_examples=300, deadline=None)
@given(siru_maps())
def test_valid_messages_decode_as_the_general_path(case):
    msg, single = case
    payload = msgpack.packb(msg, use_single_float=single)
    fast = SiruWire(4, capacity=4).decode(payload)  # small buffers: growth is exercised too
    assert fast is not None
    _same(fast, _general(payload))


def _be_int(code: int, fmt: str, v: int) -> bytes:
    return bytes([code]) + struct.pack(">" + fmt, v)


def test_wide_encodings_of_small_values():
    """Non-minimal encodings (map16, array16/32, str8, int64, uint64, float32) mean the same."""
    def ints(vals, code, fmt):
        return b"\xdc" + struct.pack(">H", len(vals)) + b"".join(_be_int(code, fmt, v) for v in vals)

    def floats(vals):
        return b"\xdd" + struct.pack(">I", len(vals)) + b"".join(b"\xca" + struct.pack(">f", v)
                                                                 for v in vals)

    def key(name):
        return b"\xd9" + bytes([len(name)]) + name.encode()

    rows = b"".join(b"\x94" + b"".join(_be_int(0xD3, "q", v) for v in (-1, 0, 1, -1))  # (|dθ| ≤ 1 rad)
                    for _ in range(2))
    payload = (b"\xde\x00\x05" + key("status") + ints([0, 3], 0xCF, "Q")
               + key("dtheta") + b"\x92" + rows + key("v") + _be_int(0xD0, "b", 1)
               + key("tt") + ints([5, 2**32 - 1], 0xCE, "I") + key("t_bus") + floats([1.5, 2.25]))
    fast = SiruWire(4).decode(payload)
    assert fast is not None
    _same(fast, _general(payload))
    assert fast[2][0].tolist() == [-1.0, 0.0, 1.0, -1.0]


def _ok_map(**changes):
    msg = {"v": 1, "t_bus": [1.0, 1.01], "tt": [10, 20], "dtheta": [[0.1] * 4, [0.2] * 4],
           "status": [0, 1]}
    msg.update(changes)
    return {k: v for k, v in msg.items() if v is not None}


@pytest.mark.parametrize("changes, reason", [
    (dict(dtheta=[[0.1] * 4, [math.nan] * 4]), "nonfinite"),
    (dict(dtheta=[[0.1] * 4, [0.1, 0.1, 0.1, 1.5]]), "bad_value"),  # beyond 1 rad per sample
    (dict(dtheta=[[0.1] * 4, [0.1, 0.1, 0.1, -1e300]]), "bad_value"),
    (dict(t_bus=[1.0, math.inf]), "nonfinite"),
    (dict(tt=[10, 2**32]), "bad_value"),
    (dict(tt=[10, 2**64 - 1]), "bad_value"),
    (dict(status=[0, -1]), "bad_value"),
    (dict(t_bus=[1.0, 0.5]), "time_backwards"),
    (dict(tt=[10, 20.0]), "bad_type"),
    (dict(tt=[10, True]), "bad_type"),
    (dict(dtheta=[[0.1] * 4, [0.2] * 3]), "bad_shape"),
    (dict(status=[0]), "bad_shape"),
    (dict(t_bus=[], tt=[], dtheta=[], status=[]), "bad_shape"),
    (dict(tt=None), "missing_field"),
    (dict(v=2), "bad_version"),
])
def test_rejected_messages_fall_back(changes, reason):
    """What the general path rejects, the fast path leaves to it (and the reason is its)."""
    payload = msgpack.packb(_ok_map(**changes))
    assert SiruWire(4).decode(payload) is None
    assert _general(payload) == reason


@pytest.mark.parametrize("payload", [
    msgpack.packb(_ok_map(extra=3)),  # another key: valid, but not the plain layout
    msgpack.packb(_ok_map(status=[True, False])),  # bools: numpy reads them, the fast path not
    msgpack.packb(_ok_map(v=1.0)),
    msgpack.packb(_ok_map(status=[0.0, 1.0])),
    msgpack.packb(_ok_map(t_bus=[1, 2**64 - 1])),
])
def test_other_layouts_fall_back_and_still_decode(payload):
    assert SiruWire(4).decode(payload) is None
    assert not isinstance(_general(payload), str)


def test_duplicate_key_and_trailing_bytes_fall_back():
    good = msgpack.packb(_ok_map())
    assert SiruWire(4).decode(good) is not None
    assert SiruWire(4).decode(good + b"\x00") is None  # msgpack: extra data
    assert _general(good + b"\x00") == "malformed"
    m = _ok_map()
    entries = [("v", 1), ("t_bus", m["t_bus"]), ("v", 1), ("dtheta", m["dtheta"]),
               ("status", m["status"])]  # five entries, "v" twice, no "tt"
    dup = b"\x85" + b"".join(msgpack.packb(k) + msgpack.packb(v) for k, v in entries)
    assert SiruWire(4).decode(dup) is None
    assert _general(dup) == "missing_field"


def test_corrupted_payloads_never_accepted_differently():
    """Seeded byte flips and truncations of a real message: the fast path either falls back or
    agrees exactly with the general path (it never accepts what msgpack/decode_siru reject)."""
    rng = np.random.default_rng(7)
    msg = _ok_map(t_bus=[10.0 + 0.01 * i for i in range(10)], tt=list(range(0, 100000, 10000)),
                  dtheta=[[1e-5 * i, -2e-5, 3e-5, 0.0] for i in range(10)], status=[0] * 10)
    good = msgpack.packb(msg)
    wire, accepted, fell_back = SiruWire(4), 0, 0
    for _ in range(3000):
        buf = bytearray(good)
        for _ in range(int(rng.integers(1, 4))):
            buf[int(rng.integers(len(buf)))] = int(rng.integers(256))
        if rng.random() < 0.2:
            buf = buf[:int(rng.integers(len(buf)))]
        payload = bytes(buf)
        fast = wire.decode(payload)
        if fast is None:
            fell_back += 1
            continue
        accepted += 1
        _same(fast, _general(payload))
    assert accepted > 100 and fell_back > 100  # both branches were exercised


def test_stream_counts_a_rejected_message_as_before():
    """Through the stream processor: a NaN batch is rejected with its reason, state untouched."""
    sp = StreamProcessor()
    sp.feed("siru", msgpack.packb(_ok_map(dtheta=[[0.1] * 4, [math.nan] * 4])))
    assert dict(sp.rejected) == {"nonfinite": 1}
    assert len(sp.gyro_q) == 0 and sp.clock.counters.get("samples", 0) == 0
