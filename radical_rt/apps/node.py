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
* query callbacks on ``radical/<vehicle>/cmd`` and ``cmd/{read,write}/<user>`` check who may
  send it and audit it (:mod:`radical_rt.apps.cmd_access`, with the security profile ``auth``),
  parse and validate a command (:mod:`radical_rt.apps.commands`), queue it for the loop, wake the loop if it is waiting for input
  (:meth:`Inbox.wake`) and wait for its reply. A ticker wakes a waiting loop every ``TICK_S`` for
  the periodic checkpoints and overflow reports.

The StreamProcessor is the batch shell's (:func:`radical_rt.apps.batch.make_processor`), so a node fed
an archive's input messages in ``log_time`` order ends with bit-identical estimates.

This module owns :class:`FilterNode` (lifecycle, filter loop, housekeeping). Around it:
:mod:`radical_rt.apps.node_vehicle` (one served vehicle; the outputs' encoding ``packb``),
:mod:`radical_rt.apps.command_queue` (commands from the query callbacks to the loop),
:mod:`radical_rt.apps.node_eos` (end of stream), :mod:`radical_rt.apps.link_watch` (link loss),
:mod:`radical_rt.apps.node_checkpoint` (periodic and on-demand checkpoints, a mixin),
:mod:`radical_rt.apps.node_setup` (``build_processors``, ``warm_up``).
"""

from __future__ import annotations

import functools
import logging
import math
import os
import threading
import time
from collections.abc import Callable
from typing import Any

from radical_rt.apps import commands
from radical_rt.apps.cmd_access import AuditLog, handle_query
from radical_rt.apps.command_queue import CommandQueue
from radical_rt.apps.link_watch import check_links, input_seen
from radical_rt.apps.node_checkpoint import NodeCheckpoints
from radical_rt.apps.node_eos import end_of_stream, release_idle
from radical_rt.apps.node_timing import LoopTiming
from radical_rt.apps.node_vehicle import Vehicle, note_reject, packb, report_fifo_losses
from radical_rt.io.transport import Inbox, Transport
from radical_rt.io.zauth import Profile
from radical_rt.io.zenoh_transport import ZenohTransport
from radical_rt.stream.eos import EOS_TOPIC
from radical_rt.stream.processor import INPUT_TOPICS, StreamProcessor

log = logging.getLogger("radical.node")
QUEUE_BYTES = 64 << 20  # default byte bound of the input FIFO (payload bytes waiting)


class NodeStartError(RuntimeError):
    """The node could not start as asked (the message says why); nothing is left running."""



class FilterNode(NodeCheckpoints):
    """Serve one or more vehicles over a :class:`~radical_rt.io.transport.Transport`.

    processors: vehicle name → StreamProcessor (see :func:`build_processors`). checkpoint_path:
    where periodic (every ``checkpoint_every_s`` of wall time), on-command and final checkpoints
    go (None: no checkpoints; a callable ``sink(states) -> where`` takes the captured states
    instead of a file, e.g. a fleet's replica). queue_size: capacity of the input FIFO (queue_wait_s: how long a
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
    MIN_VEHICLES = 1  # a fleet's node starts with none and takes them as it goes
    CHECKPOINT_HISTORY = True  # its checkpoints carry the FDI history (a resume continues it)
    CHECKPOINT_RETRY_S = 5.0  # a failed periodic checkpoint is retried this much later [s]

    def __init__(self, transport: Transport, processors: dict[str, StreamProcessor], *,
                 checkpoint_path: Any = None, checkpoint_every_s: float = 60.0,
                 queue_size: int = 4096, queue_wait_s: float = 1.0, block_outputs: bool = False,
                 command_timeout_s: float = 5.0, monotonic: Callable[[], float] = time.monotonic,
                 timing: LoopTiming | None = None, rt_priority: int | None = None,
                 idle_release_s: float | None = None, max_payload_bytes: int | None = None,
                 queue_bytes: int | None = QUEUE_BYTES, stale_after_s: float | None = None,
                 auth: Profile | None = None):
        if len(processors) < self.MIN_VEHICLES:
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
        self.max_payload_bytes = max_payload_bytes
        if max_payload_bytes is not None:  # the size bound of every vehicle's inputs
            for sp in processors.values():
                sp.max_payload_bytes = max_payload_bytes
        self.checkpoint_path, self.checkpoint_every_s = checkpoint_path, checkpoint_every_s
        self.queue_size, self.queue_wait_s, self.queue_bytes = queue_size, queue_wait_s, queue_bytes
        self.block_outputs = block_outputs
        self.command_timeout_s = command_timeout_s
        self._cmdq = CommandQueue()
        self.auth = auth  # the security profile (None: unauthenticated)
        self.audit = AuditLog(auth, lambda key, data: transport.put(key, data, block=True,
                                                                  remote_only=True))
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
        self.open_inbox()
        self.serve()

    def open_inbox(self) -> None:
        """Declare the input FIFO only: inputs are held in it until :meth:`serve` (a fleet's
        handover holds the inputs of a vehicle before it takes it over)."""
        if len(self.vehicles) == 1:  # one FIFO for every input (see the module docstring)
            key = next(iter(self.vehicles.values())).prefix + "*"
        else:
            key = "radical/*/*"
        kw: dict[str, Any] = {"capacity_bytes": self.queue_bytes}
        if isinstance(self.transport, ZenohTransport):  # oversized samples dropped uncopied
            kw["max_payload"] = max(v.sp.max_payload_bytes for v in self.vehicles.values())
        self._inbox = self.transport.inbox(key, self.queue_size, self.queue_wait_s, **kw)

    def serve(self) -> None:
        """Start the filter loop on the open FIFO; declare queryables and liveliness tokens."""
        self.running = True
        self._next_ckpt = self._mono() + self.checkpoint_every_s
        self._thread = threading.Thread(target=self._loop, name="radical-filter", daemon=True)
        self._thread.start()
        if self.rt_priority is not None:
            self._set_realtime(self._thread)
        self._ticker = threading.Thread(target=self._tick, name="radical-tick", daemon=True)
        self._ticker.start()
        for v in self.vehicles.values():
            self._handles += self.declare_vehicle(v)
        log.info("serving %s", ", ".join(self.vehicles) or "no vehicle yet")

    def declare_vehicle(self, v: Vehicle) -> list[Any]:
        """The command queryables and the liveliness token of a served vehicle (handles)."""
        out = [self.transport.queryable(v.prefix + key, functools.partial(self._on_query, v),
                                        keyed=True)
               for key in ("cmd", "cmd/*/*")]  # the contract's key, the users' (cmd_access)
        out.append(self.transport.liveliness_token(v.prefix + "alive/filter"))
        return out

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
        self._cmdq.refuse_all("node is shutting down")  # commands that arrived too late
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
    def _on_query(self, v: Vehicle, key: str, data: bytes) -> bytes:
        return packb(handle_query(v, key, data, self.audit, self._submit))

    def _submit(self, v: Vehicle, cmd: commands.Command) -> dict[str, Any]:
        if not self.running or self._stop.is_set():
            return commands.error_reply("node is shutting down", cmd)
        return self._cmdq.submit(v, cmd, self.command_timeout_s, self._wake_if_idle)

    def _wake_if_idle(self) -> None:
        if self._idle and self._inbox is not None:  # the loop waits for input: wake it
            self._inbox.wake()

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
                    self._cmdq.run(self.vehicles)
                    self._housekeeping()
                    if self.idle_release_s is not None:
                        release_idle(self, self._mono())
                    item = inbox.recv()  # waits with the GIL released; None: woken
                    self._idle = False
                    if item is None:
                        continue
                self._cmdq.run(self.vehicles)
                self.take_input(*item)
                self._housekeeping()
            while self._mono() < self._drain_until:  # stopping: finish what is queued
                item = inbox.try_recv()
                if item is None:
                    break
                self.take_input(*item)
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

    def take_input(self, key: str, data: bytes) -> None:
        """One input sample from the FIFO (filter loop thread): route it to its vehicle and feed
        it. A subclass may extend it (a fleet's handover: :mod:`radical_rt.apps.fleet_node`)."""
        v = self.vehicles.get(key.split("/", 2)[1])
        if v is not None:  # (else a vehicle this node does not serve)
            self.take_vehicle_input(v, key[len(v.prefix):], data)

    def take_vehicle_input(self, v: Vehicle, topic: str, data: bytes) -> None:
        """One sample on ``radical/<v>/<topic>`` (filter loop thread): count and feed it."""
        t_recv = time.monotonic_ns() if self.timing is not None else 0
        if topic in INPUT_TOPICS or topic == EOS_TOPIC:
            input_seen(self, v, self._mono())
        if topic not in INPUT_TOPICS:
            if topic == EOS_TOPIC:
                end_of_stream(self, v, data)
            return  # other keys of the vehicle (the FIFO also holds a local wake-up)
        with v.lock:
            v.received[topic] += 1
        v.holding = True
        if self.idle_release_s is not None:
            v.last_input_mono = self._mono()
        self._feed(v, topic, data, t_recv)
        self._processed += 1

    def _feed(self, v: Vehicle, topic: str, data: bytes, t_recv: int = 0) -> None:
        t_start = time.monotonic_ns() if self.timing is not None else 0
        try:
            outs = v.sp.feed(topic, data)
        except Exception as exc:  # a bug below the input checks: count it, keep serving
            log.exception("%s: %s message raised", v.name, topic)
            note_reject(v.sp, topic, "internal_error", f"{type(exc).__name__}: {exc}")
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
        report_fifo_losses(self.vehicles, self._inbox)
        if self.stale_after_s is not None:
            check_links(self, self._mono())
        if checkpoint and self.checkpoint_path:
            self.checkpoint_step()

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
