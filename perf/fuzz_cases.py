"""Seeded fuzz cases for the command and checkpoint harness (:mod:`perf.fuzz_commands`).

Every case is a pure function of (seed, index): :func:`command_case` gives a request map and
whether it is *valid* (inside every documented range: it must be applied, and nothing may raise
or hang afterwards) or *invalid* (outside a range, wrong type, unknown name: it must be refused
and change nothing). :func:`checkpoint_case` damages a good checkpoint file: byte-level damage
(flips, truncation, junk) or a field set to an extreme value with the checksum recomputed, so
that the field validation itself is exercised.
"""

from __future__ import annotations

import hashlib
import math
import random
from typing import Any

import msgpack
import numpy as np

from radical_rt.apps.commands import BUMP_MAX_SI
from radical_rt.contract.params import CHOICES, RANGES, Params
from radical_rt.stream.telemetry import CATALOGUE, DECIMATION_MAX, PERIOD_RANGE_S

N_GYRO = 4
GROUP_SIZE = {"b": 4, "lam": 4, "mu": 4, "du": 4, "dv": 4, "phi2": 3}
EXTREMES = [2**63 - 1, -(2**63), 2**64 - 1, math.nan, math.inf, -math.inf, 1e300, -1e300, 5e-324,
            -5e-324, 0, -1, 0.0, -0.0, True, False, None, "x", "", [], {}, [1.0] * 5, {"a": 1}]
_DEFAULTS = Params()


def _rng(seed: int, index: int, salt: int) -> random.Random:
    return random.Random(hash((seed, index, salt)) & 0xFFFFFFFFFFFF)


def _number_in(v: Any, lo: float, hi: float) -> bool:
    """Whether v is a valid number of [lo, hi] (what the validators accept)."""
    return (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(float(v))
            and lo <= v <= hi) if not (isinstance(v, int) and abs(v) > 2**1000) else False


def _extreme_in(r: random.Random, lo: float, hi: float, integer: bool) -> float | int:
    """lo, hi, or a log-uniform value between (valid but extreme)."""
    u = r.random()
    if u < 0.35:
        v = lo
    elif u < 0.7:
        v = hi
    else:
        a = max(lo, 1e-12 if not integer else 1)
        v = a * (hi / a) ** r.random() if hi > a else hi
    return int(round(v)) if integer else float(v)


def _valid_param(r: random.Random, name: str) -> Any:
    d = getattr(_DEFAULTS, name)
    if isinstance(d, bool):
        return r.random() < 0.5
    if isinstance(d, str):
        return r.choice(CHOICES[name])
    lo, hi = RANGES[name]
    if isinstance(d, list):
        return [_extreme_in(r, lo, hi, False) for _ in d]
    return _extreme_in(r, lo, hi, isinstance(d, int))


def _invalid_param(r: random.Random, name: str) -> Any:
    d = getattr(_DEFAULTS, name)
    if isinstance(d, bool):
        return r.choice([0, 1, "true", None, 1.0])
    if isinstance(d, str):
        return r.choice(["", "x" * 200, 3, None, d.upper() + "!"])
    lo, hi = RANGES[name]
    bad = [lo - max(abs(lo), 1e-3) * 0.5 - 1e-9, hi * 10 + 1, -1e-300 if lo == 0 else lo / 2]
    bad += [v for v in EXTREMES if not _number_in(v, lo, hi)]
    if isinstance(d, int) and not isinstance(d, bool):
        bad.append(lo + 0.5)
    v = r.choice(bad)
    if isinstance(d, list):
        good = [_extreme_in(r, lo, hi, False) for _ in d]
        return r.choice([good[:-1], good + [1.0], [*good[:-1], v], v])
    return v


def command_case(seed: int, index: int) -> tuple[dict[str, Any], bool]:
    """(request map, valid) for command number ``index``."""
    r = _rng(seed, index, 1)
    valid = r.random() < 0.5
    names = list(RANGES) + [n for n in vars(_DEFAULTS) if n not in RANGES]
    kind = r.choice(["set_params"] * 4 + ["bump"] * 2 + ["set_packets"] * 2 +
                    ["gyro", "simple", "junk"])
    if kind == "set_params":
        pick = r.sample(names, r.randint(1, 3))
        params = {n: _valid_param(r, n) for n in pick}
        if not valid:
            victim = r.choice(pick)
            params[victim] = _invalid_param(r, victim)
            if r.random() < 0.1:
                params = {r.choice(["no_such", 7, "", "prop_window "]): 1.0, **params}
        return {"cmd": "set_params", "params": params}, valid
    if kind == "bump":
        groups = r.sample(list(GROUP_SIZE), r.randint(1, 6))
        sigma = {g: [r.choice([0.0, BUMP_MAX_SI[g], BUMP_MAX_SI[g] * r.random()])
                     for _ in range(GROUP_SIZE[g])] for g in groups}
        req = {"cmd": "bump", "sigma": sigma, "mode": r.choice(["add", "scale"])}
        if not valid:
            g = r.choice(groups)
            bad = [BUMP_MAX_SI[g] * 1.01, -1e-12] + [
                v for v in EXTREMES if not _number_in(v, 0.0, BUMP_MAX_SI[g])]
            choice = r.randrange(4)
            if choice == 0:
                sigma[g][r.randrange(GROUP_SIZE[g])] = r.choice(bad)
            elif choice == 1:
                sigma[g] = sigma[g][:-1]
            elif choice == 2:
                sigma[r.choice(["bias", "", "B"])] = [0.0] * 4
            else:
                req["mode"] = r.choice(["mul", 1, None, True]) or "x"
        return req, valid
    if kind == "set_packets":
        name = r.choice(["small", "medium", "large"])
        spec: dict[str, Any] = {"fields": r.sample(list(CATALOGUE), r.randint(1, len(CATALOGUE))),
                                "trigger": r.choice(["window", "sample"])}
        if r.random() < 0.5:
            spec["period_s"] = _extreme_in(r, *PERIOD_RANGE_S, False)
        else:
            spec["decimation"] = _extreme_in(r, 1, DECIMATION_MAX, True)
        if not valid:
            choice = r.randrange(5)
            if choice == 0:
                spec.pop("decimation", None)
                spec["period_s"] = r.choice([math.nan, math.inf, -1.0, 0.0, True, 1e-9, 1e9, "1"])
            elif choice == 1:
                spec.pop("period_s", None)
                spec["decimation"] = r.choice([0, -1, 2**63 - 1, 1.5, True, DECIMATION_MAX + 1])
            elif choice == 2:
                spec["fields"] = r.choice([[], ["t", "t"], ["nope"], [1], [["t"]], "t", None])
            elif choice == 3:
                spec[r.choice(["rate", "period", 5])] = 1
            else:
                return {"cmd": "set_packets", "packets": {r.choice(["huge", "", 1]): spec}}, False
        return {"cmd": "set_packets", "packets": {name: spec}}, valid
    if kind == "gyro":
        cmd = r.choice(["exclude_gyro", "include_gyro"])
        if valid:
            return {"cmd": cmd, "gyro": r.randrange(N_GYRO)}, True
        return {"cmd": cmd, "gyro": r.choice([-1, 4, 2**63 - 1, 1.5, "0", True, None, [0]])}, False
    if kind == "simple":
        if valid:
            return r.choice([{"cmd": "status"}, {"cmd": "get_params"}, {"cmd": "reset_params"},
                             {"cmd": "warm_start", "bump": r.random() < 0.5},
                             {"cmd": "cold_start"}, {"cmd": "checkpoint"},
                             {"cmd": "end_stream", "next": r.choice(["warm", "cold"])}]), True
        return r.choice([{"cmd": "warm_start", "bump": r.choice([1, "yes", None])},
                         {"cmd": "end_stream", "next": r.choice(["hot", 1, None])},
                         {"cmd": "cold_start", "force": True}, {"cmd": "status", "x": 1}]), False
    return r.choice([{"cmd": "fly"}, {"cmd": 5}, {"cmd": None}, {"x": 1},
                     {"cmd": "set_params", "params": []}, {"cmd": "bump", "sigma": None},
                     {"cmd": "set_packets", "packets": {}}]), False


# ------------------------------------------------------------------------------------ checkpoints
def _leaves(node: Any, path: tuple = ()) -> list[tuple]:
    """Paths of every leaf of a decoded checkpoint (maps and lists walked; stored arrays are
    leaves with their element count)."""
    if isinstance(node, dict) and set(node) == {"dtype", "shape", "data"}:
        return [path + ("<array>",)]
    if isinstance(node, dict):
        return [p for k, v in node.items() for p in _leaves(v, path + (k,))] + [path + ("<del>",)]
    if isinstance(node, list) and node:
        return [p for i, v in enumerate(node) for p in _leaves(v, path + (i,))]
    return [path]


def _get(node: Any, path: tuple) -> Any:
    for k in path:
        node = node[k]
    return node


def _damage_array(r: random.Random, arr: dict) -> None:
    choice = r.randrange(5)
    if choice == 0:
        arr["dtype"] = r.choice(["<f4", "|b1", "<i8", "<f8", "x", 3])
    elif choice == 1:
        arr["shape"] = r.choice([[], [0], [2**62], [-1], [3, 3, 3], "3"])
    elif choice == 2:
        arr["data"] = arr["data"][: r.randrange(max(len(arr["data"]), 1))]
    else:
        dt = np.dtype(arr["dtype"])
        a = np.frombuffer(arr["data"], dt).copy()
        if a.size == 0:
            return
        if dt.kind == "f":
            pool = [np.nan, np.inf, -np.inf, 1e300, -1e300, 0.0, -1.0, 1e30]
            if choice == 4:
                a[:] = np.random.default_rng(r.randrange(2**32)).normal(size=a.size) * 10 ** r.randint(-3, 12)
            else:
                a[r.randrange(a.size)] = r.choice(pool)
        elif dt.kind == "i":
            a[r.randrange(a.size)] = r.choice([2**63 - 1, -(2**63), -1, 2**40])
        else:
            a[:] = r.random() < 0.5
        arr["data"] = a.tobytes()


def checkpoint_case(seed: int, index: int, good: bytes) -> tuple[bytes, str]:
    """(damaged file bytes, what was done) for case number ``index``."""
    r = _rng(seed, index, 2)
    u = r.random()
    if u < 0.25:  # byte-level damage
        raw = bytearray(good)
        kind = r.randrange(4)
        if kind == 0:
            for _ in range(r.randint(1, 8)):
                raw[r.randrange(len(raw))] ^= 1 << r.randrange(8)
            return bytes(raw), "bit flips"
        if kind == 1:
            return bytes(raw[: r.randrange(len(raw))]), "truncated"
        if kind == 2:
            return bytes(raw) + bytes(r.randrange(256) for _ in range(r.randint(1, 64))), "junk appended"
        return bytes(r.randrange(256) for _ in range(r.randint(0, 512))), "random bytes"
    outer = msgpack.unpackb(good, raw=False, strict_map_key=False)
    doc = msgpack.unpackb(outer["body"], raw=False, strict_map_key=False)
    st = doc["vehicles"]["v1"]
    what = []
    for _ in range(r.choice([1, 1, 1, 2, 3])):
        path = r.choice(_leaves(st))  # walked again: an earlier change may have removed a part
        parent = _get(st, path[:-1])
        key = path[-1]
        if key == "<array>":
            _damage_array(r, parent)
        elif key == "<del>":
            if parent:
                parent.pop(r.choice(list(parent)))
        else:
            parent[key] = r.choice(EXTREMES + ["x" * 10000, [0] * 10, {"dtype": "<f8"}])
        what.append("/".join(map(str, path)))
    if r.random() < 0.05:
        doc["vehicles"] = {"v2": {**st, "vehicle": "v2"}}
        what.append("foreign vehicle")
    body = msgpack.packb(doc, use_bin_type=True)
    checksum = hashlib.sha256(body).hexdigest() if r.random() < 0.95 else "0" * 64
    return msgpack.packb({"schema": outer["schema"], "sha256": checksum, "body": body},
                         use_bin_type=True), "fields " + ", ".join(what)
