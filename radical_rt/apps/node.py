"""The streaming shell: input FIFO → ONE filter loop → published outputs.

Threads and ownership:

* the inputs of every vehicle arrive in ONE bounded FIFO (:meth:`Transport.inbox`, capacity
  ``queue_size``): on ``radical/<vehicle>/*`` for one vehicle, on ``radical/*/*`` (keys of vehicles
  not served are ignored) for several, so the arrival order across the input topics of a vehicle
  is kept. No callback runs per sample: the filter loop pulls the samples itself. (Each subscriber
  callback of the Zenoh binding runs on a Python thread of its own that competes with the filter
  loop for the GIL; with a callback and a queue per vehicle a node served 24 vehicles at real time
  on 2 cores, with one callback thread 40, with the pulled FIFO 56 (10-s steps; 47 with the
  60-s steps of the full profile): perf/README.md.) A full Zenoh
  FIFO back-pressures the session (BLOCK publishers wait, DROP publishers drop on their side); the
  in-memory one makes its publisher wait up to ``queue_wait_s``, then drops and counts
  (``queue_overflow``, visible in diag and status, INPUT_REJECTED set);
* the filter loop thread owns every :class:`~radical_rt.stream.processor.StreamProcessor` (one per
  vehicle): it feeds the samples in arrival order, publishes the outputs on
  ``radical/<vehicle>/<topic>`` (to other sessions only), applies pending commands between two
  messages and writes periodic checkpoints;
* query callbacks on ``radical/<vehicle>/cmd`` parse and validate a command
  (:mod:`radical_rt.apps.commands`), queue it for the loop, wake the loop if it is waiting for input
  (:meth:`Inbox.wake`) and wait for its reply. A ticker wakes a waiting loop every ``TICK_S`` for
  the periodic checkpoints and overflow reports.

The StreamProcessor is the batch shell's (:func:`radical_rt.apps.batch.make_processor`), so a node fed
an archive's input messages in ``log_time`` order ends with bit-identical estimates.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import queue
import re
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np

from radical_rt.apps import commands
from radical_rt.apps.batch import make_processor, make_summary
from radical_rt.apps.link_watch import LinkWatch, check_links, input_seen
from radical_rt.apps.node_clock import ClockNotice
from radical_rt.apps.node_timing import LoopTiming
from radical_rt.contract.params import ParamTable
from radical_rt.io import checkpoint as ckpt
from radical_rt.io.transport import Inbox, Transport
from radical_rt.io.zenoh_transport import ZenohTransport
from radical_rt.stream.eos import EOS_TOPIC, decode_eos
from radical_rt.stream.packets import InputError
from radical_rt.stream.processor import INPUT_TOPICS, StreamProcessor

log = logging.getLogger("radical.node")
VEHICLE_RE = re.compile(r"^[a-z0-9_-]+$")
QUEUE_BYTES = 64 << 20  # default byte bound of the input FIFO (payload bytes waiting)


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
        self.lock = threading.Lock()  # guards the counters below (read by status/diag)
        self.received: dict[str, int] = defaultdict(int)
        self.overflow: dict[str, int] = defaultdict(int)
        self.overflow_bytes: dict[str, int] = defaultdict(int)
        self.fed: dict[str, int] = defaultdict(int)  # loop thread only
        self.commands_applied = 0
        self.published: dict[str, int] = defaultdict(int)
        self.clock_notice = ClockNotice(name)
        # end of stream (docs/node.md, "End of stream"): received at the last marker, markers,
        # inputs a marker reported sent but never received, releases after an idle time
        self.at_eos: dict[str, int] = {}
        self.eos_seen = self.reported_lost = self.idle_releases = 0
        self.last_input_mono = 0.0
        self.holding = False  # inputs taken since the last release of everything
        self.link = LinkWatch(node.stale_after_s) if node.stale_after_s else None

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
        self.node.publish(self, self.sp.end_stream(None))
        summary = make_summary(self.sp)
        if next_start is not None:
            self.node.publish(self, self.sp.end_stream(next_start))
        return {"summary": summary, "next": next_start or "none"}

    def node_info(self) -> dict[str, Any]:
        with self.lock:
            received, overflow = dict(self.received), dict(self.overflow)
            overflow_bytes = dict(self.overflow_bytes)
        n = self.node
        return {"received": received, "fed": dict(self.fed), "queue_overflow": overflow,
                "queue_overflow_bytes": overflow_bytes,
                "queue_depth": n.queue_depth(), "queue_size": n.queue_size,
                "queue_bytes": n.queue_bytes, "queue_bytes_used": n.queue_bytes_used(),
                "commands_applied": self.commands_applied, "published": dict(self.published),
                "eos": self.eos_seen, "reported_lost": self.reported_lost,
                "idle_releases": self.idle_releases,
                "link_lost": bool(self.sp.link_lost), "stale_after_s": n.stale_after_s,
                "checkpoint": n.checkpoint_path, "checkpoints_written": n.checkpoints_written,
                "checkpoint_failures": n.checkpoint_failures, "checkpoint_error": n.checkpoint_error,
                "last_checkpoint_age_s": (time.monotonic() - n.last_checkpoint_mono)
                if n.last_checkpoint_mono is not None else None}


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


class NodeStartError(RuntimeError):
    """The node could not start as asked (the message says why); nothing is left running."""


class FilterNode:
    """Serve one or more vehicles over a :class:`~radical_rt.io.transport.Transport`.

    processors: vehicle name → StreamProcessor (see :func:`build_processors`). checkpoint_path:
    where periodic (every ``checkpoint_every_s`` of wall time), on-command and final checkpoints
    go (None: no checkpoints). queue_size: capacity of the input FIFO (queue_wait_s: how long a
    full in-memory FIFO makes its publisher wait before dropping). block_outputs: BLOCK congestion
    control for every output (default: only ``fault``; telemetry and diag use DROP so a stuck
    consumer cannot stall the filter). rt_priority: run the filter loop thread with the
    real-time policy SCHED_FIFO at this priority (1–99; needs root or CAP_SYS_NICE; None: the
    default time-sharing policy). The loop blocks whenever its FIFO is empty, so it only takes the
    CPU when there is input, and then ahead of the Zenoh and other threads of the machine: on
    2 cores this raised the capacity from 47 to 51 vehicles (perf/README.md). idle_release_s:
    release what a vehicle holds for reordering once no input came for that long (wall time;
    None: only at an end-of-stream marker or end_stream command; docs/node.md, "End of stream").
    max_payload_bytes: the largest input payload taken (None: the processors' own bound).
    queue_bytes: the byte bound of the input FIFO (payload bytes waiting; a full FIFO drops and
    counts ``queue_overflow`` / ``queue_overflow_bytes``; None: bounded in samples only, and a
    Zenoh FIFO is then the pulled ``FifoChannel``; docs/node.md "Losses and bounds").
    stale_after_s: a vehicle whose stream was active and that sent no input for this long (wall
    time) has lost its link: LINK_LOSS, ``link_losses`` (:mod:`radical_rt.apps.link_watch`; None: no
    watch).
    """

    TICK_S = 0.25  # housekeeping period while the loop waits for input [s]
    CHECKPOINT_RETRY_S = 5.0  # a failed periodic checkpoint is retried this much later [s]

    def __init__(self, transport: Transport, processors: dict[str, StreamProcessor], *,
                 checkpoint_path: str | None = None, checkpoint_every_s: float = 60.0,
                 queue_size: int = 4096, queue_wait_s: float = 1.0, block_outputs: bool = False,
                 command_timeout_s: float = 5.0, monotonic: Callable[[], float] = time.monotonic,
                 timing: LoopTiming | None = None, rt_priority: int | None = None,
                 idle_release_s: float | None = None, max_payload_bytes: int | None = None,
                 queue_bytes: int | None = QUEUE_BYTES, stale_after_s: float | None = None):
        if not processors:
            raise ValueError("at least one vehicle is needed")
        if queue_size < 1 or checkpoint_every_s <= 0 or (queue_bytes is not None and queue_bytes < 1):
            raise ValueError("queue_size, queue_bytes must be ≥ 1 and checkpoint_every_s > 0")
        if rt_priority is not None and not 1 <= rt_priority <= 99:
            raise ValueError(f"rt_priority must be 1..99, got {rt_priority}")
        if idle_release_s is not None and not idle_release_s > 0:
            raise ValueError("idle_release_s must be > 0 (None: never)")
        if stale_after_s is not None and not stale_after_s > 0:
            raise ValueError("stale_after_s must be > 0 (None: no link watch)")
        self.rt_priority, self.idle_release_s = rt_priority, idle_release_s
        self.stale_after_s = stale_after_s
        self.transport = transport
        self.vehicles = {name: Vehicle(self, name, sp) for name, sp in processors.items()}
        if max_payload_bytes is not None:  # the size bound of every vehicle's inputs
            for sp in processors.values():
                sp.max_payload_bytes = max_payload_bytes
        self.checkpoint_path, self.checkpoint_every_s = checkpoint_path, checkpoint_every_s
        self.queue_size, self.queue_wait_s, self.queue_bytes = queue_size, queue_wait_s, queue_bytes
        self.block_outputs = block_outputs
        self.command_timeout_s = command_timeout_s
        self._cmdq: queue.Queue = queue.Queue(maxsize=64)
        self._mono = monotonic
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._ticker: threading.Thread | None = None
        self._inbox: Inbox | None = None
        self._handles: list[Any] = []
        self._idle = False  # the loop waits for input (set before its last look at commands)
        self._processed = 0
        self.checkpoints_written = 0
        self.checkpoint_failures = 0  # periodic writes that failed (retried, never fatal)
        self.checkpoint_error: str | None = None  # why the last write failed (None: it did not)
        self.last_checkpoint_mono: float | None = None
        self.loop_error: BaseException | None = None
        self.running = False
        self.timing = timing  # per-message timing records (perf), or None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Declare the input FIFO, queryables and liveliness tokens; start the filter loop."""
        self.running = True
        self._next_ckpt = self._mono() + self.checkpoint_every_s
        if len(self.vehicles) == 1:  # one FIFO for every input (see the module docstring)
            key = next(iter(self.vehicles.values())).prefix + "*"
        else:
            key = "radical/*/*"
        kw: dict[str, Any] = {"capacity_bytes": self.queue_bytes}
        if isinstance(self.transport, ZenohTransport):  # oversized samples dropped uncopied
            kw["max_payload"] = max(v.sp.max_payload_bytes for v in self.vehicles.values())
        self._inbox = self.transport.inbox(key, self.queue_size, self.queue_wait_s, **kw)
        self._thread = threading.Thread(target=self._loop, name="radical-filter", daemon=True)
        self._thread.start()
        if self.rt_priority is not None:
            self._set_realtime(self._thread)
        self._ticker = threading.Thread(target=self._tick, name="radical-tick", daemon=True)
        self._ticker.start()
        for v in self.vehicles.values():
            self._handles.append(self.transport.queryable(
                v.prefix + "cmd", functools.partial(self._on_query, v)))
            self._handles.append(self.transport.liveliness_token(v.prefix + "alive/filter"))
        log.info("serving %s", ", ".join(self.vehicles))

    def _set_realtime(self, thread: threading.Thread) -> None:
        """SCHED_FIFO at ``rt_priority`` for the filter loop thread; NodeStartError (node
        stopped again) if the system refuses."""
        try:
            if thread.native_id is None or self.rt_priority is None:
                raise OSError("no native thread id")
            os.sched_setscheduler(thread.native_id, os.SCHED_FIFO, os.sched_param(self.rt_priority))
        except (OSError, AttributeError) as exc:
            self.stop(drain_s=0.0, final_checkpoint=False)
            why = getattr(exc, "strerror", None) or exc
            raise NodeStartError(f"cannot run the filter loop with SCHED_FIFO priority "
                                 f"{self.rt_priority}: {why} (needs root or CAP_SYS_NICE)") from None
        log.info("filter loop: SCHED_FIFO priority %d", self.rt_priority)

    def stop(self, drain_s: float = 2.0, final_checkpoint: bool = True) -> None:
        """Undeclare, let the loop process what is queued (up to drain_s), final checkpoint."""
        for h in self._handles:
            h.undeclare()
        self._handles.clear()
        if self._thread is not None:
            self._drain_until = self._mono() + drain_s
            self._stop.set()
            assert self._inbox is not None
            self._inbox.wake()
            self._thread.join()
            self._thread = None
        if self._ticker is not None:
            self._ticker.join()
            self._ticker = None
        if self._inbox is not None:
            self._inbox.undeclare()  # the loop has stopped reading it
            self._inbox = None
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
        """Wait until everything received so far has been fed (tests, tools): the loop waits for
        input with an empty FIFO and no pending command, twice in a row with nothing fed between."""
        end = time.monotonic() + timeout
        seen = None
        while time.monotonic() < end:
            box = self._inbox
            pending = getattr(box, "pending", lambda: 0)() if box is not None else 0
            state = self._processed
            if self._idle and not pending and self._cmdq.empty():
                if seen == state:
                    return True
                seen = state
            else:
                seen = None
            time.sleep(0.002)
        return False

    # ------------------------------------------------------------------ query callbacks
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
        if self._idle and self._inbox is not None:  # the loop waits for input: wake it
            self._inbox.wake()
        return packb(p.wait(self.command_timeout_s))

    # ------------------------------------------------------------------ filter loop thread
    def _loop(self) -> None:
        """Take every input from the FIFO in arrival order and feed it (one Python thread does
        all per-message work: no callback thread competes for the GIL)."""
        inbox = self._inbox
        assert inbox is not None
        try:
            while not self._stop.is_set():
                item = inbox.try_recv()
                if item is None:
                    self._idle = True  # before the last look: a command queued after it wakes us
                    self._run_commands()
                    self._housekeeping()
                    self._idle_release()
                    item = inbox.recv()  # waits with the GIL released; None: woken
                    self._idle = False
                    if item is None:
                        continue
                self._run_commands()
                self._take(*item)
                self._housekeeping()
            while self._mono() < self._drain_until:  # stopping: finish what is queued
                item = inbox.try_recv()
                if item is None:
                    break
                self._take(*item)
            self._idle = True
            self._housekeeping(checkpoint=False)
        except BaseException as exc:  # pragma: no cover - a bug; keep it visible
            self.loop_error = exc
            log.exception("filter loop failed")
            raise

    def _tick(self) -> None:
        """Wake a loop that waits for input every TICK_S (its housekeeping: overflow reports,
        periodic checkpoints)."""
        while not self._stop.wait(self.TICK_S):
            if self._idle and self._inbox is not None:
                self._inbox.wake()

    def _take(self, key: str, data: bytes) -> None:
        """One input sample from the FIFO: route it to its vehicle and feed it."""
        t_recv = time.monotonic_ns() if self.timing is not None else 0
        v = self.vehicles.get(key.split("/", 2)[1])
        if v is None:  # a vehicle this node does not serve
            return
        topic = key[len(v.prefix):]
        if topic in INPUT_TOPICS or topic == EOS_TOPIC:
            input_seen(self, v, self._mono())
        if topic not in INPUT_TOPICS:
            if topic == EOS_TOPIC:
                self._end_of_stream(v, data)
            return  # other keys of the vehicle (the FIFO also holds a local wake-up)
        with v.lock:
            v.received[topic] += 1
        v.holding = True
        if self.idle_release_s is not None:
            v.last_input_mono = self._mono()
        self._feed(v, topic, data, t_recv)
        self._processed += 1

    def _end_of_stream(self, v: Vehicle, data: bytes) -> None:
        """An end-of-stream marker (:mod:`radical_rt.stream.eos`): losses counted, everything held
        released (as at the end of ``radical process``), the next stream prepared."""
        try:
            nxt, counts, source = decode_eos(data, INPUT_TOPICS)
        except InputError as exc:
            _note_reject(v.sp, EOS_TOPIC, exc.reason, str(exc))
            return
        with v.lock:
            received = dict(v.received)
        lost = sum(max(0, n - (received.get(t, 0) - v.at_eos.get(t, 0))) for t, n in counts.items())
        v.at_eos = received
        v.eos_seen += 1
        if v.link is not None:
            v.link.ended()
        if lost:
            v.reported_lost += lost
            v.sp.note_reported_loss(lost)
            log.warning("%s: end of stream: %d input message(s) sent were never received",
                        v.name, lost)
        self.publish(v, v.sp.end_stream(None, source=source) + v.sp.fault_now())
        if nxt != "none":
            self.publish(v, v.sp.end_stream(nxt))
        v.holding = False

    def _idle_release(self) -> None:
        """Release what a vehicle holds for reordering once no input came for idle_release_s
        (wall time): the end of a stream without a marker ends as ``radical process`` ends."""
        if self.idle_release_s is None:
            return
        now = self._mono()
        for v in self.vehicles.values():
            if v.holding and now - v.last_input_mono >= self.idle_release_s:
                v.holding = False
                v.idle_releases += 1
                self.publish(v, v.sp.end_stream(None))
                log.info("%s: no input for %.3g s: held samples released", v.name,
                         now - v.last_input_mono)

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
            self.publish(v, outs)
            return
        t_fed = time.monotonic_ns()
        self.publish(v, outs)
        self.timing.record(v.name, topic, t_recv, t_start, t_fed, time.monotonic_ns(), outs)

    def publish(self, v: Vehicle, outs: list[tuple[str, dict[str, Any]]]) -> None:
        for topic, msg in outs:
            if topic == "diag":
                msg = {**msg, "node": v.node_info()}
                v.clock_notice.seen(msg.get("clock"), float(msg.get("t", math.nan)))
            try:  # remote_only: never back into our own input FIFO
                self.transport.put(v.prefix + topic, packb(msg),
                                   block=self.block_outputs or topic == "fault", remote_only=True)
                v.published[topic] += 1
            except Exception as exc:
                log.warning("%s: cannot publish %s: %s", v.name, topic, exc)

    def _housekeeping(self, checkpoint: bool = True) -> None:
        """Between messages (and on the idle ticks): report the inputs the FIFO dropped, watch
        the links, and write the periodic checkpoint."""
        assert self._inbox is not None
        take_drops = getattr(self._inbox, "take_drops", None)  # counts with their bytes
        dropped, nbytes = take_drops() if take_drops else (self._inbox.take_dropped(), None)
        if dropped:
            self._report_overflows(dropped, nbytes=nbytes)
        take_oversize = getattr(self._inbox, "take_oversize", None)
        oversize = take_oversize() if take_oversize is not None else None
        if oversize:
            self._report_overflows(oversize, "too_large", "payload over the size bound")
        if self.stale_after_s is not None:
            check_links(self, self._mono())
        if checkpoint and self.checkpoint_path and self._mono() >= self._next_ckpt:
            self._periodic_checkpoint()

    def _periodic_checkpoint(self) -> None:
        """The periodic write. A failure (directory removed, disk full) never stops the filter:
        it is counted (``checkpoint_failures``), its reason kept (``checkpoint_error``, in diag
        and status), logged once per failure run, and retried after ``CHECKPOINT_RETRY_S`` (or
        the period, if shorter) until a write succeeds."""
        try:
            self.write_checkpoint()
        except (commands.CommandError, ckpt.CheckpointError, OSError) as exc:
            self.checkpoint_failures += 1
            if self.checkpoint_error is None:
                log.error("periodic checkpoint failed (will retry): %s", exc)
            self.checkpoint_error = str(exc)
            self._next_ckpt = self._mono() + min(self.CHECKPOINT_RETRY_S, self.checkpoint_every_s)
            return
        if self.checkpoint_error is not None:
            log.warning("checkpoint written again after %d failure(s)", self.checkpoint_failures)
        self.checkpoint_error = None
        self._next_ckpt = self._mono() + self.checkpoint_every_s

    def _report_overflows(self, dropped: dict[str, int], reason: str = "queue_overflow",
                          what: str = "queue full", nbytes: dict[str, int] | None = None) -> None:
        for key, n in dropped.items():
            v = self.vehicles.get(key.split("/", 2)[1])
            topic = key[len(v.prefix):] if v is not None else ""
            if v is None or topic not in INPUT_TOPICS:
                continue
            if reason == "queue_overflow":
                with v.lock:
                    v.overflow[topic] += n
                    v.overflow_bytes[topic] += (nbytes or {}).get(key, 0)
            _note_reject(v.sp, "input", reason, f"{what}: {n} message(s) dropped", count=n)
            log.warning("%s: %s, %d %s message(s) dropped", v.name, what, n, topic)

    def queue_bytes_used(self) -> int | None:
        """Payload bytes waiting in the input FIFO (None: a FIFO without a byte count)."""
        used = getattr(self._inbox, "queued_bytes", None)
        return int(used()) if used is not None else None

    def queue_depth(self) -> int | None:
        """Samples waiting in the input FIFO. A Zenoh FIFO does not tell: 0 while the loop has
        found it empty (waiting, or running a command then), None while it is feeding."""
        pending = getattr(self._inbox, "pending", None)
        if pending is not None:
            return int(pending())
        return 0 if self._idle else None

    def write_checkpoint(self) -> str:
        """Write all vehicles' state now (filter loop thread, or after it stopped)."""
        if not self.checkpoint_path:
            raise commands.CommandError("no checkpoint path: start the node with --checkpoint PATH")
        try:
            path = ckpt.write(self.checkpoint_path,
                              {name: ckpt.capture(v.sp, name) for name, v in self.vehicles.items()})
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
                     resume_bump: bool = False, force_vehicle: bool = False,
                     resume_new_stream: bool = False) -> dict[str, StreamProcessor]:
    """One StreamProcessor per vehicle (own parameter table and packets), restored if resuming.

    Resuming needs the state of every served vehicle in the checkpoint; a checkpoint of another
    vehicle is refused unless ``force_vehicle`` (then a single-vehicle checkpoint is loaded into
    a single served vehicle, and served vehicles the file does not hold start cold). Raises
    ParamError / PacketError / CheckpointError / ValueError with one-line messages.
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
        held = sorted(doc["vehicles"])
        for name, sp in out.items():
            key = name
            if name not in doc["vehicles"]:
                if not force_vehicle:
                    raise ckpt.CheckpointError(
                        f"{resume}: checkpoint of vehicle(s) {held}, not of {name!r} (refused; "
                        "--force-vehicle overrides)")
                if len(held) == 1 and len(out) == 1:
                    key = held[0]
                    log.warning("%s: loading the state of vehicle %r (--force-vehicle)", name, key)
                else:
                    log.warning("checkpoint %s has no state for vehicle %r: it starts cold "
                                "(--force-vehicle)", resume, name)
                    continue
            state = doc["vehicles"][key]
            try:
                ckpt.restore(sp, state, bump=resume_bump, new_stream=resume_new_stream)
            except ckpt.CheckpointError as exc:
                raise ckpt.CheckpointError(f"{resume}: vehicle {key}: {exc}") from None
            log.info("%s: resumed from %s (t=%.3f, mode before restart %s)", name, resume,
                     state.get("t", math.nan), state.get("mode"))
        extra = sorted(set(held) - set(vehicles))
        if extra and not force_vehicle:
            log.warning("checkpoint %s also holds %s (not served, ignored)", resume, extra)
    return out


def warm_up(clock_mode: str = "reconstruct", seconds: float = 2.0) -> float:
    """Compile/load every Numba kernel on a throwaway engine fed a tiny synthetic stream.

    A stationary vehicle, body = inertial: SIRU batches of 10 zero increments at 100 Hz, both
    trackers at 10 Hz, a throw-away FDI hypothesis bank over it, then a warm start with both
    bump modes and a cold start. Returns seconds.
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
    if sp.engine.fdi is not None:  # the FDI bank's kernels (they run only during an alarm)
        sp.engine.fdi.compile_bank(sp.engine)
    sp.end_stream("warm")
    e = sp.engine
    e.bump({g: list(v) for g, v in e.si.bump_sigma.items()}, "scale")
    e.cold_start()
    ckpt.capture(sp, "warm-up")
    return time.perf_counter() - t0
