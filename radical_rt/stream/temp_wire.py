"""The compiled decoder of a plain ``temp`` message (CONTRACT §3), for the block intake
(:mod:`radical_rt.stream.intake_block`).

A plain ``temp`` message is a msgpack map of ``v`` = 1, ``t_bus`` and any of the three
temperatures, each once, every number a finite float64 (what the simulator and msgpack-python
write for Python floats), nothing after the map. :func:`parse_temp` reads one into a row
``(t_bus [s], st1_baseplate_C, st2_baseplate_C, siru_C [°C])`` with NaN for a temperature the
message does not carry; anything else (other keys, integers, float32, non-finite values, a
second map) is not plain and goes to Python's
:func:`radical_rt.stream.packets.decode_temp`, which also names what is wrong. The values are
the message's bits, as msgpack gives them to Python.
"""

from __future__ import annotations

import numpy as np

from radical_rt._jit import kernel
from radical_rt.stream.siru_wire import be_uint

#: the temperatures of a row after t_bus, in the order decode_temp puts them in its map
TEMP_NAMES = ("st1_baseplate_C", "st2_baseplate_C", "siru_C")
#: columns of a row: t_bus and the three temperatures
TEMP_COLS = 1 + len(TEMP_NAMES)


@kernel
def _is(buf, p, text):
    """Whether buf[p:p + len(text)] holds the ASCII codes of text (uint8 (m,))."""
    for c in range(text.shape[0]):
        if buf[p + c] != text[c]:
            return False
    return True


_V = np.frombuffer(b"v", np.uint8)
_T_BUS = np.frombuffer(b"t_bus", np.uint8)
_ST1 = np.frombuffer(b"st1_baseplate_C", np.uint8)
_ST2 = np.frombuffer(b"st2_baseplate_C", np.uint8)
_SIRU = np.frombuffer(b"siru_C", np.uint8)


@kernel
def _temp_key(buf, p, n):
    """The fixstr key at p: (column of the row (0 t_bus, 1–3 the temperatures), 4 for v, −1 for
    any other key or not a fixstr; next position)."""
    if p >= n or not 0xA0 <= buf[p] <= 0xBF:
        return -1, p
    m, p = buf[p] - 0xA0, p + 1
    if p + m > n:
        return -1, p
    key = -1
    if m == 1 and _is(buf, p, _V):
        key = 4
    elif m == 5 and _is(buf, p, _T_BUS):
        key = 0
    elif m == 15 and _is(buf, p, _ST1):
        key = 1
    elif m == 15 and _is(buf, p, _ST2):
        key = 2
    elif m == 6 and _is(buf, p, _SIRU):
        key = 3
    return key, p + m


@kernel
def parse_temp(buf, row):
    """Decode the msgpack bytes buf (uint8 (n,)) of a plain temp message (module docstring) into
    row (TEMP_COLS,): t_bus [s] and the temperatures [°C] (NaN: absent). Returns whether it was
    plain (not: row is undefined, take the general path)."""
    n = buf.shape[0]
    if n < 1 or not 0x82 <= buf[0] <= 0x85:  # fixmap of 2 to 5
        return False
    for c in range(1, TEMP_COLS):
        row[c] = np.nan
    p, seen = 1, 0
    for _ in range(buf[0] - 0x80):
        key, p = _temp_key(buf, p, n)
        if key < 0 or seen & (1 << key):
            return False
        seen |= 1 << key
        if key == 4:  # v: the positive fixint 1
            if p >= n or buf[p] != 0x01:
                return False
            p += 1
            continue
        if p + 9 > n or buf[p] != 0xCB:
            return False
        x = np.uint64(be_uint(buf, p + 1, 8)).view(np.float64)
        if not np.isfinite(x):
            return False
        row[key] = x
        p += 9
    return p == n and seen & 0b10001 == 0b10001  # v and t_bus present
