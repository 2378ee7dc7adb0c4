"""The child processes of the live benches, run as ``python -m perf.live ROLE``
(:func:`perf.live.main`): the **driver** (:func:`role_drive`: publishes the stream for the vehicles at real rate, records
the publish and tlm receive instants), the **ping** and **pong** of the Zenoh round-trip reference
(:func:`role_ping`, :func:`role_pong`), and the **memory** run (:func:`role_memory`: RSS per
vehicle in one process). Stamps are CLOCK_MONOTONIC ns, common to every process of the host.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from perf.live_host import proc_stat
from perf.live_stream import INPUT_TOPICS, KINDS, load_stream, phases, vehicle_names

PING_KEY, PONG_KEY = "radical_bench/ping", "radical_bench/pong"


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
    s = _open_session(listen=a.listen, connect=a.connect)
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
    from radical_rt.apps.node_setup import build_processors, warm_up

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
