"""Node checkpoints: the running state that survives a restart (msgpack, checksummed, atomic).

One file per node process holds every vehicle it serves. On disk it is a msgpack map::

    {"schema": "radical.node_checkpoint/3", "sha256": hex digest of body, "body": bytes}

where ``body`` is itself msgpack::

    {"written_unix": float, "generator": str,
     "vehicles": {name: {"vehicle": name, "params": {"active": {...}, "default": {...}},
                         "packets": {name: {fields, period_s | decimation, trigger, seq}},
                         "stream": {"rejected": {...}, "late_dropped": int, "temps": {...}},
                         "running": ckpt_state.capture(...), "t": float, "mode": str}}}

The checksum is verified before the body is decoded, and every field of a vehicle's state is
validated (:mod:`radical_rt.io.ckpt_state`, :mod:`radical_rt.io.ckpt_validate`: shapes, dtypes, ranges,
finiteness, UD positivity, unit upper triangular U, clock arrays within bounds) before anything
is changed: a damaged file is refused with one line naming the field. It is written to
``PATH.tmp-<pid>``, flushed and fsynced, renamed over ``PATH`` (:func:`os.replace`, atomic on
POSIX) and the directory fsynced, so a node killed at any moment leaves either the previous or
the new complete checkpoint. :func:`restore` continues the captured stream (clock phase and
lock, latches, queued samples and parity sums, pending process noise); with ``new_stream`` (or
``bump``) it starts a new stream instead: the clock forgets its phase, the engine warm-starts.
"""

from __future__ import annotations

import hashlib
import math
import os
import time
from pathlib import Path
from typing import Any

import msgpack

from radical_rt import __version__
from radical_rt.contract.params import ParamError
from radical_rt.io import ckpt_state
from radical_rt.io import ckpt_validate as cv
from radical_rt.stream.processor import StreamProcessor
from radical_rt.stream.stream_log import bump_applied
from radical_rt.stream.telemetry import PacketError, PacketSpec, parse_packets

SCHEMA = "radical.node_checkpoint/3"  # /3: the FDI's tracker history as columns
#: schemas read: /2 (the FDI's tracker history as a list of rows) is converted on restore
READ_SCHEMAS = ("radical.node_checkpoint/2", SCHEMA)
MAX_BYTES = 256 * 2**20  # a checkpoint file larger than this is refused unread


class CheckpointError(ValueError):
    """A checkpoint that cannot be read or written, is damaged, or does not fit the node."""


def capture(sp: StreamProcessor, vehicle: str = "", history: bool = True) -> dict[str, Any]:
    """One vehicle's state (msgpack-able). Call it from the thread that runs ``sp``.
    ``history=False``: without the FDI's sample history, snapshots and bank (megabytes after
    10 minutes), which only a continuation of the same stream uses: a state for
    ``restore(..., new_stream=True)`` only (a fleet's periodic replica; docs/fleet.md)."""
    e = sp.engine
    return {
        "vehicle": vehicle,
        "params": {"active": e.table.as_dict("active"), "default": e.table.as_dict("default")},
        "packets": {n: {"fields": list(s.fields), "period_s": s.period_s,
                        "decimation": s.decimation, "trigger": s.trigger, "seq": s.seq}
                    for n, s in sp.packets.items()},
        "stream": {"rejected": dict(sp.rejected), "late_dropped": int(sp.late_dropped),
                   "temps": dict(sp.temps), "index": int(sp.streams.index),
                   "start": sp.streams.start, "bumped": sp.streams.bump is not None},
        "running": ckpt_state.capture(sp, history),
        "t": float(e.t), "mode": e.mode,
    }


def write(path: str | os.PathLike[str], vehicles: dict[str, dict[str, Any]]) -> str:
    """Write a checkpoint of captured vehicle states atomically (temp file, fsync, rename, fsync
    of the directory); return the path written. CheckpointError (one line) if it fails; the
    previous checkpoint is then left as it was."""
    path = Path(path)
    data = dumps(vehicles)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
        fd = os.open(path.parent if str(path.parent) else ".", os.O_RDONLY)
        try:  # make the rename itself durable
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise CheckpointError(f"cannot write checkpoint {path}: {exc.strerror or exc}") from None
    return str(path)


def dumps(vehicles: dict[str, dict[str, Any]]) -> bytes:
    """A checkpoint of captured vehicle states as bytes (the file's content: schema, checksum,
    body), e.g. to replicate it over Zenoh."""
    body = msgpack.packb({"written_unix": time.time(), "generator": f"radical-rt {__version__}",
                          "vehicles": vehicles}, use_bin_type=True)
    return msgpack.packb({"schema": SCHEMA, "sha256": hashlib.sha256(body).hexdigest(),
                          "body": body}, use_bin_type=True)


def read(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Load a checkpoint file and verify its schema and checksum (the vehicles' fields are
    checked by :func:`restore`); CheckpointError with one clear line otherwise."""
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise CheckpointError(f"checkpoint {path}: no such file") from None
    except OSError as exc:
        raise CheckpointError(f"checkpoint {path}: {exc.strerror or exc}") from None
    return loads(data, str(path))


def loads(data: bytes, path: str = "(bytes)") -> dict[str, Any]:
    """:func:`dumps`' bytes back to the checkpoint document, schema and checksum verified
    (``path`` names the source in errors); CheckpointError with one clear line otherwise."""
    if len(data) > MAX_BYTES:
        raise CheckpointError(f"checkpoint {path}: larger than {MAX_BYTES} bytes")
    try:
        outer = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as exc:
        raise CheckpointError(f"checkpoint {path}: not a msgpack checkpoint ({exc})") from None
    got = outer.get("schema") if isinstance(outer, dict) else type(outer).__name__
    if got not in READ_SCHEMAS:
        raise CheckpointError(f"checkpoint {path}: schema {str(got)[:60]!r}, expected {SCHEMA!r}"
                              f" (or {READ_SCHEMAS[0]!r})")
    body, digest = outer.get("body"), outer.get("sha256")
    if not isinstance(body, bytes) or not isinstance(digest, str) \
            or hashlib.sha256(body).hexdigest() != digest:
        raise CheckpointError(f"checkpoint {path}: checksum mismatch (damaged file)")
    try:
        doc = msgpack.unpackb(body, raw=False, strict_map_key=False)
    except Exception as exc:
        raise CheckpointError(f"checkpoint {path}: body is not msgpack ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("vehicles"), dict):
        raise CheckpointError(f"checkpoint {path}: no 'vehicles' map")
    for name, st in doc["vehicles"].items():
        if not isinstance(st, dict) or st.get("vehicle") != name:
            raise CheckpointError(f"checkpoint {path}: vehicle entry {str(name)[:40]!r} does "
                                  "not carry its own vehicle id")
    doc["schema"] = got
    return doc


def restore(sp: StreamProcessor, state: dict[str, Any], bump: bool = False,
            new_stream: bool = False) -> None:
    """Put a captured state into ``sp`` (fresh, same geometry and clock configuration).

    Continues the captured stream, or with ``new_stream``/``bump`` starts a new one (clock phase
    forgotten, warm start with the configured bump if ``bump``). Every field is validated before
    anything is changed; CheckpointError naming the field if one does not fit.
    """
    e = sp.engine
    try:
        params = cv.need(cv.need(state, "params", "state"), "active", "params")
        type(e.table)(n_gyro=e.n_gyro).set(params)
        # the default table is not restored (the node's --config sets it) but must be valid too
        type(e.table)(n_gyro=e.n_gyro).set(cv.need(state["params"], "default", "params"))
        packets = _check_packets(cv.need(state, "packets", "state"))
        st = cv.need(state, "stream", "state")
        rejected = cv.counter_map(cv.need(st, "rejected", "stream"), "stream.rejected")
        late = cv.number(cv.need(st, "late_dropped", "stream"), "stream.late_dropped", 0,
                         cv.INT_MAX, integer=True)
        temps = cv.need(st, "temps", "stream")
        if not isinstance(temps, dict) or len(temps) > 16:
            raise cv.CheckpointFieldError("stream.temps: expected a small map")
        temps = {str(k)[:64]: cv.number(v, f"stream.temps.{str(k)[:20]}", -300.0, 1000.0)
                 for k, v in temps.items()}
        index = cv.number(st.get("index", 0), "stream.index", 0, cv.INT_MAX, integer=True)
        start = st.get("start", "resume")  # (older checkpoints: no index, start or bumped)
        if start not in ("cold", "warm", "resume"):
            raise cv.CheckpointFieldError(f"stream.start: expected cold, warm or resume, got "
                                          f"{str(start)[:20]!r}")
        bumped = st.get("bumped", False) is True
        plan = ckpt_state.check(cv.need(state, "running", "state"), sp)
    except (cv.CheckpointFieldError, ParamError) as exc:
        raise CheckpointError(f"does not fit this node: {exc}") from None
    e.table.set(params)
    e.params_changed()
    sp.packets = packets
    ckpt_state.apply(sp, plan)
    sp.rejected.clear()
    sp.rejected.update(rejected)
    sp.late_dropped = late
    sp.temps.clear()
    sp.temps.update(temps)
    sp.streams.index = index
    sp.streams.begin(start, bump_applied(e.si) if bumped else None)
    if new_stream or bump:  # a new stream: forget the read sequence and the clock phase
        sp.clock.reset()
        sp.begin_stream()
        e.warm_start(bump=bump)
        sp.streams.index = index + 1
        sp.streams.begin("warm", bump_applied(e.si) if bump else None)
        sp.last_reject_t = -math.inf


def _check_packets(doc: Any) -> dict[str, PacketSpec]:
    """The packet configuration of a checkpoint, validated like set_packets, sequence numbers
    kept."""
    if not isinstance(doc, dict):
        raise cv.CheckpointFieldError("packets: expected a map")
    conf = {}
    for n, p in doc.items():
        if not isinstance(p, dict):
            raise cv.CheckpointFieldError(f"packets.{str(n)[:20]}: expected a map")
        conf[n] = {k: v for k, v in p.items() if k != "seq" and v is not None}
    try:
        specs = parse_packets(conf)
    except PacketError as exc:
        raise cv.CheckpointFieldError(f"packets: {exc}") from None
    for n, p in doc.items():
        specs[n].seq = cv.number(p.get("seq", 0), f"packets.{n}.seq", 0, cv.INT_MAX, integer=True)
    return specs
