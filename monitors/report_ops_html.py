"""``report.html`` of :mod:`monitors.report_ops`: one interactive page (Bokeh, resources inline,
nothing fetched at run time) with, per archive and on the common stream axis (minutes): attitude
quaternion and 3-2-1 Euler angles, body rates, attitude error vs truth (when present), tracker
latency ± 1σ, SIRU clock, NIS per tracker with its χ² 95 % bounds, and a flag timeline. Every
panel carries the markers of :func:`monitors.report_ops.markers` (stream boundaries labelled by
how the stream started, fault messages, gyro isolations), named in the legend and on hover.

Model names (for tests and scripts): figures ``ops:<label>:<panel>``, marker renderers
``marker:<kind>``, χ² bound lines ``chi2:<kind>:lo|hi``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from monitors.report_ops import OpsData, chi2_bounds, markers, stream_label
from monitors.report_ops_fig import DOF, MARK_STYLE
from monitors.view import euler_321
from radical_rt.contract.flags import Flag

COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728"]
MARK_LEGEND = {"boundary": "stream boundary", "isolation": "gyro isolation",
               "fault": "fault (flags set)", "clear": "fault (flags cleared)"}
EULER_TITLE = "Euler angles 3-2-1 (yaw z, pitch y', roll x'') of q_body_from_inertial [deg]"


def _add_markers(p: Any, d: OpsData) -> None:
    """Vertical markers (one renderer per kind, legend entry and hover label)."""
    from bokeh.models import ColumnDataSource, HoverTool

    rends = []
    for kind, (color, dash) in MARK_STYLE.items():
        ms = [(x, label) for x, k, label in markers(d) if k == kind]
        if not ms:
            continue
        src = ColumnDataSource({"x": [m[0] for m in ms], "label": [m[1] for m in ms]})
        rends.append(p.vspan(x="x", source=src, line_color=color, line_dash=dash,
                             line_width=1.5 if kind == "boundary" else 1.0,
                             legend_label=MARK_LEGEND[kind], name=f"marker:{kind}"))
    if rends:
        p.add_tools(HoverTool(renderers=rends, tooltips=[("marker", "@label"), ("min", "@x")]))


def _lines(p: Any, d: OpsData, y: np.ndarray, names: list[str]) -> None:
    """Each column of y per stream (no line joins two streams); NaN breaks the line."""
    for i, nm in enumerate(names):
        for _xb, k in d.boundaries:
            m = d.stream == k
            p.line(d.x[m], y[m, i], legend_label=nm, color=COLORS[i % 4])


def _figure(d: OpsData, panel: str, x_range: Any, **kw: Any) -> Any:
    from bokeh.plotting import figure

    p = figure(title=f"{d.label}: {panel}", width=1100, height=kw.pop("height", 220),
               x_range=x_range or (float(d.x.min()), float(d.x.max())),
               name=f"ops:{d.label}:{panel}", **kw)
    p.xaxis.axis_label = "min (streams on a common axis)"
    return p


def _nis(d: OpsData, x_range: Any) -> Any:
    from bokeh.models import Span

    p = _figure(d, "NIS per tracker with chi-square 95 % bounds", x_range, y_axis_type="log")
    for i, (kind, v) in enumerate(d.nis.items()):
        ok = np.isfinite(v) & (v > 0)
        p.scatter(d.x[ok], v[ok], size=3, color=COLORS[i % 4],
                  legend_label=f"{kind} NIS (dof {DOF.get(kind, 3)})", name=f"nis:{kind}")
        lo, hi = chi2_bounds(DOF.get(kind, 3))
        for nm, val in (("lo", lo), ("hi", hi)):
            p.add_layout(Span(location=val, dimension="width", line_color=COLORS[i % 4],
                              line_dash="dotted", line_width=1.2, name=f"chi2:{kind}:{nm}"))
    if not d.nis:
        p.title.text += " (no residuals in archive)"
    return p


def _flags(d: OpsData, x_range: Any) -> Any:
    """One row per flag bit set anywhere in the archive, a point where it is set, per stream."""
    rows = [f for f in Flag if f.name and ((d.flags & int(f)) != 0).any()]
    names = [f.name or "" for f in rows] or ["(no flag set)"]
    p = _figure(d, "flag timeline", x_range, y_range=names, height=max(160, 40 + 22 * len(names)))
    for f in rows:
        for _xb, k in d.boundaries:
            m = (d.stream == k) & ((d.flags & int(f)) != 0)
            if m.any():
                p.scatter(d.x[m], [f.name] * int(m.sum()), size=4, color="#d62728",
                          marker="square", name=f"flag:{f.name}:{k}")
    return p


def panels(d: OpsData) -> list[Any]:
    """The Bokeh figures of one archive, sharing the x range."""
    series = [("attitude quaternion q_body_from_inertial (scalar last)", d.q,
               ["q1", "q2", "q3", "q4"]),
              (EULER_TITLE, euler_321(d.q), ["yaw", "pitch", "roll"]),
              ("body rate [deg/s]", d.omega, ["x", "y", "z"]),
              ("tracker latency [ms]", d.lat, ["estimate", "sigma"]),
              ("SIRU clock", d.clk, ["freq ppm", "locked", "repeated", "missing"])]
    if d.att_err is not None:
        series.insert(3, ("attitude error vs /truth/attitude [arcsec]", d.att_err,
                          ["x", "y", "z"]))
    out: list[Any] = []
    x_range = None
    for title, y, names in series:
        p = _figure(d, title, x_range)
        x_range = p.x_range
        _lines(p, d, y, names)
        if title.startswith("tracker latency"):
            for _xb, k in d.boundaries:
                m = d.stream == k
                p.varea(d.x[m], d.lat[m, 0] - d.lat[m, 1], d.lat[m, 0] + d.lat[m, 1],
                        fill_alpha=0.25, color=COLORS[0], legend_label="±1σ")
        out.append(p)
    out += [_nis(d, x_range), _flags(d, x_range)]
    for p in out:
        _add_markers(p, d)
        p.legend.click_policy = "hide"
        p.legend.label_text_font_size = "8pt"
    return out


def write_html(out: Path, ops: list[OpsData], tables_html: str) -> Path:
    """report.html: one interactive page (Bokeh, resources inline) plus the tables."""
    import html

    from bokeh.embed import file_html
    from bokeh.layouts import column
    from bokeh.models import Div
    from bokeh.resources import INLINE

    items: list[Any] = [Div(text="<h1>RADICAL-RT operations report</h1>" + tables_html)]
    for d in ops:
        items.append(Div(text="<h2>" + html.escape(d.label) + "</h2><p>" + "<br>".join(
            html.escape(f"{stream_label(d, k)} (at {xb:.2f} min)") for xb, k in d.boundaries)
            + "</p>", name=f"streams:{d.label}"))
        items += panels(d)
    doc = file_html(column(*items), INLINE, "RADICAL-RT operations report")
    path = out / "report.html"
    path.write_text(doc, encoding="utf-8")
    return path
