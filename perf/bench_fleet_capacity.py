"""Fleet capacity: how many vehicles a fleet of workers serves at real time on this machine
(issue #19; docs/fleet.md, perf/README.md "Fleet capacity").

Command::

    python -m perf.bench_fleet_capacity [--profile smoke|quick|full] [--workers W]
                                        [--batch B] [--steps 16,32,...] [--out DIR]

One step, N vehicles: a ``radical router``, W fleet workers (``radical node --fleet fcap
--workers 1 --timing-out …``, separate processes) and the driver of :mod:`perf.live`
(connected to the router) run on the same CPUs (the first two this process may use). The driver
publishes the seeded 2006216 stream for every vehicle at real rate (trackers 10 Hz, temperatures
1 Hz, the SIRU reads ``B`` per message: 1 is the contract's 100 Hz stream, 10 a 10-Hz batched
one as flight telemetry often comes), each vehicle shifted by its own phase. The driver starts
once the fleet has settled (every vehicle served by its rendezvous owner, nothing held).

A step **passes** when every message was fed and fewer than 0.1 % of the SIRU messages were
served later than 10 ms (publication → the owning worker fed it and published its outputs;
:func:`perf.live_analysis.analyse` on the workers' merged timing records). The capacity is the
largest passing N (full profile: steps up until one fails, then bisection). CPU of every process
(router, each worker, driver) over the measured window is reported: the figures of the scaling
analysis in docs/fleet.md.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from perf import live, live_analysis, live_host, live_stream

PROFILES: dict[str, dict[str, Any]] = {
    "smoke": dict(steps=(2,), warmup_s=2.0, measure_s=4.0, search=False),
    "quick": dict(steps=(8, 32), warmup_s=8.0, measure_s=10.0, search=False),
    "full": dict(steps=(16, 32, 48, 64, 80, 96, 112, 128, 160, 192), warmup_s=10.0,
                 measure_s=30.0, search=True),
}
FLEET = "fcap"
MAX_MISS_FRAC = 1e-3
TAIL_S = 1.5
DEFAULT_OUT = Path(__file__).resolve().parent / "results"


class Procs:
    """The router, worker and driver processes of one step, with their CPU samples."""

    def __init__(self) -> None:
        self.named: dict[str, subprocess.Popen] = {}
        self.samples: list[tuple[int, dict[str, tuple[int, float]]]] = []

    def start(self, name: str, argv: list[str], cpus: list[int], log: Path,
              stdout_pipe: bool = False) -> subprocess.Popen:
        p = subprocess.Popen(live_host.pinned(argv, cpus), env=live_host.child_env(),
                             cwd=str(live_host.ROOT), stderr=open(log, "wb"),
                             stdout=subprocess.PIPE if stdout_pipe else subprocess.DEVNULL,
                             text=stdout_pipe)
        self.named[name] = p
        return p

    def sample(self) -> None:
        stats = {n: st for n, p in self.named.items() if (st := live_host.proc_stat(p.pid))}
        self.samples.append((time.monotonic_ns(), stats))

    def cpu_pct(self, name: str, t0: int, t1: int) -> float | None:
        """% of one core used by ``name`` between the monotonic instants t0 and t1 [ns]."""
        pts = [(t, s[name][1]) for t, s in self.samples if t0 <= t <= t1 and name in s]
        if len(pts) < 2:
            return None
        return 100.0 * (pts[-1][1] - pts[0][1]) / ((pts[-1][0] - pts[0][0]) * 1e-9)

    def rss_cpu(self, names: list[str]) -> np.ndarray:
        """(k, 3): monotonic ns, summed RSS kB, summed CPU s of ``names`` (as NodeRun.rss)."""
        rows = [(t, sum(s[n][0] for n in names), sum(s[n][1] for n in names))
                for t, s in self.samples if all(n in s for n in names)]
        return np.array(rows, dtype=np.float64).reshape(-1, 3)

    def stop_all(self) -> dict[str, int | None]:
        return {n: live_host.stop_process(p) for n, p in reversed(list(self.named.items()))}


def _settled(ep: str, names: list[str], workers: int, timeout: float) -> None:
    """Wait until W workers serve every vehicle by its rendezvous owner, nothing held."""
    from radical_rt.io.zenoh_transport import ZenohTransport

    end = time.monotonic() + timeout
    while True:  # the router may still be starting
        try:
            t = ZenohTransport("client", [], [ep])
            break
        except Exception:
            if time.monotonic() > end:
                raise
            time.sleep(0.5)
    try:
        while time.monotonic() < end:
            sts = [msgpack.unpackb(r, raw=False) for r in
                   t.get(f"radical-fleet/{FLEET}/status/*", b"", timeout=2.0, every=True)]
            served = sorted(v for st in sts for v in st["serving"])
            if (len(sts) == workers and served == sorted(names)
                    and all(set(st["owned"]) == set(st["serving"]) and not st["holding"]
                            for st in sts)):
                return
            time.sleep(0.5)
    finally:
        t.close()
    raise live_host.LiveError(f"the fleet did not settle within {timeout:g} s")


def merge_timing(paths: list[Path], names: list[str]) -> dict[str, np.ndarray]:
    """The workers' LoopTiming records as one set, vehicle indices in the driver's order."""
    parts = []
    for p in paths:
        d = dict(np.load(p))
        remap = np.array([names.index(str(v)) for v in d["vehicles"]] + [-1], dtype=np.int64)
        d["vehicle"] = remap[d["vehicle"]]  # (-1 stays -1: the last entry)
        parts.append(d)
    fields = ("vehicle", "topic", "recv_ns", "start_ns", "fed_ns", "done_ns", "tlm")
    out = {f: np.concatenate([d[f] for d in parts]) for f in fields}
    order = np.argsort(out["recv_ns"], kind="stable")
    return {f: a[order] for f, a in out.items()} | {
        f"gc_{k}": np.concatenate([d[f"gc_{k}"] for d in parts])
        for k in ("start_ns", "stop_ns", "generation")}


def fleet_step(stream_path: Path, n: int, workers: int, packets: str | None, cpus: list[int],
               work: Path, tag: str) -> tuple[live.NodeRun, Procs]:
    """One step: router, workers, settle, driver, stop, collect."""
    from radical_rt.io.zconfig import free_port

    ep = f"tcp/127.0.0.1:{free_port()}"
    names = live_stream.vehicle_names(n)
    procs = Procs()
    t_launch = time.monotonic_ns()
    try:
        procs.start("router", [*live_host.radical_argv(), "router", "--listen", ep], cpus,
                    work / f"{tag}_router.log")
        wargv = [*live_host.radical_argv(), "node", "--fleet", FLEET, "--connect", ep,
                 "--workers", "1", "--log-level", "info", "--checkpoint-every", "10"]
        for v in names:
            wargv += ["--vehicle", v]
        if packets:
            wargv += ["--packets", packets]
        timings = [work / f"{tag}_w{i}.npz" for i in range(workers)]
        for i, path in enumerate(timings):
            procs.start(f"worker{i}", [*wargv, "--timing-out", str(path)], cpus,
                        work / f"{tag}_w{i}.log")
        _settled(ep, names, workers, timeout=120.0 + n)
        drv_out = work / f"{tag}_drive.npz"
        drv = procs.start("driver", [sys.executable, "-m", "perf.live", "drive", "--connect", ep,
                                     "--stream", str(stream_path), "--vehicles", str(n),
                                     "--out", str(drv_out), "--wait-node", "60", "--linger", "1.5"],
                          cpus, work / f"{tag}_drive.log")
        while drv.poll() is None:
            procs.sample()
            dead = [k for k, p in procs.named.items() if k != "driver" and p.poll() is not None]
            if dead:
                raise live_host.LiveError(f"{dead} exited early: see {work}")
            time.sleep(0.25)
        procs.sample()
        if drv.returncode != 0:
            raise live_host.LiveError(f"driver failed ({drv.returncode}): "
                                      f"{(work / f'{tag}_drive.log').read_text()[-800:]}")
        rss = procs.rss_cpu([f"worker{i}" for i in range(workers)])
    finally:
        rcs = procs.stop_all()
    rc = max((rcs[f"worker{i}"] or 0) for i in range(workers))
    run = live.NodeRun(drive=dict(np.load(drv_out)), timing=merge_timing(timings, names), rss=rss,
                       t_launch_ns=t_launch, node_rc=rc, jit_s=None, jit_line_s=None,
                       ready_line_s=None, n_vehicles=n, log_tail="")
    return run, procs


def run(profile: str = "quick", out_dir: str | Path | None = None, *, workers: int = 2,
        batch: int = 1, steps: tuple[int, ...] | list[int] | None = None,
        cpus: list[int] | None = None, config: str = "sample") -> dict[str, Any]:
    """Step the number of vehicles; returns (and writes ``fleet_capacity_<profile>.json``)."""
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; use one of {', '.join(PROFILES)}")
    prof = PROFILES[profile]
    cpus = live_host.default_cpus() if cpus is None else cpus
    steps = tuple(steps or prof["steps"])
    res: dict[str, Any] = {"schema": "radical.bench.fleet_capacity/1", "profile": profile,
                           "machine": live_host.machine_info(), "cpus": cpus, "workers": workers,
                           "batch": batch, "config": config, "warmup_s": prof["warmup_s"],
                           "measure_s": prof["measure_s"], "max_miss_frac": MAX_MISS_FRAC,
                           "steps": {}}
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="radical-fleetcap-") as tmp:
        work = Path(tmp)
        stream_path = work / "stream.mpk"
        stream = live_stream.build_stream(prof["warmup_s"] + prof["measure_s"] + TAIL_S,
                                          stream_path, batch=batch)
        samples = live_stream.sample_times(stream)
        packets = live_stream.packet_file(config, work)

        def step(n: int) -> bool:
            run_, procs = fleet_step(stream_path, n, workers, packets, cpus, work, f"n{n}")
            r = live_analysis.analyse(run_, stream, prof["warmup_s"], prof["measure_s"], samples)
            t0 = int(run_.drive["t_base_ns"]) + int(prof["warmup_s"] * 1e9)
            t1 = t0 + int(prof["measure_s"] * 1e9)
            r["cpu_pct"] = {k: procs.cpu_pct(k, t0, t1) for k in procs.named}
            r["messages_per_s_in"] = _rate(stream, n, prof)
            r["pass"] = bool(r["node_timing_complete"] and r["node_exit_code"] == 0
                             and r["service_misses"]["frac"] < MAX_MISS_FRAC)
            res["steps"][n] = r
            print(f"fleet capacity: {n} vehicles, {workers} workers: service p99 "
                  f"{r['service_ms']['p99']:.2f} ms, misses {r['service_misses']['misses']}/"
                  f"{r['service_misses']['n']}, CPU {_cpu_line(r['cpu_pct'])} → "
                  f"{'pass' if r['pass'] else 'FAIL'}", flush=True)
            return r["pass"]

        last_pass, first_fail = _search(step, steps, prof["search"])
    res.update(capacity_vehicles=last_pass, first_failing_step=first_fail,
               bounded=first_fail is not None, wall_s=time.perf_counter() - t_start)
    res["steps"] = {str(k): v for k, v in sorted(res["steps"].items())}
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        path = Path(out_dir) / f"fleet_capacity_{profile}_w{workers}_b{batch}.json"
        path.write_text(json.dumps(res, indent=1, default=str))
        res["json_path"] = str(path)
    return res


def _search(step: Any, steps: tuple[int, ...], search: bool) -> tuple[int, int | None]:
    """Steps up (stopping at the first failure when searching), then bisection."""
    last_pass, first_fail = 0, None
    for n in steps:
        if step(n):
            last_pass = max(last_pass, n)
        elif first_fail is None:
            first_fail = n
            if search:
                break
    while search and first_fail is not None and first_fail - last_pass > max(2, last_pass // 16):
        mid = (last_pass + first_fail) // 2
        if step(mid):
            last_pass = mid
        else:
            first_fail = mid
    return last_pass, first_fail


def _rate(stream: dict[str, Any], n: int, prof: dict[str, Any]) -> float:
    """Input messages per second into the fleet (all vehicles) over the stream."""
    return n * len(stream["topics"]) / (prof["warmup_s"] + prof["measure_s"] + TAIL_S)


def _cpu_line(cpu: dict[str, float | None]) -> str:
    return ", ".join(f"{k} {v:.0f} %" for k, v in cpu.items() if v is not None)


def markdown(res: dict[str, Any]) -> str:
    lines = [f"{res['workers']} workers, SIRU reads per message {res['batch']}, CPUs "
             f"{res['cpus']}, {res['measure_s']:g} s measured after {res['warmup_s']:g} s; pass = "
             "every message fed and < 0.1 % of SIRU messages served later than 10 ms. "
             f"Capacity: **{res['capacity_vehicles']} vehicles**"
             f"{'' if res['bounded'] else ' (no step failed)'}.", "",
             "| vehicles | msgs/s in | service p50 | p99 | p99.9 | max (ms) | misses > 10 ms | "
             "workers CPU (% core) | router | driver | pass |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for n, r in res["steps"].items():
        s, m, c = r["service_ms"], r["service_misses"], r["cpu_pct"]
        wk = [v for k, v in c.items() if k.startswith("worker") and v is not None]
        lines.append(f"| {n} | {r['messages_per_s_in']:.0f} | {s['p50']:.2f} | {s['p99']:.2f} | "
                     f"{s['p99_9']:.2f} | {s['max']:.2f} | {m['misses']}/{m['n']} | "
                     f"{' + '.join(f'{v:.0f}' for v in wk)} | {_pct(c.get('router'))} | "
                     f"{_pct(c.get('driver'))} | {'yes' if r['pass'] else '**no**'} |")
    return "\n".join(lines)


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{x:.0f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m perf.bench_fleet_capacity", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default="quick", choices=sorted(PROFILES))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--batch", type=int, default=1, help="SIRU reads per message (1: 100 Hz)")
    ap.add_argument("--steps", help="comma-separated vehicle counts (default: the profile's)")
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    a = ap.parse_args(argv)
    steps = [int(x) for x in a.steps.split(",")] if a.steps else None
    res = run(a.profile, a.out, workers=a.workers, batch=a.batch, steps=steps)
    print(markdown(res))
    return 0


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    sys.exit(main())
