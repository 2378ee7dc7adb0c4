"""What fleet discovery costs the discovering worker (docs/fleet.md, "Discovery").

    python -m perf.bench_fleet_discovery [--vehicles N] [--duration S] [--topics siru,temp]
                                         [--out RESULT.json]

A router (in this process) and a publisher (this process) that sends, for N vehicles, the
simulator's default input streams: ``siru`` 10 Hz (batches of 10 samples, ~0.6 kB), ``st1`` and
``st2`` 10 Hz, ``temp`` 1 Hz. For each topic, a discoverer process (a Zenoh client with a
:class:`~radical_rt.fleet.roster.Roster` and a :class:`~radical_rt.fleet.discovery.Discovery`
on that topic, no filter) runs for S seconds; so does an idle one (the same, never subscribed).
Columns: ``msgs_per_s`` delivered to the discoverer, ``cpu_pct`` of one core (user+sys of the
process), ``cpu_pct_over_idle`` and ``us_per_msg`` (the extra CPU per delivered message),
``discovered`` (vehicles added to the roster). Seeded, synthetic payloads of the contract's
layout. On a shared 2-core machine the figures are rough: read them as orders of magnitude.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import threading
import time

import msgpack
import numpy as np

RATES = {"siru": 10.0, "st1": 10.0, "st2": 10.0, "temp": 1.0}  # messages/s per vehicle


def payloads(seed: int = 19) -> dict[str, bytes]:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    q = (q / np.linalg.norm(q)).tolist()
    return {"siru": msgpack.packb({"v": 1, "t_bus": [1000.0 + i * 0.01 for i in range(10)],
                                   "tt": list(range(0, 100000, 10000)),
                                   "dtheta": rng.normal(0, 1e-5, (10, 4)).tolist(),
                                   "status": [0] * 10}),
            "st1": msgpack.packb({"v": 1, "t_bus": 1000.0, "q": q, "n_stars": 9, "valid": True}),
            "st2": msgpack.packb({"v": 1, "t_bus": 1000.0, "q": q, "n_stars": 9, "valid": True}),
            "temp": msgpack.packb({"v": 1, "t_bus": 1000.0, "st1_baseplate_C": 20.0,
                                   "st2_baseplate_C": 21.0, "siru_C": 30.0})}


def discoverer(ep: str, topic: str | None, duration: float) -> dict:
    """One discoverer process (``--role discoverer``): its counts and CPU time."""
    from radical_rt.fleet.discovery import Discovery
    from radical_rt.fleet.roster import Roster
    from radical_rt.io.zenoh_transport import ZenohTransport

    t = ZenohTransport("client", connect=[ep])
    roster = Roster(t, "bench", "w-bench").start(timeout=0.5)
    disc = Discovery(t, roster, "w-bench", topic or "siru")
    ru0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.monotonic()
    while time.monotonic() - t0 < duration:
        if topic is not None:
            disc.follow({"w-bench"})
        time.sleep(0.25)
    ru1, wall = resource.getrusage(resource.RUSAGE_SELF), time.monotonic() - t0
    st = disc.status()
    disc.stop()
    t.close()
    cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    return {"topic": topic, "samples": st["samples"], "wall_s": wall, "cpu_s": cpu,
            "discovered": len(roster.vehicles())}


def publish(ep: str, n: int, stop: threading.Event) -> None:
    from radical_rt.io.zenoh_transport import ZenohTransport

    t = ZenohTransport("client", connect=[ep])
    data = payloads()
    period = 0.1  # 10 Hz ticks; temp every 10th
    k, t0 = 0, time.monotonic()
    while not stop.is_set():
        for v in range(n):
            for topic in ("siru", "st1", "st2") + (("temp",) if k % 10 == 0 else ()):
                t.put(f"radical/bv{v:03d}/{topic}", data[topic])
        k += 1
        time.sleep(max(0.0, t0 + k * period - time.monotonic()))
    t.close()


def run(vehicles: int, duration: float, topics: list[str]) -> dict:
    from radical_rt.io import zconfig
    from radical_rt.io.zenoh_transport import ZenohTransport

    ep = f"tcp/127.0.0.1:{zconfig.free_port()}"
    router = ZenohTransport("router", listen=[ep])
    stop = threading.Event()
    pub = threading.Thread(target=publish, args=(ep, vehicles, stop), daemon=True)
    pub.start()
    rows = []
    try:
        for topic in [None, *topics]:
            out = subprocess.run([sys.executable, "-m", "perf.bench_fleet_discovery", "--role",
                                  "discoverer", "--connect", ep, "--duration", str(duration),
                                  *(["--topic", topic] if topic else [])],
                                 capture_output=True, text=True, timeout=duration + 60)
            if out.returncode != 0:
                raise RuntimeError(out.stderr)
            rows.append(json.loads(out.stdout.strip().splitlines()[-1]))
    finally:
        stop.set()
        pub.join(10)
        router.close()
    idle = rows[0]["cpu_s"] / rows[0]["wall_s"]
    for r in rows:
        r["msgs_per_s"] = r["samples"] / r["wall_s"]
        r["cpu_pct"] = 100 * r["cpu_s"] / r["wall_s"]
        r["cpu_pct_over_idle"] = 100 * (r["cpu_s"] / r["wall_s"] - idle)
        r["us_per_msg"] = (1e6 * (r["cpu_s"] - idle * r["wall_s"]) / r["samples"]
                           if r["samples"] else None)
    return {"vehicles": vehicles, "duration_s": duration, "rates_hz": RATES, "rows": rows}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--vehicles", type=int, default=50)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--topics", default="siru,temp")
    p.add_argument("--out", metavar="RESULT.json")
    p.add_argument("--role", choices=("driver", "discoverer"), default="driver")
    p.add_argument("--connect")
    p.add_argument("--topic")
    a = p.parse_args(argv)
    if a.role == "discoverer":
        print(json.dumps(discoverer(a.connect, a.topic, a.duration)))
        return 0
    res = run(a.vehicles, a.duration, a.topics.split(","))
    print(f"{a.vehicles} vehicles, {a.duration:g} s per row")
    print(f"{'topic':<6} {'msgs/s':>8} {'cpu %':>6} {'over idle %':>11} {'us/msg':>7} discovered")
    for r in res["rows"]:
        us = "-" if r["us_per_msg"] is None else f"{r['us_per_msg']:.0f}"
        print(f"{r['topic'] or 'idle':<6} {r['msgs_per_s']:8.0f} {r['cpu_pct']:6.1f} "
              f"{r['cpu_pct_over_idle']:11.1f} {us:>7} {r['discovered']}")
    if a.out:
        with open(a.out, "w") as f:
            json.dump(res, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
