"""Seeded input streams shared by the tests: simulated archives and their damaged variants.

Messages are (topic without slash, log_time ns, payload bytes) in log-time order, as
:func:`input_messages` reads them from an archive.
"""

from __future__ import annotations

from pathlib import Path

import msgpack

from radical_rt.io.archive import ArchiveReader
from replayer.synth.api import synthesize

INPUTS = ["/siru", "/st1", "/st2", "/temp"]


def make_archive(directory: Path, name: str, seed: int, duration: float,
                 base: str = "2006216") -> Path:
    """A simulated archive of the built-in scenario ``base`` whose bus times start at 1000 s."""
    sc = directory / f"{name}.toml"
    sc.write_text(f'base = "{base}"\nt_start_s = 1000.0\n')
    out = directory / f"{name}.mcap"
    synthesize(str(sc), out, seed=seed, duration=duration)
    return out


def input_messages(path: Path) -> list[tuple[str, int, bytes]]:
    """(topic without slash, log_time ns, payload) of the input channels, in log_time order."""
    with ArchiveReader(path) as r:
        return [(t[1:], ns, data) for t, ns, data in r.iter_raw(topics=INPUTS)]


def damaged(messages):
    """The stream with a SIRU gap, garbage, duplicates, a time reversal and a NaN quaternion
    (bus times relative to the archive's start at 1000 s)."""
    out, seen = [], 0
    for i, (topic, ns, data) in enumerate(messages):
        t_rel = ns * 1e-9 - 1000.0
        if topic == "siru" and 100.0 <= t_rel < 101.0:
            continue  # a 1 s hole in the SIRU stream: gyro gap, warm start
        out.append((topic, ns, data))
        if i % 997 == 5:
            out.append((topic, ns, data))  # duplicate
        if i % 1499 == 7:
            out.append((topic, ns, b"\xc1\x00garbage"))
        if topic == "st1" and 150.0 <= t_rel and seen == 0:
            msg = msgpack.unpackb(data)
            msg["q"] = [float("nan")] * 4
            msg["t_bus"] += 0.001
            out.append((topic, ns, msgpack.packb(msg)))
            seen = 1
        if topic == "st2" and i % 2011 == 11:
            msg = msgpack.unpackb(data)
            msg["t_bus"] -= 5.0  # time going backwards
            out.append((topic, ns, msgpack.packb(msg)))
    return out


def bias_step_messages(directory: Path) -> list[tuple[str, int, bytes]]:
    """The input messages of 300 s from bus time 1000 s with a gyro B bias step of 5 deg/hr at
    120 s (an FDI alarm, its hypothesis bank, isolation and exclusion), written under
    ``directory``."""
    from perf.fdi_cases import fault_toml, synth

    text = fault_toml({"kind": "bias_step", "gyro": 1, "start_s": 120.0, "bias_deg_hr": 5.0},
                      duration=300.0, t_start=1000.0)
    return input_messages(synth(text, directory / "bias_step.mcap"))
