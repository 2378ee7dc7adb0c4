"""The web monitor's fleet page, ``/fleet``: one row per vehicle seen on the bus (issue #19).

Columns: vehicle, the worker serving it (``diag.node.fleet.worker``; "-" outside a fleet), the
node's liveliness, mode, flags, converged, estimate time, input lag (receiver-clock age of the
vehicle's newest message) and the last takeover (source, loss). Everything comes from what the
dashboard already receives (``radical/*/{tlm/*,fault,diag}`` and the tokens), so the page needs
no extra key and works for a single node as for a fleet.
"""

from __future__ import annotations

import html
from typing import Any

from monitors.common import flag_label
from monitors.live import TOPICS, LatestStore

BENIGN = {"NOT_CONVERGED"}


def fleet_rows(store: LatestStore) -> list[dict[str, Any]]:
    """One row per vehicle (sorted by name)."""
    rows = []
    for v in store.vehicles():
        snaps = {t: store.latest(v, t) for t in TOPICS}
        tlm = snaps["tlm/small"].msg or snaps["tlm/medium"].msg or snaps["tlm/large"].msg or {}
        node = (snaps["diag"].msg or {}).get("node") or {}
        fleet = node.get("fleet") or {}
        ages = [s.age_s for s in snaps.values() if s.age_s is not None]
        flags = store.last_flags(v)[0]
        mode = tlm.get("mode")
        rows.append({
            "vehicle": v, "worker": fleet.get("worker") or "-", "alive": store.alive(v),
            "mode": mode or "?", "flags": flag_label(flags), "converged": mode == "converged",
            "t": tlm.get("t"), "lag_s": min(ages) if ages else None,
            "taken": fleet.get("source") or "-",
            "lost_s": fleet.get("lost_s") if fleet.get("loss_flagged") else None})
    return rows


def _fmt(x: Any, spec: str) -> str:
    return "-" if not isinstance(x, int | float) else format(x, spec)


def fleet_html(rows: list[dict[str, Any]]) -> str:
    """The rows as an HTML table (serious flags in red, a dead node in red)."""
    head = ("<tr><th>vehicle</th><th>worker</th><th>node</th><th>mode</th><th>converged</th>"
            "<th>flags</th><th>t s</th><th>lag s</th><th>taken</th><th>lost s</th></tr>")
    body = []
    for r in rows:
        serious = [n for n in r["flags"].split(", ") if n not in BENIGN and n not in ("-", "?")]
        alive = r["alive"]
        node = ("<span style='color:green'>alive</span>" if alive else
                "<span style='color:red'>gone</span>" if alive is False else "?")
        body.append(
            f"<tr><td><b>{html.escape(r['vehicle'])}</b></td><td>{html.escape(r['worker'])}</td>"
            f"<td>{node}</td><td>{html.escape(str(r['mode']))}</td>"
            f"<td>{'yes' if r['converged'] else 'no'}</td>"
            f"<td style='color:{'#c00' if serious else 'green'}'>{html.escape(r['flags'])}</td>"
            f"<td>{_fmt(r['t'], '.1f')}</td><td>{_fmt(r['lag_s'], '.2f')}</td>"
            f"<td>{html.escape(r['taken'])}</td><td>{_fmt(r['lost_s'], '.1f')}</td></tr>")
    return (f"<div style='font-size:13px'><b>fleet</b>: {len(rows)} vehicle(s)</div>"
            "<table style='font-size:12px' cellpadding='3'>" + head + "".join(body) + "</table>")


def make_fleet_document_factory(hub: Any, period_ms: int = 1000):
    """The Bokeh app function of ``/fleet`` (one Div named ``fleet``, refreshed about 1 Hz)."""

    def make_doc(doc: Any) -> None:
        from bokeh.models import Div  # type: ignore[attr-defined]

        div = Div(text="waiting for telemetry…", name="fleet", sizing_mode="stretch_width")
        doc.add_root(div)
        doc.title = "RADICAL-RT fleet"

        def update() -> None:
            hub.poll()
            text = fleet_html(fleet_rows(hub.store))
            if div.text != text:
                div.text = text

        update()
        doc.add_periodic_callback(update, max(period_ms, 500))

    return make_doc
