"""Helpers of the replay and record tests (tests/replayer): archive contents per topic, Zenoh
sessions on loopback (free ports, multicast scouting off), a recorder thread with a counting
subscriber, and a fake Zenoh session whose publishers log what replay() puts."""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

from radical_rt.io import zconfig
from radical_rt.io.archive import (
    INPUT_TOPICS,
    ArchiveReader,
)
from replayer.recorder import record

ROOT = Path(__file__).resolve().parents[2]  # the repository
VEH = "testveh"


def inputs_of(path: Path | str, start_ns: int | None = None, end_ns: int | None = None,
              ) -> dict[str, list[tuple[int, bytes]]]:
    """Per input topic, the (log_time, payload) list of an archive (optionally a window)."""
    out: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
    with ArchiveReader(path) as r:
        for topic, t, data in r.iter_raw(INPUT_TOPICS, start_ns, end_ns):
            out[topic].append((t, data))
    return dict(out)


def recorded(path: Path | str) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
    with ArchiveReader(path) as r:
        for topic, t, data in r.iter_raw():
            out[topic].append((t, data))
    return dict(out)


def ep() -> str:
    """tcp/127.0.0.1:PORT on a free port."""
    return f"tcp/127.0.0.1:{zconfig.free_port()}"


@contextlib.contextmanager
def session(listen: str | None = None, connect: str | None = None):
    """A Zenoh peer session from zconfig.make_config (loopback endpoints, no multicast scouting)."""
    import zenoh

    s = zenoh.open(zconfig.make_config("peer", listen=[listen] if listen else [],
                                       connect=[connect] if connect else []))
    try:
        yield s
    finally:
        s.close()


class Recorder:
    """record() in a thread on its own session, plus a counting subscriber on the same keys."""

    def __init__(self, out: Path, zs, vehicle: str = VEH, **kw) -> None:
        self.stop, self.ready, self.result = threading.Event(), threading.Event(), {}
        self.count = 0

        def counter(_sample) -> None:
            self.count += 1

        self._counter = zs.declare_subscriber(f"radical/{vehicle}/**", counter)
        self.thread = threading.Thread(target=lambda: self.result.update(record(
            out, vehicle, zs, stop_event=self.stop, ready_event=self.ready, **kw)), daemon=True)
        self.thread.start()
        assert self.ready.wait(10)

    def finish(self, expect: int | None = None, timeout: float = 20.0) -> dict:
        """Wait until ``expect`` samples have arrived (if given), then stop and join."""
        t_end = time.monotonic() + timeout
        while expect is not None and self.count < expect and time.monotonic() < t_end:
            time.sleep(0.02)
        time.sleep(0.2)  # the recorder's own callback may run after the counter's
        self.stop.set()
        self.thread.join(15)
        assert not self.thread.is_alive()
        self._counter.undeclare()
        return self.result


def cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "radical_rt.apps.cli", *args]


def n_msgs(d: dict[str, list]) -> dict[str, int]:
    return {k: len(v) for k, v in sorted(d.items())}


# --------------------------------------------------------------------- without Zenoh (fake bus)
class FakePub:
    def __init__(self, log: list, key: str) -> None:
        self.log, self.key = log, key
        self.matching_status = type("M", (), {"matching": True})()

    def put(self, data: bytes) -> None:
        self.log.append((time.monotonic(), self.key, bytes(data)))

    def undeclare(self) -> None:
        pass


class FakeSession:
    """Enough of zenoh.Session for replay(): publishers that log (monotonic, key, payload); the
    end-of-stream markers (``.../eos``) go to their own log."""

    def __init__(self) -> None:
        self.log: list[tuple[float, str, bytes]] = []
        self.eos_log: list[tuple[float, str, bytes]] = []
        self.declared: list[tuple[str, dict]] = []

    def declare_publisher(self, key: str, **kw) -> FakePub:
        self.declared.append((key, kw))
        return FakePub(self.eos_log if key.endswith("/eos") else self.log, key)


def archive_order(path: Path, start_ns=None, end_ns=None) -> list[tuple[str, int, bytes]]:
    """The input messages of an archive (optionally a window) in replay order: (topic, log_time
    [ns], payload)."""
    with ArchiveReader(path) as r:
        return list(r.iter_raw(INPUT_TOPICS, start_ns, end_ns))

