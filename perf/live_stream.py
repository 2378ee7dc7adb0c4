"""The input of the live benches: the simulator's scenario as a stream of input messages at their
bus times (:func:`build_stream`, :func:`load_stream`; each SIRU read its own message unless
batched), per-vehicle phases (:func:`phases`), the SIRU samples' reconstructed times
(:func:`sample_times`, the node's clock replayed offline), and the telemetry packet settings the
node runs with (:func:`packet_presets`, :func:`packet_file`). The harness: :mod:`perf.live`.
"""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from perf.live_host import LiveError

INPUT_TOPICS = ("siru", "st1", "st2", "temp")  # = radical_rt.stream.processor.INPUT_TOPICS (codes 0..3)
KINDS = ("small", "medium", "large")
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


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
    from radical_rt.clock.clock_config import ClockConfig
    from radical_rt.clock.siru_clock import SiruClock
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
