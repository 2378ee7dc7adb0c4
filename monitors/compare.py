"""Side-by-side comparison of summary files (CONTRACT §5) against the truth of a simulated archive.

    python -m monitors.compare SIM.mcap A.json B.json [...] [--labels A,B] [--out TABLE.md]

Each summary's estimates are compared with the last ``/truth/params`` message of the archive (SI,
converted to the paper's units): the table gives error/σ per parameter and each run's σ, then
max |error/σ|, RMS error/σ, tracker edits, mode and convergence, and the latency estimate when
the summary has one. Only contract-level data are used (summary JSON, the archive's truth
channel), plus two optional summary extensions for provenance: a summary whose ``truth`` differs
from the archive's, or whose ``streams`` name no input with the archive's file name, belongs to
another archive and is refused (exit 2) unless ``--force`` (then a loud warning). Exit status 2
on a missing file, an archive without truth or a foreign summary.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

import msgpack

from monitors.common import GROUP_LABELS, ORDER, PAPER_UNITS, element_names, group_paper
from radical_rt.io.archive import ArchiveError, ArchiveReader
from radical_rt.io.outpaths import output_file


def load_truth(path: str | Path) -> dict[str, list[float]]:
    """Last /truth/params of an archive, in the paper's units, per group."""
    last = None
    with ArchiveReader(path) as reader:
        for _topic, _t, data in reader.iter_raw(topics=["/truth/params"]):
            last = data
    if last is None:
        raise ArchiveError(f"{path}: no /truth/params channel (not a simulated archive?)")
    msg = msgpack.unpackb(last, raw=False)
    return {g: group_paper(g, msg[g]) for g in ORDER}


def z_scores(summary: dict[str, Any], truth: dict[str, list[float]]) -> dict[str, list[float]]:
    """(estimate − truth)/σ per group and element (paper units on both sides)."""
    return {g: [(e - t) / s if s > 0 else math.nan
                for e, t, s in zip(summary["estimate"][g], truth[g], summary["sigma"][g], strict=True)]
            for g in ORDER}


def table(truth: dict[str, list[float]], runs: list[tuple[str, dict[str, Any]]]) -> str:
    """Markdown table: one row per parameter, error/σ and σ for each run, then totals."""
    head = "| parameter | unit | " + " | ".join(f"{lab} error/σ | {lab} σ" for lab, _ in runs) + " |"
    lines = [head, "|" + "---|" * (2 + 2 * len(runs))]
    zs = [z_scores(s, truth) for _, s in runs]
    for g in ORDER:
        for i, name in enumerate(element_names(g, len(truth[g]))):
            cells = [f"{z[g][i]:+.2f} | {s['sigma'][g][i]:.3g}" for z, (_, s) in zip(zs, runs, strict=True)]
            lines.append(f"| {GROUP_LABELS[g]} {name} | {PAPER_UNITS[g]} | " + " | ".join(cells) + " |")
    flat = [[v for g in ORDER for v in z[g]] for z in zs]
    lines.append("| max \\|error/σ\\| | | " + " | ".join(
        f"{max(abs(v) for v in f):.2f} | " for f in flat) + " |")
    lines.append("| RMS error/σ | | " + " | ".join(
        f"{math.sqrt(sum(v * v for v in f) / len(f)):.2f} | " for f in flat) + " |")
    lines.append("| tracker edits (ST1 + ST2) | | " + " | ".join(
        f"{s['counters']['st1_edited'] + s['counters']['st2_edited']} | " for _, s in runs) + " |")
    lines.append("| mode | | " + " | ".join(f"{s.get('mode', '?')} | " for _, s in runs) + " |")
    lines.append("| converged | | " + " | ".join(
        f"{'yes' if s.get('converged') else 'NO'} | " for _, s in runs) + " |")
    if all("latency_st" in s for _, s in runs):
        lines.append("| tracker latency estimate | ms | " + " | ".join(
            f"{1e3 * s['latency_st']['estimate_s']:.2f} | {1e3 * s['latency_st']['sigma_s']:.2f}"
            for _, s in runs) + " |")
    return "\n".join(lines)


def provenance_problem(archive: str | Path, truth: dict[str, list[float]],
                       summary: dict[str, Any]) -> str:
    """Why ``summary`` does not come from ``archive`` ("" if nothing says so): its ``truth``
    (paper units) differs from the archive's, or its ``streams`` sources name other files."""
    st = summary.get("truth")
    if isinstance(st, dict):
        for g in ORDER:
            if g in st and not all(math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)
                                   for a, b in zip(st[g], truth[g], strict=False)):
                return f"its truth ({GROUP_LABELS[g]}) differs from {Path(archive).name}'s"
    sources = [x.get("source") for x in summary.get("streams") or [] if isinstance(x, dict)]
    sources = [str(x) for x in sources if x]
    if sources and Path(archive).name not in {Path(x).name for x in sources}:
        return f"it was made from {', '.join(Path(x).name for x in sources)}"
    return ""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("archive", help="simulated input archive (has /truth/params)")
    ap.add_argument("summaries", nargs="+", help="summary JSON files of `radical process`")
    ap.add_argument("--labels", help="comma-separated column labels (default: file stems)")
    ap.add_argument("--out", type=output_file, help="also write the table to this file")
    ap.add_argument("--force", action="store_true",
                    help="compare summaries that belong to another archive (warned)")
    a = ap.parse_args(argv)
    labels = a.labels.split(",") if a.labels else [Path(p).stem for p in a.summaries]
    if len(labels) != len(a.summaries):
        print("compare: --labels needs one label per summary", file=sys.stderr)
        return 2
    try:
        truth = load_truth(a.archive)
        runs = [(lab, json.loads(Path(p).read_text())) for lab, p in zip(labels, a.summaries, strict=True)]
    except (OSError, ArchiveError, json.JSONDecodeError) as exc:
        print(f"compare: {exc}", file=sys.stderr)
        return 2
    for (lab, s), p in zip(runs, a.summaries, strict=True):
        why = provenance_problem(a.archive, truth, s)
        if why and not a.force:
            print(f"compare: {p} does not belong to {a.archive}: {why} (--force compares "
                  f"anyway)", file=sys.stderr)
            return 2
        if why:
            print(f"compare: WARNING: {p} ({lab}) does not belong to {a.archive}: {why}; "
                  f"its error/σ are meaningless", file=sys.stderr)
    text = table(truth, runs)
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
