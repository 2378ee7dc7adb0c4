"""The filter node's checkpoints: the periodic write and its retries, and a write on demand.

:class:`NodeCheckpoints` is a part of :class:`radical_rt.apps.node.FilterNode` (a mixin: it works
on the node's own state: ``vehicles``, ``checkpoint_path`` (a file path, or a callable that
takes the states and returns where they went: a fleet's replica), ``checkpoint_every_s``, the
monotonic clock ``_mono`` and the counters it keeps: ``checkpoints_written``,
``checkpoint_failures``, ``checkpoint_error``, ``last_checkpoint_mono``).
"""

from __future__ import annotations

import logging

from radical_rt.apps import commands
from radical_rt.io import checkpoint as ckpt

log = logging.getLogger("radical.node")


class NodeCheckpoints:
    """Checkpoint writes of :class:`radical_rt.apps.node.FilterNode`."""

    def checkpoint_step(self) -> None:
        """Housekeeping: the periodic checkpoint when it is due (a fleet's node staggers its
        vehicles' checkpoints instead)."""
        if self._mono() >= self._next_ckpt:
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

    def write_checkpoint(self, names: list[str] | None = None) -> str:
        """Write the state of the vehicles ``names`` (None: all) now (filter loop thread, or
        after it stopped)."""
        if not self.checkpoint_path:
            raise commands.CommandError("no checkpoint path: start the node with --checkpoint PATH")
        chosen = [self.vehicles[n] for n in names] if names is not None else list(self.vehicles.values())
        try:
            states = {v.name: ckpt.capture(v.sp, v.name, self.CHECKPOINT_HISTORY) for v in chosen}
            sink = self.checkpoint_path  # a file, or a callable (a fleet's replica) → where
            path = sink(states) if callable(sink) else ckpt.write(sink, states)
        except ckpt.CheckpointError as exc:
            raise commands.CommandError(str(exc)) from None
        self.checkpoints_written += 1
        self.last_checkpoint_mono = self._mono()
        for v in chosen:
            v.last_checkpoint_mono = self.last_checkpoint_mono
        log.debug("checkpoint written to %s", path)
        return path
