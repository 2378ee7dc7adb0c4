"""Terminal dashboard (textual): ``radical monitor tui [--vehicle V] [--listen EP | --connect EP]``.

Shows, for one vehicle, the parameter table (estimate ± 1σ in the paper's units, one row per
group as in Tables 2–7), the mode and the fault flags by name, per-topic packet counts, rates and
ages (age = now − receive time of the newest packet, both on this host's monotonic clock: packet
bus times and the receiver clock are different time lines), the SIRU clock state, attitude 1σ and
residual statistics, counters and the latest fault messages; the current values (attitude
quaternion and Euler angles, body rate, tracker latency ± 1σ, clock, mode, flags, gyro status,
shared with the web page: :func:`monitors.view.current_lines`); a stale-data alarm when no packet
of the vehicle arrived for ``stale_s`` seconds.

The parameter columns are at least :data:`monitors.view.CELL_WIDTH` wide from the start and widen
on wider values, so a dashboard started before any data arrives lays out as one started after.

The app only reads a :class:`~monitors.live.LatestStore` on a timer (``refresh_s``); who fills
the store is injected: :class:`~monitors.live.ZenohSource` for live traffic, or anything that
calls ``store.put`` (tests, archive replays). Keys: ``v`` next vehicle, ``q`` quit.
"""

from __future__ import annotations

from typing import Any

from rich.table import Table
from rich.text import Text
from textual.app import App, ComposeResult
from textual.containers import Horizontal, Vertical
from textual.css.query import NoMatches
from textual.widgets import DataTable, Footer, Header, Static

from monitors.common import excitation_text, flag_label
from monitors.live import TOPICS, LatestStore, pick_vehicle
from monitors.view import (
    CELL_WIDTH,
    STALE_S,
    clock_lines,
    column_names,
    counter_lines,
    current_lines,
    fault_line,
    gyro_status,
    n_gyro,
    param_rows,
    residual_lines,
)

GYRO_ROW = "gyro status"

BENIGN = {"NOT_CONVERGED"}


def _kv_table(title: str, rows: list[tuple[str, str]]) -> Table:
    t = Table(title=title, title_justify="left", show_header=False, box=None, pad_edge=False,
              expand=True)
    t.add_column(style="bold cyan", no_wrap=True)
    t.add_column()
    for k, v in rows:  # Text: "[deg]" and the like are units, not rich markup
        t.add_row(Text(k), Text(v))
    return t


class MonitorApp(App):
    """The dashboard. ``store``: the data; ``vehicle``: shown vehicle (None: first seen);
    ``source``: optional object with ``close()`` (closed on exit); ``refresh_s``: pull period
    [s]; ``stale_s``: seconds without any packet before the stale-data alarm."""

    TITLE = "RADICAL-RT monitor"
    CSS = """
    #status { height: 3; padding: 0 1; background: $boost; }
    #top { height: 1fr; }
    #left { width: 1fr; height: auto; }
    #right { width: 64; height: auto; }
    #params { height: auto; max-height: 14; }
    #packets { height: auto; max-height: 9; }
    #clock, #current, #residuals, #counters, #faults { padding: 0 1; height: auto; margin-top: 1; }
    """
    BINDINGS = [("q", "quit", "Quit"), ("v", "next_vehicle", "Next vehicle")]

    def __init__(self, store: LatestStore, vehicle: str | None = None, source: Any = None,
                 refresh_s: float = 0.5, stale_s: float = STALE_S) -> None:
        super().__init__()
        self.store, self.wanted, self.source, self.refresh_s = store, vehicle, source, refresh_s
        self.stale_s = stale_s
        self.vehicle: str | None = vehicle
        self._n_cols = 0
        self.refreshes = 0

    def compose(self) -> ComposeResult:
        yield Header()
        yield Static("waiting for telemetry…", id="status")
        with Horizontal(id="top"):
            with Vertical(id="left"):
                yield DataTable(id="params", show_cursor=False, zebra_stripes=True)
                yield Static(id="current")
                yield Static(id="residuals")
                yield Static(id="faults")
            with Vertical(id="right"):
                yield DataTable(id="packets", show_cursor=False)
                yield Static(id="clock")
                yield Static(id="counters")
        yield Footer()

    def on_mount(self) -> None:
        pk = self.query_one("#packets", DataTable)
        for label, key in (("topic", "topic"), ("count", "count"), ("rate Hz", "rate"),
                           ("age s", "age"), ("bad", "bad")):
            pk.add_column(label, key=key)
        for topic in TOPICS:
            pk.add_row(topic, "0", "-", "-", "0", key=topic)
        self._setup_params(4)
        self.refresh_data()
        self._timer = self.set_interval(self.refresh_s, self.refresh_data)

    def on_unmount(self) -> None:
        if getattr(self, "_timer", None) is not None:
            self._timer.stop()
        if self.source is not None:
            self.source.close()

    def _setup_params(self, n: int) -> None:
        t = self.query_one("#params", DataTable)
        t.clear(columns=True)
        t.add_column("parameter", key="group")
        t.add_column("unit", key="unit")
        for i, name in enumerate(column_names(n)):  # the padded label sets the minimum width
            t.add_column(Text(name.ljust(CELL_WIDTH)), key=f"e{i}")
        for label, unit, _cells in param_rows(None):
            t.add_row(label, unit, *(["—"] * n), key=label)
        t.add_row(GYRO_ROW, "", *(["—"] * n), key=GYRO_ROW)
        self._n_cols = n

    def action_next_vehicle(self) -> None:
        vs = self.store.vehicles()
        if vs:
            i = vs.index(self.vehicle) + 1 if self.vehicle in vs else 0
            self.vehicle = self.wanted = vs[i % len(vs)]
            self.refresh_data()

    # --------------------------------------------------------------------------- refresh (pull)
    def refresh_data(self) -> None:
        try:
            self._refresh()
        except NoMatches:  # the screen is being torn down
            pass

    def _refresh(self) -> None:
        self.refreshes += 1
        if self.vehicle is None:
            self.vehicle = pick_vehicle(self.store, self.wanted)
        v = self.vehicle
        status = self.query_one("#status", Static)
        if v is None:
            status.update(Text("waiting for telemetry (no vehicle seen yet)…", style="yellow"))
            return
        snaps = {t: self.store.latest(v, t) for t in TOPICS}
        large = snaps["tlm/large"].msg or snaps["tlm/medium"].msg
        newest = max((s for s in snaps.values() if s.recv is not None),
                     key=lambda s: s.recv or 0.0, default=None)
        small = snaps["tlm/small"].msg or large or {}
        flags, _src = self.store.last_flags(v)
        names = flag_label(flags)
        alive = self.store.alive(v)
        line = Text()
        line.append(f"vehicle {v}", style="bold")
        line.append(f"  node {'alive' if alive else 'gone' if alive is False else '?'}",
                    style="green" if alive else "red" if alive is False else "dim")
        mode = str(small.get("mode", "?"))
        line.append("  mode ")
        line.append(mode, style={"converged": "bold green", "degraded": "bold red"}.get(mode, "yellow"))
        t_bus = small.get("t")
        line.append(f"  t {t_bus:.2f} s" if isinstance(t_bus, int | float) else "  t ?")
        line.append(f"  seq {small.get('seq', '?')}")
        if newest is not None and newest.age_s is not None:
            stale = newest.age_s > self.stale_s
            line.append(f"  last packet {newest.age_s:.2f} s ago", style="red" if stale else "")
            if stale:
                line.append(f"  STALE DATA (> {self.stale_s:g} s)", style="bold white on red")
        line.append("\nflags ")
        serious = [n for n in names.split(", ") if n not in BENIGN and n not in ("-", "?")]
        line.append(names, style="bold red" if serious else "green")
        ex = excitation_text((snaps["diag"].msg or {}).get("excitation"))
        if ex:
            line.append("\nexcitation ")
            line.append(ex, style="bold yellow" if "NOT EXCITED" in ex else "")
        status.update(line)

        pk = self.query_one("#packets", DataTable)
        for topic, s in snaps.items():
            pk.update_cell(topic, "count", str(s.count))
            pk.update_cell(topic, "rate", f"{s.rate_hz:.1f}" if s.count else "-")
            pk.update_cell(topic, "age", f"{s.age_s:.2f}" if s.age_s is not None else "-")
            pk.update_cell(topic, "bad", str(s.bad))

        n = n_gyro(large)
        if n != self._n_cols:
            self._setup_params(n)
        if large is not None:
            t = self.query_one("#params", DataTable)
            for label, _unit, cells in param_rows(large):
                for i in range(n):
                    t.update_cell(label, f"e{i}", cells[i] if i < len(cells) else "",
                                  update_width=True)
            for i, st in enumerate(gyro_status(large, flags)):
                t.update_cell(GYRO_ROW, f"e{i}", Text(st, style="" if st == "ok" else "bold red"))
        self.query_one("#current", Static).update(
            _kv_table("current values", current_lines(large or small or None, flags)))
        self.query_one("#clock", Static).update(_kv_table("SIRU clock", clock_lines(large)))
        self.query_one("#residuals", Static).update(
            _kv_table("attitude and residuals", residual_lines(large)))
        self.query_one("#counters", Static).update(_kv_table("counters", counter_lines(large)))
        faults = self.store.faults(v)[-6:]
        ft = Text("fault messages (newest last)\n", style="bold")
        for _n, _t, m in faults:
            ft.append(fault_line(m) + "\n")
        if not faults:
            ft.append("none", style="dim")
        self.query_one("#faults", Static).update(ft)


def run_tui(vehicle: str | None, listen: str | None, connect: str | None,
            zenoh_config: str | None = None, refresh_s: float = 0.5,
            stale_s: float = STALE_S, auth: Any = None) -> int:
    from monitors.live import ZenohSource

    store = LatestStore()
    source = ZenohSource(store, vehicle, listen, connect, zenoh_config, auth=auth).start()
    MonitorApp(store, vehicle, source=source, refresh_s=refresh_s, stale_s=stale_s).run()
    return 0
