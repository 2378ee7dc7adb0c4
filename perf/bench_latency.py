"""End-to-end latency of ``radical node`` over real Zenoh on loopback, at the real input rates.

Command::

    python -m perf.bench_latency [--profile smoke|quick|full] [--out DIR]
                                 [--config window|sample|default|PACKETS.toml ...]
                                 [--vehicles N] [--batch K] [--cpus 0,1] [--aligned]

What runs (see :mod:`perf.live` for the processes and the definitions):

1. the reference: a ping and a pong process bounce 96-byte messages at 100 Hz over Zenoh;
2. for each packet configuration, a driver process publishes the seeded 2006216 scenario at
   real rate (every SIRU read as its own message at 100 Hz, trackers at 10 Hz) and receives the
   telemetry, while ``radical node --timing-out`` records its filter loop. Both are pinned to the
   same CPUs (``taskset``). The first ``warmup_s`` seconds are reported apart.

Packet configurations: ``window`` (tlm/small built at each 0.1 s filter window close: the filter's
estimate, which lags the data by the tracker latency plus the reorder slack), ``sample`` (tlm/small
built after every SIRU message, period 0.01 s, attitude predicted to the newest sample; skipped if
this version has no ``trigger`` setting), ``default`` (the node's own defaults) or a TOML file.

Latencies (ms; p50/p90/p99/p99.9/max over the measured window):

* ``reaction``: publication of the input message that triggered a packet → its reception;
* ``service``: publication of a SIRU message → the node has fed it and published its outputs;
* ``inclusion``: publication of a SIRU sample → reception of the first packet with ``t`` ≥ the
  sample's reconstructed time;
* node internal (taken from the input FIFO → outputs published) and the Zenoh hops in and out.

A deadline miss is a latency above the 10 ms SIRU sample period. The regression checks
(:func:`checks`) are ratios and miss fractions measured in the same run, never absolute times.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path
from typing import Any

from perf import live, live_analysis, live_host, live_stream

PROFILES: dict[str, dict[str, Any]] = {
    "smoke": dict(warmup_s=2.0, measure_s=5.0, rtt_n=300),
    "quick": dict(warmup_s=4.0, measure_s=15.0, rtt_n=1000),
    "full": dict(warmup_s=10.0, measure_s=120.0, rtt_n=6000),
}
CONFIGS = ("window", "sample")
TAIL_S = 1.5  # stream beyond the measured window, so that window packets include its last samples
DEFAULT_OUT = Path(__file__).resolve().parent / "results"

#: gross-regression limits (ratios and fractions measured in the same run)
MAX_MISS_FRAC = 1e-3  # deadline misses (> 10 ms) of reaction and service latency
# The reference moves with the machine's state (RTT p50 0.14–0.48 ms on the 2-vCPU VM) while the
# node's own work does not scale with it; the largest ratios seen there were 9.5 (p50, window
# config) and 9.2 (p99), so these limits only catch gross regressions.
MAX_P50_RATIO = 25.0  # reaction p50 / Zenoh round-trip p50
MAX_P99_RATIO = 25.0  # reaction p99 / Zenoh round-trip p99


def run(profile: str = "quick", out_dir: str | Path | None = None, *,
        configs: tuple[str, ...] | list[str] = CONFIGS, vehicles: int = 1, batch: int = 1,
        cpus: list[int] | None = None, aligned: bool = False) -> dict[str, Any]:
    """Run the reference round trip and one node session per packet config; returns the result
    dict (also written to ``out_dir/latency_<profile>.json``)."""
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; use one of {', '.join(PROFILES)}")
    prof = PROFILES[profile]
    cpus = live_host.default_cpus() if cpus is None else cpus
    t_start = time.perf_counter()
    res: dict[str, Any] = {"schema": "radical.bench.latency/1", "profile": profile,
                           "machine": live_host.machine_info(), "cpus": cpus, "vehicles": vehicles,
                           "batch": batch, "rate": 1.0, "aligned": aligned,
                           "deadline_ms": live_analysis.DEADLINE_NS / 1e6, **prof, "configs": {}}
    with tempfile.TemporaryDirectory(prefix="radical-latency-") as tmp:
        work = Path(tmp)
        stream_path = work / "stream.mpk"
        stream = live_stream.build_stream(prof["warmup_s"] + prof["measure_s"] + TAIL_S, stream_path,
                                   batch=batch)
        samples = live_stream.sample_times(stream)
        res["stream"] = {"messages": len(stream["topics"]), "siru_samples": int(samples[0].size),
                         "scenario": stream["scenario"], "seed": stream["seed"]}
        res["zenoh_rtt"] = live.rtt_run(prof["rtt_n"], 100.0, cpus, work)
        for cfg in configs:
            name = Path(cfg).stem if cfg not in ("window", "sample", "default") else cfg
            try:
                packets = live_stream.packet_file(cfg, work)
            except live_host.LiveError as exc:
                res["configs"][name] = {"available": False, "reason": str(exc)}
                continue
            run_ = live.node_session(stream_path, vehicles, packets, cpus, work, tag=name,
                                     aligned=aligned)
            r = live_analysis.analyse(run_, stream, prof["warmup_s"], prof["measure_s"], samples)
            r["available"] = True
            r["packets_toml"] = Path(packets).read_text() if packets else None
            res["configs"][name] = r
    res["checks"] = checks(res)
    res["wall_s"] = time.perf_counter() - t_start
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        path = Path(out_dir) / f"latency_{profile}.json"
        path.write_text(json.dumps(res, indent=1, default=str))
        res["json_path"] = str(path)
    return res


def checks(res: dict[str, Any]) -> list[dict[str, Any]]:
    """Gross-regression checks: deadline-miss fractions and latency / Zenoh round-trip ratios."""
    out = []
    rtt = res["zenoh_rtt"]["rtt_ms"]
    for name, r in res["configs"].items():
        if not r.get("available"):
            continue
        out.append(_check(f"{name}: every input message fed", r["node_timing_complete"], True))
        for metric in ("service", "reaction"):
            m = r[f"{metric}_misses"]
            out.append(_check(f"{name}: {metric} misses > 10 ms (fraction)", m["frac"],
                              MAX_MISS_FRAC, f"{m['misses']}/{m['n']}"))
        out.append(_check(f"{name}: reaction p50 / Zenoh RTT p50", r["reaction_ms"]["p50"] / rtt["p50"],
                          MAX_P50_RATIO))
        out.append(_check(f"{name}: reaction p99 / Zenoh RTT p99", r["reaction_ms"]["p99"] / rtt["p99"],
                          MAX_P99_RATIO))
    return out


def _check(name: str, value: Any, limit: Any, detail: str = "") -> dict[str, Any]:
    ok = value is limit if isinstance(limit, bool) else (value == value and value < limit)
    return {"name": name, "value": value, "limit": limit, "ok": bool(ok), "detail": detail}


def _f(x: Any, nd: int = 2) -> str:
    return "–" if x is None else f"{x:.{nd}f}"


def _row(label: str, p: dict[str, Any], extra: str = "") -> str:
    if not p or not p.get("n"):
        return f"| {label} | – | – | – | – | – | 0 | {extra} |"
    return (f"| {label} | {_f(p['p50'])} | {_f(p['p99'])} | {_f(p['p99_9'])} | {_f(p['max'])} | "
            f"{_f(p['mean'])} | {p['n']} | {extra} |")


def _miss(m: dict[str, Any]) -> str:
    return f"{m['misses']}/{m['n']} ({100 * m['frac']:.2f} %)" if m.get("n") else "–"


def markdown(res: dict[str, Any]) -> str:
    rtt = res["zenoh_rtt"]
    lines = [f"Zenoh 1.x on loopback, {res['vehicles']} vehicle(s), real rate, CPUs {res['cpus']}, "
             f"warm-up {res['warmup_s']:g} s excluded, measured {res['measure_s']:g} s; "
             f"load average at start {res['machine'].get('loadavg')}.", "",
             "| latency (ms) | p50 | p99 | p99.9 | max | mean | n | misses > 10 ms |",
             "|---|---|---|---|---|---|---|---|",
             _row("Zenoh round trip, ping/pong 100 Hz (reference)", rtt["rtt_ms"], _miss(rtt["rtt_misses"])),
             _row("Zenoh one way, ping → pong", rtt["one_way_ms"])]
    for name, r in res["configs"].items():
        if not r.get("available"):
            lines.append(f"| **{name}**: not available ({r.get('reason', '')}) | | | | | | | |")
            continue
        lines += [
            _row(f"**{name}**: reaction, trigger message published → packet received",
                 r["reaction_ms"], _miss(r["reaction_misses"])),
            _row(f"{name}: inclusion, SIRU sample published → first packet with t ≥ sample time",
                 r["inclusion_ms"], _miss(r["inclusion_misses"])),
            _row(f"{name}: service, SIRU message published → node fed + published",
                 r["service_ms"], _miss(r["service_misses"])),
            _row(f"{name}: node internal, taken → packet published", r["node_to_packet_ms"]),
            _row(f"{name}: node internal, taken → done (all messages)", r["node_total_ms"]),
            _row(f"{name}: of which wait before the feed", r["node_queue_ms"]),
            _row(f"{name}: of which StreamProcessor.feed", r["node_feed_ms"]),
            _row(f"{name}: of which publishing", r["node_publish_ms"]),
            _row(f"{name}: Zenoh hop in (publish → taken from the FIFO)", r["hop_in_ms"]),
            _row(f"{name}: Zenoh way out (node starts publishing → received)", r["hop_out_ms"]),
            _row(f"{name}: warm-up ({res['warmup_s']:g} s): reaction", r["reaction_warmup_ms"]),
        ]
    lines += ["", "| config | reaction p99 − RTT p99 (ms) | node warm-up step (s) | node RSS (MB) | "
              "node CPU (% of a core) | packets small/medium/large |", "|---|---|---|---|---|---|"]
    for name, r in res["configs"].items():
        if r.get("available"):
            pk = r["packets_received"]
            excess = r["reaction_ms"]["p99"] - rtt["rtt_ms"]["p99"]
            lines.append(f"| {name} | {excess:.2f} | {_f(r['node_jit_s'])} | {_f(r.get('rss_mb'), 1)} | "
                         f"{_f(r.get('node_cpu_pct'), 1)} | {pk['small']}/{pk['medium']}/{pk['large']} |")
    lines += ["", "| config | late SIRU messages | of which during a node GC | node GC gen 0/1/2 count | "
              "gen 2 max (ms) |", "|---|---|---|---|---|"]
    for name, r in res["configs"].items():
        if r.get("available"):
            g = r.get("node_gc") or {}
            counts = "/".join(str(g.get(f"gen{i}", {}).get("n", "–")) for i in range(3))
            lines.append(f"| {name} | {r.get('late_messages', '–')} | {r.get('late_during_gc', '–')} | "
                         f"{counts} | {_f(g.get('gen2', {}).get('max_ms'))} |")
    lines += ["", "| check | value | limit | ok |", "|---|---|---|---|"]
    for c in res["checks"]:
        v = c["value"]
        lines.append(f"| {c['name']} | {v if isinstance(v, bool) else f'{v:.4g}'} "
                     f"{c['detail']} | {c['limit']} | {'yes' if c['ok'] else '**NO**'} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default="quick", choices=list(PROFILES))
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    ap.add_argument("--config", nargs="+", default=list(CONFIGS),
                    help="packet configs: window, sample, default or TOML files")
    ap.add_argument("--vehicles", type=int, default=1)
    ap.add_argument("--batch", type=int, default=1, help="SIRU reads per message (0: archive's)")
    ap.add_argument("--cpus", help="CPU list for every process, e.g. 0,1 (default: first two)")
    ap.add_argument("--aligned", action="store_true", help="no phase offsets between vehicles")
    a = ap.parse_args()
    cpus = [int(c) for c in a.cpus.split(",")] if a.cpus else None
    print(markdown(run(a.profile, a.out, configs=a.config, vehicles=a.vehicles, batch=a.batch,
                       cpus=cpus, aligned=a.aligned)))


if __name__ == "__main__":
    main()
