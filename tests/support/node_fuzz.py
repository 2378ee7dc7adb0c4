"""Seeded payload fuzz for the node tests: each input message corrupted, truncated, replayed or
left alone (:func:`fuzz_stream`), the corruption of one payload (:func:`corrupt`)."""

from __future__ import annotations

import math
import random

import msgpack


def corrupt(rng: random.Random, topic: str, msg: dict, history: dict[str, list[bytes]]) -> bytes | None:
    """One invalid variant of a clean message (None if the chosen case does not apply)."""
    m = dict(msg)
    case = rng.randrange(16)
    if case == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(0, 48)))
    if case == 1:
        raw = msgpack.packb(msg)
        return raw[:rng.randrange(0, len(raw))]
    if case == 2:
        return msgpack.packb(msg) + b"\x00"
    if case == 3:
        return msgpack.packb(rng.choice([[1, 2], 3, "siru", None, 2.5, True]))
    if case == 4:
        if rng.random() < 0.3:
            del m["v"]
        else:
            m["v"] = rng.choice([2, 0, None, "1", 1.5])
        return msgpack.packb(m)
    if case == 5:
        required = {"siru": ["t_bus", "tt", "dtheta", "status"], "temp": ["t_bus"]}.get(
            topic, ["t_bus", "q", "n_stars", "valid"])
        del m[rng.choice(required)]
        return msgpack.packb(m)
    if case == 6:  # wrong types
        key = rng.choice(list(k for k in m if k != "v"))
        m[key] = rng.choice(["text", {"a": 1}, [["x"]], b"\x01"])
        return msgpack.packb(m)
    if case == 7:  # wrong shapes
        if topic == "siru":
            k = rng.choice(["dtheta3", "ragged", "short"])
            if k == "dtheta3":
                m["dtheta"] = [row[:3] for row in m["dtheta"]]
            elif k == "ragged":
                m["dtheta"] = [row if i else row[:2] for i, row in enumerate(m["dtheta"])]
            else:
                m["status"] = m["status"][:-1]
        elif topic in ("st1", "st2"):
            m["q"] = m["q"][:3] if rng.random() < 0.5 else m["q"] + [0.0]
        else:
            m["t_bus"] = [m["t_bus"]]
        return msgpack.packb(m)
    if case == 8:  # NaN / Inf
        bad = rng.choice([math.nan, math.inf, -math.inf])
        if topic == "siru":
            if rng.random() < 0.5:
                m["t_bus"] = [bad] + m["t_bus"][1:]
            else:
                m["dtheta"] = [list(r) for r in m["dtheta"]]
                m["dtheta"][rng.randrange(len(m["dtheta"]))][rng.randrange(4)] = bad
        elif topic in ("st1", "st2"):
            m["q"] = list(m["q"])
            m["q"][rng.randrange(4)] = bad
        else:
            m["t_bus"] = bad
        return msgpack.packb(m)
    if case == 9 and topic in ("st1", "st2"):  # non-unit quaternion
        m["q"] = [rng.choice([1.5, 0.5, 0.0]) * x for x in m["q"]]
        return msgpack.packb(m)
    if case in (10, 11) and history.get(topic):  # time going backwards (+ extra fields)
        old = msgpack.unpackb(rng.choice(history[topic]))
        old["extra_field"] = [1, 2, 3]
        return msgpack.packb(old)
    if case == 12 and history.get(topic):  # exact duplicate of the previous message
        return history[topic][-1]
    if case == 13 and topic == "siru":
        k = rng.choice(["tt_neg", "tt_wrap", "status_neg", "empty", "tt_float", "t_desc"])
        if k == "tt_neg":
            m["tt"] = [-1] + m["tt"][1:]
        elif k == "tt_wrap":
            m["tt"] = [2**32] + m["tt"][1:]
        elif k == "status_neg":
            m["status"] = [-1] + m["status"][1:]
        elif k == "tt_float":
            m["tt"] = [float(x) for x in m["tt"]]
        elif k == "t_desc":
            m["t_bus"] = m["t_bus"][::-1]
        else:
            m = {**m, "t_bus": [], "tt": [], "dtheta": [], "status": []}
        return msgpack.packb(m)
    if case == 14 and topic in ("st1", "st2"):
        m[rng.choice(["n_stars", "valid"])] = rng.choice([-3, "yes", 1.5, None])
        return msgpack.packb(m)
    return None


def fuzz_stream(msgs, seed: int, rate: float = 0.25):
    """Clean messages in order with invalid ones inserted; some clean ones carry unknown fields.
    Returns (stream of (topic, payload), number of invalid messages inserted)."""
    rng = random.Random(seed)
    history: dict[str, list[bytes]] = {}
    out, n_bad = [], 0
    for topic, _ns, data in msgs:
        msg = msgpack.unpackb(data)
        while rng.random() < rate:
            if rng.random() < 0.05 and topic != "temp":  # a siru message on a tracker key, or back
                out.append(("st2" if topic == "siru" else "siru", data))
                n_bad += 1
                continue
            bad = corrupt(rng, topic, msg, history)
            if bad is not None:
                out.append((topic, bad))
                n_bad += 1
            if rng.random() < 0.1:
                out.append(("unknown_topic", b"junk"))  # not an input: ignored, not counted
        if rng.random() < 0.05:  # unknown fields are ignored by readers (CONTRACT)
            out.append((topic, msgpack.packb({**msg, "unknown": {"x": [1.0, 2.0]}})))
        else:
            out.append((topic, data))
        history.setdefault(topic, []).append(data)
    return out, n_bad
