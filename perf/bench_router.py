"""Router hop and chain (issue #19): latency and throughput through `radical router` processes.

    python -m perf.bench_router [--profile smoke|quick|full] [--out DIR]    # radical bench --only router

Three topologies on loopback (multicast scouting off, ``tcp/127.0.0.1:PORT`` on free ports), every
process its own, pinned with ``taskset`` to the live benches' CPU set: ``direct`` (the subscriber
listens as a peer, the publisher connects to it, as perf/live.py), ``one`` router (publisher and
subscriber are its clients), ``two`` routers chained (publisher on A, subscriber on B, B → A).

One publisher (``python -m perf.bench_router pub``) and one subscriber (``... sub``) per topology
run the same steps. A message is a 16-byte header (step, seq, send stamp) and a one-read contract
``siru`` message (msgpack, CONTRACT §3) on ``radical/rbench/siru``, BLOCK congestion control
(reliable: a slow receiver slows the sender; nothing is dropped).

1. **latency**: 100 Hz at absolute deadlines after an untimed warm-up; one-way = the subscriber's
   receive stamp − the publisher's send stamp (CLOCK_MONOTONIC ns, one clock for the host).
2. **throughput**: stepped target rates, paced in slices (the messages due put in a tight loop,
   then a sleep). Per step: sent, received, the rate achieved (below the target when something
   saturates), the delivered rate, latency under load, and each process's CPU (routers,
   publisher, subscriber) from /proc/PID/stat sampled every 0.1 s; the routers' idle CPU too.

Wall-clock figures on a shared machine: reported, never asserted (perf/README.md, "Router hop
and chain").
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from perf import live_host as host
from perf.live_analysis import pct
from perf.live_host import LiveError

HDR = struct.Struct("<iiq")  # step, seq, send stamp (CLOCK_MONOTONIC ns); step -1 ends the run
KEY = "radical/rbench/siru"
TOPOLOGIES = ("direct", "one", "two")
WARMUP, LATENCY_HZ, GAP_S = 50, 100.0, 0.5
PROFILES = {"smoke": {"latency_n": 200, "rates": [2000, 5000], "step_s": 1.0},
            "quick": {"latency_n": 1000, "rates": [1000, 5000, 10000, 20000, 40000], "step_s": 2.5},
            "full": {"latency_n": 4000, "rates": [1000, 5000, 10000, 20000, 40000, 80000, 160000],
                     "step_s": 5.0}}
IDLE_S = 2.0  # routers' CPU with the links up and no traffic, before the publisher starts
DEFAULT_OUT = Path(__file__).resolve().parent / "results"


def siru_payload() -> bytes:
    """A contract ``siru`` message of one SIRU read, msgpack as the replayer publishes it."""
    return msgpack.packb({"v": 1, "t_bus": [1234.56], "tt": [3_141_592_653],
                          "dtheta": [[1.2e-5, -3.4e-5, 5.6e-6, -7.8e-6]], "status": [0]},
                         use_bin_type=True)


def _session(a: argparse.Namespace) -> Any:
    import zenoh

    from radical_rt.io.zconfig import make_config
    return zenoh.open(make_config(a.mode, listen=a.listen or [], connect=a.connect or []))


def _send_step(pub: Any, step: int, rate: float, n: int, body: bytes) -> tuple[int, int]:
    """Put n messages paced at ``rate`` (all those due, then a sleep); (first due, end) ns."""
    period = 1e9 / rate
    t0 = time.monotonic_ns() + 2_000_000
    sent = 0
    while sent < n:
        now = time.monotonic_ns()
        due = min(n, math.floor((now - t0) / period) + 1)
        if due <= sent:
            time.sleep((t0 + sent * period - now) * 1e-9)
            continue
        for seq in range(sent, due):
            pub.put(HDR.pack(step, seq, time.monotonic_ns()) + body)
        sent = due
    return t0, time.monotonic_ns()


def role_pub(a: argparse.Namespace) -> int:
    """Wait for the subscriber's route, send the steps [[rate, n], ...], write their windows."""
    import zenoh

    s = _session(a)
    pub = s.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
    end = time.monotonic() + 30
    while not pub.matching_status.matching:
        if time.monotonic() > end:
            print("pub: no subscriber", file=sys.stderr)
            return 1
        time.sleep(0.01)
    time.sleep(0.3)
    body, done = siru_payload(), []
    gc.collect()
    gc.freeze()
    gc.disable()
    for i, (rate, n) in enumerate(json.loads(a.steps)):
        t0, t1 = _send_step(pub, i, rate, n, body)
        done.append({"rate": rate, "n": n, "t0_ns": t0, "t1_ns": t1})
        time.sleep(GAP_S)
    pub.put(HDR.pack(-1, 0, 0) + body)
    gc.enable()
    Path(a.out).write_text(json.dumps(done))
    time.sleep(0.5)
    s.close()
    return 0


def role_sub(a: argparse.Namespace) -> int:
    """Record (step, seq, send, receive) of every message until the end marker; .npy to --out."""
    rec = np.zeros((a.max, 4), np.int64)
    count = [0]
    end = threading.Event()

    def on_sample(sample: Any) -> None:
        t = time.monotonic_ns()
        step, seq, t_send = HDR.unpack_from(sample.payload.to_bytes())
        if step < 0:
            end.set()
        elif count[0] < a.max:
            rec[count[0]] = (step, seq, t_send, t)
            count[0] += 1

    s = _session(a)
    sub = s.declare_subscriber(KEY, on_sample)
    gc.disable()
    print("sub: READY", file=sys.stderr, flush=True)
    end.wait(a.timeout)
    sub.undeclare()
    s.close()
    np.save(a.out, rec[:count[0]])
    return 0 if end.is_set() else 1


def _spawn(argv: list[str], log: Path) -> subprocess.Popen:
    argv = host.pinned([sys.executable, "-m", *argv], host.default_cpus())
    return subprocess.Popen(argv, env=host.child_env(), cwd=str(host.ROOT),
                            stdout=subprocess.DEVNULL, stderr=open(log, "wb"))


def _wait_log(p: subprocess.Popen, log: Path, word: str, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while word not in log.read_text(errors="replace"):
        if p.poll() is not None or time.monotonic() > end:
            raise LiveError(f"{log.stem} not ready (exit {p.poll()}): {log.read_text()[-500:]}")
        time.sleep(0.05)


def _topology(name: str, work: Path) -> tuple[dict[str, subprocess.Popen], list[str], list[str]]:
    """Start the routers of a topology: (routers by name, publisher options, subscriber options)."""
    from radical_rt.io.zconfig import free_port

    ep = [f"tcp/127.0.0.1:{free_port()}" for _ in range(2)]
    if name == "direct":
        return {}, ["--mode", "peer", "--connect", ep[0]], ["--mode", "peer", "--listen", ep[0]]
    links = {"routerA": ["--listen", ep[0]], "routerB": ["--listen", ep[1], "--connect", ep[0]]}
    routers: dict[str, subprocess.Popen] = {}
    for r in ["routerA"] if name == "one" else ["routerA", "routerB"]:
        log = work / f"{name}_{r}.log"
        routers[r] = _spawn(["radical_rt.apps.cli", "router", *links[r]], log)
        _wait_log(routers[r], log, "ready")
    return routers, ["--mode", "client", "--connect", ep[0]], \
        ["--mode", "client", "--connect", ep[1] if name == "two" else ep[0]]


def _cpu_samples(procs: dict[str, subprocess.Popen], until: subprocess.Popen,
                 timeout: float) -> dict[str, np.ndarray]:
    """CPU seconds of each process every 0.1 s (and the stamps, key ``t_ns``) while ``until`` runs."""
    rows: list[list[float]] = []
    end = time.monotonic() + timeout
    while until.poll() is None and time.monotonic() < end:
        stats = [host.proc_stat(p.pid) for p in procs.values()]
        rows.append([time.monotonic_ns()] + [st[1] if st else math.nan for st in stats])
        time.sleep(0.1)
    a = np.array(rows, dtype=np.float64).reshape(-1, len(procs) + 1)
    return {"t_ns": a[:, 0], **{k: a[:, i + 1] for i, k in enumerate(procs)}}


def _run_topology(name: str, steps: list[list[int]], work: Path) -> dict[str, Any]:
    routers, pub_opts, sub_opts = _topology(name, work)
    procs: dict[str, subprocess.Popen] = dict(routers)
    budget = 3 * sum(n / r + GAP_S for r, n in steps) + 60
    try:
        sub_log, pub_out, sub_out = (work / f"{name}_{f}" for f in ("sub.log", "pub.json", "sub.npy"))
        procs["sub"] = _spawn(["perf.bench_router", "sub", *sub_opts, "--max",
                               str(sum(n for _, n in steps)), "--timeout", str(budget),
                               "--out", str(sub_out)], sub_log)
        _wait_log(procs["sub"], sub_log, "READY")
        idle = _idle_cpu(routers)
        procs["pub"] = _spawn(["perf.bench_router", "pub", *pub_opts, "--steps", json.dumps(steps),
                               "--out", str(pub_out)], work / f"{name}_pub.log")
        cpu = _cpu_samples(procs, procs["pub"], budget)
        rcs = {k: procs[k].wait(60) for k in ("pub", "sub")}
        if any(rcs.values()) or not pub_out.exists():
            logs = {k: (work / f"{name}_{k}.log").read_text()[-400:] for k in rcs}
            raise LiveError(f"bench router {name}: exit codes {rcs}; {logs}")
    finally:
        for p in procs.values():
            host.stop_process(p, timeout=10)
    res = _analyse(json.loads(pub_out.read_text()), np.load(sub_out), cpu, list(routers))
    return {**res, "idle_cpu_pct": idle}


def _idle_cpu(procs: dict[str, subprocess.Popen]) -> dict[str, float]:
    """CPU % of each process over IDLE_S seconds without traffic (/proc ticks: ±0.5 %)."""
    a = {k: host.proc_stat(p.pid) for k, p in procs.items()}
    time.sleep(IDLE_S)
    b = {k: host.proc_stat(p.pid) for k, p in procs.items()}
    return {k: 100 * (b[k][1] - a[k][1]) / IDLE_S for k in procs if a[k] and b[k]}


def _cpu_pct(cpu: dict[str, np.ndarray], key: str, t0: float, t1: float) -> float:
    c = np.interp([t0, t1], cpu["t_ns"], cpu[key])
    return float(100 * (c[1] - c[0]) / ((t1 - t0) * 1e-9))


def _analyse(done: list[dict[str, Any]], rec: np.ndarray, cpu: dict[str, np.ndarray],
             routers: list[str]) -> dict[str, Any]:
    """Latency of step 1 and, per later step, rates, loss, latency under load and CPU."""
    steps = []
    for i, d in enumerate(done):
        r = rec[rec[:, 0] == i]
        lat = r[:, 3] - r[:, 2]
        s = {"target_hz": d["rate"], "sent": d["n"], "received": int(len(r)),
             "distinct": int(np.unique(r[:, 1]).size), "one_way_ms": pct(lat)}
        if len(r):
            dt = (d["t1_ns"] - d["t0_ns"]) * 1e-9
            t_last = max(int(r[:, 3].max()), d["t1_ns"])  # so delivered ≤ sent by construction
            s.update(sent_hz=d["n"] / dt, delivered_hz=len(r) / ((t_last - d["t0_ns"]) * 1e-9))
        s["cpu_pct"] = {k: _cpu_pct(cpu, k, d["t0_ns"], d["t1_ns"])
                        for k in cpu if k != "t_ns"}
        if routers and "delivered_hz" in s:
            per_router = np.mean([s["cpu_pct"][k] for k in routers])
            s["router_cpu_pct_per_khz"] = float(per_router / (s["delivered_hz"] / 1000))
        steps.append(s)
    return {"routers": len(routers), "latency": steps[1], "throughput": steps[2:]}


def run(profile: str = "quick", out_dir: Path | str | None = None) -> dict[str, Any]:
    cfg = PROFILES[profile]
    steps = [[LATENCY_HZ, WARMUP], [LATENCY_HZ, cfg["latency_n"]],
             *[[r, int(r * cfg["step_s"])] for r in cfg["rates"]]]
    with tempfile.TemporaryDirectory() as tmp:
        topo = {name: _run_topology(name, steps, Path(tmp)) for name in TOPOLOGIES}
    res = {"schema": "radical.bench.router/1", "profile": profile, **cfg,
           "payload_bytes": HDR.size + len(siru_payload()), "machine": host.machine_info(),
           "cpus": host.default_cpus(), "topologies": topo, "overhead_ms": _overheads(topo)}
    if out_dir is not None:
        path = Path(out_dir) / f"router_{profile}.json"
        path.write_text(json.dumps(res, indent=1))
        res["json_path"] = str(path)
    return res


def _overheads(topo: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Differences of the one-way latency percentiles between topologies (ms)."""
    pairs = {"one_vs_direct": ("one", "direct"), "two_vs_direct": ("two", "direct"),
             "two_vs_one": ("two", "one")}
    return {k: {q: topo[a]["latency"]["one_way_ms"][q] - topo[b]["latency"]["one_way_ms"][q]
                for q in ("p50", "p99", "p99_9")} for k, (a, b) in pairs.items()}


def _router_cpu(step: dict[str, Any]) -> str:
    c = step["cpu_pct"]
    return "/".join(f"{c[k]:.1f}" for k in c if k.startswith("router")) or "–"


def markdown(res: dict[str, Any]) -> str:
    t = res["topologies"]
    lines = [f"{res['payload_bytes']}-byte messages (siru, one read), CPUs {res['cpus']}, "
             f"load {res['machine'].get('loadavg')}", "",
             "| topology | n | one-way p50 ms | p99 ms | p99.9 ms | max ms | Δp50 vs direct ms | "
             "router CPU % idle | at 100 Hz |", "|---|---|---|---|---|---|---|---|---|"]
    for name in TOPOLOGIES:
        q, d = t[name]["latency"]["one_way_ms"], t["direct"]["latency"]["one_way_ms"]
        lines.append(f"| {name} | {q['n']} | {q['p50']:.3f} | {q['p99']:.3f} | {q['p99_9']:.3f} | "
                     f"{q['max']:.3f} | {q['p50'] - d['p50']:+.3f} | "
                     f"{_router_cpu({'cpu_pct': t[name]['idle_cpu_pct']})} | "
                     f"{_router_cpu(t[name]['latency'])} |")
    lines += ["", "| topology | target/s | sent/s | delivered/s | lost | router CPU % | "
              "router CPU % per 1k/s | pub CPU % | sub CPU % | p50 ms | p99 ms |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name in TOPOLOGIES:
        for s in t[name]["throughput"]:
            c, rc = s["cpu_pct"], _router_cpu(s)
            per_k = f"{s['router_cpu_pct_per_khz']:.2f}" if "router_cpu_pct_per_khz" in s else "–"
            lines.append(f"| {name} | {s['target_hz']:.0f} | {s.get('sent_hz', 0):.0f} | "
                         f"{s.get('delivered_hz', 0):.0f} | {s['sent'] - s['received']} | {rc} | "
                         f"{per_k} | {c['pub']:.0f} | {c['sub']:.0f} | "
                         f"{s['one_way_ms'].get('p50', math.nan):.2f} | "
                         f"{s['one_way_ms'].get('p99', math.nan):.2f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] in (["pub"], ["sub"]):
        ap = argparse.ArgumentParser(prog=f"python -m perf.bench_router {argv[0]}")
        ap.add_argument("--mode", choices=("peer", "client"), required=True)
        ap.add_argument("--out", required=True)
        for flag, kw in (("--listen", {"action": "append"}), ("--connect", {"action": "append"}),
                         ("--steps", {"default": "[]"}), ("--max", {"type": int, "default": 0}),
                         ("--timeout", {"type": float, "default": 600.0})):
            ap.add_argument(flag, **kw)
        a = ap.parse_args(argv[1:])
        return role_pub(a) if argv[0] == "pub" else role_sub(a)
    ap = argparse.ArgumentParser(prog="python -m perf.bench_router", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default="quick", choices=list(PROFILES))
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    a = ap.parse_args(argv)
    Path(a.out).mkdir(parents=True, exist_ok=True)
    print(markdown(run(a.profile, a.out)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
