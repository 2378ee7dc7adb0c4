"""Paper-style calibration tables (the paper's Tables 2–7) from SI estimates, σ and truth."""

from __future__ import annotations

from typing import Any

import numpy as np

from radical_rt.contract.conventions import PAPER_UNITS, SI_PER_PAPER_UNIT

TITLES = {"phi2": "Table 2. ST2 misalignment δa2", "b": "Table 3. Bias b",
          "lam": "Table 4. Symmetric scale factor λ", "mu": "Table 5. Asymmetric scale factor μ",
          "du": "Table 6. Gyro misalignment δu", "dv": "Table 7. Gyro misalignment δv"}
ORDER = ("phi2", "b", "lam", "mu", "du", "dv")
DIGITS = {"b": 4, "lam": 1, "mu": 1, "du": 1, "dv": 1, "phi2": 2}


def element_names(group: str, n: int) -> list[str]:
    if group == "phi2":
        return ["x-axis", "y-axis", "z-axis"]
    return [f"Gyro {chr(ord('A') + i)}" for i in range(n)]


def rows(est: dict[str, list[float]], sigma: dict[str, list[float]],
         truth: dict[str, list[float]] | None = None) -> list[dict[str, Any]]:
    """One row per parameter element in paper units: group, name, estimate, sigma, truth, err/σ."""
    out = []
    for g in ORDER:
        k = SI_PER_PAPER_UNIT[g]
        e, s = np.asarray(est[g]) / k, np.asarray(sigma[g]) / k
        tr = np.asarray(truth[g]) / k if truth and g in truth else None
        for i, name in enumerate(element_names(g, len(e))):
            row = {"group": g, "unit": PAPER_UNITS[g], "name": name, "estimate": float(e[i]),
                   "sigma": float(s[i])}
            if tr is not None:
                row["truth"] = float(tr[i])
                row["err_sigma"] = float((e[i] - tr[i]) / s[i]) if s[i] > 0 else float("nan")
            out.append(row)
    return out


def format_table(table_rows: list[dict[str, Any]]) -> str:
    """Plain-text rendering grouped like the paper's tables, with truth and error/σ if present."""
    lines = []
    for g in ORDER:
        grp = [r for r in table_rows if r["group"] == g]
        if not grp:
            continue
        dg = DIGITS[g]
        lines.append(f"{TITLES[g]}, {grp[0]['unit']}")
        has_truth = "truth" in grp[0]
        head = f"  {'':8s} {'estimate':>12s} {'± 1σ':>10s}"
        if has_truth:
            head += f" {'truth':>12s} {'error/σ':>8s}"
        lines.append(head)
        for r in grp:
            line = f"  {r['name']:8s} {r['estimate']:12.{dg}f} {r['sigma']:10.{dg + 1}f}"
            if has_truth:
                line += f" {r['truth']:12.{dg}f} {r['err_sigma']:8.2f}"
            lines.append(line)
        lines.append("")
    return "\n".join(lines)
