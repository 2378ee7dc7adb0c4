"""Tables 2–7 of ``radical report``: per group, one row per archive with each element's estimate
and 1σ (paper units) from the last telemetry packet, and the truth and error/σ when the archive
has ``/truth/params`` (:func:`table_rows`); written as Markdown (:func:`table_markdown`) and CSV
at full precision (:func:`table_csv`), in the files named by :func:`table_files`.
"""

from __future__ import annotations

import csv
import io
import math
from typing import Any

from monitors.common import (
    DIGITS,
    GROUP_LABELS,
    ORDER,
    PAPER_UNITS,
    TABLE_NUMBER,
    TITLES,
    element_names,
)
from monitors.report_data import ArchiveData
from radical_rt.contract.conventions import SI_PER_PAPER_UNIT
from radical_rt.contract.flags import GYRO_FAILED
from radical_rt.contract.paper_table import rows as paper_rows


def _fmt(v: float | None, digits: int) -> str:
    if v is None or not math.isfinite(v):
        return "—"
    return f"{v:.{digits}f}".replace("-", "−")


def _si(group: str, vals: list[float]) -> list[float]:
    return [v * SI_PER_PAPER_UNIT[group] for v in vals]


def table_rows(data: list[ArchiveData], group: str) -> tuple[list[str], list[dict[str, Any]]]:
    """Element names and per-archive rows for one group (paper units), with err/σ from
    :func:`radical_rt.contract.paper_table.rows` when truth is known."""
    out = []
    names: list[str] = []
    for d in data:
        if group not in d.final_est:
            out.append({"label": d.label, "path": d.path, "t_end": d.t_end, "elements": []})
            continue
        n = len(d.final_est[group])
        names = names if len(names) >= n else element_names(group, n)
        truth = d.truth_final if d.truth_final and group in d.truth_final else None
        # paper_table.rows wants every group; give it this one and placeholders for the rest
        est = {g: [0.0] * (3 if g == "phi2" else n) for g in ORDER}
        sig = {g: [1.0] * (3 if g == "phi2" else n) for g in ORDER}
        est[group], sig[group] = _si(group, d.final_est[group]), _si(group, d.final_sig[group])
        tr = {group: _si(group, truth[group])} if truth else None
        if tr and len(tr[group]) != n:
            tr = None
        elements = [r for r in paper_rows(est, sig, tr) if r["group"] == group]
        for r, e, s in zip(elements, d.final_est[group], d.final_sig[group], strict=True):
            r["estimate"], r["sigma"] = e, s  # exactly the packet's values (no round trip)
        out.append({"label": d.label, "path": d.path, "t_end": d.t_end, "elements": elements,
                    "flags": d.last.get("flags")})
    return names, out


def _gyro_failed(flags: Any, i: int) -> bool:
    """True when gyro i's GYRO_<A+i>_FAILED bit (radical_rt.contract.flags.GYRO_FAILED) is set."""
    return isinstance(flags, int) and i < len(GYRO_FAILED) and bool(flags & int(GYRO_FAILED[i]))


def table_markdown(data: list[ArchiveData], group: str) -> str:
    names, trows = table_rows(data, group)
    dg, unit = DIGITS[group], PAPER_UNITS[group]
    sym = GROUP_LABELS[group].split()[0]
    lines = [f"### {TITLES[group]}, {unit}", ""]
    head = ["Archive", "t_end [s]"]
    for nm in names:
        head += [f"{nm} {sym}", "σ"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in trows:
        cells = [r["label"], _fmt(r["t_end"], 2)]
        for i in range(len(names)):
            e = r["elements"][i] if i < len(r["elements"]) else None
            cells += [_fmt(e["estimate"], dg), _fmt(e["sigma"], dg + 1)] if e else ["—", "—"]
            if e and group != "phi2" and _gyro_failed(r.get("flags"), i):
                cells[-2] = f"FAILED {cells[-2]}"
        lines.append("| " + " | ".join(cells) + " |")
    if any(r["elements"] and "truth" in r["elements"][0] for r in trows):
        lines += ["", f"Truth (/truth/params at t_end) and error/σ, {unit}:", ""]
        head = ["Archive"]
        for nm in names:
            head += [f"{nm} truth", "err/σ"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in trows:
            if not (r["elements"] and "truth" in r["elements"][0]):
                continue
            cells = [r["label"]]
            for e in r["elements"]:
                cells += [_fmt(e["truth"], dg), _fmt(e["err_sigma"], 2)]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def table_csv(data: list[ArchiveData], group: str) -> str:
    """CSV, one row per archive: label, archive, t_end_s, then per element estimate and sigma
    (and truth, err_sigma when any archive has truth); full precision, paper units in headers."""
    names, trows = table_rows(data, group)
    unit = PAPER_UNITS[group]
    has_truth = any(r["elements"] and "truth" in r["elements"][0] for r in trows)
    head = ["label", "archive", "t_end_s"]
    for nm in names:
        head += [f"{nm} estimate [{unit}]", f"{nm} sigma [{unit}]"]
    if has_truth:
        for nm in names:
            head += [f"{nm} truth [{unit}]", f"{nm} err/sigma"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(head)
    for r in trows:
        el = r["elements"]
        row: list[Any] = [r["label"], r["path"], repr(float(r["t_end"]))]
        for i in range(len(names)):
            row += [repr(el[i]["estimate"]), repr(el[i]["sigma"])] if i < len(el) else ["", ""]
        if has_truth:
            for i in range(len(names)):
                ok = i < len(el) and "truth" in el[i]
                row += [repr(el[i]["truth"]), repr(el[i]["err_sigma"])] if ok else ["", ""]
        w.writerow(row)
    return buf.getvalue()


def table_files(group: str) -> tuple[str, str]:
    stem = f"table{TABLE_NUMBER[group]}_{group}"
    return stem + ".md", stem + ".csv"
