"""Live web dashboard (Bokeh server): ``radical monitor web [--vehicle V] [--port P]
[--listen EP | --connect EP] [--stale-s S]``.

One Bokeh server process, bound to 127.0.0.1 only (the Bokeh JS is served by the server itself:
no external resources). Zenoh callbacks only store messages in a
:class:`~monitors.live.LatestStore` (the newest per (vehicle, topic), and every tlm/large packet
in a bounded ring). Each browser session runs a periodic callback (4 Hz) on the Bokeh IOLoop that
pulls the store through a shared :class:`Hub` — which turns *every* tlm/large packet received
into one row of display-unit columns and keeps a bounded history per vehicle — and sends only the
new rows with ``ColumnDataSource.stream(..., rollover)``.

Page: vehicle selector (vehicles from ``radical/*/alive/filter`` liveliness tokens and from
traffic), stale-data alarm (no packet of the vehicle for ``stale_s`` s of the receiver's
monotonic clock), status (mode, flags by name, bus time, per-topic counts/rates/ages), SIRU
clock, latest fault messages, a table of current values (attitude, rates, latency ± 1σ, clock,
mode, flags, gyro status; parameter estimates ± 1σ per gyro in the paper's units); the figures
of :mod:`monitors.web_figs` (attitude 1σ, residuals with boresight apart on robust axes, flag
timeline; Euler angles, rates, latency; parameters; clock and counters).
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

from monitors.common import FLAG_BITS, excitation_text, flag_label
from monitors.live import TOPICS, LatestStore, pick_vehicle
from monitors.view import (
    STALE_S,
    StreamAxis,
    clock_lines,
    column_names,
    counter_lines,
    current_lines,
    fault_line,
    gyro_status,
    param_rows,
    tlm_row,
    tlm_shape,
)
from monitors.web_figs import RANGE_ROWS, build_plots, residual_columns, robust_range

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
        self.axis: dict[str, StreamAxis] = {}  # streams one after the other on the plots' x

    def poll(self) -> None:
        """Turn every tlm/large packet and fault message received since the last poll into rows."""
        with self._lock:
            for v in self.store.vehicles():
                for n, msg in self.store.since(v, "tlm/large", self._seen.get(v, 0)):
                    self._seen[v] = n
                    shape = tlm_shape(msg)
                    if shape != self.shape.get(v):  # new vehicle or new geometry: restart
                        self.shape[v] = shape
                        self.rows[v] = deque(maxlen=self.keep)
                        self.total[v] = 0
                        self.axis[v] = StreamAxis()
                    row = tlm_row(msg, shape)
                    row["t"] = t = self.axis[v].x(row["t"], msg.get("stream"))
                    self.rows[v].append(row)
                    self.total[v] += 1
                    self._add_flags(v, _flag_rows(t, msg.get("flags", 0), "tlm"))
                faults = self.store.faults(v, after=self._seen_fault.get(v, 0))
                axis = self.axis.get(v) or StreamAxis()
                for n, _recv, m in faults:
                    self._seen_fault[v] = n
                    t = axis.at(float(m.get("t", math.nan)), m.get("stream"))
                    self._add_flags(v, _flag_rows(t, m.get("flags", 0), "fault"))

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

    def y_ranges(self, v: str, shape: dict[str, int]) -> dict[str, tuple[float, float]]:
        """Residual figure name → :func:`~monitors.web_figs.robust_range` of its columns over
        the newest RANGE_ROWS rows (arcsec); figures with no finite data are left out."""
        with self._lock:
            d = self.rows.get(v)
            rows = list(d)[-RANGE_ROWS:] if d else []
        out = {}
        for name, cols in residual_columns(shape).items():
            r = robust_range(np.array([[row.get(c, math.nan) for c in cols] for row in rows]))
            if r is not None:
                out[name] = r
        return out

    def flags_since(self, v: str, n: int) -> tuple[list[tuple[float, str, str]], int]:
        with self._lock:
            total = self.flag_total.get(v, 0)
            return self._since(self.flags.get(v), total, n), total


def _moved(old: tuple[float, float], new: tuple[float, float], tol: float = 0.1) -> bool:
    """True when a y range moved by more than ``tol`` of its span at either end (small changes
    are not sent: each one costs the browser a redraw)."""
    span = max(old[1] - old[0], 1e-12)
    return abs(new[0] - old[0]) > tol * span or abs(new[1] - old[1]) > tol * span


def _set_text(div: Any, text: str) -> None:
    if div.text != text:
        div.text = text


def _kv_html(rows: list[tuple[str, str]]) -> str:
    return "<table style='font-size:12px'>" + "".join(
        f"<tr><th style='text-align:left;padding-right:8px'>{html.escape(k)}</th>"
        f"<td>{html.escape(v)}</td></tr>" for k, v in rows) + "</table>"


def current_html(msg: dict[str, Any] | None, flags: int | None) -> str:
    """The current-values table: :func:`~monitors.view.current_lines` (attitude, rates, latency,
    clock, mode, flags, gyros) and the parameter estimates ± 1σ per gyro in the paper's units
    (units in the row headers), failed/excluded gyros marked in the column headers and cells."""
    if msg is None:
        return "<i>no tlm packet received yet</i>"
    state = gyro_status(msg, flags)
    bad = {i for i, st in enumerate(state) if st != "ok"}
    td = "<td style='padding:0 6px;font-family:monospace'>"
    cells = [f"<th style='padding:0 6px'>{html.escape(c)}"
             + (f" <span style='color:#c00'>✗ {state[i]}</span>" if i in bad else "") + "</th>"
             for i, c in enumerate(column_names(len(state)))]
    rows = "".join(
        f"<tr><th style='text-align:left'>{html.escape(label)} [{html.escape(unit)}]</th>"
        + "".join(f"{td}<span style='color:{'#c00' if i in bad else 'inherit'}'>"
                  f"{html.escape(c)}</span></td>" for i, c in enumerate(vals)) + "</tr>"
        for label, unit, vals in param_rows(msg))
    return ("<div style='display:flex;gap:24px'><div><b>current values</b>"
            + _kv_html(current_lines(msg, flags)) + "</div><div><b>parameters (estimate ± 1σ)"
            "</b><table id='params' style='font-size:12px'><tr><th></th>" + "".join(cells)
            + "</tr>" + rows + "</table></div></div>")


def stale_html(age_s: float | None, stale_s: float) -> str:
    """The stale-data alarm: red banner when the newest packet of the vehicle is older than
    ``stale_s`` s (receiver clock), empty while data flows or before any packet."""
    if age_s is None or age_s <= stale_s:
        return ""
    return (f"<div style='background:#c00;color:white;font-weight:bold;padding:4px 8px'>"
            f"STALE DATA: no packet for {age_s:.0f} s (alarm after {stale_s:g} s)</div>")


def newest_age(store: LatestStore, v: str) -> float | None:
    """Seconds since the newest packet of any topic of the vehicle (receiver clock), or None."""
    ages = [s.age_s for s in (store.latest(v, t) for t in TOPICS) if s.age_s is not None]
    return min(ages) if ages else None


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


def make_document_factory(hub: Hub, vehicle: str | None, period_ms: int = 250,
                          stale_s: float = STALE_S):
    """The Bokeh app function: one call per browser session. ``stale_s``: seconds without a
    packet before the stale-data alarm shows."""

    def make_doc(doc: Any) -> None:
        from bokeh.layouts import column, row
        from bokeh.models import Div, Select  # type: ignore[attr-defined]

        store = hub.store
        state: dict[str, Any] = {"vehicle": pick_vehicle(store, vehicle), "n": 0, "nf": 0,
                                 "shape": None, "src": None, "fsrc": None, "counters": None,
                                 "ranges": {}, "tick": 0}
        select = Select(title="vehicle", options=store.vehicles() or ([vehicle] if vehicle else []),
                        value=state["vehicle"] or "", width=160, name="vehicle")
        stale = Div(text="", name="stale", sizing_mode="stretch_width", height=28)
        status = Div(text="waiting for telemetry…", name="status", width=560, height=170)
        faults = Div(text="", name="faults", sizing_mode="stretch_width", height=170)
        clock = Div(text="", name="clock", width=380, height=170)
        current = Div(text="", name="current", sizing_mode="stretch_width", height=190)
        body = Div(text="<i>no tlm/large received yet</i>", sizing_mode="stretch_width")
        root = column(stale, row(select, status, clock, faults, sizing_mode="stretch_width"),
                      current, body, sizing_mode="stretch_width")
        doc.add_root(root)
        doc.title = "RADICAL-RT monitor"
        once_a_second = max(1, 1000 // period_ms)

        def switch(_attr: str, _old: str, new: str) -> None:
            if new and new != state["vehicle"]:
                state.update(vehicle=new, n=0, nf=0, shape=None)

        select.on_change("value", switch)

        def stream(v: str) -> None:
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
            if rows and (state["tick"] % once_a_second == 0 or not state.get("ranged")):
                state["ranged"] = True
                for name, (lo, hi) in hub.y_ranges(v, state["shape"]).items():
                    rng, last = state["ranges"][name], state["auto"].get(name)
                    if last is not None and (rng.start, rng.end) != last:
                        continue  # the operator zoomed or panned: hold until the reset tool
                    if last is None or _moved(last, (lo, hi)):  # reset: to the newest auto range
                        rng.update(start=lo, end=hi, reset_start=lo, reset_end=hi)
                        state["auto"][name] = (lo, hi)

        def pump() -> None:
            doc.hold("combine")  # one patch message per tick: the browser renders once
            try:
                update()
            finally:
                doc.unhold()

        def update() -> None:
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
                tabs, src, fsrc, counters, ranges = build_plots(shape, hub.keep)
                root.children[3] = tabs
                state.update(shape=shape, src=src, fsrc=fsrc, counters=counters, ranges=ranges,
                             auto={}, n=0, nf=0, ranged=False)
            state["tick"] += 1
            if state["src"] is not None:
                stream(v)
            # text panels: only when changed and at most ~1 Hz (ages tick, values move), but a
            # flags change at once; each Div change costs the browser a re-layout (fixed heights
            # keep it local)
            flags = store.last_flags(v)[0]
            if flags == state.get("flags") and state["tick"] % once_a_second != 0:
                return
            state["flags"] = flags
            _set_text(status, status_html(store, v))
            _set_text(stale, stale_html(newest_age(store, v), stale_s))
            large = store.latest(v, "tlm/large").msg
            newest = large or store.latest(v, "tlm/medium").msg or store.latest(v, "tlm/small").msg
            _set_text(current, current_html(newest, flags))
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
          period_ms: int = 250, keep: int = 3600, stale_s: float = STALE_S) -> int:
    """Run the Bokeh server on 127.0.0.1:port until SIGINT/SIGTERM. ``keep``: rows of history
    per vehicle; ``stale_s``: seconds without a packet before the stale-data alarm."""
    from bokeh.application import Application
    from bokeh.application.handlers.function import FunctionHandler
    from bokeh.server.server import Server

    from monitors.web_fleet import make_fleet_document_factory

    hub = Hub(store, keep=keep)
    app = Application(FunctionHandler(make_document_factory(hub, vehicle, period_ms, stale_s)))
    fleet = Application(FunctionHandler(make_fleet_document_factory(hub)))
    origins = [f"127.0.0.1:{port}", f"localhost:{port}"]
    server = Server({"/": app, "/fleet": fleet}, port=port, address="127.0.0.1",
                    allow_websocket_origin=origins)
    server.start()
    loop = server.io_loop
    from tornado.ioloop import PeriodicCallback

    history = PeriodicCallback(hub.poll, period_ms)  # histories grow with no browser open too
    history.start()

    def stop(*_a: Any) -> None:
        loop.add_callback(loop.stop)

    signal.signal(signal.SIGTERM, stop)
    print(f"radical monitor web: serving http://127.0.0.1:{port}/ (fleet page: "
          f"http://127.0.0.1:{port}/fleet)", flush=True)
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
