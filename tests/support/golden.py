"""Golden outputs of seeded scenarios: what the engine emits, frozen so that every numerical
change is deliberate and shows as a diff of ``tests/golden/<case>.json``.

A record holds, per output topic, the message count and the SHA-256 of the msgpack bytes; the
summary file (CONTRACT §5, full float precision); the engine's counters, flags and mode; and a
trace of five decoded messages per topic (first, last and three between) so that a change shows
*where* it starts. ``tests/system/test_golden.py`` recomputes every case and compares.

Regenerate after a deliberate change (and commit the diff with the reason)::

    RADICAL_GOLDEN_UPDATE=1 python -m pytest tests/system/test_golden.py

Floating-point results depend on the CPU's instruction set only through BLAS/LAPACK and the
compiled kernels; a record stores the platform it was made on, and on another platform the
comparison of the numbers falls back to a relative tolerance (:data:`RTOL`) while counts, flags
and modes stay exact.
"""

from __future__ import annotations

import hashlib
import json
import math
import platform
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgpack
import numba
import numpy as np

from radical_rt.apps.batch import make_processor, make_summary
from radical_rt.contract.params import ParamTable

GOLDEN_DIR = Path(__file__).resolve().parent.parent / "golden"
SCHEMA = "radical.golden/1"
RTOL = 1e-9  # relative tolerance of the numbers when the platform differs
N_TRACE = 5  # decoded messages per topic in a record


def cpu_model() -> str:
    """The CPU model name (Linux /proc/cpuinfo), or the platform's processor string."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def platform_id() -> dict[str, str]:
    return {"cpu": cpu_model(), "numpy": np.__version__, "numba": numba.__version__,
            "machine": platform.machine()}


#: how run_streams feeds the processor: "many" — chunks of CHUNK_MESSAGES through feed_many (the
#: block intake that ``radical process`` runs on whole archive chunks); "one" — message by message
#: through feed, as the node does (test_golden checks both against the same records)
FEED = {"mode": "many"}
CHUNK_MESSAGES = 256


def run_streams(streams: list[list[tuple[str, int, bytes]]], params: dict | None = None,
                start: str = "warm") -> tuple[list[tuple[str, bytes]], Any]:
    """Feed the streams in order through one stream processor (``start`` at each boundary, as
    ``radical process`` does between its inputs; FEED says how); returns ([(topic, msgpack
    bytes)], processor)."""
    table = ParamTable()
    table.set(params or {})
    sp = make_processor(table)
    out: list[tuple[str, bytes]] = []
    for i, messages in enumerate(streams):
        if i > 0:
            out += [(t, msgpack.packb(m)) for t, m in sp.end_stream(start)]
        if FEED["mode"] == "one":
            for topic, _ns, data in messages:
                out += [(t, msgpack.packb(m)) for t, m in sp.feed(topic, data)]
            continue
        for c in range(0, len(messages), CHUNK_MESSAGES):
            chunk = [(topic, data) for topic, _ns, data in messages[c:c + CHUNK_MESSAGES]]
            out += [(t, msgpack.packb(m)) for t, m in sp.feed_many(chunk)]
    out += [(t, msgpack.packb(m)) for t, m in sp.end_stream(None)]
    return out, sp


def _plain(x: Any) -> Any:
    """JSON-ready copy: numpy scalars and arrays as Python numbers and lists, bytes as hex."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, bytes):
        return x.hex()
    return x


def record(name: str, description: str, outputs: list[tuple[str, bytes]], sp) -> dict:
    """The golden record of one run (see the module docstring)."""
    by_topic: dict[str, list[bytes]] = {}
    for topic, data in outputs:
        by_topic.setdefault(topic, []).append(data)
    every = hashlib.sha256()
    for topic, data in outputs:
        every.update(topic.encode() + b"\0" + data)
    trace = {}
    for topic, msgs in sorted(by_topic.items()):
        idx = sorted(set(np.linspace(0, len(msgs) - 1, N_TRACE).round().astype(int).tolist()))
        trace[topic] = [{"index": i, "message": msgpack.unpackb(msgs[i], raw=False,
                                                                 strict_map_key=False)}
                        for i in idx]
    e = sp.engine
    return _plain({
        "schema": SCHEMA, "case": name, "description": description, "platform": platform_id(),
        "outputs": {"n": len(outputs), "sha256": every.hexdigest(),
                    "count": {t: len(m) for t, m in sorted(by_topic.items())},
                    "topic_sha256": {t: hashlib.sha256(b"".join(m)).hexdigest()
                                     for t, m in sorted(by_topic.items())}},
        "summary": make_summary(sp),
        "engine": {"counters": dict(sorted(e.counters.items())), "flags": int(e.flags),
                   "mode": e.mode, "t": float(e.t), "rejected": dict(sorted(sp.rejected.items()))},
        "trace": trace})


def load(name: str) -> dict:
    return json.loads((GOLDEN_DIR / f"{name}.json").read_text())


def save(rec: dict) -> Path:
    GOLDEN_DIR.mkdir(parents=True, exist_ok=True)
    path = GOLDEN_DIR / f"{rec['case']}.json"
    path.write_text(json.dumps(rec, indent=1, sort_keys=False) + "\n")
    return path


def differences(new: Any, old: Any, path: str = "", exact: bool = True,
                out: list[str] | None = None, limit: int = 20) -> list[str]:
    """Paths where ``new`` differs from ``old`` (floats exactly, or at :data:`RTOL` when
    ``exact`` is false; the platform entry and, when not exact, the digests are not compared)."""
    out = [] if out is None else out
    if len(out) >= limit:
        return out
    if isinstance(old, dict) and isinstance(new, dict):
        for k in sorted(set(old) | set(new)):
            if k == "platform" or (not exact and k in ("sha256", "topic_sha256")):
                continue
            if k not in old or k not in new:
                out.append(f"{path}/{k}: {'added' if k in new else 'removed'}")
            else:
                differences(new[k], old[k], f"{path}/{k}", exact, out, limit)
    elif isinstance(old, list) and isinstance(new, list):
        if len(old) != len(new):
            out.append(f"{path}: length {len(new)} (golden {len(old)})")
        for i, (a, b) in enumerate(zip(new, old, strict=False)):
            differences(a, b, f"{path}[{i}]", exact, out, limit)
    elif isinstance(old, float) and isinstance(new, float) and not exact:
        if not (math.isclose(new, old, rel_tol=RTOL, abs_tol=1e-300)
                or (math.isnan(new) and math.isnan(old))):
            out.append(f"{path}: {new!r} (golden {old!r})")
    elif new != old and not (isinstance(new, float) and isinstance(old, float)
                             and math.isnan(new) and math.isnan(old)):
        out.append(f"{path}: {new!r} (golden {old!r})")
    return out


Case = Callable[[Path], tuple[str, list[tuple[str, bytes]], Any]]


def with_tmp(case: Case) -> tuple[str, list[tuple[str, bytes]], Any]:
    with tempfile.TemporaryDirectory(prefix="golden-") as d:
        return case(Path(d))
