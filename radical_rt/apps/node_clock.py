"""Operator notices of the node about the SIRU clock: said once, not at every diag message.

The node logs when a vehicle's clock locks, when it loses its lock, and, once, when it has not
locked after ``warn_after_s`` of stream time (with the clock's own explanation: no sawtooth wrap
yet, or only one). The same state and note are in ``diag.clock`` and in the summary of
``status`` (docs/clock.md, docs/node.md).
"""

from __future__ import annotations

import logging
import math
from typing import Any

log = logging.getLogger("radical.node")


class ClockNotice:
    """Follows one vehicle's ``diag.clock`` and logs its state changes (see the module doc)."""

    def __init__(self, vehicle: str, warn_after_s: float = 600.0) -> None:
        self.vehicle = vehicle
        self.warn_after_s = warn_after_s
        self.state: str | None = None
        self.t_start = math.nan
        self.warned = False

    def seen(self, clock: dict[str, Any] | None, t: float) -> None:
        """One diag message's clock map at stream time t [s]."""
        if not isinstance(clock, dict) or not math.isfinite(t):
            return
        state, note = clock.get("state"), clock.get("note", "")
        if not math.isfinite(self.t_start):
            self.t_start = t
        if state == "locked" and self.state != "locked":
            log.info("%s: SIRU clock locked (ε %+.3f ppm)", self.vehicle,
                     float(clock.get("freq_offset_ppm") or 0.0))
        elif self.state == "locked" and state != "locked":
            log.warning("%s: SIRU clock lost its lock: %s", self.vehicle, note)
        elif (state not in ("locked", "naive") and not self.warned
              and t - self.t_start >= self.warn_after_s):
            log.warning("%s: SIRU clock not locked after %.0f s: %s; the filter runs on the "
                        "coarse time line with its σ", self.vehicle, t - self.t_start, note)
            self.warned = True
        self.state = state
