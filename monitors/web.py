"""Live web dashboard (Bokeh server): ``radical monitor web [--vehicle V] [--port P]
[--listen EP | --connect EP]``.

One Bokeh server process, bound to 127.0.0.1 only (the Bokeh JS is served by the server itself:
no external resources). Zenoh callbacks only store the newest message per (vehicle, topic) in a
:class:`~monitors.live.LatestStore`. Each browser session runs a periodic callback (4 Hz) on the
Bokeh IOLoop that pulls the store through a shared :class:`Hub` — which turns each new tlm/large
packet into one row of paper-unit columns and keeps a bounded history per vehicle — and sends only
the new rows with ``ColumnDataSource.stream(..., rollover)``.

Page: vehicle selector (vehicles from ``radical/*/alive/filter`` liveliness tokens and from
traffic), status (mode, flags by name, bus time, per-topic counts/rates/ages on the receiver's
monotonic clock), latest fault messages; tab "attitude & residuals" (attitude 1σ; parity residual
±1σ; ST1 and ST2 residuals ±1σ; fault flag timeline by name); one tab per parameter group
(estimates and 1σ over time); tab "clock & counters" (SIRU clock frequency offset, offset and
tag error 1σ; counters).
"""

from __future__ import annotations

import html
import math
import signal
import sys
import threading
from collections import deque
from typing import Any

import numpy as np

from monitors.common import (
    FLAG_BITS,
    GROUP_LABELS,
    ORDER,
    PAPER_UNITS,
    element_names,
    excitation_text,
    flag_label,
)
from monitors.live import TOPICS, LatestStore, pick_vehicle
from monitors.view import clock_lines, counter_lines, fault_line, tlm_columns, tlm_row, tlm_shape

FLAG_NAMES = [name for _b, name in FLAG_BITS] + ["OTHER"]
COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f"]
BENIGN = {"NOT_CONVERGED"}


def _flag_rows(t: float, flags: Any, src: str) -> list[tuple[float, str, str]]:
    try:
        bits = int(flags)
    except (TypeError, ValueError):
        return []
    out = []
    for b in range(max(bits.bit_length(), 0)):
        if bits >> b & 1:
            name = next((n for bb, n in FLAG_BITS if bb == b), "OTHER")
            out.append((t, name, src))
    return out


def _flag_color(r: tuple[float, str, str]) -> str:
    """Fault messages black; benign flags (NOT_CONVERGED) grey; the others red."""
    return "#000000" if r[2] == "fault" else "#999999" if r[1] in BENIGN else "#d62728"


class Hub:
    """Shared by all browser sessions: pulls the store, keeps per-vehicle bounded histories.

    Runs on the Bokeh IOLoop (every session's pump calls :meth:`poll`; it is idempotent)."""

    def __init__(self, store: LatestStore, keep: int = 3600) -> None:
        self.store, self.keep = store, keep
        self._lock = threading.Lock()
        self.rows: dict[str, deque[dict[str, float]]] = {}
        self.total: dict[str, int] = {}
        self.shape: dict[str, dict[str, int]] = {}
        self.flags: dict[str, deque[tuple[float, str, str]]] = {}
        self.flag_total: dict[str, int] = {}
        self._seen: dict[str, int] = {}
        self._seen_fault: dict[str, int] = {}

    def poll(self) -> None:
        with self._lock:
            for v in self.store.vehicles():
                s = self.store.latest(v, "tlm/large")
                if s.msg is not None and s.count != self._seen.get(v):
                    self._seen[v] = s.count
                    shape = tlm_shape(s.msg)
                    if shape != self.shape.get(v):  # new vehicle or new geometry: restart
                        self.shape[v] = shape
                        self.rows[v] = deque(maxlen=self.keep)
                        self.total[v] = 0
                    self.rows[v].append(tlm_row(s.msg, shape))
                    self.total[v] += 1
                    t = float(s.msg.get("t", math.nan))
                    self._add_flags(v, _flag_rows(t, s.msg.get("flags", 0), "tlm"))
                faults = self.store.faults(v, after=self._seen_fault.get(v, 0))
                for n, _recv, m in faults:
                    self._seen_fault[v] = n
                    self._add_flags(v, _flag_rows(float(m.get("t", math.nan)), m.get("flags", 0),
                                                  "fault"))

    def _add_flags(self, v: str, rows: list[tuple[float, str, str]]) -> None:
        d = self.flags.setdefault(v, deque(maxlen=self.keep * 4))
        d.extend(rows)
        self.flag_total[v] = self.flag_total.get(v, 0) + len(rows)

    @staticmethod
    def _since(d: deque | None, total: int, n: int) -> list[Any]:
        if d is None or total <= n:
            return []
        k = min(total - n, len(d))
        return list(d)[len(d) - k:]

    def rows_since(self, v: str, n: int) -> tuple[list[dict[str, float]], int]:
        with self._lock:
            total = self.total.get(v, 0)
            return self._since(self.rows.get(v), total, n), total

    def flags_since(self, v: str, n: int) -> tuple[list[tuple[float, str, str]], int]:
        with self._lock:
            total = self.flag_total.get(v, 0)
            return self._since(self.flags.get(v), total, n), total


# ------------------------------------------------------------------------------------ document
def _fig(title: str, y_label: str, log: bool = False, height: int = 240, x_range: Any = None,
         y_range: Any = None):
    from bokeh.plotting import figure

    kw: dict[str, Any] = {"x_range": x_range} if x_range is not None else {}
    if y_range is not None:
        kw["y_range"] = y_range
    f = figure(title=title, height=height, sizing_mode="stretch_width", output_backend="canvas",
               tools="pan,wheel_zoom,box_zoom,reset,save", y_axis_type="log" if log else "auto",
               x_axis_label="bus time [s]", y_axis_label=y_label, **kw)
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


def build_plots(shape: dict[str, int], keep: int) -> tuple[Any, Any, Any, Any]:
    """The tabs for one vehicle's packet shape; returns (tabs, tlm source, flags source,
    counters div)."""
    from bokeh.layouts import column, gridplot, row
    from bokeh.models import ColumnDataSource, Div, FactorRange, TabPanel, Tabs  # type: ignore[attr-defined]

    src = ColumnDataSource({c: np.zeros(0) for c in tlm_columns(shape)}, name="tlm")
    fsrc = ColumnDataSource({"t": np.zeros(0), "flag": [], "src": [], "color": []},
                            name="flags")
    figs = []
    att = _fig("attitude 1σ", "arcsec", log=True)
    for i, a in enumerate("xyz"):
        att.line("t", f"att_{a}", source=src, color=COLORS[i], legend_label=a, line_width=1.5)
    x = att.x_range
    figs.append(att)
    par = _fig("parity (null-space) residual ±1σ", "arcsec", x_range=x)
    for i in range(shape["parity"]):
        c = COLORS[i]
        par.scatter("t", f"par{i}", source=src, color=c, size=3, legend_label=f"p{i + 1}")
        par.line("t", f"par{i}_s", source=src, color=c, line_width=1)
        par.line("t", f"par{i}_sn", source=src, color=c, line_width=1)
    figs.append(par)
    for k in ("st1", "st2"):
        f = _fig(f"{k.upper()} residuals ±1σ", "arcsec", x_range=x)
        for i, a in enumerate("xyz"):
            c = COLORS[i]
            f.scatter("t", f"{k}_{a}", source=src, color=c, size=3, legend_label=a)
            f.line("t", f"{k}_{a}_s", source=src, color=c, line_width=1, legend_label=a)
            f.line("t", f"{k}_{a}_sn", source=src, color=c, line_width=1, legend_label=a)
        figs.append(f)
    for f in figs:
        _legend(f)
    flags_fig = _fig("fault flags (tlm/large: circles, grey if benign; fault messages: black "
                     "squares)", "", height=300,
                     x_range=x, y_range=FactorRange(factors=list(reversed(FLAG_NAMES))))
    from bokeh.transform import factor_mark

    flags_fig.scatter("t", "flag", source=fsrc, size=7,
                      marker=factor_mark("src", ["circle", "square"], ["tlm", "fault"]),
                      color="color")
    tab1 = TabPanel(title="attitude & residuals", child=column(
        gridplot([[figs[0], figs[1]], [figs[2], figs[3]]], sizing_mode="stretch_width",
                 toolbar_location="right"), flags_fig, sizing_mode="stretch_width"))
    tabs = [tab1, TabPanel(title="parameters", child=_param_panel(src, shape, x))]
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
    return Tabs(tabs=tabs, sizing_mode="stretch_width", name="tabs"), src, fsrc, counters


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


def _set_text(div: Any, text: str) -> None:
    if div.text != text:
        div.text = text


def _kv_html(rows: list[tuple[str, str]]) -> str:
    return "<table style='font-size:12px'>" + "".join(
        f"<tr><th style='text-align:left;padding-right:8px'>{html.escape(k)}</th>"
        f"<td>{html.escape(v)}</td></tr>" for k, v in rows) + "</table>"


def status_html(store: LatestStore, v: str) -> str:
    snaps = {t: store.latest(v, t) for t in TOPICS}
    small = snaps["tlm/small"].msg or snaps["tlm/large"].msg or snaps["tlm/medium"].msg or {}
    flags, _src = store.last_flags(v)
    names = flag_label(flags)
    serious = [n for n in names.split(", ") if n not in BENIGN and n not in ("-", "?")]
    alive = store.alive(v)
    mode = html.escape(str(small.get("mode", "?")))
    t = small.get("t")
    parts = [f"<b>vehicle {html.escape(v)}</b>",
             f"node <span style='color:{'green' if alive else 'red' if alive is False else 'gray'}'>"
             f"{'alive' if alive else 'gone' if alive is False else '?'}</span>",
             f"mode <b>{mode}</b>",
             f"t {t:.2f} s" if isinstance(t, int | float) else "t ?",
             f"seq {html.escape(str(small.get('seq', '?')))}"]
    flag_html = (f"<span id='flags' style='color:{'#c00' if serious else 'green'};"
                 f"font-weight:bold'>{html.escape(names)}</span>")
    rows = "".join(
        f"<tr><td>{html.escape(tp)}</td><td>{s.count}</td><td>{s.rate_hz:.1f}</td>"
        f"<td>{'-' if s.age_s is None else f'{s.age_s:.2f}'}</td></tr>"
        for tp, s in snaps.items())
    ex = excitation_text((snaps["diag"].msg or {}).get("excitation"))
    if ex:  # diag's excitation map (docs/design.md §5)
        flag_html += (f"<br>excitation <span id='excitation' style='color:"
                      f"{'#c60' if 'NOT EXCITED' in ex else 'inherit'}'>{html.escape(ex)}</span>")
    return (f"<div style='font-size:13px'>{' &nbsp; '.join(parts)}<br>flags {flag_html}</div>"
            "<table style='font-size:11px;margin-top:4px'><tr><th>topic</th><th>count</th>"
            "<th>rate Hz</th><th>age s (receiver clock)</th></tr>" + rows + "</table>")


def make_document_factory(hub: Hub, vehicle: str | None, period_ms: int = 250):
    """The Bokeh app function: one call per browser session."""

    def make_doc(doc: Any) -> None:
        from bokeh.layouts import column, row
        from bokeh.models import Div, Select  # type: ignore[attr-defined]

        store = hub.store
        state: dict[str, Any] = {"vehicle": pick_vehicle(store, vehicle), "n": 0, "nf": 0,
                                 "shape": None, "src": None, "fsrc": None, "counters": None}
        select = Select(title="vehicle", options=store.vehicles() or ([vehicle] if vehicle else []),
                        value=state["vehicle"] or "", width=160, name="vehicle")
        status = Div(text="waiting for telemetry…", name="status", width=560, height=170)
        faults = Div(text="", name="faults", sizing_mode="stretch_width", height=170)
        clock = Div(text="", name="clock", width=380, height=170)
        body = Div(text="<i>no tlm/large received yet</i>", sizing_mode="stretch_width")
        root = column(row(select, status, clock, faults, sizing_mode="stretch_width"), body,
                      sizing_mode="stretch_width")
        doc.add_root(root)
        doc.title = "RADICAL-RT monitor"

        def switch(_attr: str, _old: str, new: str) -> None:
            if new and new != state["vehicle"]:
                state.update(vehicle=new, n=0, nf=0, shape=None)

        select.on_change("value", switch)

        def pump() -> None:
            hub.poll()
            vs = store.vehicles()
            if vehicle and vehicle not in vs:
                vs = [vehicle, *vs]
            if list(select.options) != vs:
                select.options = vs
            if not state["vehicle"] and vs:
                state["vehicle"] = pick_vehicle(store, None)
                select.value = state["vehicle"]
            v = state["vehicle"]
            if not v:
                return
            shape = hub.shape.get(v)
            if shape is not None and shape != state["shape"]:
                tabs, src, fsrc, counters = build_plots(shape, hub.keep)
                root.children[1] = tabs
                state.update(shape=shape, src=src, fsrc=fsrc, counters=counters, n=0, nf=0)
            if state["src"] is not None:
                rows, total = hub.rows_since(v, state["n"])
                if rows:
                    cols = {c: np.array([r[c] for r in rows], dtype=float) for c in rows[0]}
                    state["src"].stream(cols, rollover=hub.keep)
                    state["n"] = total
                frows, ftotal = hub.flags_since(v, state["nf"])
                if frows:
                    state["fsrc"].stream({"t": np.array([r[0] for r in frows], dtype=float),
                                          "flag": [r[1] for r in frows],
                                          "src": [r[2] for r in frows],
                                          "color": [_flag_color(r) for r in frows]},
                                         rollover=hub.keep * 4)
                    state["nf"] = ftotal
            # text panels: only when changed, the status (ages tick) at most ~1 Hz, but a
            # flags change at once; each Div change costs the browser a re-layout
            state["tick"] = state.get("tick", 0) + 1
            flags = store.last_flags(v)[0]
            if flags != state.get("flags") or state["tick"] % max(1, 1000 // period_ms) == 0:
                state["flags"] = flags
                _set_text(status, status_html(store, v))
            large = store.latest(v, "tlm/large").msg
            _set_text(clock, "<b>SIRU clock</b>" + _kv_html(clock_lines(large)))
            fl = store.faults(v)[-6:]
            _set_text(faults, "<b>fault messages</b> (newest last)<br><span style='font-size:11px'>"
                      + ("<br>".join(html.escape(fault_line(m)) for _n, _t, m in fl) or "none")
                      + "</span>")
            if state["counters"] is not None and large is not None:
                _set_text(state["counters"], "<b>counters</b>" + _kv_html(counter_lines(large)))

        pump()
        doc.add_periodic_callback(pump, period_ms)

    return make_doc


def serve(store: LatestStore, vehicle: str | None, port: int, source: Any = None,
          period_ms: int = 250, keep: int = 3600) -> int:
    """Run the Bokeh server on 127.0.0.1:port until SIGINT/SIGTERM."""
    from bokeh.application import Application
    from bokeh.application.handlers.function import FunctionHandler
    from bokeh.server.server import Server

    hub = Hub(store, keep=keep)
    app = Application(FunctionHandler(make_document_factory(hub, vehicle, period_ms)))
    origins = [f"127.0.0.1:{port}", f"localhost:{port}"]
    server = Server({"/": app}, port=port, address="127.0.0.1", allow_websocket_origin=origins)
    server.start()
    loop = server.io_loop
    from tornado.ioloop import PeriodicCallback

    history = PeriodicCallback(hub.poll, period_ms)  # histories grow with no browser open too
    history.start()

    def stop(*_a: Any) -> None:
        loop.add_callback(loop.stop)

    signal.signal(signal.SIGTERM, stop)
    print(f"radical monitor web: serving http://127.0.0.1:{port}/", flush=True)
    try:
        loop.start()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
        if source is not None:
            source.close()
    print("radical monitor web: stopped", file=sys.stderr, flush=True)
    return 0
