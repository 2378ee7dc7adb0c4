"""Engine throughput: seconds of telemetry processed per wall second (batch shell, one core),
for the UD engine and for its dense-covariance reference (:mod:`tests.oracles.dense_engine`).

Command::

    python -m perf.bench_engine [--profile smoke|quick|full] [--out DIR]

The scenario (2006216, seeded, bus time starting at 1000 s) is synthesized outside the timed region.
A first, untimed pass over a short prefix compiles/loads the Numba kernels of both engines (its
time is reported as ``warmup_s``); the timed passes run ``radical process`` (no output archive)
over the whole archive, first with the UD engine (``REPEATS`` passes: ``wall_s`` is their
median, ``wall_s_runs`` all of them), then once with
:class:`tests.oracles.dense_engine.DenseEngine` in its place (same stream processor, clock,
packets and loop). ``x_realtime`` = telemetry seconds / wall seconds (UD engine); ``us_per_gyro_sample`` = wall time per distinct SIRU sample
(everything included: MCAP reading, decoding, clock, engine, packets). ``dense`` holds the same
figures for the dense engine; ``ud_speedup`` = UD ``x_realtime`` / dense ``x_realtime`` (> 1: the
UD engine is faster); ``dense_max_param_diff_sigma`` = largest final parameter difference between
the two engines in units of the UD σ (a check that both ran the same filter).

``end_to_end``: the command a user runs, ``radical process SIM.mcap -o OUT.mcap --summary S.json``,
as a new process (start-up, imports, the Numba kernels loaded from the warm cache, MCAP reading and
writing included): wall time from launch to exit (median of ``REPEATS`` runs) and × real time. ``outside_compiled_share``: the
share of py-spy's samples (``py-spy record --native``, 100 Hz, over the same command) whose
innermost frame is not in Numba-compiled code, i.e. the time the process spends in Python,
numpy, msgpack and the MCAP library rather than in the kernels (None without py-spy, and in
the smoke profile).
The process is pinned to one CPU when the platform allows it (the subprocesses inherit it).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

PROFILES = {"smoke": 30.0, "quick": 600.0, "full": 7200.0}
#: timed UD passes and end-to-end runs per profile (the median is reported, with the range: the
#: 2-vCPU VM's speed drifts by several per cent between runs)
REPEATS = {"smoke": 1, "quick": 3, "full": 3}
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
        walls = []
        for _ in range(REPEATS[profile]):
            t2 = time.perf_counter()
            summary, ud_engine = _process(sim, Engine)
            walls.append(time.perf_counter() - t2)
        t2 = time.perf_counter()
        _, dense_engine = _process(sim, DenseEngine)
        t3 = time.perf_counter()
        e2es = [_end_to_end(sim, Path(tmp)) for _ in range(REPEATS[profile])]
        spy = None if profile == "smoke" else _outside_compiled_share(sim, Path(tmp))
    wall, wall_dense, e2e = statistics.median(walls), t3 - t2, statistics.median(e2es)
    n = summary["counters"]["siru_samples"]
    tel = PROFILES[profile]
    res = {"bench": "engine", "profile": profile, "telemetry_s": tel,
           "wall_s": wall, "x_realtime": tel / wall, "wall_s_runs": walls,
           "us_per_gyro_sample": 1e6 * wall / max(n, 1), "siru_samples": n,
           "warmup_s": t1 - t0, "n_states": int(ud_engine.ns),
           "dense": {"wall_s": wall_dense, "x_realtime": tel / wall_dense,
                     "us_per_gyro_sample": 1e6 * wall_dense / max(n, 1)},
           "ud_speedup": wall_dense / wall,
           "dense_max_param_diff_sigma": compare(ud_engine, dense_engine)["max_param_diff_sigma"],
           "end_to_end": {"wall_s": e2e, "x_realtime": tel / e2e, "wall_s_runs": e2es},
           "outside_compiled_share": spy}
    return res


def _command(sim: Path, tmp: Path) -> list[str]:
    return [sys.executable, "-m", "radical_rt.apps.cli", "process", str(sim), "-o",
            str(tmp / "out.mcap"), "--summary", str(tmp / "summary.json"), "--quiet"]


def _end_to_end(sim: Path, tmp: Path) -> float:
    """Wall time [s] of ``radical process`` as a new process, launch to exit."""
    t0 = time.perf_counter()
    subprocess.run(_command(sim, tmp), check=True, capture_output=True, timeout=3600)
    return time.perf_counter() - t0


def _outside_compiled_share(sim: Path, tmp: Path) -> float | None:
    """Share of py-spy samples of ``radical process`` outside Numba-compiled code (see the
    module docstring); None when py-spy is not installed or cannot attach."""
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    if not Path(spy).exists():
        return None
    raw = tmp / "spy.txt"
    r = subprocess.run([spy, "record", "--native", "--rate", "100", "--format", "raw", "-o",
                        str(raw), "--", *_command(sim, tmp)], capture_output=True, timeout=3600)
    if r.returncode != 0 or not raw.exists():
        return None
    return outside_share(raw.read_text())


def outside_share(collapsed: str) -> float | None:
    """From py-spy's collapsed native stacks ("frame;frame;... count" per line, root first): the
    share of samples not in Numba-compiled code. Numba's machine code has no symbols: py-spy
    shows it as unresolved frames ``0x7f… (?)`` below the Python frame that called the kernel;
    a sample is in compiled code when such a frame follows its innermost Python frame (the
    allocator and libm called from a kernel included)."""
    total = inside = 0
    for line in collapsed.splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack or not count.isdigit():
            continue
        n = int(count)
        total += n
        frames = stack.split(";")
        last_py = max((i for i, f in enumerate(frames) if ".py:" in f or "<frozen" in f),
                      default=-1)
        if any(f.startswith("0x") and f.endswith("(?)") for f in frames[last_py + 1:]):
            inside += n
    return None if total == 0 else 1.0 - inside / total


def markdown(res: dict[str, Any]) -> str:
    lines = ["| engine | telemetry s | wall s | × real time | µs / gyro sample | warm-up s |",
             "|---|---|---|---|---|---|",
             f"| UD | {res['telemetry_s']:.0f} | {res['wall_s']:.2f}{_spread(res)} | "
             f"{res['x_realtime']:.0f} | {res['us_per_gyro_sample']:.2f} | {res['warmup_s']:.2f} |"]
    if "dense" in res:
        d = res["dense"]
        lines.append(f"| dense P | {res['telemetry_s']:.0f} | {d['wall_s']:.2f} | {d['x_realtime']:.0f} | "
                     f"{d['us_per_gyro_sample']:.2f} | (shared) |")
        lines += ["", f"UD / dense speed ratio {res['ud_speedup']:.2f} ({res.get('n_states', '?')} states); "
                      f"largest final parameter difference {res['dense_max_param_diff_sigma']:.1e} σ."]
    if "end_to_end" in res:
        e = res["end_to_end"]
        share = res.get("outside_compiled_share")
        lines += ["", f"End to end (`radical process` as a new process, start-up included): "
                      f"{e['wall_s']:.2f} s{_spread(e)}, {e['x_realtime']:.0f}× real time; share of "
                      "the time outside compiled code (py-spy): "
                      + ("n/a" if share is None else f"{100 * share:.0f} %") + "."]
    return "\n".join(lines)


def _spread(r: dict[str, Any]) -> str:
    """The text ' (min–max, n runs)' when r holds several runs (``wall_s_runs``), else ''."""
    runs = r.get("wall_s_runs") or []
    return f" ({min(runs):.2f}–{max(runs):.2f}, {len(runs)} runs)" if len(runs) > 1 else ""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default="quick", choices=list(PROFILES))
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    a = ap.parse_args()
    print(markdown(run(a.profile, a.out)))


if __name__ == "__main__":
    main()
