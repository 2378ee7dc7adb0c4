"""One self-contained calibration report: ``calibration_report.html`` (written by ``radical report``).

A single HTML file with everything inline (CSS, the figures as base64 PNG, no scripts, no external
resources), so it can be mailed or archived alone:

1. run metadata: archive(s), ``radical.scenario`` metadata, packets, time span, final mode and
   flags, the generator;
2. the paper's Tables 2–7 (estimate ± 1σ per element, paper units; truth and error/σ when the
   archive has ``/truth/params``);
3. convergence times per group: the first bus time (s since the first packet) from which the
   group's largest σ stays below 10× and 2× its final value, and, with truth, from which every
   element of the group stays within 3σ of it; plus the first time the mode reads ``converged``;
4. residual statistics and NIS per measurement kind (st1, st2, parity) over every ``/tlm/large``
   packet: count, mean and RMS of the innovation and of innovation/σ per axis (arcsec), the mean
   NIS against its degrees of freedom with the chi-square 95 % band of the mean;
5. edits and faults: the counters of the last packet (used/edited per tracker and parity, SIRU
   repeated/missing, rejected inputs), the number of times each flag was set, the first fault
   messages;
6. the figures of ``radical report`` (Figures 4–8).

Values are read from the contract's messages only (CONTRACT §3) and shown in paper units.
"""

from __future__ import annotations

import base64
import html
import math
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

import radical_rt
from monitors.common import ARCSEC, GROUP_LABELS, ORDER, PAPER_UNITS, flag_label

_CSS = """body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em;
color:#222;max-width:1300px}table{border-collapse:collapse;margin:.4em 0 1.2em;font-size:13px}
th,td{border:1px solid #bbb;padding:3px 7px;text-align:right}th{background:#eef}
td:first-child,th:first-child{text-align:left}img{max-width:100%;border:1px solid #ccc;
margin:.3em 0 1.2em}h2{border-bottom:2px solid #99c;margin-top:1.6em}.note{color:#555}
.bad{color:#b00;font-weight:600}.ok{color:#070}code{background:#f4f4f4;padding:0 3px}"""


def _t(headers: list[str], rows: list[list[Any]]) -> str:
    h = ["<table><tr>" + "".join(f"<th>{html.escape(str(c))}</th>" for c in headers) + "</tr>"]
    for r in rows:
        h.append("<tr>" + "".join(c if isinstance(c, _Raw) else f"<td>{html.escape(str(c))}</td>"
                                  for c in r) + "</tr>")
    return "\n".join(h) + "</table>"


class _Raw(str):
    """A cell that is already HTML."""


def _f(v: float | None, digits: int = 2) -> str:
    return "—" if v is None or not math.isfinite(v) else f"{v:.{digits}f}"


def stays_below(t: np.ndarray, ok: np.ndarray) -> float | None:
    """The first time from which ``ok`` holds to the end (None if it does not hold at the end)."""
    if ok.size == 0 or not ok[-1]:
        return None
    bad = np.flatnonzero(~ok)
    return float(t[0] if bad.size == 0 else t[bad[-1] + 1])


def convergence(d: Any) -> list[list[Any]]:
    """Rows: group, unit, final max σ, σ_end/σ_0, t(σ ≤ 10σ_end), t(σ ≤ 2σ_end), t(|err| ≤ 3σ)
    (s since the first packet); a group whose σ did not halve is "not converging"."""
    rows = []
    t = d.t - d.t[0]
    for g in d.groups:
        sig = np.nanmax(np.abs(d.sig[g]), axis=1) if d.sig[g].size else np.zeros(0)
        if sig.size == 0 or not np.isfinite(sig[-1]):
            continue
        final, ratio = sig[-1], sig[-1] / sig[0] if sig[0] > 0 else math.nan
        if not ratio < 0.5:  # σ hardly reduced: the group is not (yet) observed
            rows.append([GROUP_LABELS[g], PAPER_UNITS[g], f"{final:.4g}", f"{ratio:.3g}",
                         "not converging", "not converging", "—"])
            continue
        t10 = stays_below(t, sig <= 10 * final)
        t2 = stays_below(t, sig <= 2 * final)
        t3 = None
        if g in d.truth and d.truth_t.size:
            tr = np.array([np.interp(d.t, d.truth_t, d.truth[g][:, i])
                           for i in range(d.truth[g].shape[1])]).T
            z = np.abs(d.est[g] - tr) / np.where(d.sig[g] > 0, d.sig[g], np.nan)
            t3 = stays_below(t, np.all(z <= 3.0, axis=1))
        rows.append([GROUP_LABELS[g], PAPER_UNITS[g], f"{final:.4g}", f"{ratio:.3g}",
                     _f(t10, 1), _f(t2, 1),
                     _f(t3, 1) if g in d.truth else "no truth"])
    return rows


def residual_stats(path: str, topic: str) -> dict[str, dict[str, Any]]:
    """Per kind: n, innovation and innovation/σ mean and RMS per axis (arcsec), NIS values."""
    from radical_rt.io.archive import ArchiveReader

    acc: dict[str, dict[str, list[Any]]] = {}
    with ArchiveReader(path) as r:
        for _t, _ns, data in r.iter_raw(topic):
            try:
                m = msgpack.unpackb(data, raw=False, strict_map_key=False)
            except Exception:
                continue
            res = m.get("residuals") if isinstance(m, dict) else None
            for kind, v in (res or {}).items():
                if not isinstance(v, dict):
                    continue
                a = acc.setdefault(kind, {"innov": [], "sigma": [], "nis": []})
                inn, sg = v.get("innov"), v.get("sigma")
                if isinstance(inn, list) and isinstance(sg, list) and len(inn) == len(sg):
                    a["innov"].append(inn)
                    a["sigma"].append(sg)
                if isinstance(v.get("nis"), int | float):
                    a["nis"].append(float(v["nis"]))
    out = {}
    for kind, a in acc.items():
        try:
            inn = np.array(a["innov"], dtype=float) / ARCSEC
            sg = np.array(a["sigma"], dtype=float) / ARCSEC
        except ValueError:  # ragged (a kind whose dimension changed): skip its axes
            inn = sg = np.zeros((0, 0))
        out[kind] = {"n": len(a["nis"]) or len(inn), "innov": inn, "sigma": sg,
                     "nis": np.array(a["nis"]), "dof": inn.shape[1] if inn.ndim == 2 else 0}
    return out


def residual_rows(stats: dict[str, dict[str, Any]]) -> list[list[Any]]:
    from scipy.stats import chi2

    rows = []
    for kind in sorted(stats, key=lambda k: ("st1", "st2", "parity").index(k)
                       if k in ("st1", "st2", "parity") else 9):
        s = stats[kind]
        inn, sg, nis, m = s["innov"], s["sigma"], s["nis"], s["dof"]
        if inn.size == 0:
            continue
        z = inn / np.where(sg > 0, sg, np.nan)
        mean_nis = float(np.mean(nis)) if nis.size else math.nan
        band = "—"
        ok = None
        if nis.size and m:
            lo, hi = chi2.ppf([0.025, 0.975], m * nis.size) / nis.size
            band = f"[{lo:.2f}, {hi:.2f}]"
            ok = lo <= mean_nis <= hi
        cls = "" if ok is None else ("ok" if ok else "bad")
        axes = [f"{_f(float(np.mean(inn[:, i])), 3)} / {_f(float(np.sqrt(np.mean(inn[:, i]**2))), 3)}"
                for i in range(inn.shape[1])]
        zs = [f"{_f(float(np.nanmean(z[:, i])), 2)} / {_f(float(np.sqrt(np.nanmean(z[:, i]**2))), 2)}"
              for i in range(z.shape[1])]
        rows.append([kind, s["n"], "; ".join(axes), "; ".join(zs), m,
                     _Raw(f"<td class='{cls}'>{_f(mean_nis, 3)}</td>"), band])
    return rows


def _img(path: Path, caption: str) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return (f"<h3>{html.escape(caption)}</h3><img alt='{html.escape(caption)}' "
            f"src='data:image/png;base64,{data}'>")


def _counters(d: Any) -> list[list[Any]]:
    c = d.last.get("counters") if isinstance(d.last.get("counters"), dict) else {}
    keys = ["siru_samples", "siru_repeated", "siru_missing", "st1_used", "st1_edited",
            "st2_used", "st2_edited", "parity_used", "parity_edited", "input_rejected"]
    return [[k, c[k]] for k in keys if k in c] + [[k, v] for k, v in sorted(c.items())
                                                   if k not in keys and isinstance(v, int)]


def _flag_sets(d: Any) -> list[list[Any]]:
    n: dict[str, int] = {}
    for f in d.faults:
        for name in f.get("set") or []:
            n[str(name)] = n.get(str(name), 0) + 1
    return [[k, v] for k, v in sorted(n.items(), key=lambda kv: -kv[1])]


def write_calibration_report(out: Path, data: list[Any], tables_md: dict[str, str],
                             figures: list[tuple[str, str]]) -> Path:
    """Write ``out/calibration_report.html`` from loaded archives, the table Markdown and the
    figure files already written in ``out``; returns its path."""
    from monitors.report_html import md_table_to_html

    h = ["<!DOCTYPE html><html><head><meta charset='utf-8'>",
         "<title>RADICAL-RT calibration report</title>", f"<style>{_CSS}</style></head><body>",
         "<h1>RADICAL-RT calibration report</h1>",
         f"<p class='note'>radical-rt {html.escape(radical_rt.__version__)}, generated "
         f"{time.strftime('%Y-%m-%d %H:%M:%S')}. Paper units: "
         + ", ".join(f"{GROUP_LABELS[g]} [{u}]" for g, u in PAPER_UNITS.items())
         + "; residuals in arcsec.</p>", "<h2>1. Run</h2>"]
    rows = []
    for d in data:
        sc = d.scenario
        rows.append([d.label, d.path, sc.get("name", "—"), sc.get("vehicle", "—"),
                     sc.get("seed", "—"), sc.get("generator", "—"), d.topic, d.n_packets,
                     f"{d.t[0]:.2f}", f"{d.t_end:.2f}", f"{(d.t_end - d.t[0]) / 60:.1f}",
                     d.last.get("mode", "?"), flag_label(d.last.get("flags")),
                     "yes" if d.truth_final else "no"])
    h.append(_t(["label", "archive", "scenario", "vehicle", "seed", "generator", "telemetry",
                 "packets", "t start [s]", "t end [s]", "span [min]", "final mode",
                 "final flags", "truth"], rows))
    for d in data:
        inputs = d.scenario.get("inputs")
        if inputs:
            h.append(f"<p class='note'>{html.escape(d.label)} inputs: {html.escape(inputs)}</p>")
        for n in d.notes:
            h.append(f"<p class='note'>{html.escape(d.label)}: {html.escape(n)}</p>")
    h.append("<h2>2. Tables 2–7: estimate ± 1σ (last packet)</h2>")
    for g in ORDER:
        if g in tables_md:
            h.append(md_table_to_html(tables_md[g]))
    h.append("<h2>3. Convergence</h2><p class='note'>Times in s since the first packet: from "
             "when the group's largest 1σ stays below 10× and 2× its final value, and (with "
             "truth) from when every element stays within 3σ of the truth.</p>")
    for d in data:
        conv = [i for i, m in enumerate(_modes(d)) if m == "converged"]
        first = f"{d.t[conv[0]] - d.t[0]:.1f} s" if conv else "never"
        h.append(f"<h3>{html.escape(d.label)} (NOT_CONVERGED first clear: {first})</h3>")
        h.append(_t(["group", "unit", "final max σ", "σ_end / σ_0", "t(σ ≤ 10σ_end) [s]",
                     "t(σ ≤ 2σ_end) [s]",
                     "t(|err| ≤ 3σ) [s]"], convergence(d)))
    h.append("<h2>4. Residuals and NIS</h2><p class='note'>Every telemetry packet's latest "
             "residual per kind. Columns: innovation mean / RMS per axis [arcsec]; innovation/σ "
             "mean / RMS per axis; mean NIS against the chi-square 95 % band of a mean of n "
             "values with the kind's degrees of freedom.</p>")
    for d in data:
        h.append(f"<h3>{html.escape(d.label)}</h3>")
        h.append(_t(["kind", "n", "innov mean / RMS [arcsec]", "innov/σ mean / RMS", "dof",
                     "mean NIS", "95 % band"], residual_rows(residual_stats(d.path, d.topic))))
    h.append("<h2>5. Edits and faults</h2>")
    for d in data:
        h.append(f"<h3>{html.escape(d.label)}: counters (last packet), flags set, "
                 f"{d.n_faults} fault messages</h3>")
        h.append("<div style='display:flex;gap:2em;flex-wrap:wrap;align-items:flex-start'>"
                 + _t(["counter", "value"], _counters(d))
                 + _t(["flag set", "times"], _flag_sets(d)) + "</div>")
        if d.faults:
            h.append(_t(["t [s]", "flags", "set", "cleared"], [
                [f"{float(f.get('t', math.nan)):.3f}", flag_label(f.get("flags")),
                 ", ".join(map(str, f.get("set") or [])),
                 ", ".join(map(str, f.get("cleared") or []))] for f in d.faults[:30]]))
    h.append("<h2>6. Figures</h2>")
    for name, caption in figures:
        p = out / name
        if p.exists():
            h.append(_img(p, caption))
    h.append("</body></html>")
    path = out / "calibration_report.html"
    path.write_text("\n".join(h) + "\n", encoding="utf-8")
    return path


def _modes(d: Any) -> list[str]:
    """'converged' / 'converging' per decimated packet, from its NOT_CONVERGED flag bit."""
    from radical_rt.contract.flags import Flag

    return ["converged" if not (int(f) & int(Flag.NOT_CONVERGED)) else "converging"
            for f in d.flags]


CHROMIUM = "/usr/bin/chromium"


def write_pdf(html_path: Path, chromium: str = CHROMIUM) -> Path:
    """Print the report to PDF (A4) with headless Chromium through Playwright (both optional:
    ``pip install playwright`` and Debian's ``chromium``; no browser download). Raises
    RuntimeError with the install hint when either is missing."""
    import os

    if not os.path.exists(chromium):
        raise RuntimeError(f"--pdf needs Chromium at {chromium} (apt-get install chromium)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        raise RuntimeError("--pdf needs playwright (pip install playwright; it drives the "
                           "system Chromium, no browser download)") from None
    pdf = html_path.with_suffix(".pdf")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=chromium, args=[
            "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run"])
        try:
            page = b.new_page()
            page.goto(html_path.resolve().as_uri())
            page.pdf(path=str(pdf), format="A4", print_background=True,
                     margin={"top": "12mm", "bottom": "12mm", "left": "10mm", "right": "10mm"})
        finally:
            b.close()
    return pdf
