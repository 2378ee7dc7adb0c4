"""Fleet test helpers: watching a fleet from a client session (ownership tokens and who publishes
diag), `radical` subprocesses and waiting for a line on their stderr."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import msgpack


class FleetWatch:
    """Subscribes ``transport`` to a fleet's ownership tokens and to every vehicle's diag:
    ``most`` is the most owners any vehicle had at once, ``runs()`` each vehicle's sequence of
    publishing workers (consecutive repeats merged)."""

    def __init__(self, transport, fleet: str) -> None:
        self.lock = threading.Lock()
        self.owners: dict[str, set[str]] = {}
        self.most = 0
        self.diag: list[tuple[str, str | None]] = []
        transport.liveliness_subscribe(f"radical-fleet/{fleet}/owner/*/*", self._on_owner)
        transport.subscribe("radical/*/diag", self._on_diag)

    def _on_owner(self, key: str, alive: bool) -> None:
        v, w = key.split("/")[-2:]
        with self.lock:
            s = self.owners.setdefault(v, set())
            (s.add if alive else s.discard)(w)
            self.most = max(self.most, len(s))

    def _on_diag(self, key: str, data: bytes) -> None:
        m = msgpack.unpackb(data, raw=False, strict_map_key=False)
        with self.lock:
            self.diag.append((key.split("/")[1], (m["node"].get("fleet") or {}).get("worker")))

    def runs(self) -> dict[str, list[str | None]]:
        out: dict[str, list[str | None]] = {}
        with self.lock:
            for v, w in self.diag:
                if not out.setdefault(v, []) or out[v][-1] != w:
                    out[v].append(w)
        return out


def spawn_cli(*argv: str) -> subprocess.Popen:
    """`radical ARGV…` in a subprocess, stderr piped (text), stdout discarded."""
    return subprocess.Popen([sys.executable, "-m", "radical_rt.apps.cli", *argv],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def wait_line(p: subprocess.Popen, needle: str, timeout: float = 120.0) -> None:
    """Read p's stderr until a line contains ``needle`` (then keep the pipe drained in a
    thread); AssertionError after ``timeout`` s or when p ends first."""
    assert p.stderr is not None
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = p.stderr.readline()
        if needle in line:
            threading.Thread(target=p.stderr.read, daemon=True).start()  # keep the pipe drained
            return
        if not line and p.poll() is not None:
            break
    raise AssertionError(f"no {needle!r} from {p.args}")
