"""Optional per-message timing records of the node's filter loop (``radical node --timing-out``),
read by the live benchmarks of ``perf/``."""

from __future__ import annotations

import gc
import time
from array import array
from typing import Any

import numpy as np

from radical_rt.stream.processor import INPUT_TOPICS


class LoopTiming:
    """Optional per-message timing of the filter loop (``radical node --timing-out``, perf/).

    One record per message the loop takes: vehicle and topic indices, CLOCK_MONOTONIC ns stamps
    (comparable across processes on one host) when the loop took it from its input FIFO
    (``recv_ns``), before the StreamProcessor (``start_ns``), after it (``fed_ns``) and after its
    outputs were published (``done_ns``), and the tlm packets it published, packed as
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
        vi = self._vi.get(vehicle)
        if vi is None:  # a vehicle a fleet worker took after the start
            vi = self._vi[vehicle] = len(self.vehicles)
            self.vehicles.append(vehicle)
        self.buf.extend((vi, self._ti.get(topic, -1), recv_ns, start_ns, fed_ns, done_ns, tlm))

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
