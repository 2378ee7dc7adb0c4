"""Start-up time of ``radical node``: launch → first telemetry packet, cold and with the Numba cache.

Command::

    python -m perf.bench_startup [--profile smoke|quick|full] [--out DIR] [--config PACKETS]

Each run launches ``radical node`` (pinned, connecting to the driver of :mod:`perf.live`, which
starts publishing the real-rate stream as soon as the node's liveliness token is visible) and
stops at the first ``tlm/*`` packet received. Reported, from the launch (monotonic):

* ``numba_ready_s``: the node's log line "Numba kernels ready" (imports, processors built and every
  kernel compiled or loaded; ``warm_up_s`` is the node's own figure for the last step only);
* ``ready_s``: the node's liveliness token seen by the driver (session open, keys declared);
* ``first_packet_s``: the first telemetry packet received — what an operator waits for. It also
  includes the data the first packet needs (a few SIRU reads with sample-triggered packets, about
  0.3 s of stream with window-triggered ones).

Cold: ``NUMBA_CACHE_DIR`` points to a new empty directory, so every kernel is compiled. Cached:
the same directory again (full profile: three times). The smoke profile (and ``--no-cold``) skips
the cold run and measures the default cache (``__pycache__`` next to the sources) instead.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

from perf import live, live_host, live_stream

PROFILES: dict[str, dict[str, Any]] = {
    "smoke": dict(cold=False, cached_runs=1),
    "quick": dict(cold=True, cached_runs=1),
    "full": dict(cold=True, cached_runs=3),
}
MAX_CACHED_OVER_COLD = 0.5  # the cache must at least halve the start-up (it is ~20× here)
DEFAULT_OUT = Path(__file__).resolve().parent / "results"


def one(stream_path: Path, cache_dir: Path | None, packets: str | None, cpus: list[int],
        work: Path, tag: str) -> dict[str, Any]:
    """One launch → first packet (cache_dir None: the default Numba cache, next to the sources)."""
    run_ = live.node_session(stream_path, 1, packets, cpus, work, tag=tag, until_first_packet=True,
                             env={"NUMBA_CACHE_DIR": str(cache_dir)} if cache_dir else None,
                             linger=0.3)
    d = run_.drive
    t0 = run_.t_launch_ns
    first = int(d["rx_ns"].min()) if d["rx_ns"].size else None
    return {"numba_ready_s": run_.jit_line_s, "warm_up_s": run_.jit_s,
            "ready_log_s": run_.ready_line_s, "ready_s": (int(d["t_alive_ns"]) - t0) * 1e-9,
            "stream_start_s": (int(d["t_base_ns"]) - t0) * 1e-9,
            "first_packet_s": (first - t0) * 1e-9 if first is not None else None,
            "node_exit_code": run_.node_rc,
            "rss_mb": float(run_.rss[-1, 1]) / 1024 if len(run_.rss) else None}


def run(profile: str = "quick", out_dir: str | Path | None = None, *, config: str = "default",
        cpus: list[int] | None = None, cold: bool | None = None) -> dict[str, Any]:
    """Cold and cached start-ups; returns (and writes ``startup_<profile>.json``) the result."""
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; use one of {', '.join(PROFILES)}")
    prof = PROFILES[profile]
    cold = prof["cold"] if cold is None else cold
    cpus = live_host.default_cpus() if cpus is None else cpus
    t_start = time.perf_counter()
    res: dict[str, Any] = {"schema": "radical.bench.startup/1", "profile": profile,
                           "machine": live_host.machine_info(), "cpus": cpus, "config": config,
                           "small_trigger": _small_trigger(), "cold": None, "cached": []}
    with tempfile.TemporaryDirectory(prefix="radical-startup-") as tmp:
        work = Path(tmp)
        stream_path = work / "stream.mpk"
        live_stream.build_stream(6.0, stream_path)
        packets = live_stream.packet_file(config, work)
        cache: Path | None = None
        if cold:
            cache = work / "numba-cache"
            cache.mkdir()
            res["cold"] = one(stream_path, cache, packets, cpus, work, "cold")
        for i in range(prof["cached_runs"]):
            res["cached"].append(one(stream_path, cache, packets, cpus, work, f"cached{i}"))
    vals = [r["first_packet_s"] for r in res["cached"] if r["first_packet_s"] is not None]
    res["cached_first_packet_s"] = statistics.median(vals) if vals else None
    res["checks"] = checks(res)
    res["wall_s"] = time.perf_counter() - t_start
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        path = Path(out_dir) / f"startup_{profile}.json"
        path.write_text(json.dumps(res, indent=1, default=str))
        res["json_path"] = str(path)
    return res


def _small_trigger() -> str:
    from radical_rt.stream.telemetry import default_packets
    return getattr(default_packets()["small"], "trigger", "window")


def checks(res: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for r in ([res["cold"]] if res["cold"] else []) + res["cached"]:
        ok = r["first_packet_s"] is not None
        out.append({"name": "a first packet arrived", "value": ok, "limit": True, "ok": ok, "detail": ""})
    if res["cold"] and res["cold"]["first_packet_s"] and res["cached_first_packet_s"]:
        ratio = res["cached_first_packet_s"] / res["cold"]["first_packet_s"]
        out.append({"name": "start-up with cache / cold", "value": ratio,
                    "limit": MAX_CACHED_OVER_COLD, "ok": bool(ratio < MAX_CACHED_OVER_COLD),
                    "detail": ""})
    return out


def _f(x: Any, nd: int = 2) -> str:
    return "–" if x is None else f"{x:.{nd}f}"


def markdown(res: dict[str, Any]) -> str:
    lines = [f"`radical node`, one vehicle, packets `{res['config']}` (tlm/small trigger: "
             f"{res['small_trigger']}), CPUs {res['cpus']}; seconds from the launch.", "",
             "| run | Numba kernels ready | (node warm-up step) | liveliness token seen | first packet | "
             "node RSS (MB) |", "|---|---|---|---|---|---|"]
    where = "same NUMBA_CACHE_DIR" if res["cold"] else "default cache"
    runs = ([("cold (empty NUMBA_CACHE_DIR)", res["cold"])] if res["cold"] else []) + \
        [(f"cached #{i + 1} ({where})", r) for i, r in enumerate(res["cached"])]
    for label, r in runs:
        lines.append(f"| {label} | {_f(r['numba_ready_s'])} | {_f(r['warm_up_s'])} | {_f(r['ready_s'])} | "
                     f"{_f(r['first_packet_s'])} | {_f(r['rss_mb'], 1)} |")
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
    ap.add_argument("--config", default="default", help="packets: default, window, sample or a TOML file")
    ap.add_argument("--cpus", help="CPU list, e.g. 0,1 (default: first two)")
    ap.add_argument("--no-cold", action="store_true", help="skip the cold (compiling) run")
    a = ap.parse_args()
    print(markdown(run(a.profile, a.out, config=a.config,
                       cpus=[int(c) for c in a.cpus.split(",")] if a.cpus else None,
                       cold=False if a.no_cold else None)))


if __name__ == "__main__":
    main()
