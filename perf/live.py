"""Live-bench harness shared by bench_latency, bench_capacity and bench_startup.

Each measurement runs real processes on loopback Zenoh:

* a **driver** (``python -m perf.live drive``) that listens on a free ``tcp/127.0.0.1`` port,
  publishes an input stream for one or more vehicles at real rate and records, on
  CLOCK_MONOTONIC, the instant just before every ``put`` and the arrival of every ``tlm/*``
  packet. It is at once the replayer and the ground station;
* ``radical node`` connecting to it, with ``--timing-out`` so that its filter loop records the
  taken/fed/published instants of every message (:class:`radical_rt.apps.node.LoopTiming`);
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
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

DEADLINE_NS = 10_000_000  # the SIRU sample period
INPUT_TOPICS = ("siru", "st1", "st2", "temp")  # = radical_rt.stream.processor.INPUT_TOPICS (codes 0..3)
KINDS = ("small", "medium", "large")
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0
PING_KEY, PONG_KEY = "radical_bench/ping", "radical_bench/pong"
ROOT = Path(__file__).resolve().parent.parent


class LiveError(RuntimeError):
    """A live run could not be completed (a process failed, a time-out)."""


# ------------------------------------------------------------------------------------ helpers
def default_cpus() -> list[int]:
    """The first two CPUs this process may run on (the whole machine on a 2-vCPU host)."""
    try:
        return sorted(os.sched_getaffinity(0))[:2]
    except AttributeError:  # pragma: no cover - not Linux
        return []


def pinned(argv: list[str], cpus: list[int]) -> list[str]:
    """argv prefixed with ``taskset -c CPUS`` (exec'd, so the pid is the program's own)."""
    if cpus and shutil.which("taskset"):
        return ["taskset", "-c", ",".join(map(str, cpus)), *argv]
    return argv


def radical_argv() -> list[str]:
    """How to launch ``radical`` from this interpreter (the venv's console script if present)."""
    script = Path(sys.executable).with_name("radical")
    return [str(script)] if script.exists() else [sys.executable, "-m", "radical_rt.apps.cli"]


def child_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.setdefault("PYTHONUNBUFFERED", "1")
    env.update(extra or {})
    return env


def proc_stat(pid: int) -> tuple[int, float] | None:
    """(RSS in kB, CPU seconds user+system) of a process, or None if it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            rss = next(int(line.split()[1]) for line in f if line.startswith("VmRSS:"))
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        ticks = os.sysconf("SC_CLK_TCK")
        return rss, (int(fields[11]) + int(fields[12])) / ticks
    except (OSError, StopIteration, ValueError, IndexError):
        return None


def stop_process(p: subprocess.Popen, sig: int = signal.SIGINT, timeout: float = 20.0) -> int | None:
    """Signal one process we started (by its pid), wait, then kill it if it does not exit."""
    if p.poll() is None:
        try:
            p.send_signal(sig)
            return p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)
    return p.returncode


def pct(x: np.ndarray, scale: float = 1e-6) -> dict[str, Any]:
    """p50/p90/p99/p99.9/max/mean of ns values, in ms (scale 1e-6), and n."""
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0:
        return {"n": 0}
    q = np.percentile(x, [50, 90, 99, 99.9])
    return {"n": int(x.size), "p50": q[0] * scale, "p90": q[1] * scale, "p99": q[2] * scale,
            "p99_9": q[3] * scale, "max": float(x.max()) * scale, "mean": float(x.mean()) * scale}


def misses(x: np.ndarray, deadline_ns: int = DEADLINE_NS) -> dict[str, Any]:
    x = np.asarray(x)
    n = int((x > deadline_ns).sum())
    return {"n": int(x.size), "misses": n, "frac": n / x.size if x.size else float("nan")}


def machine_info() -> dict[str, Any]:
    """CPU model and count, load average and package versions (for the results table)."""
    info: dict[str, Any] = {"python": platform.python_version(), "platform": platform.platform(),
                            "cpus_online": os.cpu_count()}
    try:
        info["cpus_allowed"] = sorted(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        pass
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                info["cpu_model"] = line.split(":", 1)[1].strip()
                break
    except OSError:  # pragma: no cover
        pass
    try:
        info["loadavg"] = [float(x) for x in open("/proc/loadavg").read().split()[:3]]
    except OSError:  # pragma: no cover
        pass
    from importlib.metadata import PackageNotFoundError, version
    for pkg in ("numba", "llvmlite", "numpy", "eclipse-zenoh", "msgpack"):
        try:
            info[pkg] = version(pkg)
        except PackageNotFoundError:  # pragma: no cover
            info[pkg] = None
    return info


# ------------------------------------------------------------------------------------ packets
def trigger_supported() -> bool:
    """Whether this version's packet files know ``trigger`` (sample-triggered telemetry)."""
    from radical_rt.stream.telemetry import PacketError, parse_packets
    try:
        parse_packets({"small": {"trigger": "sample", "period_s": 0.01}})
        return True
    except PacketError:
        return False


SMALL_FIELDS = ["seq", "t", "q_body_from_inertial", "flags", "mode"]


def packet_presets() -> dict[str, str | None]:
    """Named packet files (TOML text): ``window`` (tlm/small at every 0.1 s window close, the
    filter's lagged estimate) and ``sample`` (tlm/small after every SIRU sample with the predicted
    attitude and rate; None when this version has no sample trigger). medium/large keep their
    defaults (1 Hz, window-triggered)."""
    has = trigger_supported()
    fields = json.dumps(SMALL_FIELDS)
    window = f'[packets.small]\nperiod_s = 0.1\nfields = {fields}\n'
    if has:
        window += 'trigger = "window"\n'
    sample = None
    if has:
        sample = ('[packets.small]\nperiod_s = 0.01\ntrigger = "sample"\n'
                  f'fields = {json.dumps(SMALL_FIELDS + ["omega_body"])}\n')
    return {"window": window, "sample": sample}


def packet_file(config: str, directory: Path) -> str | None:
    """A packet file path for a preset name or an existing TOML path (None: node defaults)."""
    if config == "default":
        return None
    if config in ("window", "sample"):
        text = packet_presets()[config]
        if text is None:
            raise LiveError(f"packet preset {config!r} needs sample-triggered packets, which this "
                            "version of radical_rt.stream.telemetry does not have")
        path = directory / f"packets_{config}.toml"
        path.write_text(text)
        return str(path)
    if not Path(config).is_file():
        raise LiveError(f"packet config {config!r}: not a preset (window, sample, default) or a file")
    return config


# ------------------------------------------------------------------------------------ stream
def build_stream(duration_s: float, path: Path, batch: int = 1, seed: int = 1,
                 scenario: str = "2006216") -> dict[str, Any]:
    """Synthesize ``duration_s`` of a scenario and write the input stream to ``path`` (msgpack).

    batch: SIRU reads per published message (1: every read at its own bus time, 100 Hz; 0: keep
    the archive's batching). Returns the stream dict (topic codes, times from the start [s],
    payloads, per SIRU message its reads' ``tt``).
    """
    from radical_rt.io.archive import ArchiveReader
    from replayer.synth.api import synthesize

    with tempfile.TemporaryDirectory() as tmp:
        sim = Path(tmp) / "sim.mcap"
        synthesize(scenario, sim, seed=seed, duration=duration_s)
        items: list[tuple[int, int, int, bytes, list[int]]] = []
        with ArchiveReader(sim) as reader:
            for order, (topic, log_ns, data) in enumerate(
                    reader.iter_raw(topics=[f"/{t}" for t in INPUT_TOPICS])):
                code = INPUT_TOPICS.index(topic[1:])
                if code != 0:
                    items.append((log_ns, order, code, data, []))
                    continue
                m = msgpack.unpackb(data)
                k = len(m["t_bus"])
                step = k if batch <= 0 else batch
                for j in range(0, k, step):
                    part = {"v": m.get("v", 1), "t_bus": m["t_bus"][j:j + step],
                            "tt": m["tt"][j:j + step], "dtheta": m["dtheta"][j:j + step],
                            "status": m["status"][j:j + step]}
                    items.append((round(part["t_bus"][-1] * 1e9), order, 0,
                                  msgpack.packb(part, use_bin_type=True), list(part["tt"])))
    items.sort(key=lambda it: (it[0], it[1]))
    t0 = items[0][0]
    stream = {"topics": [it[2] for it in items], "t": [(it[0] - t0) * 1e-9 for it in items],
              "payloads": [it[3] for it in items], "tt": [it[4] for it in items],
              "duration_s": duration_s, "batch": batch, "seed": seed, "scenario": scenario}
    path.write_bytes(msgpack.packb(stream, use_bin_type=True))
    return stream


def load_stream(path: str | Path) -> dict[str, Any]:
    return msgpack.unpackb(Path(path).read_bytes(), raw=False)


INCLUSION_TOL_S = 0.005  # half the 10 ms SIRU sample period


def sample_times(stream: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Reconstructed time of every distinct SIRU sample and the stream index of its first read.

    Runs the node's clock (same class, same default configuration, same message split, hence
    bit-identical times) over the stream's SIRU messages offline; bridged samples (never read)
    are skipped.
    """
    from radical_rt.clock.siru_clock import ClockConfig, SiruClock
    from radical_rt.stream.packets import decode_siru

    clock = SiruClock(ClockConfig(), n_gyro=4)
    reads: list[tuple[int, int]] = []  # (tt, stream index) of every read, in order
    t_out, idx_out = [], []
    ptr = 0
    for i, (code, payload) in enumerate(zip(stream["topics"], stream["payloads"], strict=True)):
        if code != 0:
            continue
        t_bus, tt, dth, status = decode_siru(msgpack.unpackb(payload), 4)
        reads.extend((int(x), i) for x in tt)
        out = clock.push(t_bus, tt, dth, status)
        for t, tag in zip(out.t, clock.last_tt, strict=True):
            if tag < 0:
                continue
            while ptr < len(reads) and reads[ptr][0] != tag:
                ptr += 1
            if ptr == len(reads):  # not found (should not happen): resynchronise at the end
                break
            t_out.append(float(t))
            idx_out.append(reads[ptr][1])
            ptr += 1
    return np.asarray(t_out), np.asarray(idx_out, dtype=np.int64)


def vehicle_names(n: int) -> list[str]:
    return [f"bench{i}" for i in range(n)]


def phases(n: int, spread_s: float = 0.1, aligned: bool = False) -> np.ndarray:
    """Per-vehicle time offsets: 0 for vehicle 0, then a low-discrepancy spread over spread_s."""
    if aligned:
        return np.zeros(n)
    return np.array([(i * GOLDEN) % 1.0 for i in range(n)]) * spread_s


# ------------------------------------------------------------------------------------ roles
def _open_session(listen: str | None = None, connect: str | None = None) -> Any:
    import zenoh

    from radical_rt.io.zconfig import make_config
    return zenoh.open(make_config("peer", listen=[listen] if listen else [],
                                  connect=[connect] if connect else []))


def role_drive(a: argparse.Namespace) -> int:
    """Publish the stream for the vehicles at real rate; record publish and tlm receive times."""
    import zenoh

    stream = load_stream(a.stream)
    vehicles = vehicle_names(a.vehicles)
    topics = np.asarray(stream["topics"], dtype=np.int64)
    t_rel = np.asarray(stream["t"], dtype=np.float64)
    payloads = stream["payloads"]
    s = _open_session(listen=a.listen)
    rx: list[tuple[int, str, bytes]] = []
    first = threading.Event()

    def on_tlm(sample: Any) -> None:
        rx.append((time.monotonic_ns(), str(sample.key_expr), sample.payload.to_bytes()))
        first.set()

    sub = s.declare_subscriber("radical/*/tlm/*", on_tlm)
    enc = zenoh.Encoding("application/msgpack")
    pubs = [[s.declare_publisher(f"radical/{v}/{t}", encoding=enc,
                                 congestion_control=zenoh.CongestionControl.BLOCK)
             for t in INPUT_TOPICS] for v in vehicles]
    print("LISTENING", flush=True)

    # the node is up when every vehicle's liveliness token is visible, and it listens when every
    # publisher has a matching subscriber
    want = {f"radical/{v}/alive/filter" for v in vehicles}
    deadline = time.monotonic() + a.wait_node
    while True:
        alive = {str(r.ok.key_expr) for r in s.liveliness().get("radical/*/alive/filter", timeout=1.0)
                 if r.ok is not None}
        if want <= alive:
            break
        if time.monotonic() > deadline:
            print(f"drive: node not alive after {a.wait_node} s", file=sys.stderr)
            return 1
        time.sleep(0.05)
    t_alive_ns = time.monotonic_ns()
    while not all(p.matching_status.matching for row in pubs for p in row):
        if time.monotonic() > deadline:
            print("drive: publishers never matched", file=sys.stderr)
            return 1
        time.sleep(0.01)

    # schedule: every vehicle gets the whole stream, shifted by its phase
    n_msg, n_veh = len(topics), len(vehicles)
    if a.until_first_packet:  # start-up run: at most a few seconds of stream
        keep = t_rel <= min(float(t_rel[-1]), 5.0)
        n_msg = int(keep.sum())
    ph = phases(n_veh, aligned=a.aligned)
    due_rel = (t_rel[None, :n_msg] / a.rate + ph[:, None]).ravel()  # [vehicle, message]
    order = np.argsort(due_rel, kind="stable")
    veh_of = order // n_msg
    msg_of = order % n_msg
    due_ns = np.round(due_rel[order] * 1e9).astype(np.int64)
    pub_ns = np.zeros(order.size, dtype=np.int64)
    top_of = topics[msg_of]
    # per-(vehicle, message) lookup for the analysis
    gc.collect()
    gc.freeze()
    gc.disable()
    base = time.monotonic_ns() + 20_000_000
    try:
        for j in range(order.size):
            due = base + int(due_ns[j])
            left = due - time.monotonic_ns()
            if left > 0:
                time.sleep(left * 1e-9)
            v, m = int(veh_of[j]), int(msg_of[j])
            pub_ns[j] = time.monotonic_ns()
            pubs[v][int(top_of[j])].put(payloads[m])
            if a.until_first_packet and first.is_set():
                pub_ns = pub_ns[:j + 1]
                break
    finally:
        gc.enable()
        gc.unfreeze()
    t_last = time.monotonic_ns()
    time.sleep(a.linger)
    sub.undeclare()
    for row in pubs:
        for p in row:
            p.undeclare()
    s.close()

    # decode the packets: vehicle index, kind, t, seq
    vi = {v: i for i, v in enumerate(vehicles)}
    n_rx = len(rx)
    r_ns = np.zeros(n_rx, np.int64)
    r_v = np.full(n_rx, -1, np.int64)
    r_k = np.full(n_rx, -1, np.int64)
    r_t = np.full(n_rx, np.nan)
    r_seq = np.full(n_rx, -1, np.int64)
    for i, (ns, key, data) in enumerate(rx):
        parts = key.split("/")  # radical/<v>/tlm/<kind>
        r_ns[i] = ns
        r_v[i] = vi.get(parts[1], -1)
        r_k[i] = KINDS.index(parts[3]) if parts[3] in KINDS else -1
        try:
            m = msgpack.unpackb(data)
            r_t[i] = float(m.get("t", math.nan))
            r_seq[i] = int(m.get("seq", -1))
        except Exception:  # noqa: BLE001 - a malformed packet is recorded as such
            pass
    n_pub = pub_ns.size
    np.savez(a.out, pub_ns=pub_ns, due_ns=base + due_ns[:n_pub], veh=veh_of[:n_pub],
             msg=msg_of[:n_pub], t_alive_ns=t_alive_ns, t_base_ns=base, t_last_ns=t_last,
             rx_ns=r_ns, rx_veh=r_v, rx_kind=r_k, rx_t=r_t, rx_seq=r_seq,
             phases=ph, n_msg=n_msg)
    return 0


def role_pong(a: argparse.Namespace) -> int:
    """Echo every ping on the pong key, with the receive time appended (8 bytes)."""
    import zenoh

    s = _open_session(listen=a.listen)
    pub = s.declare_publisher(PONG_KEY, congestion_control=zenoh.CongestionControl.BLOCK)

    def on_ping(sample: Any) -> None:
        t = time.monotonic_ns()
        pub.put(sample.payload.to_bytes() + t.to_bytes(8, "little"))

    sub = s.declare_subscriber(PING_KEY, on_ping)
    print("LISTENING", flush=True)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    stop.wait(a.timeout)
    sub.undeclare()
    s.close()
    return 0


def role_ping(a: argparse.Namespace) -> int:
    """Send ``n`` pings at ``rate`` Hz (absolute deadlines) after ``warmup`` untimed ones."""
    import zenoh

    s = _open_session(connect=a.connect)
    n_all = a.warmup + a.n
    t_send = np.zeros(n_all, np.int64)
    t_pong = np.zeros(n_all, np.int64)
    t_back = np.zeros(n_all, np.int64)

    def on_pong(sample: Any) -> None:
        t = time.monotonic_ns()
        b = sample.payload.to_bytes()
        seq = msgpack.unpackb(b[:-8])[0]
        if 0 <= seq < n_all:
            t_back[seq] = t
            t_pong[seq] = int.from_bytes(b[-8:], "little")

    sub = s.declare_subscriber(PONG_KEY, on_pong)
    pub = s.declare_publisher(PING_KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    deadline = time.monotonic() + 30
    while not pub.matching_status.matching:
        if time.monotonic() > deadline:
            print("ping: no pong", file=sys.stderr)
            return 1
        time.sleep(0.01)
    time.sleep(0.2)  # the pong's publisher route to us
    floats = [0.1 * i for i in range(10)]
    period = int(1e9 / a.rate)
    gc.collect()
    gc.freeze()
    gc.disable()
    base = time.monotonic_ns() + 10_000_000
    for i in range(n_all):
        due = base + i * period
        left = due - time.monotonic_ns()
        if left > 0:
            time.sleep(left * 1e-9)
        t = time.monotonic_ns()
        t_send[i] = t
        pub.put(msgpack.packb([i, t, *floats]))
    gc.enable()
    time.sleep(0.5)
    sub.undeclare()
    s.close()
    np.savez(a.out, t_send=t_send[a.warmup:], t_pong=t_pong[a.warmup:], t_back=t_back[a.warmup:])
    return 0


def role_memory(a: argparse.Namespace) -> int:
    """RSS after 0, 1, 2, 4, … vehicles in ONE process: warm-up (kernels loaded) first, then each
    new vehicle is built as the node builds it and fed the stream (as fast as possible), so its
    buffers, clock and packet state are those of a running vehicle. Writes JSON to ``--out``."""
    from radical_rt.apps.node import build_processors, warm_up

    stream = load_stream(a.stream)
    warm_up()
    gc.collect()
    points = [(0, proc_stat(os.getpid())[0])]  # type: ignore[index]
    kept = []
    n = 0
    for target in sorted({int(x) for x in a.steps.split(",")}):
        while n < target:
            sp = build_processors([f"m{n}"], packets=a.packets)[f"m{n}"]
            for code, payload in zip(stream["topics"], stream["payloads"], strict=True):
                sp.feed(INPUT_TOPICS[code], payload)
            kept.append(sp)
            n += 1
        gc.collect()
        points.append((n, proc_stat(os.getpid())[0]))  # type: ignore[index]
    growth = []
    if a.growth_stream:  # a few more vehicles fed a long stream together: RSS against stream time
        long = load_stream(a.growth_stream)
        sps = list(build_processors([f"g{i}" for i in range(a.growth_vehicles)],
                                    packets=a.packets).values())
        gc.collect()
        r0 = proc_stat(os.getpid())[0]  # type: ignore[index]
        growth.append((0.0, 0))
        mark = a.growth_every
        for t, code, payload in zip(long["t"], long["topics"], long["payloads"], strict=True):
            if t >= mark:
                gc.collect()
                growth.append((mark, proc_stat(os.getpid())[0] - r0))  # type: ignore[index]
                mark += a.growth_every
            for sp in sps:
                sp.feed(INPUT_TOPICS[code], payload)
    Path(a.out).write_text(json.dumps({"points_kb": points, "growth_kb": growth,
                                       "growth_vehicles": a.growth_vehicles}))
    return 0


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


# ------------------------------------------------------------------------------------ orchestration
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


# ------------------------------------------------------------------------------------ analysis
def analyse(run: NodeRun, stream: dict[str, Any], warmup_s: float, measure_s: float,
            samples: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, Any]:
    """Latency figures of one session (see the module docstring), warm-up reported apart."""
    d = run.drive
    topics = np.asarray(stream["topics"], dtype=np.int64)
    t_rel = np.asarray(stream["t"], dtype=np.float64)
    n_msg = int(d["n_msg"])
    nv = run.n_vehicles
    # publication time of (vehicle, message); 0 where not published
    pub = np.zeros((nv, n_msg), dtype=np.int64)
    pub[d["veh"], d["msg"]] = d["pub_ns"]
    lateness = d["pub_ns"] - d["due_ns"]
    t_end = warmup_s + measure_s
    in_meas = (t_rel[:n_msg] >= warmup_s) & (t_rel[:n_msg] < t_end)
    in_warm = t_rel[:n_msg] < warmup_s
    out: dict[str, Any] = {"vehicles": nv, "messages_published": int(d["pub_ns"].size),
                           "pacing_late_ms": pct(lateness)}

    # ---- node timing: map each record to its (vehicle, message)
    tm = run.timing
    svc, svc_w, node_tot, node_q, node_sp, node_pub, hop_in = [], [], [], [], [], [], []
    node_pkt: list[np.ndarray] = []
    siru_stamps: list[np.ndarray] = []  # (pub, recv, start, fed, done) of measured SIRU messages
    react, react_w, hop_out = [], [], []
    complete = True
    if tm is not None:
        for v in range(nv):
            sel = np.nonzero(tm["vehicle"] == v)[0]
            msg_of_rec = np.full(sel.size, -1, dtype=np.int64)
            for code in range(len(INPUT_TOPICS)):
                recs = sel[tm["topic"][sel] == code]
                msgs = np.nonzero(topics[:n_msg] == code)[0]
                msgs = msgs[pub[v, msgs] > 0]
                if recs.size != msgs.size:
                    complete = False
                k = min(recs.size, msgs.size)
                msg_of_rec[np.searchsorted(sel, recs[:k])] = msgs[:k]
            ok = msg_of_rec >= 0
            r, m = sel[ok], msg_of_rec[ok]
            siru = topics[m] == 0
            meas, warm = in_meas[m], in_warm[m]
            p = pub[v, m]
            done, recv = tm["done_ns"][r], tm["recv_ns"][r]
            svc.append((done - p)[siru & meas])
            siru_stamps.append(np.stack([p, recv, tm["start_ns"][r], tm["fed_ns"][r], done],
                                        axis=1)[siru & meas])
            svc_w.append((done - p)[siru & warm])
            node_tot.append((done - recv)[meas])
            node_pkt.append((done - recv)[meas & (tm["tlm"][r] > 0)])
            node_q.append((tm["start_ns"][r] - recv)[meas])
            node_sp.append((tm["fed_ns"][r] - tm["start_ns"][r])[meas])
            node_pub.append((done - tm["fed_ns"][r])[meas])
            hop_in.append((recv - p)[meas])
            # packets → the record that built them (per kind, by sequence number)
            for k in range(len(KINDS)):
                cnt = (tm["tlm"][sel] >> (8 * k)) & 0xFF
                cum = np.cumsum(cnt)
                pk = np.nonzero((d["rx_veh"] == v) & (d["rx_kind"] == k) & (d["rx_seq"] > 0))[0]
                if pk.size == 0:
                    continue
                ri = np.searchsorted(cum, d["rx_seq"][pk], side="left")
                good = ri < sel.size
                pk, ri = pk[good], ri[good]
                mm = msg_of_rec[ri]
                good = mm >= 0
                pk, ri, mm = pk[good], ri[good], mm[good]
                lat = d["rx_ns"][pk] - pub[v, mm]
                react.append(lat[in_meas[mm]])
                react_w.append(lat[in_warm[mm]])
                hop_out.append((d["rx_ns"][pk] - tm["fed_ns"][sel[ri]])[in_meas[mm]])
        cat = np.concatenate
        out["node_timing_complete"] = complete
        out["records"] = int(tm["vehicle"].size)
        out["service_ms"] = pct(cat(svc))
        out["service_misses"] = misses(cat(svc))
        out["service_warmup_ms"] = pct(cat(svc_w))
        out["hop_in_ms"] = pct(cat(hop_in))
        out["node_total_ms"] = pct(cat(node_tot))
        out["node_queue_ms"] = pct(cat(node_q))
        out["node_feed_ms"] = pct(cat(node_sp))
        out["node_publish_ms"] = pct(cat(node_pub))
        # taken from the FIFO → packet published, for the messages that published tlm packets
        out["node_to_packet_ms"] = pct(cat(node_pkt))
        out["reaction_ms"] = pct(cat(react) if react else np.zeros(0))
        out["reaction_misses"] = misses(cat(react) if react else np.zeros(0))
        out["reaction_warmup_ms"] = pct(cat(react_w) if react_w else np.zeros(0))
        out["hop_out_ms"] = pct(cat(hop_out) if hop_out else np.zeros(0))
        out.update(_late_and_gc(cat(siru_stamps), tm, int(d["t_base_ns"]) + int(warmup_s * 1e9),
                                int(d["t_base_ns"]) + int((warmup_s + measure_s) * 1e9)))

    # ---- inclusion: first packet with t ≥ the sample's reconstructed time
    if samples is None:
        samples = sample_times(stream)
    s_t, s_msg = samples
    keep = s_msg < n_msg
    s_t, s_msg = s_t[keep], s_msg[keep]
    s_meas = in_meas[s_msg]
    s_warm = in_warm[s_msg]
    inc, inc_w, never = [], [], 0
    for v in range(nv):
        pk = np.nonzero((d["rx_veh"] == v) & np.isfinite(d["rx_t"]))[0]
        if pk.size == 0:
            never += int(s_meas.sum())
            continue
        o = np.argsort(d["rx_t"][pk], kind="stable")
        pt = d["rx_t"][pk][o]
        pr = d["rx_ns"][pk][o]
        suffix_min = np.minimum.accumulate(pr[::-1])[::-1]
        # a packet includes a sample when its t is that sample's time or later; the t of a
        # sample-triggered packet is the clock's *prediction* for the newest read (one period
        # after the last released sample), which differs from the time reconstructed later by
        # µs, so a packet is matched to a sample within half a sample period
        j = np.searchsorted(pt, s_t - INCLUSION_TOL_S, side="left")
        has = j < pt.size
        rec = np.where(has, suffix_min[np.minimum(j, pt.size - 1)], 0)
        lat = rec - pub[v, s_msg]
        ok = has & (pub[v, s_msg] > 0)
        never += int((~ok & s_meas).sum())
        inc.append(lat[ok & s_meas])
        inc_w.append(lat[ok & s_warm])
    cat = np.concatenate
    out["inclusion_ms"] = pct(cat(inc))
    out["inclusion_misses"] = misses(cat(inc))
    out["inclusion_warmup_ms"] = pct(cat(inc_w))
    out["samples_never_included"] = never
    out["packets_received"] = {k: int((d["rx_kind"] == i).sum()) for i, k in enumerate(KINDS)}

    # ---- node process: RSS and CPU over the measured window
    rss = run.rss
    t0 = int(d["t_base_ns"]) + int(warmup_s * 1e9)
    t1 = int(d["t_base_ns"]) + int(t_end * 1e9)
    if rss.size:
        before = rss[rss[:, 0] <= int(d["t_base_ns"])]
        during = rss[(rss[:, 0] >= t0) & (rss[:, 0] <= t1)]
        out["rss_ready_mb"] = float(before[-1, 1]) / 1024 if len(before) else None
        out["rss_mb"] = float(np.median(during[:, 1])) / 1024 if len(during) else None
        out["rss_at_warmup_end_mb"] = float(during[0, 1]) / 1024 if len(during) else None
        out["rss_max_mb"] = float(rss[:, 1].max()) / 1024
        if len(during) >= 2:
            out["node_cpu_pct"] = 100.0 * (during[-1, 2] - during[0, 2]) / ((during[-1, 0] - during[0, 0]) * 1e-9)
    out["node_jit_s"] = run.jit_s
    out["node_exit_code"] = run.node_rc
    return out


def _late_and_gc(st: np.ndarray, tm: dict[str, np.ndarray], t0: int, t1: int) -> dict[str, Any]:
    """Where the time of the late SIRU messages went, and the node's garbage collections.

    st: (n, 5) publish, taken, loop start, fed, done stamps of the measured SIRU messages.
    """
    out: dict[str, Any] = {}
    late = st[(st[:, 4] - st[:, 0]) > DEADLINE_NS]
    if late.size:
        d = np.diff(late, axis=1)  # hop in, queue wait, feed, publish
        out["late_breakdown_ms"] = {name: float(np.median(d[:, i])) * 1e-6 for i, name in
                                    enumerate(("hop_in", "queue", "feed", "publish"))}
    if "gc_start_ns" in tm:
        gs, ge, gg = tm["gc_start_ns"], tm["gc_stop_ns"], tm["gc_generation"]
        inside = (ge >= t0) & (gs <= t1)
        gc_out: dict[str, Any] = {}
        for g in (0, 1, 2):
            dur = (ge - gs)[inside & (gg == g)]
            gc_out[f"gen{g}"] = {"n": int(dur.size),
                                 "max_ms": float(dur.max()) * 1e-6 if dur.size else 0.0,
                                 "total_ms": float(dur.sum()) * 1e-6}
        out["node_gc"] = gc_out
        if late.size:  # late messages in flight during a collection
            hit = np.zeros(len(late), bool)
            for a, b in zip(gs[inside], ge[inside], strict=True):
                hit |= (late[:, 0] <= b) & (late[:, 4] >= a)
            out["late_during_gc"] = int(hit.sum())
    out["late_messages"] = int(len(late))
    return out


# ------------------------------------------------------------------------------------ CLI roles
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m perf.live", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="role", required=True)
    p = sub.add_parser("drive")
    p.add_argument("--listen", required=True)
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
