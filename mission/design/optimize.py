"""Shortest calibration maneuver of a documented family that meets σ targets (covariance analysis).

Family (MESSENGER-style, rate ≤ ``rate_deg_s`` = 0.3 °/s, ramps ``ramp_s`` = 20 s, i.e. an
acceleration of 0.015 °/s²): after ``start_s`` (the SIRU clock's lock + 30 s: slews before the
lock do not calibrate λ, μ, du, dv), ``±A_xz`` about x (+A, −2A, +A), ``±A_xz`` about z, then
``repeats`` × ``±A_y`` about y, every move followed by ``hold_s``; the run ends after the last
hold. ``A_xz`` is the largest the Sun constraint allows (the constrained axis y leaves the Sun by
up to A_xz during x and z slews; MESSENGER: 12° inside 0.85 AU), capped at 10°.

Search (seeded by construction, deterministic): a coarse grid over A_y ∈ {30, 60, 90}°, hold ∈
{60, 120, 240} s, repeats ∈ {1, 2} and a final dwell ∈ {0, 900, 1800, 2700} s (the trackers keep
averaging φ2 and the biases at rest), shortest first where it prunes; every candidate is checked against the pointing constraints
(:func:`mission.design.constraints.check`) and the maximum duration, designed (cold, or after
the warm start + bump), and the shortest meeting every target is refined by bisection on the
final dwell (4 steps). Progress is printed per candidate.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np

from mission.design import analysis
from mission.design import plan as planmod
from mission.design.constraints import check

GRID_AY = (30.0, 60.0, 90.0)
GRID_HOLD = (60.0, 120.0, 240.0)
GRID_REPEATS = (1, 2)
GRID_DWELL = (0.0, 900.0, 1800.0, 2700.0)


@dataclass
class Candidate:
    a_y: float
    a_xz: float
    hold_s: float
    repeats: int
    start_s: float
    dwell_s: float = 0.0  # final inertial hold after the last move's hold [s]

    def moves(self) -> list[dict]:
        out = []
        seq = [("x", self.a_xz), ("z", self.a_xz)] + [("y", self.a_y)] * self.repeats
        for axis, a in seq:
            for ang in (a, -2 * a, a):
                out.append({"axis": axis, "angle_deg": ang, "hold_s": self.hold_s})
        return out

    def duration_s(self, rate_deg_s: float = 0.3, ramp_s: float = 20.0) -> float:
        t = self.start_s
        for m in self.moves():
            a = abs(m["angle_deg"])
            slew = a / rate_deg_s + ramp_s if a >= rate_deg_s * ramp_s else 2 * math.sqrt(
                a * ramp_s / rate_deg_s)
            t += slew + m["hold_s"]
        return t + self.dwell_s

    def scenario(self, name: str = "designed") -> dict:
        return {"base": "2006216", "name": name, "duration_s": round(self.duration_s(), 3),
                "maneuver": {"start_s": self.start_s, "moves": self.moves()}}


def evaluate(c: Candidate, targets, pointing, table=None, warm_factory=None):
    """(meets, final σ paper units, pointing report) of candidate c."""
    sc = planmod.load(c.scenario())
    eng = warm_factory() if warm_factory else None
    hist, plan = planmod.design(sc, table, eng, record_dt=30.0, pointing=pointing)
    sig = hist.sigma[-1]
    missed = [g for g, sl in analysis.group_slices().items() if not np.all(sig[sl] <= targets[g])]
    meets = not missed
    geo = (eng.geo if eng else planmod.new_engine().geo)
    point = check(plan.trajectory, plan.t0, plan.duration_s,
                  sc.cfg["maneuver"]["q0_body_from_inertial"], pointing, geo, step_s=2.0)
    point["missed"] = missed
    return meets and point["ok"], analysis.paper_sigma(sig), point


def optimize(targets, pointing, warm: bool = False, table=None, max_duration_s: float = 7200.0,
             log=print):
    """Grid + bisection (module docstring). Returns (best Candidate or None, its σ, rows)."""
    import copy

    base = None
    if warm:
        base, _ = planmod.warm_engine("2006216", table)
    factory = (lambda: copy.deepcopy(base)) if warm else None
    lock = 142.5 if warm else 392.5
    a_xz = min(10.0, pointing.sun_max_deg) if math.isfinite(pointing.sun_max_deg) else 10.0
    rows, best = [], None
    cands = sorted((Candidate(a, a_xz, h, r, lock + 30.0, w) for r in GRID_REPEATS
                    for a in GRID_AY for h in GRID_HOLD for w in GRID_DWELL),
                   key=lambda c: c.duration_s())
    for c in cands:  # shortest first: the first that meets the targets is the grid's best
        dur = c.duration_s()
        if dur > max_duration_s:
            break
        ok, sig, point = evaluate(c, targets, pointing, table, factory)
        rows.append((c, dur, ok, sig))
        log(f"  A_y {c.a_y:4.0f}° hold {c.hold_s:4.0f} s ×{c.repeats} dwell {c.dwell_s:5.0f} s: "
            f"{dur:6.0f} s {'meets the targets' if ok else 'misses ' + ', '.join(point['missed'])}"
            f"{'' if point['ok'] else ' (pointing violated)'}")
        if ok:
            best = (c, sig)
            break
    if best is None:
        return None, None, rows
    b0 = best[0]
    lo, hi = 0.0, b0.dwell_s
    for _ in range(4 if hi > 0 else 0):  # bisection on the final dwell of the best
        mid = 0.5 * (lo + hi)
        c = Candidate(b0.a_y, a_xz, b0.hold_s, b0.repeats, b0.start_s, round(mid, 1))
        ok, sig, _ = evaluate(c, targets, pointing, table, factory)
        log(f"  bisection: dwell {mid:6.1f} s → {c.duration_s():6.0f} s "
            f"{'meets' if ok else 'misses'}")
        if ok:
            hi, best = mid, (c, sig)
        else:
            lo = mid
    return best[0], best[1], rows


def default_targets(table=None) -> dict:
    """max(paper final σ, 1.1 × the as-flown 2006216 design at 2 h) per element, SI: the paper's
    accuracy where this noise model can reach it, else (nearly) what the as-flown maneuver gives."""
    paper = analysis.paper_targets(planmod.tables())
    hist, _ = planmod.design(planmod.load("2006216"), table, record_dt=60.0)
    flown = hist.sigma[-1]
    return {g: np.maximum(paper[g], 1.1 * flown[sl])
            for g, sl in analysis.group_slices().items()}


def run_cli(args, table, targets, pointing) -> int:
    """`radical design --optimize`: search cold and warm; write the best (cold) as TOML."""
    if args.target_scale == 1.0:
        targets = default_targets(table)
    if args.groups:
        keep = set(args.groups.split(","))
        targets = {g: (v if g in keep else np.full(v.shape, np.inf)) for g, v in targets.items()}
    out = {}
    for start in ("cold", "warm"):
        print(f"optimizing ({start} start)…", file=sys.stderr, flush=True)
        best, sig, _rows = optimize(targets, pointing, start == "warm", table,
                                    args.max_duration, log=lambda m: print(m, file=sys.stderr))
        out[start] = (best, sig)
        if best is None:
            print(f"{start}: no maneuver of the family meets the targets")
            continue
        print(f"{start}: shortest {best.duration_s():.0f} s ({best.duration_s() / 60:.1f} min): "
              f"±{best.a_xz:g}° x, ±{best.a_xz:g}° z, {best.repeats}× ±{best.a_y:g}° y, "
              f"holds {best.hold_s:g} s; final σ " + ", ".join(
                  f"{g} {max(v):.3g}" for g, v in sig.items()))
    best = out["cold"][0] or out["warm"][0]
    if args.out and best is not None:
        from pathlib import Path
        Path(args.out).write_text(planmod.load(best.scenario()).to_toml())
        print(f"wrote {args.out} (radical synth {args.out} -o sim.mcap)")
    return 0 if best is not None else 1
