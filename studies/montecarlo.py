"""Monte Carlo statistical consistency of the engine: parameter NEES and innovation NIS.

    python -m studies.montecarlo [--runs 20] [--first-seed 1] [--workers 2] [--json OUT.json]

Each run synthesizes a short MESSENGER-like scenario (``scenario_toml``: 2006216 sensors, a hold
until the SIRU clock reconstruction has locked, then short slews about x, z and y) with its own
seed, and with true calibration parameters drawn at random: x_int ~ N(0, s²·P0) in the engine's
internal coordinates (P0 = ``p0_params`` of the active table, s = ``truth_scale``), converted
exactly to the contract's parameters for the simulator. With s = 1 the truth comes from the
engine's own prior, which makes the averaged NEES a χ² statistic for every state, observed or not;
with s = 1/3 the truth has the spread of the paper's "uniform on [−L, L]" initial errors (the
default P0 is 3L²), and the NEES is a χ² statistic when the data dominate the prior in every
direction (reported per run: ``prior_share`` = tr(P0⁻¹P); for a linear-Gaussian filter
E[NEES] = dof − (1 − s²)·tr(P0⁻¹P)). A fixed truth (a table row) would let
the states a short run does not observe contribute ≈ x²/P0 ≪ 1 and bias the average low.

Per run, at the end of the stream:

* parameter NEES in the engine's *internal* parameter coordinates (docs/engine.md §3.1 "NEES
  note"), over every parameter state whose truth is known: the contract's groups from
  ``/truth/params`` (mapped with :func:`radical_rt.kernels.parametrization.internal_from_contract`) and, when the
  layout has it, the residual tracker latency ``lat`` = ``latency_st`` (truth) − configured
  latency. dof = number of those states (read from ``engine.layout``, never hard-coded);
* star-tracker and parity NIS: the engine's own sums (``engine.nis_sum``, ``counters[kind_used]``),
  plus the same restricted to updates after the SIRU clock locked (σ_t ≤ ``timing_consider_s``).

The pooled statistics and their two-sided chi-square bounds (``summarize``): the sum of N
independent NEES values is χ²(N·dof); the sum of M tracker NIS values is χ²(3M) (3 rows per update,
innovations white for a consistent filter); parity χ²((n−3)M).

Runs are independent and seeded, so the results do not depend on the number of worker processes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from radical_rt.apps.batch import INPUTS, make_processor
from radical_rt.contract.conventions import to_paper_units
from radical_rt.contract.params import ParamTable, to_si
from radical_rt.contract.state import PARAM_GROUPS
from radical_rt.kernels import ud
from radical_rt.kernels.parametrization import contract_from_internal, internal_from_contract

#: Moves of the MC scenario (body axis, angle in degrees): +10° then −10° about x, z and y (every
#: axis turns with both rate signs), at the 2006216 rate (0.3 deg/s, 20 s ramps): 53 s per move.
MOVES = (("x", 10.0), ("x", -10.0), ("z", 10.0), ("z", -10.0), ("y", 10.0), ("y", -10.0))
#: Scenario keys (paper units) of the explicit truth, per parameter group.
TRUTH_KEYS = {"b": "b_deg_hr", "lam": "lam_ppm", "mu": "mu_ppm", "du": "du_arcsec",
              "dv": "dv_arcsec", "phi2": "phi2_arcsec"}
SEED_TAG = 20240604  # mixes into every truth draw: np.random.default_rng([SEED_TAG, seed])


@dataclass
class MCConfig:
    """One Monte Carlo configuration (everything a worker needs; picklable)."""

    duration_s: float = 880.0  # run length (the last hold ends at 420 + 6 × (53.3 + 20) = 860 s)
    start_s: float = 420.0  # first move, s after the run start (after the SIRU clock locks)
    hold_s: float = 20.0  # hold after each move
    moves: tuple[tuple[str, float], ...] = MOVES
    t_start_s: float = 1000.0  # bus time of the run start
    params: dict[str, Any] = field(default_factory=dict)  # engine parameter overrides
    draw_truth: bool = True  # truth drawn at random (below); False: the 2006216 table row
    truth_scale: float = 1.0  # truth ~ N(0, truth_scale² P0); 1/3 gives the σ of the paper's
    # "uniform on [−L, L]" initial errors under the default P0 = 3L²
    thermal: bool = True  # ST2 misalignment follows the baseplate temperature (a ramp, not the
    # filter's random walk); False sets the simulator's thermal coefficients to zero


def scenario_toml(seed: int, cfg: MCConfig, truth_paper: dict[str, list[float]] | None) -> str:
    """The scenario of one run: 2006216 sensors, the short maneuver ``cfg.moves``."""
    lines = ['base = "2006216"', f'name = "mc-{seed}"', f"seed = {int(seed)}",
             f"duration_s = {cfg.duration_s!r}", f"t_start_s = {cfg.t_start_s!r}",
             "[truth]", 'source = "2006216"']
    for g, vals in (truth_paper or {}).items():
        lines.append(f"{TRUTH_KEYS[g]} = [{', '.join(repr(float(v)) for v in vals)}]")
    if not cfg.thermal:
        lines += ["[thermal]", "k_temp_arcsec_per_C = [0.0, 0.0, 0.0]"]
    lines += ["[maneuver]", f"start_s = {cfg.start_s!r}"]
    for axis, angle in cfg.moves:
        lines += ["[[maneuver.moves]]", f'axis = "{axis}"', f"angle_deg = {angle!r}",
                  f"hold_s = {cfg.hold_s!r}"]
    return "\n".join(lines) + "\n"


def make_table(cfg: MCConfig) -> ParamTable:
    table = ParamTable()
    if cfg.params:
        table.set(dict(cfg.params))
    return table


def draw_truth(seed: int, table: ParamTable, n_gyro: int = 4,
               scale: float = 1.0) -> dict[str, list[float]]:
    """True parameters (paper units, per group) for run ``seed``, drawn from the engine's prior.

    x_int ~ N(0, scale²·diag(p0)) over the contract groups in the engine's internal coordinates,
    then the exact map to the contract's parameters (:func:`radical_rt.kernels.parametrization.contract_from_internal`).
    """
    si = to_si(table.active, n_gyro)
    m = 5 * n_gyro + 3  # b, λ, μ, du, dv (n each), φ2 (3): the contract's groups
    sd = scale * np.sqrt(np.asarray(si.p0_params[:m]))
    x_int = sd * np.random.default_rng([SEED_TAG, int(seed)]).standard_normal(m)
    x_c, _ = contract_from_internal(x_int, n_gyro)
    out, k = {}, 0
    for g in PARAM_GROUPS:
        size = 3 if g == "phi2" else n_gyro
        out[g] = [float(to_paper_units(g, v)) for v in x_c[k:k + size]]
        k += size
    return out


def truth_internal(engine, truth: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """Truth of the engine's parameter states (state order, internal coordinates) and the mask of
    the states whose truth is known. Generic in ``engine.layout``: contract groups from
    ``/truth/params``; ``lat`` (residual latency) = true − configured latency; others unknown."""
    npar = engine.ns - 3
    x = np.zeros(npar)
    known = np.zeros(npar, dtype=bool)
    for block in engine.layout:
        if block.name == "att":
            continue
        sl = slice(block.start - 3, block.stop - 3)
        if block.name in PARAM_GROUPS and block.name in truth:
            x[sl] = np.asarray(truth[block.name], float)
            known[sl] = True
        elif block.name == "lat" and "latency_st" in truth:
            x[sl] = float(truth["latency_st"]) - float(engine.si.latency_st_s)
            known[sl] = True
    # the contract → internal map acts on the leading 5n+3 entries (gyro groups, φ2) only
    return internal_from_contract(x, engine.n_gyro), known


def parameter_nees(engine, truth: dict[str, Any]) -> dict[str, Any]:
    """NEES of the parameter states with known truth (internal coordinates), and per-state z."""
    x_true, known = truth_internal(engine, truth)
    P = np.empty((engine.ns, engine.ns))
    ud.ud_to_cov(engine.U, engine.d, P)
    Pp = P[3:, 3:][np.ix_(known, known)]
    err = (engine.xp - x_true)[known]
    nees = float(err @ np.linalg.solve(Pp, err))
    names = [f"{b.name}[{k}]" for b in engine.layout if b.name != "att" for k in range(b.size)]
    z = err / np.sqrt(np.diag(Pp))
    # how much the data taught: posterior σ / prior σ per state, and in the least informed
    # direction (√ of the largest eigenvalue of P0^-½ P P0^-½); ≪ 1: the NEES is not the prior's
    s0 = np.sqrt(np.asarray(engine.si.p0_params)[known])
    ratio = np.sqrt(np.diag(Pp)) / s0
    worst = float(np.sqrt(np.max(np.linalg.eigvalsh(Pp / np.outer(s0, s0)))))
    # tr(P0⁻¹P): for a linear-Gaussian filter with prior P0 and truth ~ N(0, s²P0),
    # E[NEES] = dof − (1 − s²)·tr(P0⁻¹P), so this bounds the effect of a truth_scale ≠ 1
    return {"nees": nees, "dof": int(known.sum()),
            "states": [nm for nm, kn in zip(names, known, strict=True) if kn], "z": z.tolist(),
            "post_over_prior_sigma": ratio.tolist(), "post_over_prior_worst": worst,
            "prior_share": float(np.sum(ratio**2))}


def process_archive(path: str | Path, table: ParamTable):
    """Run the batch pipeline over one archive; return (processor, last /truth/params, NIS log).

    The log holds per kind: updates used and NIS sum, all and after the SIRU clock locked."""
    from radical_rt.io.archive import ArchiveReader

    sp = make_processor(table)
    e = sp.engine
    truth = None
    with ArchiveReader(str(path)) as reader:
        for topic, _, data in reader.iter_raw(topics=[*INPUTS, "/truth/params"]):
            if topic == "/truth/params":
                truth = data
                continue
            sp.feed(topic[1:], data)
    sp.end_stream(None)
    c, nis, locked = e.counters, e.nis_sum, e.nis_locked
    log = {k: {"n": c[f"{k}_used"], "sum": nis[k], "n_locked": locked[k][0],
               "sum_locked": locked[k][1], "edited": c[f"{k}_edited"]}
           for k in ("st1", "st2", "parity")}
    return sp, (msgpack.unpackb(truth, raw=False) if truth is not None else None), log


def run_one(seed: int, cfg: MCConfig) -> dict[str, Any]:
    """Synthesize and process run ``seed``; return its NEES, NIS sums and counters."""
    from replayer.synth.api import synthesize

    t0 = time.perf_counter()
    table = make_table(cfg)
    truth_paper = draw_truth(seed, table, scale=cfg.truth_scale) if cfg.draw_truth else None
    with tempfile.TemporaryDirectory(prefix="radical_mc_") as tmp:
        toml = Path(tmp) / "mc.toml"
        toml.write_text(scenario_toml(seed, cfg, truth_paper))
        sim = Path(tmp) / "mc.mcap"
        synthesize(str(toml), sim)
        sp, truth, log = process_archive(sim, table)
    e = sp.engine
    if truth is None:
        raise RuntimeError("the archive has no /truth/params")
    res = {"seed": int(seed), **parameter_nees(e, truth), "nis": log,
           "engine_nis": {k: {"n": int(e.counters.get(f"{k}_used", 0)),
                              "sum": float(e.nis_sum.get(k, 0.0))} for k in ("st1", "st2", "parity")},
           "parity_rows": int(e.N.shape[1]), "mode": e.mode,
           "numeric_faults": int(e.counters.get("numeric_faults", 0)),
           "wall_s": time.perf_counter() - t0}
    return res


def _run_one_star(args):
    return run_one(*args)


def run_many(seeds, cfg: MCConfig, workers: int = 1, progress: bool = False) -> list[dict[str, Any]]:
    """Run the seeds (in ``workers`` processes when > 1); results in seed order."""
    seeds = [int(s) for s in seeds]
    jobs = [(s, cfg) for s in seeds]
    out: list[dict[str, Any]] = []
    if workers > 1:
        import multiprocessing as mp

        ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
        with ctx.Pool(min(workers, len(jobs))) as pool:
            for r in pool.imap(_run_one_star, jobs):
                out.append(r)
                _progress(progress, r, len(out), len(jobs))
    else:
        for j in jobs:
            out.append(run_one(*j))
            _progress(progress, out[-1], len(out), len(jobs))
    return sorted(out, key=lambda r: r["seed"])


def _progress(on: bool, r: dict[str, Any], k: int, n: int) -> None:
    if on:
        nis = r["engine_nis"]
        st = (nis["st1"]["sum"] + nis["st2"]["sum"]) / max(nis["st1"]["n"] + nis["st2"]["n"], 1)
        print(f"[{k}/{n}] seed {r['seed']}: NEES {r['nees']:.1f} (dof {r['dof']}), ST NIS {st:.3f}, "
              f"{r['wall_s']:.1f} s", file=sys.stderr, flush=True)


def chi2_mean_bounds(dof_total: float, count: int, p: float = 0.95) -> tuple[float, float]:
    """Two-sided ``p`` bounds of the mean of ``count`` values whose sum is χ²(dof_total)."""
    from scipy.stats import chi2

    a = (1.0 - p) / 2.0
    return float(chi2.ppf(a, dof_total) / count), float(chi2.ppf(1.0 - a, dof_total) / count)


def summarize(results: list[dict[str, Any]], p: float = 0.95) -> dict[str, Any]:
    """Pooled NEES and NIS with their two-sided ``p`` chi-square bounds."""
    n = len(results)
    dof = results[0]["dof"]
    if any(r["dof"] != dof for r in results):
        raise ValueError("runs with different NEES dof")
    nees = np.array([r["nees"] for r in results])
    out: dict[str, Any] = {"runs": n, "p": p, "nees": {
        "dof": dof, "mean": float(nees.mean()), "bounds": chi2_mean_bounds(n * dof, n, p),
        "per_run": nees.round(3).tolist()}}
    z = np.array([r["z"] for r in results])
    out["nees"]["state_z2_mean"] = dict(zip(results[0]["states"], (z**2).mean(0).round(3).tolist(),
                                            strict=True))
    rows = {"st": 3, "parity": results[0]["parity_rows"]}
    for key, src in (("engine", "engine_nis"), ("all", "nis"), ("locked", "nis")):
        for kind, kinds in (("st", ("st1", "st2")), ("parity", ("parity",))):
            nk, sk = ("n_locked", "sum_locked") if key == "locked" else ("n", "sum")
            m = sum(r[src][k][nk] for r in results for k in kinds)
            s = sum(r[src][k][sk] for r in results for k in kinds)
            if m == 0:
                continue
            k_rows = rows[kind]
            lo, hi = chi2_mean_bounds(k_rows * m, m, p)
            out.setdefault("nis", {}).setdefault(key, {})[kind] = {
                "updates": int(m), "dof_per_update": k_rows, "mean": s / m, "bounds": (lo, hi),
                "mean_per_dof": s / m / k_rows}
    out["prior_share_max"] = max(r.get("prior_share", math.nan) for r in results)
    out["edited"] = {k: sum(r["nis"][k]["edited"] for r in results) for k in ("st1", "st2", "parity")}
    out["numeric_faults"] = sum(r["numeric_faults"] for r in results)
    return out


def format_summary(s: dict[str, Any]) -> str:
    lo, hi = s["nees"]["bounds"]
    lines = [f"runs {s['runs']}; parameter NEES (internal coordinates, dof {s['nees']['dof']}): "
             f"mean {s['nees']['mean']:.2f}, {100 * s['p']:.0f} % bounds [{lo:.2f}, {hi:.2f}]"]
    for key, d in s.get("nis", {}).items():
        for kind, v in d.items():
            lo, hi = v["bounds"]
            lines.append(f"NIS {kind:6s} ({key:6s}): {v['updates']:7d} updates × {v['dof_per_update']} "
                         f"dof, mean {v['mean']:.4f}, bounds [{lo:.4f}, {hi:.4f}]")
    z2 = s["nees"]["state_z2_mean"]
    lines.append("mean z² per state: " + ", ".join(f"{k} {v:.2f}" for k, v in z2.items()))
    lines.append(f"edits {s['edited']}, numeric faults {s['numeric_faults']}, "
                 f"max tr(P0⁻¹P) {s['prior_share_max']:.3g}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--first-seed", type=int, default=1)
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--duration", type=float, default=MCConfig.duration_s)
    ap.add_argument("--start", type=float, default=MCConfig.start_s)
    ap.add_argument("--hold", type=float, default=MCConfig.hold_s)
    ap.add_argument("--moves", default=None, metavar="AXIS:DEG,...",
                    help="moves, e.g. x:10,x:-20,x:10 (default: " +
                    ",".join(f"{ax}:{ang:g}" for ax, ang in MOVES) + ")")
    ap.add_argument("--fixed-truth", action="store_true", help="use the 2006216 truth for every run")
    ap.add_argument("--no-thermal", action="store_true", help="constant ST2 misalignment (no thermal ramp)")
    ap.add_argument("--truth-scale", type=float, default=1.0,
                    help="truth ~ N(0, s²·P0) (1/3: the σ of the paper's uniform [−L, L] errors)")
    ap.add_argument("--param", action="append", default=[], metavar="NAME=VALUE",
                    help="engine parameter override (TOML value), repeatable")
    ap.add_argument("--json", metavar="OUT.json", help="write the per-run results and the summary")
    a = ap.parse_args(argv)
    import tomllib

    params = {}
    for item in a.param:
        name, _, value = item.partition("=")
        params[name.strip()] = tomllib.loads(f"v = {value}")["v"]
    moves = MOVES if a.moves is None else tuple(
        (m.split(":")[0].strip(), float(m.split(":")[1])) for m in a.moves.split(","))
    cfg = MCConfig(duration_s=a.duration, start_s=a.start, hold_s=a.hold, params=params, moves=moves,
                   draw_truth=not a.fixed_truth, thermal=not a.no_thermal,
                   truth_scale=a.truth_scale)
    t0 = time.perf_counter()
    res = run_many(range(a.first_seed, a.first_seed + a.runs), cfg, a.workers, progress=True)
    s = summarize(res)
    print(format_summary(s))
    print(f"wall {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    if a.json:
        Path(a.json).write_text(json.dumps({"config": asdict(cfg), "summary": s, "runs": res},
                                           indent=1, default=float))
    return 0 if all(math.isfinite(r["nees"]) for r in res) else 1


if __name__ == "__main__":
    raise SystemExit(main())
