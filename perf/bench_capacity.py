"""Capacity: how many vehicles one ``radical node`` process serves at real time, and memory per vehicle.

Command::

    python -m perf.bench_capacity [--profile smoke|quick|full] [--out DIR]
                                  [--config sample|window|default|PACKETS.toml] [--steps 1,2,4,...]

One node process serves N vehicles (``--vehicle`` repeated); the driver of :mod:`perf.live`
publishes the same seeded stream for each vehicle at real rate (100 Hz SIRU reads, 10 Hz trackers),
each vehicle shifted by its own phase, with the node and the driver pinned to the same CPUs.
N steps up (full profile: 1, 2, 4, 6, 8, 12, 16, … until a step fails, then bisection between the
last pass and the first failure; quick: two points).

A step **passes** when the node fed every message and fewer than 0.1 % of the SIRU messages have a
``service`` latency (publication → node fed it and published its outputs) above the 10 ms sample
period. The capacity is the largest passing N. CPU per vehicle is the slope of the node's CPU
use against N (passing steps).

Memory per vehicle is measured in ONE process (``python -m perf.live memory``): RSS after the
kernels are loaded, then after 1, 2, 4, … vehicles, each built as the node builds it and fed the
whole stream; the figure is the least-squares slope. It depends on the stream's length while the
filter's histories fill up, so the full profile also feeds two more vehicles a 900 s stream and
reports their RSS every 60 s of stream (``growth_mb_per_vehicle``). (The node's RSS differs by
several MB between separate processes, more than a vehicle costs, so the slope across the capacity
steps, ``rss_slope_mb``, is only indicative.)
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from perf import live, live_analysis, live_host, live_stream

PROFILES: dict[str, dict[str, Any]] = {
    "smoke": dict(steps=(1, 2), warmup_s=2.0, measure_s=4.0, search=False, memory=(1, 2, 4)),
    "quick": dict(steps=(1, 4), warmup_s=3.0, measure_s=10.0, search=False,
                  memory=(1, 2, 4, 8, 16)),
    "full": dict(steps=(1, 2, 4, 6, 8, 12, 16, 24, 32, 48, 64), warmup_s=10.0, measure_s=60.0,
                 search=True, memory=(1, 2, 4, 8, 16, 32), growth_s=900.0),
}
MAX_MISS_FRAC = 1e-3
MAX_P50_GROWTH = 10.0  # quick check: service p50 at the largest step / at one vehicle
MAX_MEM_FRACTION = 0.05  # memory per vehicle / RSS of the process with the kernels and no vehicle
TAIL_S = 1.5
DEFAULT_OUT = Path(__file__).resolve().parent / "results"


def default_config() -> str:
    return "sample" if live_stream.trigger_supported() else "window"


def run(profile: str = "quick", out_dir: str | Path | None = None, *, config: str | None = None,
        steps: tuple[int, ...] | list[int] | None = None, cpus: list[int] | None = None,
        aligned: bool = False, rt_priority: int | None = None) -> dict[str, Any]:
    """Step the number of vehicles; returns (and writes ``capacity_<profile>.json``) the result.
    rt_priority: ``radical node --rt-priority`` (SCHED_FIFO filter loop; None: time-sharing)."""
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; use one of {', '.join(PROFILES)}")
    prof = PROFILES[profile]
    cpus = live_host.default_cpus() if cpus is None else cpus
    config = config or default_config()
    steps = tuple(steps or prof["steps"])
    t_start = time.perf_counter()
    res: dict[str, Any] = {"schema": "radical.bench.capacity/1", "profile": profile,
                           "machine": live_host.machine_info(), "cpus": cpus, "config": config,
                           "warmup_s": prof["warmup_s"], "measure_s": prof["measure_s"],
                           "aligned": aligned, "rt_priority": rt_priority,
                           "deadline_ms": live_analysis.DEADLINE_NS / 1e6,
                           "max_miss_frac": MAX_MISS_FRAC, "steps": {}}
    with tempfile.TemporaryDirectory(prefix="radical-capacity-") as tmp:
        work = Path(tmp)
        stream_path = work / "stream.mpk"
        stream = live_stream.build_stream(prof["warmup_s"] + prof["measure_s"] + TAIL_S, stream_path)
        samples = live_stream.sample_times(stream)
        packets = live_stream.packet_file(config, work)
        res["packets_toml"] = Path(packets).read_text() if packets else None
        res["memory"] = live.memory_run(stream_path, list(prof["memory"]), packets, cpus, work,
                                        growth_s=prof.get("growth_s"))

        def step(n: int) -> bool:
            run_ = live.node_session(
                stream_path, n, packets, cpus, work, tag=f"n{n}", aligned=aligned,
                node_args=["--rt-priority", str(rt_priority)] if rt_priority else None)
            r = live_analysis.analyse(run_, stream, prof["warmup_s"], prof["measure_s"], samples)
            r["timing_mb"] = _timing_mb(run_, prof["warmup_s"])
            r["rss_net_mb"] = (r["rss_at_warmup_end_mb"] - r["timing_mb"]
                               if r.get("rss_at_warmup_end_mb") is not None else None)
            r["pass"] = bool(r["node_timing_complete"] and r["service_misses"]["frac"] < MAX_MISS_FRAC
                             and r["node_exit_code"] == 0)
            res["steps"][n] = r
            print(f"capacity: {n} vehicle(s): service p99 {r['service_ms']['p99']:.2f} ms, misses "
                  f"{r['service_misses']['misses']}/{r['service_misses']['n']} → "
                  f"{'pass' if r['pass'] else 'FAIL'}", flush=True)
            return r["pass"]

        last_pass, first_fail = 0, None
        for n in steps:
            if step(n):
                last_pass = max(last_pass, n)
            elif first_fail is None:
                first_fail = n
                if prof["search"]:
                    break
        while prof["search"] and first_fail is not None and first_fail - last_pass > 1:
            mid = (last_pass + first_fail) // 2
            if step(mid):
                last_pass = mid
            else:
                first_fail = mid
    res["capacity_vehicles"] = last_pass
    res["first_failing_step"] = first_fail
    res["bounded"] = first_fail is not None
    res.update(_per_vehicle(res["steps"]))
    res["mem_per_vehicle_mb"] = res["memory"]["per_vehicle_mb"]
    res["checks"] = checks(res)
    res["wall_s"] = time.perf_counter() - t_start
    res["steps"] = {str(k): v for k, v in sorted(res["steps"].items())}
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        path = Path(out_dir) / f"capacity_{profile}.json"
        path.write_text(json.dumps(res, indent=1, default=str))
        res["json_path"] = str(path)
    return res


def _timing_mb(run_: live.NodeRun, warmup_s: float) -> float:
    """Memory of the node's timing records at the end of the warm-up (56 B each)."""
    if run_.timing is None:
        return 0.0
    t = int(run_.drive["t_base_ns"]) + int(warmup_s * 1e9)
    return float((run_.timing["recv_ns"] <= t).sum()) * 56 / 2**20


def _per_vehicle(steps: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """Slopes against N of RSS (net of the timing records) and CPU, least squares."""
    ns = sorted(steps)
    out: dict[str, Any] = {"rss_slope_mb": None, "cpu_per_vehicle_pct": None}
    mem = [(n, steps[n]["rss_net_mb"]) for n in ns if steps[n].get("rss_net_mb") is not None]
    if len(mem) >= 2:
        out["rss_slope_mb"] = _fit(mem)[0]
    cpu = [(n, steps[n]["node_cpu_pct"]) for n in ns
           if steps[n].get("node_cpu_pct") is not None and steps[n]["pass"]]
    if len(cpu) >= 2:
        out["cpu_per_vehicle_pct"] = _fit(cpu)[0]
    return out


def _fit(pts: list[tuple[int, float]]) -> tuple[float, float]:
    x = np.array([p[0] for p in pts], dtype=float)
    y = np.array([p[1] for p in pts], dtype=float)
    slope, base = np.polyfit(x, y, 1)
    return float(slope), float(base)


def checks(res: dict[str, Any]) -> list[dict[str, Any]]:
    """Gross-regression checks (same-run ratios): every step fed every message; the service p50 at
    the largest step is within MAX_P50_GROWTH of the one-vehicle p50 (only if both ran); a vehicle
    costs less than MAX_MEM_FRACTION of the process's own RSS."""
    out = []
    steps = {int(k): v for k, v in res["steps"].items()}
    for n, r in sorted(steps.items()):
        out.append({"name": f"{n} vehicle(s): every input message fed", "value": r["node_timing_complete"],
                    "limit": True, "ok": bool(r["node_timing_complete"]), "detail": ""})
    if 1 in steps and len(steps) > 1:
        top = max(steps)
        ratio = steps[top]["service_ms"]["p50"] / steps[1]["service_ms"]["p50"]
        out.append({"name": f"service p50 at {top} vehicles / at 1 vehicle", "value": ratio,
                    "limit": MAX_P50_GROWTH, "ok": bool(ratio < MAX_P50_GROWTH), "detail": ""})
    mem = res.get("memory")
    if mem:
        frac = mem["per_vehicle_mb"] / mem["points_mb"][0][1]
        out.append({"name": "memory per vehicle / RSS without vehicles", "value": frac,
                    "limit": MAX_MEM_FRACTION, "ok": bool(0 < frac < MAX_MEM_FRACTION), "detail": ""})
    return out


def _f(x: Any, nd: int = 2) -> str:
    return "–" if x is None else f"{x:.{nd}f}"


def markdown(res: dict[str, Any]) -> str:
    cap = res["capacity_vehicles"]
    bound = "" if res["bounded"] else f" (no step failed: ≥ {cap})"
    sched = (f"filter loop SCHED_FIFO {res['rt_priority']}" if res.get("rt_priority")
             else "filter loop time-sharing")
    lines = [f"Packet config `{res['config']}`, {sched}, CPUs {res['cpus']}, {res['measure_s']:g} s measured per "
             f"step after {res['warmup_s']:g} s of warm-up; pass = every message fed and < "
             f"{100 * res['max_miss_frac']:g} % of SIRU messages served later than 10 ms; load "
             f"average at start {res['machine'].get('loadavg')}.", "",
             "| vehicles | service p50 | p99 | p99.9 | max (ms) | misses > 10 ms | reaction p99 (ms) | "
             "node CPU (% core) | node RSS (MB) | pass |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for n, r in res["steps"].items():
        s, m = r["service_ms"], r["service_misses"]
        lines.append(f"| {n} | {_f(s.get('p50'))} | {_f(s.get('p99'))} | {_f(s.get('p99_9'))} | "
                     f"{_f(s.get('max'))} | {m['misses']}/{m['n']} | {_f(r['reaction_ms'].get('p99'))} | "
                     f"{_f(r.get('node_cpu_pct'), 1)} | {_f(r.get('rss_net_mb'), 1)} | "
                     f"{'yes' if r['pass'] else '**no**'} |")
    lines += ["", "Late SIRU messages (service > 10 ms): median time per stage, and the node's garbage "
              "collections in the measured window:", "",
              "| vehicles | late | hop in (incl. FIFO) | wait | feed | publish (ms) | late during a GC | "
              "GC gen 0/1/2 count | gen 2 max (ms) |", "|---|---|---|---|---|---|---|---|---|"]
    for n, r in res["steps"].items():
        b = r.get("late_breakdown_ms") or {}
        g = r.get("node_gc") or {}
        counts = "/".join(str(g.get(f"gen{i}", {}).get("n", "–")) for i in range(3))
        lines.append(f"| {n} | {r.get('late_messages', '–')} | {_f(b.get('hop_in'))} | {_f(b.get('queue'))} | "
                     f"{_f(b.get('feed'))} | {_f(b.get('publish'))} | {r.get('late_during_gc', '–')} | "
                     f"{counts} | {_f(g.get('gen2', {}).get('max_ms'))} |")
    cpu = res.get("cpu_per_vehicle_pct")
    ceiling = f" (one core's worth at ≈ {100 / cpu:.0f} vehicles)" if cpu and cpu > 0 else ""
    mem = res["memory"]
    lines += ["", f"**Capacity: {cap} vehicle(s)**{bound}; CPU per vehicle {_f(cpu, 1)} % of a core"
              f"{ceiling}; memory per vehicle {_f(res.get('mem_per_vehicle_mb'), 2)} MB (one process, "
              f"RSS {' / '.join(f'{m:.1f}' for _n, m in mem['points_mb'])} MB after "
              f"{' / '.join(str(n) for n, _m in mem['points_mb'])} vehicles fed {mem['stream_s']:g} s "
              "of stream each)."]
    if mem.get("growth_mb_per_vehicle"):
        lines += ["", "RSS per vehicle against stream time (MB): " + ", ".join(
            f"{t:g} s: {m:.1f}" for t, m in mem["growth_mb_per_vehicle"])]
    if res.get("checks"):
        lines += ["", "| check | value | limit | ok |", "|---|---|---|---|"]
        for c in res["checks"]:
            v = c["value"]
            lines.append(f"| {c['name']} | {v if isinstance(v, bool) else f'{v:.4g}'} | {c['limit']} | "
                         f"{'yes' if c['ok'] else '**NO**'} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default="quick", choices=list(PROFILES))
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    ap.add_argument("--config", help="packet config: sample (default when available), window, "
                                     "default or a TOML file")
    ap.add_argument("--steps", help="vehicle counts, e.g. 1,2,4,8 (default: the profile's)")
    ap.add_argument("--cpus", help="CPU list for every process, e.g. 0,1 (default: first two)")
    ap.add_argument("--aligned", action="store_true", help="no phase offsets between vehicles")
    ap.add_argument("--rt-priority", type=int, metavar="N",
                    help="run the node's filter loop SCHED_FIFO at priority N (needs root)")
    a = ap.parse_args()
    print(markdown(run(a.profile, a.out, config=a.config,
                       steps=[int(x) for x in a.steps.split(",")] if a.steps else None,
                       cpus=[int(c) for c in a.cpus.split(",")] if a.cpus else None,
                       aligned=a.aligned, rt_priority=a.rt_priority)))


if __name__ == "__main__":
    main()
