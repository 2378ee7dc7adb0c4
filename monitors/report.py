"""Paper-style report from output archives: Tables 2–7 (Markdown + CSV) and Figures 4–8 (PNG).

    radical report OUT.mcap [OUT2.mcap ...] -o DIR [--labels warm,cold] [--max-points N]

Reads the telemetry of archives written by ``radical process`` or ``radical record``
(``/tlm/large``, else ``/tlm/medium``; ``/fault``; ``/diag`` temperatures; ``/truth/params`` when
present) and writes into DIR:

* ``tables.md`` (all six tables) and ``table<N>_<group>.md`` / ``.csv`` for N = 2..7 — the
  paper's layout: one row per archive, per gyro (or axis) the estimate and its 1σ, paper units;
  with truth (``/truth/params`` at the end time) also the truth and error/σ per element;
* ``fig4_<label>.png`` (attitude 1σ; parity residual ±1σ; ST1, ST2 residuals ±1σ; ST2 alignment
  estimates and σ), ``fig5_<label>.png`` (b, λ, μ estimates and σ), ``fig6_<label>.png`` (δu, δv
  estimates and σ) per archive; with two or more archives ``fig7.png`` (δu, δv side by side) and
  ``fig8.png`` (ST2 misalignment side by side, with the ST2 baseplate temperature when ``/diag``
  carries it);
* ``index.html`` showing all of it (relative links, no external resources);
* ``calibration_report.html``: one self-contained file (figures inline) with run metadata,
  Tables 2–7 with σ, convergence times, residual statistics and NIS, edits and faults
  (:mod:`monitors.calreport`).

The tables use the last telemetry packet of each archive; figures decimate to ``--max-points``
packets per archive (the last one is always kept). Exit status 0, or 2 with a one-line error
(missing file, not an MCAP archive, no telemetry channels, bad option).

This module is the driver (labels, the order of the outputs, the command line). The parts:
:mod:`monitors.report_data` (loading), :mod:`monitors.report_tables` (Tables 2–7),
:mod:`monitors.report_figs` (Figures 4–8), :mod:`monitors.report_html` (``index.html``),
:mod:`monitors.report_ops` and its figure and page (operations view), :mod:`monitors.calreport`.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from monitors.common import ORDER, safe_name
from monitors.report_data import ReportError, load_archive
from monitors.report_figs import figure4, figure_groups, figure_side_by_side
from monitors.report_html import md_table_to_html, write_index
from monitors.report_tables import table_csv, table_files, table_markdown
from radical_rt.io.outpaths import output_dir


def make_labels(paths: list[str], labels: str | None) -> list[str]:
    """One distinct label per archive: ``labels`` (comma-separated) or the file stems."""
    if labels is not None:
        out = [s.strip() for s in labels.split(",")]
        if len(out) != len(paths) or not all(out):
            raise ReportError(f"--labels: {len(out)} label(s) for {len(paths)} archive(s); give "
                              "one non-empty label per archive, comma-separated")
        if len(set(out)) != len(out):
            raise ReportError("--labels: labels must be distinct")
        return out
    out = [Path(p).stem for p in paths]
    if len(set(out)) != len(out):
        out = [f"{i + 1}-{s}" for i, s in enumerate(out)]
    return out


def make_report(paths: list[str], out_dir: str | Path, labels: str | None = None,
                max_points: int = 1500, figures: bool = True) -> dict[str, Any]:
    """Write the report; returns {"tables": [...], "figures": [...], "index": path}."""
    labs = make_labels(paths, labels)
    data = [load_archive(p, lab, max_points) for p, lab in zip(paths, labs, strict=True)]
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ReportError(f"{out}: cannot create output directory: {e.strerror or e}") from None
    groups = [g for g in ORDER if any(g in d.final_est for d in data)]
    tables_md = {g: table_markdown(data, g) for g in groups}
    written = []
    for g in groups:
        md, cs = table_files(g)
        (out / md).write_text(tables_md[g], encoding="utf-8")
        (out / cs).write_text(table_csv(data, g), encoding="utf-8")
        written += [md, cs]
    (out / "tables.md").write_text("# RADICAL-RT calibration tables\n\n" + "\n".join(
        tables_md[g] for g in groups), encoding="utf-8")
    written.append("tables.md")
    figs: list[tuple[str, str]] = []
    if figures:
        import matplotlib

        matplotlib.use("Agg", force=True)
        for d in data:
            s = safe_name(d.label)
            figure4(d, out / f"fig4_{s}.png")
            figs.append((f"fig4_{s}.png", f"Figure 4 ({d.label}): attitude 1σ; parity, ST1, ST2 "
                         "residuals ±1σ; ST2 alignment estimates and σ"))
            figure_groups(d, ["b", "lam", "mu"], out / f"fig5_{s}.png",
                          "Figure 5 analog: gyro bias b, symmetric scale factor λ, asymmetric μ")
            figs.append((f"fig5_{s}.png", f"Figure 5 ({d.label}): b, λ, μ estimates and σ"))
            figure_groups(d, ["du", "dv"], out / f"fig6_{s}.png",
                          "Figure 6 analog: gyro axis misalignments δu, δv")
            figs.append((f"fig6_{s}.png", f"Figure 6 ({d.label}): δu, δv estimates and σ"))
        if len(data) >= 2:
            figure_side_by_side(data, ["du", "dv"], out / "fig7.png",
                                "Figure 7 analog: gyro axis misalignments δu, δv side by side")
            figs.append(("fig7.png", "Figure 7: δu, δv estimates and σ, archives side by side"))
            figure_side_by_side(data, ["phi2"], out / "fig8.png",
                                "Figure 8 analog: ST2 misalignment side by side", temps=True)
            figs.append(("fig8.png", "Figure 8: ST2 misalignment estimates and σ (with ST2 "
                         "baseplate temperature), archives side by side"))
        from monitors.report_ops import load_ops
        from monitors.report_ops_fig import figure_ops
        from monitors.report_ops_html import write_html

        ops = [load_ops(d.path, d.label, max_points) for d in data]
        for o in ops:
            figure_ops(o, out / f"ops_{safe_name(o.label)}.png")
            figs.append((f"ops_{safe_name(o.label)}.png", f"Operations ({o.label}): attitude, "
                         "rates, attitude error, latency, clock, NIS, flags; streams apart"))
        write_html(out, ops, "".join(md_table_to_html(tables_md[g]) for g in groups))
    write_index(out, data, tables_md, figs)
    from monitors.calreport import write_calibration_report

    cal = write_calibration_report(out, data, tables_md, figs)
    return {"tables": written, "figures": [f for f, _ in figs], "index": str(out / "index.html"),
            "calibration_report": str(cal),
            "archives": [{"label": d.label, "path": d.path, "packets": d.n_packets,
                          "decimated": len(d.t)} for d in data]}


#: the subcommand's line in `radical --help`
HELP = "paper-style tables and figures from an output archive"


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The options of ``radical report``."""
    p.add_argument("inputs", nargs="+", metavar="OUT.mcap",
                   help="output archives (radical process / radical record)")
    p.add_argument("-o", "--out", "--output", dest="out", required=True, metavar="DIR",
                   type=output_dir,
                   help="output directory (created)")
    p.add_argument("--labels", metavar="L1,L2", help="one label per archive (default: file stems)")
    p.add_argument("--max-points", type=int, default=1500, metavar="N",
                   help="telemetry packets per archive kept for the figures (default 1500)")
    p.add_argument("--no-figures", action="store_true", help="tables and index only")
    p.add_argument("--pdf", action="store_true", help="also calibration_report.pdf (headless "
                   "Chromium through Playwright; both optional)")


def run(args: argparse.Namespace) -> int:
    """``radical report``: exit status 0, or 2 with a one-line error."""
    t0 = time.perf_counter()
    if args.max_points < 2:
        print("radical report: --max-points must be ≥ 2", file=sys.stderr)
        return 2
    try:
        res = make_report(args.inputs, args.out, args.labels, args.max_points,
                          figures=not args.no_figures)
    except ReportError as e:
        print(f"radical report: {e}", file=sys.stderr)
        return 2
    print(f"radical report: {len(res['tables'])} table files, {len(res['figures'])} figures, "
          f"{res['index']}, {res['calibration_report']} ({time.perf_counter() - t0:.1f} s)")
    if args.pdf:
        from monitors.calreport import write_pdf

        try:
            print(f"radical report: {write_pdf(Path(res['calibration_report']))}")
        except RuntimeError as e:
            print(f"radical report: {e}", file=sys.stderr)
            return 2
    return 0
