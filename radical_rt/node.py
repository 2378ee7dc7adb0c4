"""The streaming shell: transport callbacks → bounded queue → ONE filter loop → published outputs.

Threads and ownership:

* transport callbacks (one subscriber per vehicle on ``radical/<vehicle>/*``, so the arrival order
  across the input topics is kept) only put ``(vehicle, topic, payload bytes)`` on a bounded queue;
  when it is full they wait up to ``queue_wait_s`` (back-pressure to a BLOCK publisher), then drop
  the message and count it (``queue_overflow``, visible in diag and status, INPUT_REJECTED set);
* query callbacks on ``radical/<vehicle>/cmd`` parse and validate a command
  (:mod:`radical_rt.commands`), hand it to the filter loop and wait for its reply;
* the filter loop thread owns every :class:`~radical_rt.stream.StreamProcessor` (one per vehicle):
  it applies pending commands between filter steps, feeds messages in arrival order, publishes the
  outputs on ``radical/<vehicle>/<topic>`` and writes periodic checkpoints.

The StreamProcessor is the batch shell's (:func:`radical_rt.batch.make_processor`), so a node fed
an archive's input messages in ``log_time`` order ends with bit-identical estimates.
"""

from __future__ import annotations

import functools
import gc
import logging
import math
import queue
import re
import threading
import time
from array import array
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np

from . import checkpoint as ckpt
from . import commands
from .batch import make_processor, make_summary
from .params import ParamTable
from .stream import INPUT_TOPICS, StreamProcessor
from .transport import Transport

log = logging.getLogger("radical.node")
VEHICLE_RE = re.compile(r"^[a-z0-9_-]+$")


def packb(msg: Any) -> bytes:
    """msgpack with numpy scalars/arrays converted (outputs are mostly plain Python already)."""
    return msgpack.packb(msg, use_bin_type=True, default=_np_default)


def _np_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot serialize {type(obj).__name__}")


class Vehicle:
    """One vehicle served by the node: its StreamProcessor and its counters."""

    def __init__(self, node: FilterNode, name: str, sp: StreamProcessor) -> None:
        if not VEHICLE_RE.match(name):
            raise ValueError(f"vehicle name {name!r} must match [a-z0-9_-]+")
        self.node, self.name, self.sp = node, name, sp
        self.prefix = f"radical/{name}/"
        self.lock = threading.Lock()  # guards the callback-side counters below
        self.received: dict[str, int] = defaultdict(int)
        self.overflow: dict[str, int] = defaultdict(int)
        self.fed: dict[str, int] = defaultdict(int)  # loop thread only
        self._overflow_seen = 0
        self.commands_applied = 0
        self.published: dict[str, int] = defaultdict(int)

    # ---- called by commands.apply (filter loop thread)
    def status(self) -> dict[str, Any]:
        e, sp = self.sp.engine, self.sp
        return {"vehicle": self.name, "t": float(e.t), "mode": e.mode, "flags": int(sp.flags),
                "flag_names": sp.flag_names(), "q_body_from_inertial": e.q.tolist(),
                "est": e.estimates(), "sigma": e.sigmas(),
                "excluded": [int(i) for i in np.nonzero(e.excluded)[0]],
                "counters": sp.counters(), "rejected": dict(sp.rejected),
                "summary": make_summary(sp), "node": self.node_info()}

    def write_checkpoint(self) -> str:
        return self.node.write_checkpoint()

    def end_stream(self, next_start: str | None) -> dict[str, Any]:
        self.node._publish(self, self.sp.end_stream(None))
        summary = make_summary(self.sp)
        if next_start is not None:
            self.node._publish(self, self.sp.end_stream(next_start))
        return {"summary": summary, "next": next_start or "none"}

    def node_info(self) -> dict[str, Any]:
        with self.lock:
            received, overflow = dict(self.received), dict(self.overflow)
        n = self.node
        return {"received": received, "fed": dict(self.fed), "queue_overflow": overflow,
                "queue_depth": n.queue.qsize(), "queue_size": n.queue.maxsize,
                "commands_applied": self.commands_applied, "published": dict(self.published),
                "checkpoint": n.checkpoint_path, "checkpoints_written": n.checkpoints_written,
                "last_checkpoint_age_s": (time.monotonic() - n.last_checkpoint_mono)
                if n.last_checkpoint_mono is not None else None}


class LoopTiming:
    """Optional per-message timing of the filter loop (``radical node --timing-out``, perf/).

    One record per message the loop takes: vehicle and topic indices, CLOCK_MONOTONIC ns stamps
    (comparable across processes on one host) at the subscriber callback (``recv_ns``), when the
    loop took it (``start_ns``), after the StreamProcessor (``fed_ns``) and after its outputs were
    published (``done_ns``), and the tlm packets it published, packed as
    ``n_small | n_medium << 8 | n_large << 16``. Records go to a flat int64 ``array`` (56 B each).
    With :meth:`watch_gc`, every garbage collection of the process is recorded too (start, stop,
    generation).
    """

    FIELDS = ("vehicle", "topic", "recv_ns", "start_ns", "fed_ns", "done_ns", "tlm")
    KINDS = ("small", "medium", "large")

    def __init__(self, vehicles: list[str]) -> None:
        self.vehicles = list(vehicles)
        self._vi = {name: i for i, name in enumerate(self.vehicles)}
        self._ti = {name: i for i, name in enumerate(INPUT_TOPICS)}
        self._shift = {f"tlm/{k}": 8 * i for i, k in enumerate(self.KINDS)}
        self.buf = array("q")
        self.gc_buf = array("q")  # (start_ns, stop_ns, generation) per garbage collection
        self._gc_t0 = 0

    def watch_gc(self) -> None:
        """Record every garbage collection of this process from now on (``gc.callbacks``)."""
        gc.callbacks.append(self._on_gc)

    def _on_gc(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._gc_t0 = time.monotonic_ns()
        else:
            self.gc_buf.extend((self._gc_t0, time.monotonic_ns(), int(info.get("generation", -1))))

    def record(self, vehicle: str, topic: str, recv_ns: int, start_ns: int, fed_ns: int,
               done_ns: int, outs: list[tuple[str, Any]]) -> None:
        tlm = 0
        for out_topic, _msg in outs:
            sh = self._shift.get(out_topic)
            if sh is not None:
                tlm += 1 << sh
        self.buf.extend((self._vi.get(vehicle, -1), self._ti.get(topic, -1), recv_ns, start_ns,
                         fed_ns, done_ns, tlm))

    def arrays(self) -> dict[str, np.ndarray]:
        a = np.frombuffer(self.buf, dtype=np.int64).reshape(-1, len(self.FIELDS))
        return {name: a[:, i].copy() for i, name in enumerate(self.FIELDS)}

    def save(self, path: str) -> None:
        """Write the records as an ``.npz`` (one array per field, plus vehicle and topic names)."""
        arrays = self.arrays()
        g = np.frombuffer(self.gc_buf, dtype=np.int64).reshape(-1, 3)
        arrays.update(vehicles=np.array(self.vehicles), topics=np.array(INPUT_TOPICS),
                      kinds=np.array(self.KINDS), gc_start_ns=g[:, 0].copy(),
                      gc_stop_ns=g[:, 1].copy(), gc_generation=g[:, 2].copy())
        np.savez(path, **arrays)  # type: ignore[arg-type]


class _Pending:
    """A command waiting for the filter loop; the reply is handed back through an event."""

    def __init__(self, vehicle: Vehicle, cmd: commands.Command) -> None:
        self.vehicle, self.cmd = vehicle, cmd
        self.done = threading.Event()
        self.lock = threading.Lock()
        self.state = "pending"  # → running → done, or pending → cancelled
        self.reply: dict[str, Any] = {}

    def claim(self) -> bool:
        with self.lock:
            if self.state != "pending":
                return False
            self.state = "running"
            return True

    def finish(self, reply: dict[str, Any]) -> None:
        self.reply = reply
        with self.lock:
            self.state = "done"
        self.done.set()

    def wait(self, timeout: float) -> dict[str, Any]:
        if not self.done.wait(timeout):
            with self.lock:
                if self.state == "pending":
                    self.state = "cancelled"
                    return commands.error_reply(
                        f"not applied: the filter loop did not take the command within {timeout:g} s",
                        self.cmd)
            self.done.wait()  # running: finishing is quick
        return self.reply


class FilterNode:
    """Serve one or more vehicles over a :class:`~radical_rt.transport.Transport`.

    processors: vehicle name → StreamProcessor (see :func:`build_processors`). checkpoint_path:
    where periodic (every ``checkpoint_every_s`` of wall time), on-command and final checkpoints
    go (None: no checkpoints). block_outputs: BLOCK congestion control for every output (default:
    only ``fault``; telemetry and diag use DROP so a stuck consumer cannot stall the filter).
    """

    def __init__(self, transport: Transport, processors: dict[str, StreamProcessor], *,
                 checkpoint_path: str | None = None, checkpoint_every_s: float = 60.0,
                 queue_size: int = 4096, queue_wait_s: float = 1.0, block_outputs: bool = False,
                 command_timeout_s: float = 5.0, monotonic: Callable[[], float] = time.monotonic,
                 timing: LoopTiming | None = None):
        if not processors:
            raise ValueError("at least one vehicle is needed")
        if queue_size < 1 or checkpoint_every_s <= 0:
            raise ValueError("queue_size must be ≥ 1 and checkpoint_every_s > 0")
        self.transport = transport
        self.vehicles = {name: Vehicle(self, name, sp) for name, sp in processors.items()}
        self.checkpoint_path, self.checkpoint_every_s = checkpoint_path, checkpoint_every_s
        self.queue: queue.Queue = queue.Queue(maxsize=queue_size)
        self.queue_wait_s, self.block_outputs = queue_wait_s, block_outputs
        self.command_timeout_s = command_timeout_s
        self._cmdq: queue.Queue = queue.Queue(maxsize=64)
        self._mono = monotonic
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._handles: list[Any] = []
        self._count_lock = threading.Lock()
        self._enqueued = self._processed = 0
        self._overflow_pending = False  # a callback dropped a message since the last report
        self.checkpoints_written = 0
        self.last_checkpoint_mono: float | None = None
        self.loop_error: BaseException | None = None
        self.running = False
        self.timing = timing  # per-message timing records (perf), or None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Declare subscribers, queryables and liveliness tokens; start the filter loop."""
        self.running = True
        self._next_ckpt = self._mono() + self.checkpoint_every_s
        self._thread = threading.Thread(target=self._loop, name="radical-filter", daemon=True)
        self._thread.start()
        for v in self.vehicles.values():
            self._handles.append(self.transport.subscribe(  # not our own outputs
                v.prefix + "*", functools.partial(self._on_sample, v), remote_only=True))
            self._handles.append(self.transport.queryable(
                v.prefix + "cmd", functools.partial(self._on_query, v)))
            self._handles.append(self.transport.liveliness_token(v.prefix + "alive/filter"))
        log.info("serving %s", ", ".join(self.vehicles))

    def stop(self, drain_s: float = 2.0, final_checkpoint: bool = True) -> None:
        """Undeclare, let the loop process what is queued (up to drain_s), final checkpoint."""
        for h in self._handles:
            h.undeclare()
        self._handles.clear()
        if self._thread is not None:
            self._drain_until = self._mono() + drain_s
            self._stop.set()
            self._thread.join()
            self._thread = None
        self.running = False
        while True:  # commands that arrived too late
            try:
                p = self._cmdq.get_nowait()
            except queue.Empty:
                break
            if p.claim():
                p.finish(commands.error_reply("node is shutting down", p.cmd))
        if final_checkpoint and self.checkpoint_path:
            self.write_checkpoint()

    def wait_idle(self, timeout: float = 10.0) -> bool:
        """Wait until everything received so far has been fed (tests, tools)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._count_lock:
                if self._processed >= self._enqueued and self._cmdq.empty():
                    return True
            time.sleep(0.002)
        return False

    # ------------------------------------------------------------------ callbacks (any thread)
    def _on_sample(self, v: Vehicle, key: str, data: bytes) -> None:
        t_recv = time.monotonic_ns() if self.timing is not None else 0
        topic = key[len(v.prefix):] if key.startswith(v.prefix) else key
        if topic not in INPUT_TOPICS:
            return  # our own outputs and unrelated keys
        with v.lock:
            v.received[topic] += 1
        try:
            with self._count_lock:
                self._enqueued += 1
            self.queue.put((v, topic, data, t_recv), timeout=self.queue_wait_s)
        except queue.Full:
            with self._count_lock:
                self._enqueued -= 1
            with v.lock:
                v.overflow[topic] += 1
            self._overflow_pending = True  # after the count: the loop's next look sees it

    def _on_query(self, v: Vehicle, data: bytes) -> bytes:
        try:
            cmd = commands.parse(data, v.sp.engine.n_gyro)
        except commands.CommandError as exc:
            return packb(commands.error_reply(str(exc), exc))
        if not self.running or self._stop.is_set():
            return packb(commands.error_reply("node is shutting down", cmd))
        p = _Pending(v, cmd)
        try:
            self._cmdq.put_nowait(p)
        except queue.Full:
            return packb(commands.error_reply("too many pending commands, try again", cmd))
        return packb(p.wait(self.command_timeout_s))

    # ------------------------------------------------------------------ filter loop thread
    def _loop(self) -> None:
        try:
            while not self._stop.is_set():
                self._run_commands()
                try:
                    item = self.queue.get(timeout=0.05)
                except queue.Empty:
                    item = None
                if item is not None:
                    self._feed(*item)
                self._housekeeping()
                if item is not None:  # counted once its consequences (checkpoint) are done
                    with self._count_lock:
                        self._processed += 1
            while self._mono() < self._drain_until:  # stopping: finish what is queued
                try:
                    item = self.queue.get_nowait()
                except queue.Empty:
                    break
                self._feed(*item)
                with self._count_lock:
                    self._processed += 1
            self._housekeeping(checkpoint=False)
        except BaseException as exc:  # pragma: no cover - a bug; keep it visible
            self.loop_error = exc
            log.exception("filter loop failed")
            raise

    def _run_commands(self) -> None:
        if self._cmdq.empty():  # the common case: no exception raised per message
            return
        while True:
            try:
                p = self._cmdq.get_nowait()
            except queue.Empty:
                return
            if not p.claim():
                continue  # the caller gave up waiting: never apply it late
            try:
                reply = commands.apply(p.cmd, p.vehicle)
                p.vehicle.commands_applied += 1
                log.log(logging.DEBUG if p.cmd.name in ("status", "get_params") else logging.INFO,
                        "%s: command %s applied", p.vehicle.name, p.cmd.name)
            except commands.CommandError as exc:
                reply = commands.error_reply(str(exc), p.cmd)
            except Exception as exc:
                log.exception("%s: command %s failed", p.vehicle.name, p.cmd.name)
                reply = commands.error_reply(f"internal error: {exc}", p.cmd)
            p.finish(reply)

    def _feed(self, v: Vehicle, topic: str, data: bytes, t_recv: int = 0) -> None:
        t_start = time.monotonic_ns() if self.timing is not None else 0
        try:
            outs = v.sp.feed(topic, data)
        except Exception as exc:  # a bug below the input checks: count it, keep serving
            log.exception("%s: %s message raised", v.name, topic)
            _note_reject(v.sp, topic, "internal_error", f"{type(exc).__name__}: {exc}")
            outs = v.sp.take_outputs()
        v.fed[topic] += 1
        if self.timing is None:
            self._publish(v, outs)
            return
        t_fed = time.monotonic_ns()
        self._publish(v, outs)
        self.timing.record(v.name, topic, t_recv, t_start, t_fed, time.monotonic_ns(), outs)

    def _publish(self, v: Vehicle, outs: list[tuple[str, dict[str, Any]]]) -> None:
        for topic, msg in outs:
            if topic == "diag":
                msg = {**msg, "node": v.node_info()}
            try:
                self.transport.put(v.prefix + topic, packb(msg),
                                   block=self.block_outputs or topic == "fault")
                v.published[topic] += 1
            except Exception as exc:
                log.warning("%s: cannot publish %s: %s", v.name, topic, exc)

    def _housekeeping(self, checkpoint: bool = True) -> None:
        """After every message: report queue overflows (only when a callback saw one, so the cost
        per message does not grow with the number of vehicles) and write a periodic checkpoint."""
        if self._overflow_pending:
            self._overflow_pending = False
            self._report_overflows()
        if checkpoint and self.checkpoint_path and self._mono() >= self._next_ckpt:
            self._next_ckpt = self._mono() + self.checkpoint_every_s
            try:
                self.write_checkpoint()
            except ckpt.CheckpointError as exc:
                log.error("%s", exc)

    def _report_overflows(self) -> None:
        for v in self.vehicles.values():
            with v.lock:
                total = sum(v.overflow.values())
            if total > v._overflow_seen:
                n, v._overflow_seen = total - v._overflow_seen, total
                _note_reject(v.sp, "input", "queue_overflow",
                             f"queue full: {n} message(s) dropped", count=n)
                log.warning("%s: input queue full, %d message(s) dropped", v.name, n)

    def write_checkpoint(self) -> str:
        """Write all vehicles' state now (filter loop thread, or after it stopped)."""
        if not self.checkpoint_path:
            raise commands.CommandError("no checkpoint path: start the node with --checkpoint PATH")
        try:
            path = ckpt.write(self.checkpoint_path,
                              {name: ckpt.capture(v.sp) for name, v in self.vehicles.items()})
        except ckpt.CheckpointError as exc:
            raise commands.CommandError(str(exc)) from None
        self.checkpoints_written += 1
        self.last_checkpoint_mono = self._mono()
        log.debug("checkpoint written to %s", path)
        return path


def _note_reject(sp: StreamProcessor, topic: str, reason: str, message: str, count: int = 1) -> None:
    """Count a rejection the StreamProcessor did not see itself (same bookkeeping as its own)."""
    sp.rejected[reason] += count
    sp.last_reject_t = sp.t_max
    sp.last_reject = f"{topic}: {message}"


# ------------------------------------------------------------------------------------ set-up
def build_processors(vehicles: list[str], config: str | None = None, packets: str | None = None,
                     clock_mode: str = "reconstruct", resume: str | None = None,
                     resume_bump: bool = False) -> dict[str, StreamProcessor]:
    """One StreamProcessor per vehicle (own parameter table and packets), restored if resuming.

    Raises ParamError / PacketError / CheckpointError / ValueError with clear messages.
    """
    if not vehicles:
        raise ValueError("give at least one --vehicle")
    for name in vehicles:
        if not VEHICLE_RE.match(name):
            raise ValueError(f"vehicle name {name!r} must match [a-z0-9_-]+")
    if len(set(vehicles)) != len(vehicles):
        raise ValueError(f"vehicle names repeat: {vehicles}")
    out = {}
    for name in vehicles:
        table = ParamTable.from_toml(config) if config else ParamTable()
        out[name] = make_processor(table, clock_mode, packets)
    if resume:
        doc = ckpt.read(resume)
        for name, sp in out.items():
            state = doc["vehicles"].get(name)
            if state is None:
                log.warning("checkpoint %s has no state for vehicle %r: it starts cold", resume, name)
                continue
            try:
                ckpt.restore(sp, state, bump=resume_bump)
            except ckpt.CheckpointError as exc:
                raise ckpt.CheckpointError(f"{resume}: vehicle {name}: {exc}") from None
            log.info("%s: resumed from %s (t=%.3f, mode before restart %s)", name, resume,
                     state["t"], state["mode"])
        extra = sorted(set(doc["vehicles"]) - set(vehicles))
        if extra:
            log.warning("checkpoint %s also holds %s (not served, ignored)", resume, extra)
    return out


def warm_up(clock_mode: str = "reconstruct", seconds: float = 2.0) -> float:
    """Compile/load every Numba kernel on a throwaway engine fed a tiny synthetic stream.

    A stationary vehicle, body = inertial: SIRU batches of 10 zero increments at 100 Hz, both
    trackers at 10 Hz, then a warm start with both bump modes and a cold start. Returns seconds.
    """
    t0 = time.perf_counter()
    sp = make_processor(ParamTable(), clock_mode)
    q_st1 = [1.0, 0.0, 0.0, 0.0]  # R_st1_from_body = diag(1, -1, -1)
    q_st2 = [math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0]  # R_st2_from_body_nom
    n = sp.engine.n_gyro
    for b in range(int(seconds * 10)):
        k0 = b * 10
        t = [1.0 + 0.01 * (k0 + i) for i in range(1, 11)]
        sp.feed("siru", packb({"v": 1, "t_bus": t, "tt": [(k0 + i) * 10000 for i in range(1, 11)],
                               "dtheta": [[0.0] * n for _ in range(10)], "status": [0] * 10}))
        for topic, q in (("st1", q_st1), ("st2", q_st2)):
            sp.feed(topic, packb({"v": 1, "t_bus": t[-1], "q": q, "n_stars": 9, "valid": True}))
    sp.end_stream("warm")
    e = sp.engine
    e.bump({g: list(v) for g, v in e.si.bump_sigma.items()}, "scale")
    e.cold_start()
    ckpt.capture(sp)
    return time.perf_counter() - t0
