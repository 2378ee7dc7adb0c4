"""The compiled temp decoder (radical_rt.stream.temp_wire.parse_temp) against Python's
decode_temp: a plain message gives the same values bit for bit; every other form is refused, so
that Python's decoder (which names the problem or takes what the contract allows) decides."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from radical_rt.stream.packets import InputError, decode_temp, unpack
from radical_rt.stream.temp_wire import TEMP_COLS, TEMP_NAMES, parse_temp

BASE = {"v": 1, "t_bus": 1234.5678901234, "st1_baseplate_C": 19.875, "st2_baseplate_C": -3.25e-7,
        "siru_C": 25.000000000000004}


def _parse(payload: bytes) -> tuple[bool, list[float]]:
    row = np.full(TEMP_COLS, -1.0)
    ok = parse_temp(np.frombuffer(payload, np.uint8), row)
    return bool(ok), row.tolist()


PLAIN = {
    "all": BASE,
    "reordered": {"siru_C": 1.5, "t_bus": 2.0, "v": 1},
    "t_only": {"v": 1, "t_bus": 7.0},
    "two": {"v": 1, "t_bus": 7.0, "st2_baseplate_C": 1e300, "st1_baseplate_C": -273.15},
}


@pytest.mark.parametrize("name", sorted(PLAIN))
def test_plain_messages_decode_as_python_does(name):
    payload = msgpack.packb(PLAIN[name])
    ok, row = _parse(payload)
    assert ok
    t, values = decode_temp(unpack(payload))
    assert row[0] == t
    for name_, v in zip(TEMP_NAMES, row[1:], strict=True):
        if name_ in values:
            assert v == values[name_] and math.copysign(1, v) == math.copysign(1, values[name_])
        else:
            assert math.isnan(v)


NOT_PLAIN = {
    "integer_value": msgpack.packb(dict(BASE, siru_C=20)),
    "integer_time": msgpack.packb(dict(BASE, t_bus=1000)),
    "float32": msgpack.packb(BASE, use_single_float=True),
    "nan": msgpack.packb(dict(BASE, st1_baseplate_C=float("nan"))),
    "inf_time": msgpack.packb(dict(BASE, t_bus=float("inf"))),
    "unknown_key": msgpack.packb(dict(BASE, heater=1.0)),
    "no_time": msgpack.packb({"v": 1, "siru_C": 1.0}),
    "no_version": msgpack.packb({"t_bus": 1.0, "siru_C": 1.0}),
    "version_2": msgpack.packb(dict(BASE, v=2)),
    "version_float": msgpack.packb(dict(BASE, v=1.0)),
    "trailing_byte": msgpack.packb(BASE) + b"\x00",
    "truncated": msgpack.packb(BASE)[:-3],
    "repeated_key": b"\x83\xa1v\x01\xa5t_bus\xcb" + np.float64(1.0).byteswap().tobytes()
                    + b"\xa5t_bus\xcb" + np.float64(2.0).byteswap().tobytes(),
    "array": msgpack.packb([1, 2.0]),
    "empty": b"",
    "garbage": b"\x85garbage",
}


@pytest.mark.parametrize("name", sorted(NOT_PLAIN))
def test_other_forms_are_left_to_python(name):
    ok, _row = _parse(NOT_PLAIN[name])
    assert not ok


def test_python_still_takes_what_the_contract_allows():
    """Forms the kernel refuses that Python accepts (so the general path is needed)."""
    for name in ("integer_value", "float32", "unknown_key", "repeated_key"):
        t, values = decode_temp(unpack(NOT_PLAIN[name]))
        assert math.isfinite(t) and all(math.isfinite(v) for v in values.values())
    for name in ("nan", "no_time", "version_2", "trailing_byte", "garbage"):
        with pytest.raises(InputError):
            decode_temp(unpack(NOT_PLAIN[name]))
