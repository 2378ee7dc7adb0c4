"""Figures of the web dashboard (:mod:`monitors.web`): the Bokeh tabs for one vehicle's packet
shape, all fed by one ``ColumnDataSource`` named ``tlm`` (columns of
:func:`monitors.view.tlm_columns`, display units) and one named ``flags``.

Residual plots do not autoscale on everything they hold: the convergence transient (thousands of
arcsec) would flatten the converged residuals (arcsec). Their y ranges are set by the dashboard
from :func:`robust_range` of the most recent rows instead (percentiles, padded); a zoom or pan
by the operator holds a plot's range until the reset tool returns it to automatic.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from monitors.common import FLAG_BITS, GROUP_LABELS, ORDER, PAPER_UNITS, element_names
from monitors.view import tlm_columns

FLAG_NAMES = [name for _b, name in FLAG_BITS] + ["OTHER"]
COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f"]
#: Rows (newest) that set the residual plots' y ranges, and their percentiles.
RANGE_ROWS = 300
RANGE_PCT = (2.0, 98.0)


def robust_range(values: np.ndarray, pct: tuple[float, float] = RANGE_PCT, pad: float = 0.15,
                 min_span: float = 1e-3) -> tuple[float, float] | None:
    """(lo, hi) covering the ``pct`` percentiles of the finite ``values`` (any shape, display
    units), widened by ``pad`` of the span on each side and to at least ``min_span``; None when
    nothing is finite. A few outliers (a transient) fall outside it by design."""
    v = np.asarray(values, dtype=float).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    lo, hi = (float(x) for x in np.percentile(v, pct))
    span = max(hi - lo, min_span)
    mid = 0.5 * (lo + hi)
    half = 0.5 * span * (1.0 + 2.0 * pad)
    return mid - half, mid + half


def residual_columns(shape: dict[str, int]) -> dict[str, list[str]]:
    """Name of each residual figure → the source columns (innovation and ±σ) its range covers."""
    def cols(names: list[str]) -> list[str]:
        return [c for n in names for c in (n, f"{n}_s", f"{n}_sn")]

    out = {"res_parity": cols([f"par{i}" for i in range(shape["parity"])])}
    for k in ("st1", "st2"):
        out[f"res_{k}_xy"] = cols([f"{k}_x", f"{k}_y"])
        out[f"res_{k}_bs"] = cols([f"{k}_z"])
    return out


def _fig(title: str, y_label: str, log: bool = False, height: int = 240, x_range: Any = None,
         y_range: Any = None):
    from bokeh.plotting import figure

    kw: dict[str, Any] = {"x_range": x_range} if x_range is not None else {}
    if y_range is not None:
        kw["y_range"] = y_range
    f = figure(title=title, height=height, sizing_mode="stretch_width", output_backend="canvas",
               tools="pan,wheel_zoom,box_zoom,reset,save", y_axis_type="log" if log else "auto",
               x_axis_label="bus time [s] (a later stream after the previous one)", y_axis_label=y_label, **kw)
    f.title.text_font_size = "11px"  # type: ignore[union-attr]
    return f


def _legend(f: Any) -> None:
    if f.legend:
        f.legend.click_policy = "hide"
        f.legend.label_text_font_size = "9px"
        f.legend.location = "top_right"
        f.legend.background_fill_alpha = 0.6
        f.legend.spacing = 0
        f.legend.padding = 2


def _band(f: Any, src: Any, col: str, color: str, label: str) -> None:
    """Innovation dots and ±1σ lines of one residual component (columns col, col_s, col_sn)."""
    f.scatter("t", col, source=src, color=color, size=3, legend_label=label)
    f.line("t", f"{col}_s", source=src, color=color, line_width=1, legend_label=label)
    f.line("t", f"{col}_sn", source=src, color=color, line_width=1, legend_label=label)


def build_plots(shape: dict[str, int], keep: int) -> tuple[Any, Any, Any, Any, dict[str, Any]]:
    """The tabs for one vehicle's packet shape; returns (tabs, tlm source, flags source, counters
    div, {residual figure name: its y Range1d}) — the ranges are set by the caller from
    :func:`robust_range` (see :func:`residual_columns`)."""
    from bokeh.layouts import column, gridplot, row
    from bokeh.models import ColumnDataSource, Div, FactorRange, Range1d, TabPanel, Tabs  # type: ignore[attr-defined]
    from bokeh.transform import factor_mark

    src = ColumnDataSource({c: np.zeros(0) for c in tlm_columns(shape)}, name="tlm")
    fsrc = ColumnDataSource({"t": np.zeros(0), "flag": [], "src": [], "color": []},
                            name="flags")
    att = _fig("attitude 1σ", "arcsec", log=True)
    for i, a in enumerate("xyz"):
        att.line("t", f"att_{a}", source=src, color=COLORS[i], legend_label=a, line_width=1.5)
    x = att.x_range
    ranges: dict[str, Any] = {}

    def res_fig(name: str, title: str) -> Any:
        ranges[name] = Range1d(-1.0, 1.0)
        f = _fig(title, "arcsec", x_range=x, y_range=ranges[name])
        f.name = name
        return f

    par = res_fig("res_parity", "parity (null-space) residual ±1σ")
    for i in range(shape["parity"]):
        _band(par, src, f"par{i}", COLORS[i], f"p{i + 1}")
    grid = [[att, par]]
    for k in ("st1", "st2"):
        fxy = res_fig(f"res_{k}_xy", f"{k.upper()} residuals x, y (cross-boresight) ±1σ")
        for i, a in enumerate("xy"):
            _band(fxy, src, f"{k}_{a}", COLORS[i], a)
        fbs = res_fig(f"res_{k}_bs", f"{k.upper()} residual z (boresight) ±1σ")
        _band(fbs, src, f"{k}_z", COLORS[2], "z")
        grid.append([fxy, fbs])
    for f in (fig for r in grid for fig in r):
        _legend(f)
    flags_fig = _fig("fault flags (tlm/large: circles, grey if benign; fault messages: black "
                     "squares)", "", height=300,
                     x_range=x, y_range=FactorRange(factors=list(reversed(FLAG_NAMES))))
    flags_fig.name = "flag_timeline"
    flags_fig.scatter("t", "flag", source=fsrc, size=7,
                      marker=factor_mark("src", ["circle", "square"], ["tlm", "fault"]),
                      color="color")
    tab1 = TabPanel(title="attitude & residuals", child=column(
        gridplot(grid, sizing_mode="stretch_width", toolbar_location="right"), flags_fig,
        sizing_mode="stretch_width"))
    tabs = [tab1, TabPanel(title="attitude, rates, latency", child=_motion_panel(src, x, shape["parity"])),
            TabPanel(title="parameters", child=_param_panel(src, shape, x))]
    fc = _fig("SIRU clock frequency offset", "ppm", x_range=x)
    fc.line("t", "clk_ppm", source=src, line_width=1.5, legend_label="freq offset")
    ft = _fig("SIRU clock offset and time-tag error 1σ", "ms", x_range=x)
    ft.line("t", "clk_tag_ms", source=src, line_width=1.5, color=COLORS[1],
            legend_label="tag error 1σ")
    ft.line("t", "clk_offset_ms", source=src, line_width=1.5, color=COLORS[2],
            legend_label="offset")
    _legend(fc)
    _legend(ft)
    counters = Div(text="", name="counters", sizing_mode="stretch_width")
    tabs.append(TabPanel(title="clock & counters", child=column(
        row(fc, ft, sizing_mode="stretch_width"), counters, sizing_mode="stretch_width")))
    return Tabs(tabs=tabs, sizing_mode="stretch_width", name="tabs"), src, fsrc, counters, ranges


def _motion_panel(src: Any, x_range: Any, parity_dof: int) -> Any:
    """Euler angles [deg], body rates [deg/s], the tracker latency estimate ± 1σ [ms] and the NIS."""
    from bokeh.layouts import column, row

    fe = _fig("attitude, Euler 3-2-1 (body from inertial)", "deg", x_range=x_range)
    for i, k in enumerate(("yaw", "pitch", "roll")):
        fe.line("t", k, source=src, color=COLORS[i], line_width=1.5, legend_label=k)
    fw = _fig("body rate ω", "deg/s", x_range=x_range)
    for i, a in enumerate("xyz"):
        fw.line("t", f"w_{a}", source=src, color=COLORS[i], line_width=1.5, legend_label=a)
    fl = _fig("tracker latency estimate ± 1σ", "ms", x_range=x_range)
    fl.line("t", "lat_ms", source=src, line_width=1.5, legend_label="estimate")
    fl.line("t", "lat_hi", source=src, line_width=1, line_dash="dashed", legend_label="± 1σ")
    fl.line("t", "lat_lo", source=src, line_width=1, line_dash="dashed", legend_label="± 1σ")
    fn = _nis_fig(src, x_range, parity_dof)
    for f in (fe, fw, fl, fn):
        _legend(f)
    return column(row(fe, fw, sizing_mode="stretch_width"),
                  row(fl, fn, sizing_mode="stretch_width"), sizing_mode="stretch_width")


def _nis_fig(src: Any, x_range: Any, parity_dof: int) -> Any:
    """NIS of each residual kind (log axis) with its two-sided 95 % χ² bounds (dotted; dof 3
    for a tracker, ``parity_dof`` for the parity residual; monitors.report_ops.chi2_bounds)."""
    from bokeh.models import Span

    from monitors.report_ops import chi2_bounds

    fn = _fig("NIS with 95 % χ² bounds (dotted)", "NIS", x_range=x_range, log=True)
    fn.name = "nis"
    for i, (k, dof) in enumerate((("st1", 3), ("st2", 3), ("par", parity_dof))):
        if dof <= 0:
            continue
        fn.scatter("t", f"{k}_nis", source=src, color=COLORS[i], size=3, legend_label=k)
        for b in chi2_bounds(dof):
            fn.add_layout(Span(location=b, dimension="width", line_dash="dotted",
                               line_color=COLORS[i], name=f"chi2_{k}"))
    return fn


def _param_panel(src: Any, shape: dict[str, int], x_range: Any) -> Any:
    """Estimates and 1σ over time of one parameter group at a time, chosen with buttons: two
    figures whose lines are re-pointed at the group's columns (cheaper for the browser than
    twelve figures all streaming)."""
    from bokeh.core.property.vectorization import value
    from bokeh.layouts import column, row
    from bokeh.models import RadioButtonGroup  # type: ignore[attr-defined]

    width = max(shape["n"], 3)
    fe = _fig("estimates", "", height=340, x_range=x_range)
    fs = _fig("1σ", "", log=True, height=340, x_range=x_range)
    fe.name, fs.name = "param_est", "param_sigma"
    est_r = [fe.line("t", f"b{i}", source=src, color=COLORS[i % 8], line_width=1.5,
                     legend_label=f"e{i}") for i in range(width)]
    sig_r = [fs.line("t", f"b{i}_s", source=src, color=COLORS[i % 8], line_width=1.5,
                     legend_label=f"e{i}") for i in range(width)]
    _legend(fe)
    _legend(fs)
    buttons = RadioButtonGroup(labels=[f"{GROUP_LABELS[g]} [{PAPER_UNITS[g]}]" for g in ORDER],
                               active=ORDER.index("b"), name="group")

    def show(g: str) -> None:
        n = 3 if g == "phi2" else shape["n"]
        names = element_names(g, n)
        for f, rs, suffix in ((fe, est_r, ""), (fs, sig_r, "_s")):
            for i, r in enumerate(rs):
                vis = i < n
                r.visible = vis
                if vis:
                    r.glyph.y = f"{g}{i}{suffix}"
            for i, item in enumerate(f.legend.items):
                item.visible = i < n
                if i < n:
                    item.label = value(names[i])
        unit = PAPER_UNITS[g]
        fe.title.text = f"{GROUP_LABELS[g]} estimates [{unit}]"
        fs.title.text = f"{GROUP_LABELS[g]} 1σ [{unit}]"
        fe.yaxis.axis_label = fs.yaxis.axis_label = unit

    buttons.on_change("active", lambda _a, _o, new: show(ORDER[new]))
    show("b")
    return column(buttons, row(fe, fs, sizing_mode="stretch_width"), sizing_mode="stretch_width")


