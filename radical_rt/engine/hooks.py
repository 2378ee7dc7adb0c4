"""What the engine asks of the process that drives it, as a small protocol passed at construction.

The engine calls its hooks object at three points: the σ of the gyro time line when it loads its
scalar state (tracker noise and the consider rule, docs/engine.md §3.3), the wake times before
each compiled call (when the window hook has work although the flags stay the same), and the
window hook itself after a close where the compiled loop stops. The stream processor
(:class:`radical_rt.stream.processor.StreamProcessor`) is the usual implementation; the maneuver
design tool passes a clock model of its own; :class:`NoHooks` is the default (a perfect clock,
no outputs).
"""

from __future__ import annotations

import math
from typing import Protocol


class EngineHooks(Protocol):
    """The engine's collaborator (see the module docstring)."""

    def timing_sigma(self, t: float) -> float:
        """1σ [s] of the gyro time line at engine time t [s] (0: exact)."""
        ...

    def wake(self) -> tuple[float, float]:
        """(wake_t, wake_e): the event time and the engine time [s] from which :meth:`on_window`
        has work although the engine's flags stay the same (−inf: at once, inf: never)."""
        ...

    def on_window(self, t: float) -> None:
        """After a window close at event time t [s] (the engine's mode and flags are current)."""
        ...


class NoHooks:
    """Hooks of an engine run on its own: an exact time line, nothing to wake for, no outputs."""

    def timing_sigma(self, t: float) -> float:
        return 0.0

    def wake(self) -> tuple[float, float]:
        return math.inf, math.inf

    def on_window(self, t: float) -> None:
        return None
