"""Fleet failover and handover times (issue #19; docs/fleet.md): `radical bench --only fleet`.

A router and two fleet workers (``radical node --fleet fb --workers 1``, separate processes)
serve N vehicles, each fed the simulator's stream at real time by this process (every SIRU read
its own message). Then, K times: the worker that serves the most vehicles is killed with
SIGKILL, and a new worker is started in its place. Per moved vehicle it measures:

* **failover** (crash): from the kill to the first ``tlm/small`` of the vehicle from the survivor;
* **handover gap** (clean join): the longest pause between two ``tlm/small`` of a vehicle that
  moves to the new worker, around the join (its ordinary period is 0.1 s);
* the calibration progress the crash lost (``lost_s``, from the takeover records).

Everything runs on this machine's cores, the driver too. Wall-clock figures, reported, never
asserted (perf/README.md, "Fleet").
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

PROFILES = {"smoke": {"vehicles": 2, "kills": 1, "stream_s": 45.0},
            "quick": {"vehicles": 6, "kills": 3, "stream_s": 120.0},
            "full": {"vehicles": 12, "kills": 8, "stream_s": 300.0}}
FLEET = "fb"


def _spawn(*argv: str, log: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "radical_rt.apps.cli", *argv],
                            stdout=subprocess.DEVNULL, stderr=open(log, "ab"))


def _wait_for(pred, timeout: float, what: str) -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = pred()
        if v:
            return v
        time.sleep(0.2)
    raise RuntimeError(f"bench fleet: timed out waiting for {what}")


class Harness:
    """Router, workers, publisher and packet watcher of one run."""

    def __init__(self, n: int, stream: dict[str, Any], work: Path) -> None:
        from radical_rt.io import zconfig
        from radical_rt.io.zenoh_transport import ZenohTransport

        self.ep = f"tcp/127.0.0.1:{zconfig.free_port()}"
        self.work, self.stream = work, stream
        self.vehicles = [f"fv{i:02d}" for i in range(n)]
        self.router = _spawn("router", "--listen", self.ep, log=work / "router.log")
        _wait_for(lambda: "ready" in (work / "router.log").read_text(errors="replace"), 60,
                  "the router")
        self.workers: list[subprocess.Popen] = []
        self.client = ZenohTransport("client", connect=[self.ep])
        self.lock = threading.Lock()
        self.arrivals: dict[str, list[float]] = {v: [] for v in self.vehicles}
        self.client.subscribe("radical/*/tlm/small", self._on_packet)
        self.stop = threading.Event()
        self.publisher: threading.Thread | None = None

    def _on_packet(self, key: str, _data: bytes) -> None:
        v = key.split("/")[1]
        with self.lock:
            self.arrivals.setdefault(v, []).append(time.monotonic())

    def add_worker(self) -> None:
        argv = ["node", "--fleet", FLEET, "--connect", self.ep, "--workers", "1",
                "--checkpoint-every", "5", *[a for v in self.vehicles for a in ("--vehicle", v)]]
        self.workers.append(_spawn(*argv, log=self.work / f"worker{len(self.workers)}.log"))

    def status(self) -> list[dict[str, Any]]:
        replies = self.client.get(f"radical-fleet/{FLEET}/status/*", b"", timeout=3.0, every=True)
        return [msgpack.unpackb(r, raw=False) for r in replies]

    def settled(self, n_workers: int) -> list[dict[str, Any]] | None:
        from radical_rt.fleet.ownership import assign

        ws = self.status()
        want = assign(self.vehicles, [w["worker"] for w in ws])
        ok = len(ws) == n_workers and all(
            w["serving"] == sorted(v for v in self.vehicles if want[v] == w["worker"]) for w in ws)
        return ws if ok else None

    def publish(self) -> None:
        """The stream at real time to every vehicle (each message to each), until stopped."""
        s = self.stream
        t0 = time.monotonic()
        for code, t, data in zip(s["topics"], s["t"], s["payloads"], strict=True):
            if self.stop.is_set():
                return
            delay = t0 + t - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            topic = ("siru", "st1", "st2", "temp")[code]
            for v in self.vehicles:
                self.client.put(f"radical/{v}/{topic}", data, block=True)

    def first_after(self, v: str, t: float) -> float | None:
        with self.lock:
            later = [a for a in self.arrivals[v] if a > t]
        return later[0] if later else None

    def longest_gap(self, v: str, t_from: float, t_to: float) -> float:
        with self.lock:
            a = [x for x in self.arrivals[v] if t_from <= x <= t_to]
        return float(np.max(np.diff(a))) if len(a) > 1 else float("nan")

    def close(self) -> None:
        self.stop.set()
        if self.publisher is not None:
            self.publisher.join(10)
        self.client.close()
        for p in [*self.workers, self.router]:
            if p.poll() is None:
                p.terminate()
        for p in [*self.workers, self.router]:
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()


def _one_round(h: Harness, out: dict[str, list[float]]) -> None:
    ws = h.settled(2)
    assert ws is not None
    victim = max(ws, key=lambda w: len(w["serving"]))
    moved = list(victim["serving"])
    pid = int(victim["worker"].split("-")[-2])
    t_kill, unix_kill = time.monotonic(), time.time()
    os.kill(pid, signal.SIGKILL)
    ws1 = _wait_for(lambda: h.settled(1), 60, "the survivor to take every vehicle")
    _wait_for(lambda: all(h.first_after(v, t_kill) for v in moved), 30, "packets after the kill")
    out["failover_s"] += [h.first_after(v, t_kill) - t_kill for v in moved]
    out["lost_s"] += [t["lost_s"] for t in ws1[0]["takeovers"]
                      if t["taken_unix"] > unix_kill and t.get("loss_flagged")]
    t_join = time.monotonic()
    h.add_worker()
    ws2 = _wait_for(lambda: h.settled(2), 120, "the new worker's share")
    newcomer = next(w for w in ws2 if w["worker"] != ws1[0]["worker"])
    time.sleep(2.0)  # packets after the handover
    out["handover_gap_s"] += [h.longest_gap(v, t_join, time.monotonic())
                              for v in newcomer["serving"]]
    out["joined"].append(len(newcomer["serving"]))  # (hashing may give a joiner nothing)


def run(profile: str = "quick", out_dir: Path | str | None = None) -> dict[str, Any]:
    from perf.live_stream import build_stream, load_stream

    cfg = PROFILES[profile]
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        build_stream(cfg["stream_s"], work / "stream.msgpack")
        h = Harness(cfg["vehicles"], load_stream(work / "stream.msgpack"), work)
        figures: dict[str, list[float]] = {"failover_s": [], "handover_gap_s": [], "lost_s": [],
                                           "joined": []}
        try:
            h.add_worker()
            h.add_worker()
            _wait_for(lambda: h.settled(2), 180, "two workers to share the vehicles")
            h.publisher = threading.Thread(target=h.publish, daemon=True)
            h.publisher.start()
            time.sleep(8.0)  # packets flowing, periodic replicas written
            for _ in range(cfg["kills"]):
                _one_round(h, figures)
        finally:
            h.close()
    res = {"schema": "radical.bench.fleet/1", "profile": profile, **cfg,
           "cpus": os.cpu_count(), "moved_to_joiners": int(sum(figures.pop("joined"))),
           **{k: _stats(v) for k, v in figures.items()},
           "samples": figures}
    if out_dir is not None:
        path = Path(out_dir) / f"fleet_{profile}.json"
        path.write_text(json.dumps(res, indent=1))
        res["json_path"] = str(path)
    return res


def _stats(xs: list[float]) -> dict[str, float | int]:
    a = np.array([x for x in xs if np.isfinite(x)], dtype=float)
    if not a.size:
        return {"n": 0}
    return {"n": int(a.size), "p50": float(np.percentile(a, 50)), "max": float(a.max()),
            "min": float(a.min())}


def markdown(res: dict[str, Any]) -> str:
    rows = [("failover (kill → first packet from the survivor)", "failover_s"),
            ("handover gap (longest packet pause of a vehicle moving to a joiner)", "handover_gap_s"),
            ("calibration progress lost by a crash (since the replica)", "lost_s")]
    lines = [f"{res['vehicles']} vehicles, 2 workers, {res['kills']} kill/join rounds, "
             f"{res['cpus']} CPUs", "", "| figure | n | p50 s | max s |", "|---|---|---|---|"]
    for label, key in rows:
        s = res[key]
        lines.append(f"| {label} | {s['n']} | {s.get('p50', float('nan')):.2f} | "
                     f"{s.get('max', float('nan')):.2f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", default="quick", choices=list(PROFILES))
    a = ap.parse_args()
    print(markdown(run(a.profile)))
