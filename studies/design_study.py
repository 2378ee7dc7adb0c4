"""Tables of docs/design.md: design prediction vs `radical process`, and the paper's ±60° question.

    python -m studies.design_study --out out/design          # ≈ 2 min on one busy core

1. The 2-hour 2006216 scenario (seed 1) is synthesized and processed; its final σ are compared
   with the design prediction element by element.
2. 2006216 as flown (±10° x, ±10° z, +360°/−360° y) against the same maneuver with ±60° about y
   (+60°, −120°, +60°), cold and warm (after 2006216 and the §3.1 bump): final σ at 2 h, time to the
   paper's σ, σ at the end of the motion + 10 min.
Writes ``design_study.json`` and ``design_study.md`` in --out.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from mission.design import analysis
from mission.design import plan as planmod
from radical_rt.apps.batch import process
from radical_rt.contract.state import PARAM_GROUPS


def y60_scenario(amp: float = 60.0) -> dict:
    moves = []
    for axis in ("x", "z"):
        for a in (10.0, -20.0, 10.0):
            moves.append({"axis": axis, "angle_deg": a, "hold_s": 240.0})
    for a in (amp, -2 * amp, amp):
        moves.append({"axis": "y", "angle_deg": a, "hold_s": 60.0})
    return {"base": "2006216", "name": f"2006216-y{amp:g}", "maneuver": {"moves": moves}}


def group_max(sig_paper: dict) -> dict:
    return {g: max(sig_paper[g]) for g in PARAM_GROUPS}


def compare_process(out: Path) -> dict:
    from replayer.synth import synthesize

    mcap = out / "2006216_seed1.mcap"
    if not mcap.exists():
        synthesize("2006216", mcap, seed=1)
    summ = process([str(mcap)], None)
    hist, _ = planmod.design(planmod.load("2006216"))
    pred = analysis.paper_sigma(hist.sigma[-1])
    return {"process": summ["sigma"], "design": pred,
            "ratio": {g: [p / q for p, q in zip(pred[g], summ["sigma"][g], strict=True)]
                      for g in PARAM_GROUPS}, "design_elapsed_s": hist.elapsed_s}


def motion_end_s(sc) -> float:
    prof = sc.profile()
    return float(prof.slew_end[-1] - prof.t0) if len(prof.moves) else 0.0


def case(spec, warm_engine_factory=None) -> dict:
    sc = planmod.load(spec)
    targets = analysis.paper_targets(planmod.tables())
    eng = warm_engine_factory() if warm_engine_factory else None
    hist, _ = planmod.design(sc, engine=eng)
    end = motion_end_s(sc)
    i = min(int(np.searchsorted(hist.t, end + 600.0)), len(hist.t) - 1)
    ttt = analysis.time_to_target(hist.t, hist.sigma, targets)
    return {"motion_end_s": end,
            "final": group_max(analysis.paper_sigma(hist.sigma[-1])),
            "at_motion_end_plus_10min": group_max(analysis.paper_sigma(hist.sigma[i])),
            "time_to_paper_sigma_s": {g: (None if math.isinf(v) else v) for g, v in ttt.items()},
            "poor": analysis.poor_directions(hist.cov, targets, k=1)[0]}


def fmt(x):
    return "—" if x is None else f"{x / 60:.1f}"


def markdown(res: dict) -> str:
    L = ["## Prediction vs `radical process` (2006216, 2 h, seed 1)", "",
         "| group | element | process σ | design σ | design/process |", "|---|---|---|---|---|"]
    c = res["compare"]
    for g in PARAM_GROUPS:
        for k, (p, d, r) in enumerate(zip(c["process"][g], c["design"][g], c["ratio"][g],
                                          strict=True)):
            L.append(f"| {g} | {k} | {p:.4g} | {d:.4g} | {r:.3f} |")
    L += ["", "## As flown vs ±60° about y (largest element per group, paper units)", "",
          "| case | start | motion ends (min) | group | σ at motion end + 10 min | σ at 2 h | "
          "time to paper σ (min) |", "|---|---|---|---|---|---|---|"]
    for name, r in res["cases"].items():
        for g in PARAM_GROUPS:
            L.append(f"| {name.split('/')[0]} | {name.split('/')[1]} | {r['motion_end_s'] / 60:.1f} | "
                     f"{g} | {r['at_motion_end_plus_10min'][g]:.4g} | {r['final'][g]:.4g} | "
                     f"{fmt(r['time_to_paper_sigma_s'][g])} |")
    return "\n".join(L) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/design")
    ap.add_argument("--skip-process", action="store_true")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    res = {"compare": compare_process(out) if not a.skip_process else None, "cases": {}}

    def warm():
        return planmod.warm_engine("2006216")[0]

    for name, spec in (("as flown (±360° y)", "2006216"), ("±60° y", y60_scenario())):
        res["cases"][f"{name}/cold"] = case(spec)
        res["cases"][f"{name}/warm"] = case(spec, warm)
        print(name, "done", flush=True)
    (out / "design_study.json").write_text(json.dumps(res, indent=1) + "\n")
    if res["compare"]:
        (out / "design_study.md").write_text(markdown(res))
    print(f"wrote {out}/design_study.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
