"""Gyro noise characterization: ``radical allan IN.mcap [--segment T0:T1] [-o DIR]``.

Overlapping Allan deviation of each SIRU gyro over a static segment of an archive's ``/siru``
channel (allantools), with 68 % confidence intervals, and the IEEE Std 952 noise terms fitted to
it: angle random walk N (deg/√hr), bias instability B (deg/hr), rate random walk K (deg/hr/√s)
and angle quantization Q (arcsec), each with its 1σ; also the classic readouts (σ at τ = 1 s,
min σ / 0.664). See :mod:`monitors.allan_core` for the method.

Writes into DIR (default ``<stem>_allan``): ``allan.png`` (log-log σ(τ) per gyro with the
confidence band, the fitted terms and, for simulated archives, the simulator's truth),
``allan.json`` (σ(τ) in rad/s, terms in SI and in datasheet units, truth), ``allan.md`` (the
table printed on stdout) and ``allan_params.toml``: the noise entries of the parameter table
(``arw_deg_sqrt_hr``, ``quant_arcsec``, ``q_b_deg_hr_sqrt_s``) for ``radical process --config``.

The segment must be static (inertial hold): a segment whose 10 s mean rates move by more than
``--max-rate-dev`` deg/s is refused. Exit status 0, or 2 with a one-line error.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from monitors.allan_core import (
    PAPER,
    TERMS,
    AllanError,
    GyroResult,
    Segment,
    analyse,
    load_segment,
    paper_units,
    param_table,
)
from radical_rt.contract.conventions import ARCSEC, DEG, DEG_PER_HR
from radical_rt.io.outpaths import output_dir

TERM_NAMES = {"N": "angle random walk N", "B": "bias instability B", "K": "rate random walk K",
              "Q": "quantization Q"}


def truth_terms(scenario: dict[str, str]) -> dict[str, float] | None:
    """The simulator's noise terms (SI) from an archive's ``radical.scenario`` metadata."""
    text = scenario.get("scenario_toml")
    if not text:
        return None
    try:
        s = tomllib.loads(text).get("siru", {})
        return {"N": float(s["arw_deg_sqrt_hr"]) * DEG / 60.0,
                "B": float(s.get("bias_instability_deg_hr", 0.0)) * DEG_PER_HR,
                "K": float(s["bias_rw_rad_s_sqrt_s"]),
                "Q": float(s["quantum_arcsec"]) * ARCSEC / math.sqrt(12.0)}
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError):
        return None


def parse_segment(text: str | None) -> tuple[float | None, float | None]:
    if not text:
        return None, None
    try:
        a, b = text.split(":")
        t0 = float(a) if a.strip() else None
        t1 = float(b) if b.strip() else None
    except ValueError:
        raise AllanError(f"--segment {text!r}: expected T0:T1 in bus seconds (either may be "
                         "empty)") from None
    if t0 is not None and t1 is not None and t1 <= t0:
        raise AllanError(f"--segment {text!r}: T1 must be greater than T0")
    return t0, t1


def model_adev(terms: dict[str, float], tau: np.ndarray) -> np.ndarray:
    from monitors.allan_core import BI_FACTOR

    return np.sqrt(3 * terms["Q"] ** 2 / tau**2 + terms["N"] ** 2 / tau
                   + BI_FACTOR**2 * terms["B"] ** 2 + terms["K"] ** 2 * tau / 3)


def figure(results: list[GyroResult], truth: dict[str, float] | None, seg: Segment,
           title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, (len(results) + 1) // 2, figsize=(12, 8.5), squeeze=False,
                             sharex=True, sharey=True)
    for ax, r in zip(axes.flat, results, strict=False):
        k = 1.0 / DEG_PER_HR
        ax.fill_between(r.tau, r.lo * k, r.hi * k, color="tab:blue", alpha=0.25, lw=0,
                        label="68 % confidence")
        ax.loglog(r.tau, r.adev * k, "o", ms=3, color="tab:blue", label="overlapping ADEV")
        ax.loglog(r.tau, model_adev(r.terms, r.tau) * k, "-", color="tab:red", lw=1.5,
                  label="fit: " + ", ".join(f"{t}" for t in ("Q", "N", "B", "K")))
        if truth is not None:
            ax.loglog(r.tau, model_adev(truth, r.tau) * k, ":", color="k", lw=1.2,
                      label="simulator truth")
        p, s = paper_units(r.terms), paper_units(r.sigma)
        ax.text(0.03, 0.04, "\n".join(
            f"{t} = {p[t]:.3g} ± {s[t]:.2g} {PAPER[t][1]}" for t in ("N", "B", "K", "Q")),
            transform=ax.transAxes, fontsize=8, family="monospace",
            bbox={"facecolor": "white", "alpha": 0.8, "lw": 0})
        ax.set_title(f"gyro {r.name}")
        ax.grid(True, which="both", alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("averaging time τ [s]")
    for ax in axes[:, 0]:
        ax.set_ylabel("Allan deviation σ(τ) [deg/hr]")
    axes.flat[0].legend(fontsize=8, loc="upper right")
    fig.suptitle(f"{title}\nstatic segment {seg.t0:.1f}–{seg.t1:.1f} s, τ0 = "
                 f"{seg.tau0 * 1e3:.4f} ms", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def table(results: list[GyroResult], truth: dict[str, float] | None) -> str:
    head = ["gyro"] + [f"{TERM_NAMES[t]} [{PAPER[t][1]}]" for t in ("N", "B", "K", "Q")]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in results:
        p, s = paper_units(r.terms), paper_units(r.sigma)
        cells = [r.name] + [f"{p[t]:.4g} ± {s[t]:.2g}" for t in ("N", "B", "K", "Q")]
        lines.append("| " + " | ".join(cells) + " |")
    if truth is not None:
        tp = paper_units(truth)
        lines.append("| truth | " + " | ".join(f"{tp[t]:.4g}" for t in ("N", "B", "K", "Q"))
                     + " |")
    return "\n".join(lines) + "\n"


def run_allan(path: str, out_dir: str | None, segment: str | None, max_rate_dev: float,
              per_decade: int, progress: bool = False) -> dict[str, Any]:
    from radical_rt.io.archive import read_scenario

    t0, t1 = parse_segment(segment)
    seg = load_segment(path, t0, t1, progress)
    if seg.max_rate_dev_deg_s > max_rate_dev:
        raise AllanError(f"{path}: the segment is not static: 10 s mean gyro rates move by "
                         f"{seg.max_rate_dev_deg_s:.3g} deg/s (> --max-rate-dev "
                         f"{max_rate_dev:g}); choose an inertial hold with --segment T0:T1")
    results = analyse(seg, per_decade)
    scen = read_scenario(path)
    truth = truth_terms(scen)
    out = Path(out_dir) if out_dir else Path(f"{Path(path).stem}_allan")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise AllanError(f"{out}: cannot create output directory: {e.strerror or e}") from None
    title = f"radical allan: {Path(path).name} ({scen.get('name', '?')}, seed {scen.get('seed', '?')})"
    figure(results, truth, seg, title, out / "allan.png")
    md = table(results, truth)
    (out / "allan.md").write_text(f"# {title}\n\n{md}", encoding="utf-8")
    params = param_table(results)
    (out / "allan_params.toml").write_text(
        "# Gyro noise from radical allan (worst gyro); use: radical process --config FILE\n"
        f"# source: {path}, segment {seg.t0:.3f}..{seg.t1:.3f} s\n[params]\n"
        + "".join(f"{k} = {v!r}\n" for k, v in params.items()), encoding="utf-8")
    doc = {"schema": "radical.allan/1", "archive": str(path), "segment_s": [seg.t0, seg.t1],
           "tau0_s": seg.tau0, "samples": int(seg.dtheta.shape[0]),
           "repeated_dropped": seg.n_repeated, "missing_filled": seg.n_missing,
           "invalid_filled": seg.n_invalid,
           "units": {"tau": "s", "adev": "rad/s", "si": {"N": "rad/sqrt(s)", "B": "rad/s",
                                                         "K": "rad/s/sqrt(s)", "Q": "rad"},
                     "paper": {t: PAPER[t][1] for t in TERMS}},
           "gyros": [{"name": r.name, "tau": r.tau.tolist(), "adev": r.adev.tolist(),
                      "ci68_lo": r.lo.tolist(), "ci68_hi": r.hi.tolist(), "edf": r.edf.tolist(),
                      "si": r.terms, "si_sigma": r.sigma, "paper": paper_units(r.terms),
                      "paper_sigma": paper_units(r.sigma), "readout_si": r.readout}
                     for r in results],
           "truth_si": truth, "truth_paper": paper_units(truth) if truth else None,
           "params": params}
    (out / "allan.json").write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return {"dir": str(out), "table": md, "doc": doc}


#: the subcommand's line in `radical --help`
HELP = "Allan deviation and gyro noise parameters from a static segment"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="IN.mcap", help="archive with a /siru channel")
    p.add_argument("--segment", metavar="T0:T1", help="bus-time segment in s (default: all)")
    p.add_argument("-o", "--out", "--output", dest="out", metavar="DIR", type=output_dir,
                   help="output directory (default: <stem>_allan)")
    p.add_argument("--max-rate-dev", type=float, default=0.01, metavar="DEG_S",
                   help="refuse a segment whose 10 s mean rates move more (deg/s, default 0.01)")
    p.add_argument("--per-decade", type=int, default=12, metavar="N",
                   help="averaging times per decade (default 12)")


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    if not 2 <= args.per_decade <= 100:
        print("radical allan: --per-decade must be within 2..100", file=sys.stderr)
        return 2
    print(f"radical allan: reading {args.input} ...", file=sys.stderr)
    try:
        res = run_allan(args.input, args.out, args.segment, args.max_rate_dev, args.per_decade,
                        progress=sys.stderr.isatty())
    except AllanError as e:
        print(f"radical allan: {e}", file=sys.stderr)
        return 2
    print(res["table"], end="")
    print(f"radical allan: {res['dir']}/allan.png, allan.json, allan.md, allan_params.toml "
          f"({time.perf_counter() - t0:.1f} s)")
    return 0
