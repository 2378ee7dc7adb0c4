"""Commands on their way from the query callbacks to the filter loop (docs/node.md, "Commands").

A query callback (:meth:`radical_rt.apps.node.FilterNode` on ``radical/<vehicle>/cmd``) parses and
validates a command (:mod:`radical_rt.apps.commands`), then :meth:`CommandQueue.submit` queues it,
wakes the loop and waits for the reply; the loop applies the queued commands between two messages
(:meth:`CommandQueue.run`). A command whose caller gave up waiting is never applied late.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Any

from radical_rt.apps import commands
from radical_rt.apps.node_vehicle import Vehicle

log = logging.getLogger("radical.node")


class PendingCommand:
    """A command waiting for the filter loop; the reply is handed back through an event."""

    def __init__(self, vehicle: Vehicle, cmd: commands.Command) -> None:
        self.vehicle, self.cmd = vehicle, cmd
        self.done = threading.Event()
        self.lock = threading.Lock()
        self.state = "pending"  # → running → done, or pending → cancelled
        self.reply: dict[str, Any] = {}

    def claim(self) -> bool:
        """Filter loop: take the command to apply it (False: its caller gave up waiting)."""
        with self.lock:
            if self.state != "pending":
                return False
            self.state = "running"
            return True

    def finish(self, reply: dict[str, Any]) -> None:
        """Filter loop: hand the reply back to the waiting caller."""
        self.reply = reply
        with self.lock:
            self.state = "done"
        self.done.set()

    def wait(self, timeout: float) -> dict[str, Any]:
        """Query callback: the reply, or a refusal if the loop did not take the command within
        ``timeout`` [s]."""
        if not self.done.wait(timeout):
            with self.lock:
                if self.state == "pending":
                    self.state = "cancelled"
                    return commands.error_reply(
                        f"not applied: the filter loop did not take the command within {timeout:g} s",
                        self.cmd)
            self.done.wait()  # running: finishing is quick
        return self.reply



class CommandQueue:
    """The bounded queue of :class:`PendingCommand` between the query callbacks and the loop."""

    def __init__(self, maxsize: int = 64) -> None:
        self.q: queue.Queue = queue.Queue(maxsize=maxsize)

    def empty(self) -> bool:
        """No command is waiting for the loop."""
        return self.q.empty()

    def submit(self, vehicle: Vehicle, cmd: commands.Command, timeout: float,
               wake: Callable[[], None]) -> dict[str, Any]:
        """Query callback: queue ``cmd``, ``wake()`` the loop, wait up to ``timeout`` [s] for
        the reply (a refusal when the queue is full or the loop did not take it in time)."""
        p = PendingCommand(vehicle, cmd)
        try:
            self.q.put_nowait(p)
        except queue.Full:
            return commands.error_reply("too many pending commands, try again", cmd)
        wake()
        return p.wait(timeout)

    def run(self, served: dict[str, Vehicle] | None = None) -> None:
        """Filter loop, between two messages: apply every pending command, in order (refused
        for a vehicle no longer in ``served``: a fleet worker let it go meanwhile)."""
        if self.q.empty():  # the common case: no exception raised per message
            return
        while True:
            try:
                p = self.q.get_nowait()
            except queue.Empty:
                return
            if not p.claim():
                continue  # the caller gave up waiting: never apply it late
            if served is not None and served.get(p.vehicle.name) is not p.vehicle:
                p.finish(commands.error_reply("vehicle no longer served by this node", p.cmd))
                continue
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


    def refuse_all(self, message: str) -> None:
        """Answer every command still queued with an error ``message`` (the node stops)."""
        while True:
            try:
                p = self.q.get_nowait()
            except queue.Empty:
                break
            if p.claim():
                p.finish(commands.error_reply(message, p.cmd))
