"""The web monitor's fleet page (monitors/web_fleet.py): one row per vehicle, from the packets
the dashboard already receives."""

from __future__ import annotations

import msgpack

from monitors.live import LatestStore
from monitors.web_fleet import fleet_html, fleet_rows


def _put(store: LatestStore, v: str, topic: str, msg: dict, now: float) -> None:
    store.put(v, topic, msgpack.packb(msg, use_bin_type=True), now=now)


def test_rows_show_worker_mode_lag_and_a_flagged_takeover():
    s = LatestStore()
    _put(s, "sat-1", "tlm/small", {"seq": 1, "t": 50.0, "flags": 0, "mode": "converged"}, 10.0)
    _put(s, "sat-1", "diag", {"t": 50.0, "node": {"fleet": {
        "worker": "vm-12-ab", "source": "replica", "lost_s": 4.2, "loss_flagged": True}}}, 10.0)
    _put(s, "sat-2", "tlm/small", {"seq": 9, "t": 70.0, "flags": 1 << 5, "mode": "converging"},
         11.0)
    _put(s, "sat-2", "diag", {"t": 70.0, "node": {"fleet": None}}, 11.0)
    s.set_alive("sat-1", True)
    rows = fleet_rows(s)
    assert [r["vehicle"] for r in rows] == ["sat-1", "sat-2"]
    r1, r2 = rows
    assert (r1["worker"], r1["mode"], r1["converged"], r1["taken"], r1["lost_s"]) == \
        ("vm-12-ab", "converged", True, "replica", 4.2)
    assert (r2["worker"], r2["converged"], r2["lost_s"], r2["alive"]) == ("-", False, None, None)
    assert "ST1_EDITED" in r2["flags"] and r1["lag_s"] is not None and r1["lag_s"] >= 0
    page = fleet_html(rows)
    assert "2 vehicle(s)" in page and "vm-12-ab" in page and "4.2" in page
    assert page.count("<tr>") == 3 and "color:#c00'>ST1_EDITED" in page
