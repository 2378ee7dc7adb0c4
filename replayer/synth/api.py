"""Python API: ``synthesize(scenario, out_path, ...) -> SynthResult``.

Two passes over the scenario with fresh random streams: the first runs only the SIRU clock and
the tracker flags to get the true counters (they go into the archive's ``radical.scenario``
metadata, which is written when the archive is opened); the second generates and writes
everything and checks that it reproduces the same counters.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

from radical_rt import __version__
from radical_rt.io.archive import ArchiveWriter

from .clock import jitter_clip_s
from .scenario import Scenario, describe_truth, load_scenario
from .schema import TIMING_DEFAULTS, siru_timing
from .simulator import Simulator, timing_summary

GENERATOR = f"radical-rt synth {__version__}"


@dataclass
class SynthResult:
    """What a synthesis produced.

    ``paths``: one archive, or one per part with ``split_at_gaps``; ``message_counts``: per topic,
    all parts; ``truth_counts``: true counters per part (simulator.COUNT_KEYS); ``file_size``:
    bytes, all parts; ``elapsed_s``: wall time; ``truth``: parameters at the start and the end of
    the run in paper units (deg/hr, ppm, arcsec); ``timing``: the bus-read timing truth per part
    (:func:`timing_truth`).
    """

    paths: list[Path]
    scenario: Scenario
    message_counts: dict[str, int] = field(default_factory=dict)
    truth_counts: list[dict[str, int]] = field(default_factory=list)
    file_size: int = 0
    elapsed_s: float = 0.0
    truth: dict = field(default_factory=dict)
    timing: list[dict] = field(default_factory=list)

    @property
    def path(self) -> Path:
        """The (first) archive."""
        return self.paths[0]


def part_paths(out_path: str | Path, n_parts: int) -> list[Path]:
    """Archive paths: ``out_path`` itself, or ``<stem>.partN<suffix>`` (N = 1..) when split."""
    out = Path(out_path)
    if n_parts == 1:
        return [out]
    return [out.with_name(f"{out.stem}.part{i + 1}{out.suffix or '.mcap'}") for i in range(n_parts)]


def timing_truth(sc: Scenario, sums: dict) -> dict:
    """Bus-read timing truth of one archive part (SI): the scenario's knobs (defaults filled in),
    the ε, jitters and tracker latency, the realized read lead on the tag (``read_lead_mean_s``,
    ``read_lead_std_s``: mean and std of ``t_bus − t_read``; late and clipped read counts) and
    ``latency_truth_s`` = tracker latency − mean read lead, the value a filter that rebuilds the
    SIRU time line from the tags should estimate for the tracker latency (the constant read
    offset is not observable from the tags, so it moves into the latency)."""
    s = sc.cfg["siru"]
    out = {**siru_timing(s), "read_jitter_s": s["read_jitter_s"],
           "read_jitter_clip_s": jitter_clip_s(s), "sample_jitter_s": s["sample_jitter_s"],
           "eps_ppm": s["eps_ppm"], "bus_period_s": s["bus_period_s"],
           "tracker_latency_s": sc.cfg["trackers"]["latency_s"], **timing_summary(sums)}
    out["latency_truth_s"] = out["tracker_latency_s"] - out["read_lead_mean_s"]
    return out


def scenario_metadata(sc: Scenario, counts: dict, part: int, n_parts: int,
                      timing: dict | None = None) -> dict[str, str]:
    """The ``radical.scenario`` key-values (all strings) of one archive part. ``siru_timing``
    (JSON of :func:`timing_truth`) is written when the scenario sets a bus-read timing key
    (absent: the defaults, tag = read instant), so that older scenarios keep their bytes."""
    meta = {"name": sc.name, "vehicle": sc.cfg["vehicle"], "seed": str(sc.seed),
            "generator": GENERATOR, "part": f"{part + 1}/{n_parts}",
            "duration_s": repr(sc.cfg["duration_s"]), "t_start_s": repr(sc.cfg["t_start_s"]),
            "profile": sc.cfg["maneuver"]["profile"],
            "truth_counts": json.dumps(counts, sort_keys=True),
            "truth_params_paper_units": json.dumps(describe_truth(sc.truth), sort_keys=True),
            "scenario_toml": sc.to_toml()}
    meta.update({k: str(v) for k, v in counts.items()})
    if timing is not None and any(k in sc.cfg["siru"] for k in TIMING_DEFAULTS):
        meta["siru_timing"] = json.dumps(timing, sort_keys=True)
    return meta


def _resolve(scenario, seed, duration, vehicle) -> Scenario:
    if isinstance(scenario, Scenario):
        if seed is None and duration is None and vehicle is None:
            return scenario
        return load_scenario(scenario.cfg, seed=seed, duration=duration, vehicle=vehicle)
    return load_scenario(scenario, seed=seed, duration=duration, vehicle=vehicle)


def count_only(sc: Scenario) -> list[dict[str, int]]:
    """True counters per archive part, from a clock-and-flags-only pass (fast)."""
    return _count_pass(sc).counts


def _count_pass(sc: Scenario) -> Simulator:
    sim = Simulator(sc, full=False)
    for j0, j1 in sim.lay.chunks():
        sim.chunk(j0, j1)
    return sim


def synthesize(scenario, out_path, seed: int | None = None, duration: float | None = None,
               progress: bool = False, vehicle: str | None = None) -> SynthResult:
    """Simulate ``scenario`` (built-in name, TOML path, mapping or :class:`Scenario`) into MCAP.

    ``seed``/``duration``/``vehicle`` override the scenario's. Same scenario and seed give the
    same bytes. Raises :class:`~replayer.synth.schema.ScenarioError` for a bad scenario.
    """
    t_wall = time.perf_counter()
    sc = _resolve(scenario, seed, duration, vehicle)
    pre = _count_pass(sc)
    counts = pre.counts
    timing = [timing_truth(sc, t) for t in pre.timing]
    paths = part_paths(out_path, len(counts))
    for p in paths:
        p.parent.mkdir(parents=True, exist_ok=True)
    writers = [ArchiveWriter(p, scenario=scenario_metadata(sc, c, i, len(paths), tm))
               for i, (p, c, tm) in enumerate(zip(paths, counts, timing, strict=True))]
    sim = Simulator(sc, full=True)
    n_msgs: dict[str, int] = {}
    try:
        with tqdm(total=round(sc.cfg["duration_s"]), unit="s", desc=f"synth {sc.name}",
                  disable=not progress, file=sys.stderr, leave=False) as bar:
            for j0, j1 in sim.lay.chunks():
                for part, _ns, _o, topic, msg, t in sim.chunk(j0, j1):
                    writers[part].write(topic, msg, t_bus=t)
                    n_msgs[topic] = n_msgs.get(topic, 0) + 1
                bar.update(round((j1 - j0) * sim.lay.P))
    finally:
        for w in writers:
            w.close()
    if sim.counts != counts or sim.timing != pre.timing:
        raise RuntimeError(f"synth: counter passes disagree: {counts} vs {sim.counts}")
    t_end = sc.cfg["t_start_s"] + sc.cfg["duration_s"]
    end = {"b": sim.siru.bias(np.array([t_end]))[0], "lam": sim.siru.lam(np.array([t_end]))[0],
           "phi2": sim.thermal.phi2(np.array([t_end]))[0]}
    return SynthResult(paths=paths, scenario=sc, message_counts=dict(sorted(n_msgs.items())),
                       truth_counts=counts, file_size=sum(p.stat().st_size for p in paths),
                       elapsed_s=time.perf_counter() - t_wall,
                       truth={"start": describe_truth(sc.truth), "end": describe_truth(end)},
                       timing=timing)
