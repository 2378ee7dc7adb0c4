"""Data fuzz harness (issue 23): seeded bad input payloads interleaved with a clean archive.

    python -m perf.fuzz_inputs [--payloads 1000000] [--seed 23] [--archive A.mcap]
                               [--duration 60] [--per-message 10] [--json OUT.json]

A clean simulated archive (or ``--archive``) is fed through the batch shell's stream processor
(:func:`radical_rt.apps.batch.make_processor`) in ``log_time`` order, pass after pass (seed
``seed + pass``), with ``--per-message`` bad payloads (on average) inserted before each clean
message (but the first: the first message of a stream sets its time line, docs/node.md "Time
sanity"), until ``--payloads`` bad payloads were fed. Every bad payload is of one of the kinds
below; each must be rejected and counted, and change nothing:

* malformed: random bytes, truncated or padded msgpack, a non-map, a bad ``v``, missing fields,
  wrong types (str, map, bytes, bool, nil, integers beyond int64), wrong shapes, NaN/Inf;
* **plausible but false**: the next clean message shifted in time far ahead or behind (3 s to
  10⁹ s, outside the plausibility window), t_bus = ±1e300, an old message replayed (going back
  or repeating), a siru payload on a tracker key and back, ``n_stars`` beyond 1000 (up to
  2⁶⁴ − 1), a quaternion just outside the unit-norm tolerance, a siru increment beyond the
  physical range (|dθ| > 1 rad per sample), an oversized payload (> 1 MiB, rarely).

Per pass the final estimates and σ must be bit-identical to the clean run and the counters equal
but for ``input_rejected`` (= the bad payloads of the pass): a difference counts as a **state
change**. An exception escaping ``feed`` is a **crash**; a rejection with the reason
``internal_error`` an **internal error**; a ``feed`` call longer than ``--hang-s`` a **hang**.
The report gives the payloads tried per kind, those four counts (0 expected), the rejection
reasons, the throughput and the peak RSS. Exit status 1 if any count is not 0.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import resource
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import msgpack

KINDS = ("random_bytes", "truncated", "padded", "not_a_map", "bad_version", "missing_field",
         "wrong_type", "wrong_shape", "nonfinite", "time_far", "time_huge", "replayed",
         "wrong_topic", "n_stars_huge", "quat_off", "dtheta_range", "oversized")
_TRACKERS = ("st1", "st2")
_REQUIRED = {"siru": ("t_bus", "tt", "dtheta", "status"), "temp": ("t_bus",),
             "st1": ("t_bus", "q", "n_stars", "valid"), "st2": ("t_bus", "q", "n_stars", "valid")}


def _shift(m: dict, dt: float) -> dict:
    m = dict(m)
    m["t_bus"] = [t + dt for t in m["t_bus"]] if isinstance(m["t_bus"], list) else m["t_bus"] + dt
    return m


def bad_payload(rng: random.Random, topic: str, msg: dict, raw: bytes,
                history: dict[str, list[bytes]]) -> tuple[str, str, bytes]:
    """One bad variant of the next clean message (topic, its map, its bytes): (kind, topic to
    send it on, payload)."""
    kind = KINDS[rng.randrange(len(KINDS) - 1)] if rng.random() > 1e-4 else "oversized"
    m = dict(msg)
    if kind == "random_bytes":
        return kind, topic, bytes(rng.randrange(256) for _ in range(rng.randrange(0, 64)))
    if kind == "truncated":
        return kind, topic, raw[:rng.randrange(0, len(raw))]
    if kind == "padded":
        return kind, topic, raw + bytes([rng.randrange(256)])
    if kind == "not_a_map":
        return kind, topic, msgpack.packb(rng.choice([[1, 2], 3, "siru", None, 2.5, True, b"x"]))
    if kind == "bad_version":
        m["v"] = rng.choice([2, 0, None, "1", 1.5, -1, 2**64 - 1])
        return kind, topic, msgpack.packb(m)
    if kind == "missing_field":
        del m[rng.choice(_REQUIRED[topic])]
        return kind, topic, msgpack.packb(m)
    if kind == "wrong_type":
        key = rng.choice(_REQUIRED[topic])
        m[key] = rng.choice(["text", {"a": 1}, [["x"]], b"\x01", None, 2**64 - 1,
                             -2**63, [2**64 - 1]] + ([] if key == "valid" else [True]))
        if topic == "temp" and rng.random() < 0.5:
            m[rng.choice(["siru_C", "st1_baseplate_C"])] = rng.choice(["hot", None, [1.0]])
        return kind, topic, msgpack.packb(m)
    if kind == "wrong_shape":
        if topic == "siru":
            case = rng.randrange(4)
            if case == 0:
                m["dtheta"] = [row[:3] for row in m["dtheta"]]
            elif case == 1:
                m["status"] = m["status"][:-1]
            elif case == 2:
                m["tt"] = m["tt"] + [m["tt"][-1] + 10000]
            else:
                m = {**m, "t_bus": [], "tt": [], "dtheta": [], "status": []}
        elif topic in _TRACKERS:
            m["q"] = m["q"][:3] if rng.random() < 0.5 else m["q"] + [0.0]
        else:
            m["t_bus"] = [m["t_bus"]]
        return kind, topic, msgpack.packb(m)
    if kind == "nonfinite":
        bad = rng.choice([math.nan, math.inf, -math.inf])
        if topic == "siru":
            m["dtheta"] = [list(r) for r in m["dtheta"]]
            m["dtheta"][rng.randrange(len(m["dtheta"]))][rng.randrange(len(m["dtheta"][0]))] = bad
        elif topic in _TRACKERS:
            m["q"] = list(m["q"])
            m["q"][rng.randrange(4)] = bad
        else:
            m["t_bus"] = bad
        return kind, topic, msgpack.packb(m)
    if kind == "time_far":
        dt = rng.choice([-1, 1]) * 10 ** rng.uniform(math.log10(3.0), 9.0)
        return kind, topic, msgpack.packb(_shift(m, dt))
    if kind == "time_huge":
        t = rng.choice([1e300, -1e300, 1.7e308, -1e18])
        return kind, topic, msgpack.packb(_shift(m, t))
    if kind == "replayed" and history.get(topic):
        return kind, topic, rng.choice(history[topic][-50:])
    if kind == "wrong_topic":
        if topic == "siru":
            return kind, rng.choice(_TRACKERS), raw
        return kind, "siru", raw
    if kind == "n_stars_huge" and topic in _TRACKERS:
        m["n_stars"] = rng.choice([1001, 10**6, 2**31, 2**63 - 1, 2**63, 2**64 - 1])
        return kind, topic, msgpack.packb(m)
    if kind == "quat_off" and topic in _TRACKERS:
        f = 1.0 + rng.choice([-1, 1]) * rng.uniform(1.5e-3, 0.5)
        m["q"] = [f * x for x in m["q"]]
        return kind, topic, msgpack.packb(m)
    if kind == "dtheta_range" and topic == "siru":
        m["dtheta"] = [list(r) for r in m["dtheta"]]
        m["dtheta"][rng.randrange(len(m["dtheta"]))][0] = rng.choice([-1, 1]) * 10 ** rng.uniform(
            0.1, 300)
        return kind, topic, msgpack.packb(m)
    if kind == "oversized":
        return kind, topic, msgpack.packb({**m, "pad": b"\0" * (1 << 21)})
    return "random_bytes", topic, bytes(rng.randrange(256) for _ in range(rng.randrange(1, 16)))


def _result(sp) -> tuple[bytes, dict[str, Any]]:
    e = sp.engine
    est = msgpack.packb([e.estimates(), e.sigmas(), e.q.tolist(), float(e.t), e.mode],
                        default=lambda o: o.tolist())
    c = {k: v for k, v in sp.counters().items() if k != "input_rejected"}
    return est, c


def run(msgs: list[tuple[str, int, bytes]], n_payloads: int, seed: int, per_message: float,
        hang_s: float = 1.0, log=print) -> dict[str, Any]:
    """The harness (module docstring); msgs: the clean (topic, log_ns, payload) stream."""
    from radical_rt.apps.batch import make_processor

    clean = make_processor()
    for topic, _ns, data in msgs:
        clean.feed(topic, data)
    clean.end_stream(None)
    ref_est, ref_c = _result(clean)
    decoded = [(t, msgpack.unpackb(d), d) for t, _ns, d in msgs]
    p = per_message / (1.0 + per_message)  # geometric number of bad payloads per clean message
    tried: Counter = Counter()
    reasons: Counter = Counter()
    crashes = hangs = internal = changes = passes = 0
    worst_s = 0.0
    t0 = time.perf_counter()
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    while sum(tried.values()) < n_payloads:
        rng = random.Random(seed + passes)
        sp, history, n_bad = make_processor(), {}, 0
        for i, (topic, msg, raw) in enumerate(decoded):
            while i and rng.random() < p and sum(tried.values()) < n_payloads:
                kind, key, payload = bad_payload(rng, topic, msg, raw, history)
                tried[kind] += 1
                n_bad += 1
                t1 = time.perf_counter()
                try:
                    sp.feed(key, payload)
                except Exception as exc:  # noqa: BLE001 - a crash is what is counted here
                    crashes += 1
                    log(f"crash: pass {passes} {kind} on {key}: {type(exc).__name__}: {exc}")
                dt = time.perf_counter() - t1
                worst_s = max(worst_s, dt)
                if dt > hang_s:
                    hangs += 1
                    log(f"hang: pass {passes} {kind} on {key}: {dt:.2f} s")
            sp.feed(topic, raw)
            history.setdefault(topic, []).append(raw)
        sp.end_stream(None)
        est, c = _result(sp)
        rej = dict(sp.rejected)
        reasons.update(rej)
        internal += rej.get("internal_error", 0)
        if est != ref_est or c != ref_c or sum(rej.values()) != n_bad:
            changes += 1
            diff = {k: (c[k], ref_c[k]) for k in c if c[k] != ref_c.get(k)}
            log(f"state change: pass {passes} (seed {seed + passes}): estimates "
                f"{'differ' if est != ref_est else 'equal'}, counters {diff}, rejected "
                f"{sum(rej.values())} of {n_bad}")
        passes += 1
        log(f"pass {passes}: {sum(tried.values())} payloads, {time.perf_counter() - t0:.1f} s")
    wall = time.perf_counter() - t0
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    total = sum(tried.values())
    return {"payloads": total, "passes": passes, "clean_messages_per_pass": len(msgs),
            "seed": seed, "kinds": dict(sorted(tried.items())),
            "crashes": crashes, "hangs": hangs, "internal_errors": internal,
            "state_changes": changes, "reasons": dict(sorted(reasons.items())),
            "wall_s": wall, "payloads_per_s": total / wall if wall > 0 else None,
            "worst_feed_s": worst_s, "peak_rss_mb": rss1 / 1024.0,
            "rss_growth_mb": (rss1 - rss0) / 1024.0}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m perf.fuzz_inputs", description=__doc__.split(
        "\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--payloads", type=int, default=1_000_000)
    ap.add_argument("--seed", type=int, default=23)
    ap.add_argument("--archive", help="clean input archive (default: a simulated one)")
    ap.add_argument("--duration", type=float, default=60.0, help="simulated archive length [s]")
    ap.add_argument("--per-message", type=float, default=10.0,
                    help="mean bad payloads before each clean message")
    ap.add_argument("--hang-s", type=float, default=1.0, help="a feed longer than this hangs")
    ap.add_argument("--json", metavar="OUT.json")
    a = ap.parse_args(argv)
    from radical_rt.io.archive import ArchiveReader

    path = a.archive
    if path is None:
        import tempfile

        from replayer.synth.api import synthesize
        d = Path(tempfile.mkdtemp(prefix="fuzz_"))
        (d / "s.toml").write_text('base = "2006216"\nt_start_s = 1000.0\n')
        path = str(d / "clean.mcap")
        synthesize(str(d / "s.toml"), path, seed=a.seed, duration=a.duration)
    with ArchiveReader(path) as r:
        msgs = [(t[1:], ns, data) for t, ns, data in
                r.iter_raw(topics=["/siru", "/st1", "/st2", "/temp"])]
    res = run(msgs, a.payloads, a.seed, a.per_message, a.hang_s,
              log=lambda s: print(s, file=sys.stderr, flush=True))
    res["archive"] = path
    print(json.dumps(res, indent=1, sort_keys=True))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1, sort_keys=True))
    bad = res["crashes"] + res["hangs"] + res["internal_errors"] + res["state_changes"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
