"""Reading a covariance history: targets, time to target, poorly determined directions, summary.

All inputs SI (σ of the CONTRACT parameters in state order b, λ, μ, du, dv (n each), φ2 (3), τ);
paper units (deg/hr, ppm, arcsec) only in what this module returns for printing and JSON.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from radical_rt.contract.conventions import PAPER_UNITS, SI_PER_PAPER_UNIT
from radical_rt.contract.state import PARAM_GROUPS

TABLE_KEYS = {"b": "b_sigma", "lam": "lam_sigma", "mu": "mu_sigma", "du": "du_sigma",
              "dv": "dv_sigma", "phi2": "phi2_sigma"}


def group_slices(n_gyro: int = 4) -> dict[str, slice]:
    """Slices of each parameter group in the contract parameter vector (npar,)."""
    out, k = {}, 0
    for g in PARAM_GROUPS:
        size = 3 if g == "phi2" else n_gyro
        out[g] = slice(k, k + size)
        k += size
    return out


def paper_targets(tables: dict, row: str = "2006216") -> dict[str, np.ndarray]:
    """The paper's final 1σ of a table row (messenger_tables.json), SI per group."""
    est = tables["estimates"][row]
    return {g: np.asarray(est[key], float) * SI_PER_PAPER_UNIT[g] for g, key in TABLE_KEYS.items()}


def scale_targets(targets: dict[str, np.ndarray], factor: float) -> dict[str, np.ndarray]:
    return {g: v * factor for g, v in targets.items()}


def time_to_target(t: np.ndarray, sigma: np.ndarray, targets: dict[str, np.ndarray],
                   n_gyro: int = 4) -> dict[str, float]:
    """Per group, the first time [s] after which every element stays at or below its target
    until the end of the history; inf if it is not met at the end."""
    out = {}
    for g, sl in group_slices(n_gyro).items():
        ok = np.all(sigma[:, sl] <= targets[g][None, :] * (1 + 1e-12), axis=1)
        if not ok[-1]:
            out[g] = math.inf
            continue
        bad = np.nonzero(~ok)[0]
        out[g] = float(t[bad[-1] + 1]) if bad.size else float(t[0])
    return out


def element_labels(n_gyro: int = 4) -> list[str]:
    """'lam_C', 'phi2_z', … in contract parameter order (without τ)."""
    out = []
    for g in PARAM_GROUPS:
        names = "xyz" if g == "phi2" else [chr(ord("A") + i) for i in range(n_gyro)]
        out += [f"{g}_{c}" for c in names]
    return out


def poor_directions(cov: np.ndarray, targets: dict[str, np.ndarray], n_gyro: int = 4,
                    k: int = 3, n_terms: int = 4) -> list[dict[str, Any]]:
    """The k most poorly determined directions of the parameter space: eigenvectors of the
    parameter covariance normalized by the targets, C = D⁻¹PD⁻¹ (D = diag(target σ), τ left
    out), largest eigenvalue first. Each: ``sigma_over_target`` = √λ (1 = exactly at target
    along that direction) and its largest ``n_terms`` components (label, weight)."""
    npar = 5 * n_gyro + 3
    d = np.concatenate([targets[g] for g in PARAM_GROUPS])
    C = cov[:npar, :npar] / np.outer(d, d)
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    labels = element_labels(n_gyro)
    out = []
    for idx in np.argsort(w)[::-1][:k]:
        v = V[:, idx]
        v = v * (1.0 if v[np.argmax(np.abs(v))] > 0 else -1.0)
        top = np.argsort(np.abs(v))[::-1][:n_terms]
        out.append({"sigma_over_target": float(math.sqrt(max(w[idx], 0.0))),
                    "components": [[labels[i], round(float(v[i]), 3)] for i in top]})
    return out


def paper_sigma(sigma_row: np.ndarray, n_gyro: int = 4) -> dict[str, list[float]]:
    """A σ row (npar,) SI → {group: [paper units]} (CONTRACT §5 layout)."""
    return {g: [float(x) for x in sigma_row[sl] / SI_PER_PAPER_UNIT[g]]
            for g, sl in group_slices(n_gyro).items()}


def design_summary(name: str, hist, targets: dict[str, np.ndarray], n_gyro: int = 4,
                   extra: dict | None = None) -> dict[str, Any]:
    """The JSON of ``radical design --json``: the summary file's ``sigma`` map (CONTRACT §5,
    paper units) of the predicted final σ, the targets and times to target, the poorly determined
    directions, and the time histories (σ per element, paper units, at ``t_s``)."""
    ttt = time_to_target(hist.t, hist.sigma, targets, n_gyro)
    hist_map = {g: (hist.sigma[:, sl] / SI_PER_PAPER_UNIT[g]).T.round(7).tolist()
                for g, sl in group_slices(n_gyro).items()}
    out = {"schema": "radical.design/1", "scenario": name, "t_end": float(hist.t[-1]),
           "units": dict(PAPER_UNITS),
           "sigma": paper_sigma(hist.sigma[-1], n_gyro),
           "latency_sigma_s": float(hist.sigma[-1][-1]),
           "targets": {g: [float(x) for x in v / SI_PER_PAPER_UNIT[g]] for g, v in targets.items()},
           "time_to_target_s": {g: (None if math.isinf(v) else v) for g, v in ttt.items()},
           "meets_targets": all(not math.isinf(v) for v in ttt.values()),
           "poor_directions": poor_directions(hist.cov, targets, n_gyro),
           "history": {"t_s": hist.t.round(3).tolist(), "sigma": hist_map},
           "elapsed_s": hist.elapsed_s}
    if extra:
        out.update(extra)
    return out


def format_report(s: dict[str, Any], every_s: float = 600.0) -> str:
    """Plain-text report of a design summary: final σ vs target per group, time to target, σ
    history (largest element of each group) every ``every_s``, poorly determined directions."""
    lines = [f"design: {s['scenario']}  ({s['t_end']:.0f} s, analysed in {s['elapsed_s']:.1f} s)"]
    lines.append(f"  {'group':6s} {'unit':7s} {'predicted final 1σ':>36s} {'target (max)':>13s} "
                 f"{'time to target':>15s}")
    for g in PARAM_GROUPS:
        sig = " ".join(f"{x:8.4g}" for x in s["sigma"][g])
        ttt = s["time_to_target_s"][g]
        when = "not met" if ttt is None else f"{ttt / 60:8.1f} min"
        lines.append(f"  {g:6s} {PAPER_UNITS[g]:7s} {sig:>36s} {max(s['targets'][g]):13.4g} "
                     f"{when:>15s}")
    t = np.asarray(s["history"]["t_s"])
    lines.append("  σ history (largest element of the group, paper units):")
    lines.append("    " + f"{'t (min)':>8s}" + "".join(f"{g:>10s}" for g in PARAM_GROUPS))
    marks = np.arange(0.0, t[-1] + 1e-9, every_s)
    for m in list(marks) + ([t[-1]] if t[-1] - marks[-1] > 1 else []):
        i = int(np.searchsorted(t, m - 1e-9))
        i = min(i, len(t) - 1)
        vals = "".join(f"{max(col[i] for col in s['history']['sigma'][g]):10.4g}"
                       for g in PARAM_GROUPS)
        lines.append(f"    {t[i] / 60:8.1f}{vals}")
    lines.append("  most poorly determined directions (σ / target along the eigenvector):")
    for d in s["poor_directions"]:
        comp = " ".join(f"{w:+.2f}·{lab}" for lab, w in d["components"])
        lines.append(f"    {d['sigma_over_target']:9.3g}  {comp}")
    return "\n".join(lines)
