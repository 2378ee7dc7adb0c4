"""Node checkpoints: calibration state that survives a restart (msgpack, written atomically).

One file per node process holds every vehicle it serves::

    {"schema": "radical.node_checkpoint/1", "written_unix": float, "generator": str,
     "vehicles": {name: {"engine": Engine.get_state(), "params": {"active": {...}, "default": {...}},
                         "clock": SiruClock.get_state(), "packets": {name: {fields, period_s |
                         decimation, trigger, seq}}, "stream": {"rejected": {...}, "late_dropped": int,
                         "temps": {...}}, "t": float, "mode": str}}}

It is written to ``PATH.tmp-<pid>``, flushed and fsynced, then renamed over ``PATH``
(:func:`os.replace` is atomic on POSIX), so a node killed at any moment leaves either the previous
or the new complete checkpoint. :func:`restore` puts a vehicle's state back into a fresh
:class:`~radical_rt.stream.StreamProcessor` and starts a new stream: the clock forgets its phase
(keeps its frequency range), the engine warm-starts (attitude re-initialized from the next valid
tracker, parameter estimates and UD factors kept; no covariance bump unless asked).
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any

import msgpack

from . import __version__
from .params import ParamError
from .stream import StreamProcessor
from .telemetry import PacketSpec

SCHEMA = "radical.node_checkpoint/1"


class CheckpointError(ValueError):
    """A checkpoint that cannot be read, has the wrong schema, or does not fit the node."""


def capture(sp: StreamProcessor) -> dict[str, Any]:
    """One vehicle's state (msgpack-able). Call it from the thread that runs ``sp``."""
    e = sp.engine
    return {
        "engine": e.get_state(),
        "params": {"active": e.table.as_dict("active"), "default": e.table.as_dict("default")},
        "clock": sp.clock.get_state(),
        "packets": {n: {"fields": list(s.fields), "period_s": s.period_s,
                        "decimation": s.decimation, "trigger": s.trigger, "seq": s.seq}
                    for n, s in sp.packets.items()},
        "stream": {"rejected": dict(sp.rejected), "late_dropped": int(sp.late_dropped),
                   "temps": dict(sp.temps)},
        "t": float(e.t), "mode": e.mode,
    }


def write(path: str | os.PathLike[str], vehicles: dict[str, dict[str, Any]]) -> str:
    """Write a checkpoint of captured vehicle states atomically; return the path written."""
    path = Path(path)
    doc = {"schema": SCHEMA, "written_unix": time.time(), "generator": f"radical-rt {__version__}",
           "vehicles": vehicles}
    data = msgpack.packb(doc, use_bin_type=True)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise CheckpointError(f"cannot write checkpoint {path}: {exc.strerror or exc}") from None
    try:  # make the rename itself durable
        fd = os.open(path.parent if str(path.parent) else ".", os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError:
        pass
    return str(path)


def read(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Load and check a checkpoint file; CheckpointError with a clear message otherwise."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        raise CheckpointError(f"checkpoint {path}: no such file") from None
    except OSError as exc:
        raise CheckpointError(f"checkpoint {path}: {exc.strerror or exc}") from None
    try:
        doc = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as exc:
        raise CheckpointError(f"checkpoint {path}: not a msgpack checkpoint ({exc})") from None
    if not isinstance(doc, dict) or doc.get("schema") != SCHEMA:
        got = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
        raise CheckpointError(f"checkpoint {path}: schema {got!r}, expected {SCHEMA!r}")
    if not isinstance(doc.get("vehicles"), dict):
        raise CheckpointError(f"checkpoint {path}: no 'vehicles' map")
    return doc


def restore(sp: StreamProcessor, state: dict[str, Any], bump: bool = False) -> None:
    """Put a captured state into ``sp`` (fresh, same geometry) and start a new stream (warm).

    All parts are validated before anything is changed; CheckpointError if they do not fit.
    """
    e = sp.engine
    try:
        probe = type(e.table)(n_gyro=e.n_gyro)
        probe.set(state["params"]["active"])
        packets = {n: PacketSpec(n, list(p["fields"]), period_s=p["period_s"],
                                 decimation=p["decimation"], seq=int(p["seq"]),
                                 trigger=p.get("trigger", "window"))
                   for n, p in state["packets"].items()}
        engine_state, clock_state = state["engine"], state["clock"]
        snapshot = e.get_state()
        e.set_state(engine_state)
    except (KeyError, TypeError, ValueError, ParamError) as exc:
        raise CheckpointError(f"checkpoint does not fit this node: {exc}") from None
    try:
        sp.clock.set_state(clock_state)
    except (KeyError, TypeError, ValueError) as exc:
        e.set_state(snapshot)
        raise CheckpointError(f"checkpoint clock state does not fit: {exc}") from None
    e.table.set(state["params"]["active"])
    e.params_changed()
    sp.packets = packets
    st = state.get("stream", {})
    sp.rejected.clear()
    sp.rejected.update({str(k): int(v) for k, v in st.get("rejected", {}).items()})
    sp.late_dropped = int(st.get("late_dropped", 0))
    sp.temps.update(st.get("temps", {}))
    # a new stream: forget the read sequence and the clock phase, re-initialize the attitude
    sp.clock.reset()
    e.warm_start(bump=bump)
    sp.last_reject_t = -math.inf
