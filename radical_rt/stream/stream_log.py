"""Stream bookkeeping: which telemetry stream an output belongs to, and how each stream ended.

Both shells run several disjoint input streams through one :class:`radical_rt.stream.processor.StreamProcessor`
(``radical process A.mcap B.mcap``; the node between end-of-stream markers or ``end_stream``
commands). Streams are numbered from 0 in processing order; every output message carries that
index as ``stream`` (int) so that streams whose bus times overlap can be told apart. A
:class:`StreamLog` keeps, per stream: how it started (``cold`` / ``warm``, and the covariance bump
applied at its start), its bus-time span and, once it has ended, the engine's end estimates ± 1σ
(SI, converted to paper units only in :meth:`StreamLog.summary`). docs/contract_extensions.md,
"Streams".
"""

from __future__ import annotations

import math
from typing import Any

from radical_rt.contract.conventions import to_paper_units
from radical_rt.contract.state import PARAM_GROUPS


def _paper(groups: dict[str, Any]) -> dict[str, list[float]]:
    return {g: [float(to_paper_units(g, v)) for v in groups[g]] for g in PARAM_GROUPS
            if g in groups}


def bump_applied(si: Any) -> dict[str, Any]:
    """The configured warm-start bump (``Engine.si``) as a stream record holds it: {"mode",
    "sigma": {group: [1σ, SI]}}."""
    return {"mode": si.bump_mode, "sigma": {g: list(v) for g, v in si.bump_sigma.items()}}


class StreamLog:
    """Per-stream records of one processor. ``index``: the current stream (0-based)."""

    def __init__(self) -> None:
        self.index = 0
        self.done: list[dict[str, Any]] = []  # ended streams, in order
        self.begin("cold", None)

    def begin(self, start: str, bump: dict[str, Any] | None) -> None:
        """Open the current stream. start: "cold" | "warm" | "resume"; bump: {"mode": str,
        "sigma": {group: [1σ, SI]}} applied at the start, or None. Its ``source`` (archive path,
        replay source) is set by the caller once known."""
        self.start, self.bump, self.source = start, bump, None
        self.t_first = self.t_last = math.nan  # bus-time span of the stream's inputs [s]

    def seen(self, t: float) -> None:
        """The stream's inputs reached bus time t [s] (the first call opens its span)."""
        if math.isnan(self.t_first):
            self.t_first = t
        self.t_last = t

    def end(self, engine: Any) -> None:
        """Close the current stream with the engine's end state; the next one is index + 1."""
        self.done.append(self.record(engine))
        self.index += 1

    def record(self, engine: Any) -> dict[str, Any]:
        """The current stream's record with the engine's present estimates (SI)."""
        return {"index": self.index, "source": self.source, "start": self.start,
                "bump": self.bump, "t_bus_first": self.t_first, "t_bus_last": self.t_last,
                "t_end": float(engine.t), "mode": engine.mode,
                "estimate": engine.estimates(), "sigma": engine.sigmas()}

    def info(self) -> dict[str, Any]:
        """The current stream for the diag message: index, start, bump applied (SI), first t_bus."""
        return {"index": self.index, "start": self.start, "bump": self.bump,
                "t_bus_first": None if math.isnan(self.t_first) else self.t_first}

    def summary(self, engine: Any) -> list[dict[str, Any]]:
        """The summary's ``streams`` list (paper units): every ended stream, then the current one
        if it saw input (or if no stream has ended)."""
        recs = list(self.done)
        if not math.isnan(self.t_first) or not recs:
            recs.append(self.record(engine))
        out = []
        for r in recs:
            bump = r["bump"]
            out.append({"index": r["index"], "source": r["source"], "start": r["start"],
                        "bump": None if bump is None else {"mode": bump["mode"],
                                                           "sigma": _paper(bump["sigma"])},
                        "t_bus": [_num(r["t_bus_first"]), _num(r["t_bus_last"])],
                        "t_end": r["t_end"], "mode": r["mode"],
                        "converged": r["mode"] == "converged",
                        "estimate": _paper(r["estimate"]), "sigma": _paper(r["sigma"])})
        return out


def _num(v: float) -> float | None:
    return None if math.isnan(v) else float(v)
