"""Engine throughput: seconds of telemetry processed per wall second (batch shell, one core),
for the UD engine and for its dense-covariance reference (:mod:`tests.oracles.dense_engine`).

Command::

    python -m perf.bench_engine [--profile smoke|quick|full] [--out DIR]

The scenario (2006216, seeded, bus time starting at 1000 s) is synthesized outside the timed region.
A first, untimed pass over a short prefix compiles/loads the Numba kernels of both engines (its
time is reported as ``warmup_s``); the timed passes run ``radical process`` (no output archive)
over the whole archive, first with the UD engine, then with :class:`tests.oracles.dense_engine.DenseEngine`
in its place (same stream processor, clock, packets and loop). ``x_realtime`` = telemetry seconds
/ wall seconds (UD engine); ``us_per_gyro_sample`` = wall time per distinct SIRU sample
(everything included: MCAP reading, decoding, clock, engine, packets). ``dense`` holds the same
figures for the dense engine; ``ud_speedup`` = UD ``x_realtime`` / dense ``x_realtime`` (> 1: the
UD engine is faster); ``dense_max_param_diff_sigma`` = largest final parameter difference between
the two engines in units of the UD σ (a check that both ran the same filter).
The process is pinned to one CPU when the platform allows it.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

PROFILES = {"smoke": 30.0, "quick": 600.0, "full": 7200.0}
SCENARIO_TOML = 'base = "2006216"\nt_start_s = 1000.0\n'
DEFAULT_OUT = Path(__file__).resolve().parent / "results"


def _process(path: Path, engine_cls):
    """``radical process`` of one archive, no output archive, with ``engine_cls`` in the batch
    shell's processor (its factory is swapped for the duration of the call; the stream processor,
    clock, packets and loop are the shell's own). Returns (summary, engine)."""
    from unittest import mock

    from radical_rt.apps import batch

    make_processor = _oracle().make_processor
    made = []

    def factory(table=None, clock_mode="reconstruct", packets_path=None):
        made.append(make_processor(engine_cls, table, clock_mode))
        return made[-1]

    with mock.patch.object(batch, "make_processor", factory):
        summary = batch.process([str(path)], None, None)
    return summary, made[0].engine


def run(profile: str = "quick", out_dir: str | Path | None = None) -> dict[str, Any]:
    """Synthesize, warm up, then time the UD and the dense engines; returns (and writes) the
    result dict."""
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; use one of {', '.join(PROFILES)}")
    try:  # one CPU for the timed passes; restored after (radical bench runs more benches)
        allowed = os.sched_getaffinity(0)
        os.sched_setaffinity(0, {min(allowed)})
        pinned = True
    except (AttributeError, OSError):
        allowed, pinned = None, False
    try:
        res = _timed(profile)
    finally:
        if allowed is not None:
            os.sched_setaffinity(0, allowed)
    res["pinned_one_cpu"] = pinned
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        (Path(out_dir) / f"engine_{profile}.json").write_text(json.dumps(res, indent=1))
    return res


def _oracle():
    """The dense-covariance oracle module (tests/oracles/dense_engine.py, a test oracle, not part
    of the product): the benchmark runs from a checkout of the repository."""
    try:
        from tests.oracles import dense_engine
    except ImportError as exc:
        raise RuntimeError("the engine benchmark compares with the dense oracle of "
                           "tests/oracles/dense_engine.py: run it from a checkout") from exc
    return dense_engine


def _timed(profile: str) -> dict[str, Any]:
    """Synthesize, warm up, time the UD then the dense engine (see the module docstring)."""
    from radical_rt.engine.filter import Engine
    from replayer.synth.api import synthesize

    DenseEngine, compare = _oracle().DenseEngine, _oracle().compare

    with tempfile.TemporaryDirectory() as tmp:
        toml = Path(tmp) / "s.toml"
        toml.write_text(SCENARIO_TOML)
        sim = Path(tmp) / "sim.mcap"
        warm = Path(tmp) / "warm.mcap"
        synthesize(str(toml), sim, seed=1, duration=PROFILES[profile])
        synthesize(str(toml), warm, seed=2, duration=5.0)
        t0 = time.perf_counter()
        _process(warm, Engine)
        _process(warm, DenseEngine)
        t1 = time.perf_counter()
        summary, ud_engine = _process(sim, Engine)
        t2 = time.perf_counter()
        _, dense_engine = _process(sim, DenseEngine)
        t3 = time.perf_counter()
    wall, wall_dense = t2 - t1, t3 - t2
    n = summary["counters"]["siru_samples"]
    tel = PROFILES[profile]
    res = {"bench": "engine", "profile": profile, "telemetry_s": tel,
           "wall_s": wall, "x_realtime": tel / wall,
           "us_per_gyro_sample": 1e6 * wall / max(n, 1), "siru_samples": n,
           "warmup_s": t1 - t0, "n_states": int(ud_engine.ns),
           "dense": {"wall_s": wall_dense, "x_realtime": tel / wall_dense,
                     "us_per_gyro_sample": 1e6 * wall_dense / max(n, 1)},
           "ud_speedup": wall_dense / wall,
           "dense_max_param_diff_sigma": compare(ud_engine, dense_engine)["max_param_diff_sigma"]}
    return res


def markdown(res: dict[str, Any]) -> str:
    lines = ["| engine | telemetry s | wall s | × real time | µs / gyro sample | warm-up s |",
             "|---|---|---|---|---|---|",
             f"| UD | {res['telemetry_s']:.0f} | {res['wall_s']:.2f} | {res['x_realtime']:.0f} | "
             f"{res['us_per_gyro_sample']:.2f} | {res['warmup_s']:.2f} |"]
    if "dense" in res:
        d = res["dense"]
        lines.append(f"| dense P | {res['telemetry_s']:.0f} | {d['wall_s']:.2f} | {d['x_realtime']:.0f} | "
                     f"{d['us_per_gyro_sample']:.2f} | (shared) |")
        lines += ["", f"UD / dense speed ratio {res['ud_speedup']:.2f} ({res.get('n_states', '?')} states); "
                      f"largest final parameter difference {res['dense_max_param_diff_sigma']:.1e} σ."]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default="quick", choices=list(PROFILES))
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    a = ap.parse_args()
    print(markdown(run(a.profile, a.out)))


if __name__ == "__main__":
    main()
