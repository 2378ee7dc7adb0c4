"""Live-bench harness shared by bench_latency, bench_capacity and bench_startup.

Each measurement runs real processes on loopback Zenoh:

* a **driver** (``python -m perf.live drive``) that listens on a free ``tcp/127.0.0.1`` port,
  publishes an input stream for one or more vehicles at real rate and records, on
  CLOCK_MONOTONIC, the instant just before every ``put`` and the arrival of every ``tlm/*``
  packet. It is at once the replayer and the ground station;
* ``radical node`` connecting to it, with ``--timing-out`` so that its filter loop records the
  taken/fed/published instants of every message (:class:`radical_rt.apps.node_timing.LoopTiming`);
* for the reference, a **ping** and a **pong** process (``python -m perf.live ping|pong``)
  bouncing 96-byte msgpack messages at 100 Hz.

Every process is pinned with ``taskset`` to the same CPU set (by default the first two CPUs this
process may use) before Zenoh starts its threads. CLOCK_MONOTONIC is one clock for every process
on the host, so stamps taken in different processes are subtracted directly.

The input stream is the simulator's 2006216 scenario (seeded), with each SIRU read published as
its own message at its bus time (100 Hz; ``batch`` reads per message if asked), the trackers at
10 Hz and the temperatures at 1 Hz. Several vehicles get the same stream, each shifted by its own
phase (a low-discrepancy spread over one tracker period), as independent spacecraft would be.

Analysis (:func:`analyse`), per vehicle, after the warm-up:

* ``service``: publication of a SIRU message → the node has fed it and published its outputs;
* ``reaction``: publication of the message that triggered a tlm packet → reception of the packet;
* ``inclusion``: publication of a SIRU sample → reception of the first tlm packet that includes
  it: whose ``t`` is at least the sample's reconstructed time (the node's own clock, replayed
  offline here) less half a sample period (``INCLUSION_TOL_S``: a sample-triggered packet's ``t``
  is the clock's prediction for the newest read, µs off the value reconstructed later);
* node-internal: taken from the node's input FIFO → published (``node_total``), split into the
  wait before the feed, StreamProcessor and publish; the Zenoh hop in (``hop_in``: publication →
  the filter loop takes it from its FIFO, so the FIFO wait is included) and the way out
  (``hop_out``: the node starts publishing a message's outputs → the packet is received; ``put``
  returns after the subscriber may already have the packet, so the end of publishing is no
  reference).

A deadline miss is a latency above the 10 ms SIRU sample period.

This module starts and collects the sessions (:func:`node_session`, :func:`rtt_run`,
:func:`memory_run`) and is the children's entry point (:func:`main`). The parts:
:mod:`perf.live_host` (pinning, launching, process statistics, :class:`~perf.live_host.LiveError`),
:mod:`perf.live_stream` (the input stream, packet presets, sample times), :mod:`perf.live_roles`
(the driver, ping, pong and memory processes), :mod:`perf.live_analysis` (:func:`analyse`).
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from perf.live_analysis import misses, pct
from perf.live_host import ROOT, LiveError, child_env, pinned, proc_stat, radical_argv, stop_process
from perf.live_roles import role_drive, role_memory, role_ping, role_pong
from perf.live_stream import build_stream, load_stream, vehicle_names


def _spawn(argv: list[str], cpus: list[int], env: dict[str, str] | None, log: Path,
           stdout_pipe: bool = False) -> subprocess.Popen:
    return subprocess.Popen(pinned(argv, cpus), env=child_env(env), cwd=str(ROOT),
                            stdout=subprocess.PIPE if stdout_pipe else open(log.with_suffix(".out"), "wb"),
                            stderr=open(log, "wb"), text=stdout_pipe)


class StampedLog:
    """Copy a child's stderr to a file, keeping the monotonic ns at which each line arrived."""

    def __init__(self, p: subprocess.Popen, path: Path) -> None:
        self.lines: list[tuple[int, str]] = []
        self.path = path
        self._th = threading.Thread(target=self._read, args=(p,), daemon=True)
        self._th.start()

    def _read(self, p: subprocess.Popen) -> None:
        with open(self.path, "w") as f:
            for raw in p.stderr:  # type: ignore[union-attr]
                line = raw.decode(errors="replace") if isinstance(raw, bytes) else raw
                self.lines.append((time.monotonic_ns(), line.rstrip("\n")))
                f.write(line)
                f.flush()

    def join(self, timeout: float = 5.0) -> None:
        self._th.join(timeout)

    def first(self, text: str) -> tuple[int, str] | None:
        return next(((t, line) for t, line in self.lines if text in line), None)

    def text(self) -> str:
        return "\n".join(line for _t, line in self.lines)


def _wait_line(p: subprocess.Popen, word: str, timeout: float, what: str) -> None:
    """Wait for a line containing ``word`` on the process's stdout pipe."""
    box: list[str] = []

    def reader() -> None:
        for line in p.stdout:  # type: ignore[union-attr]
            if word in line:
                box.append(line)
                return

    th = threading.Thread(target=reader, daemon=True)
    th.start()
    th.join(timeout)
    if not box:
        raise LiveError(f"{what} did not start within {timeout:g} s (exit code {p.poll()})")

def rtt_run(n: int, rate: float, cpus: list[int], work: Path, warmup: int = 50) -> dict[str, Any]:
    """Zenoh round trip between two pinned processes at ``rate`` Hz (the reference)."""
    from radical_rt.io.zconfig import free_port

    ep = f"tcp/127.0.0.1:{free_port()}"
    me = [sys.executable, "-m", "perf.live"]
    pong = _spawn([*me, "pong", "--listen", ep, "--timeout", str(n / rate + 120)], cpus, None,
                  work / "pong.log", stdout_pipe=True)
    try:
        _wait_line(pong, "LISTENING", 60, "pong")
        out = work / "ping.npz"
        ping = _spawn([*me, "ping", "--connect", ep, "--n", str(n), "--rate", str(rate),
                       "--warmup", str(warmup), "--out", str(out)], cpus, None, work / "ping.log")
        try:
            rc = ping.wait(n / rate + 120)
        finally:
            stop_process(ping, signal.SIGTERM)
        if rc != 0 or not out.exists():
            raise LiveError(f"ping failed (exit {rc}): {(work / 'ping.log').read_text()[-500:]}")
    finally:
        stop_process(pong)
    d = np.load(out)
    ok = d["t_back"] > 0
    rtt = (d["t_back"] - d["t_send"])[ok]
    one = (d["t_pong"] - d["t_send"])[ok]
    return {"rate_hz": rate, "n": n, "lost": int((~ok).sum()), "rtt_ms": pct(rtt),
            "one_way_ms": pct(one), "rtt_misses": misses(rtt)}

def memory_run(stream_path: Path, steps: list[int], packets: str | None, cpus: list[int],
               work: Path, growth_s: float | None = None, growth_vehicles: int = 2,
               growth_every_s: float = 60.0) -> dict[str, Any]:
    """Memory per vehicle from :func:`role_memory` (least-squares slope of RSS against N) and,
    with ``growth_s``, the RSS per vehicle against stream time over a ``growth_s`` stream."""
    out = work / "memory.json"
    argv = [sys.executable, "-m", "perf.live", "memory", "--stream", str(stream_path),
            "--steps", ",".join(map(str, steps)), "--out", str(out)]
    if packets:
        argv += ["--packets", packets]
    if growth_s:
        long = work / "growth_stream.mpk"
        build_stream(growth_s, long)
        argv += ["--growth-stream", str(long), "--growth-vehicles", str(growth_vehicles),
                 "--growth-every", str(growth_every_s)]
    p = _spawn(argv, cpus, None, work / "memory.log")
    rc = p.wait(1800)
    if rc != 0:
        raise LiveError(f"memory run failed ({rc}): {(work / 'memory.log').read_text()[-800:]}")
    doc = json.loads(out.read_text())
    pts = doc["points_kb"]
    x = np.array([q[0] for q in pts], dtype=float)
    y = np.array([q[1] for q in pts], dtype=float) / 1024
    slope, base = np.polyfit(x[1:], y[1:], 1) if len(x) > 2 else (float("nan"), float("nan"))
    res: dict[str, Any] = {
        "points_mb": [[int(q[0]), q[1] / 1024] for q in pts], "per_vehicle_mb": float(slope),
        "first_vehicle_mb": float(y[1] - y[0]) if len(y) > 1 else None, "base_mb": float(base),
        "stream_s": load_stream(stream_path)["duration_s"]}
    if doc["growth_kb"]:
        nv = doc["growth_vehicles"]
        res["growth_mb_per_vehicle"] = [[t, kb / 1024 / nv] for t, kb in doc["growth_kb"]]
    return res

@dataclass
class NodeRun:
    """Raw data of one driver + node session (see :func:`node_session`)."""

    drive: dict[str, np.ndarray]  # the driver's arrays (publish and receive times, packets)
    timing: dict[str, np.ndarray] | None  # the node's LoopTiming records
    rss: np.ndarray  # (k, 3): monotonic ns, RSS kB, CPU s of the node process
    t_launch_ns: int
    node_rc: int | None
    jit_s: float | None  # the node's "Numba kernels ready in X s" (its warm-up step)
    jit_line_s: float | None  # that log line, s after the launch
    ready_line_s: float | None  # the "ready" log line, s after the launch
    n_vehicles: int
    log_tail: str


def node_session(stream_path: Path, n_vehicles: int, packets: str | None, cpus: list[int],
                 work: Path, *, rate: float = 1.0, env: dict[str, str] | None = None,
                 aligned: bool = False, until_first_packet: bool = False, wait_node: float = 600.0,
                 linger: float = 1.5, tag: str = "run", node_args: list[str] | None = None,
                 driver_cpus: list[int] | None = None) -> NodeRun:
    """Start the driver (listening) and ``radical node`` (connecting), stream, stop, collect."""
    from radical_rt.io.zconfig import free_port

    ep = f"tcp/127.0.0.1:{free_port()}"
    drv_out = work / f"{tag}_drive.npz"
    timing = work / f"{tag}_timing.npz"
    node_log = work / f"{tag}_node.log"
    drv = _spawn([sys.executable, "-m", "perf.live", "drive", "--listen", ep, "--stream",
                  str(stream_path), "--vehicles", str(n_vehicles), "--out", str(drv_out),
                  "--rate", str(rate), "--wait-node", str(wait_node), "--linger", str(linger),
                  *(["--aligned"] if aligned else []),
                  *(["--until-first-packet"] if until_first_packet else [])],
                 driver_cpus if driver_cpus is not None else cpus, None, work / f"{tag}_drive.log",
                 stdout_pipe=True)
    node = None
    rss: list[tuple[int, int, float]] = []  # (monotonic ns, kB, cpu s)
    try:
        _wait_line(drv, "LISTENING", 60, "the driver")
        argv = [*radical_argv(), "node", "--connect", ep, "--log-level", "info",
                "--timing-out", str(timing), *(node_args or [])]
        for v in vehicle_names(n_vehicles):
            argv += ["--vehicle", v]
        if packets:
            argv += ["--packets", packets]
        t_launch = time.monotonic_ns()
        node = subprocess.Popen(pinned(argv, cpus), env=child_env(env), cwd=str(ROOT),
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        node_stderr = StampedLog(node, node_log)
        limit = time.monotonic() + wait_node + 60 + (0 if until_first_packet else 3600)
        while drv.poll() is None:
            st = proc_stat(node.pid)
            if st is not None:
                rss.append((time.monotonic_ns(), st[0], st[1]))
            if node.poll() is not None:
                node_stderr.join()
                raise LiveError(f"radical node exited early ({node.returncode}): "
                                f"{node_stderr.text()[-800:]}")
            if time.monotonic() > limit:
                raise LiveError("the driver did not finish in time")
            time.sleep(0.25)
        if drv.returncode != 0:
            raise LiveError(f"driver failed ({drv.returncode}): "
                            f"{(work / f'{tag}_drive.log').read_text()[-800:]}")
        st = proc_stat(node.pid)
        if st is not None:
            rss.append((time.monotonic_ns(), st[0], st[1]))
        rc = stop_process(node)
    finally:
        stop_process(drv, signal.SIGTERM)
        if node is not None:
            stop_process(node)
    node_stderr.join()
    log_text = node_stderr.text()
    jit_s = jit_line_s = ready_line_s = None
    hit = node_stderr.first("Numba kernels ready in")
    if hit is not None:
        jit_line_s = (hit[0] - t_launch) * 1e-9
        try:
            jit_s = float(hit[1].split("ready in")[1].split()[0])
        except (IndexError, ValueError):
            pass
    hit = node_stderr.first("; ready")
    if hit is not None:
        ready_line_s = (hit[0] - t_launch) * 1e-9
    return NodeRun(drive=dict(np.load(drv_out)), timing=dict(np.load(timing)) if timing.exists() else None,
                   rss=np.array(rss, dtype=np.float64).reshape(-1, 3), t_launch_ns=t_launch,
                   node_rc=rc, jit_s=jit_s, jit_line_s=jit_line_s, ready_line_s=ready_line_s,
                   n_vehicles=n_vehicles, log_tail=log_text[-2000:])

def main(argv: list[str] | None = None) -> int:
    """``python -m perf.live drive|memory|pong|ping``: run one child role (:mod:`perf.live_roles`)."""
    ap = argparse.ArgumentParser(prog="python -m perf.live", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="role", required=True)
    p = sub.add_parser("drive")
    ends = p.add_mutually_exclusive_group(required=True)
    ends.add_argument("--listen", help="listen here (the node connects to the driver)")
    ends.add_argument("--connect", help="connect to a router (a fleet's)")
    p.add_argument("--stream", required=True)
    p.add_argument("--vehicles", type=int, default=1)
    p.add_argument("--out", required=True)
    p.add_argument("--rate", type=float, default=1.0)
    p.add_argument("--wait-node", type=float, default=600.0)
    p.add_argument("--linger", type=float, default=1.5)
    p.add_argument("--aligned", action="store_true")
    p.add_argument("--until-first-packet", action="store_true")
    p = sub.add_parser("memory")
    p.add_argument("--stream", required=True)
    p.add_argument("--steps", default="1,2,4,8,16")
    p.add_argument("--packets")
    p.add_argument("--out", required=True)
    p.add_argument("--growth-stream")
    p.add_argument("--growth-vehicles", type=int, default=2)
    p.add_argument("--growth-every", type=float, default=60.0)
    p = sub.add_parser("pong")
    p.add_argument("--listen", required=True)
    p.add_argument("--timeout", type=float, default=600.0)
    p = sub.add_parser("ping")
    p.add_argument("--connect", required=True)
    p.add_argument("--n", type=int, default=1000)
    p.add_argument("--rate", type=float, default=100.0)
    p.add_argument("--warmup", type=int, default=50)
    p.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    from radical_rt.io.zconfig import check_endpoint
    for ep in (getattr(a, "listen", None), getattr(a, "connect", None)):
        if ep:
            check_endpoint(ep)
    return {"drive": role_drive, "pong": role_pong, "ping": role_ping,
            "memory": role_memory}[a.role](a)


if __name__ == "__main__":
    sys.exit(main())
