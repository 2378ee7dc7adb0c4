"""The terminal dashboard, driven by textual's pilot from an in-memory data source."""

from __future__ import annotations

import asyncio
import io
import math
from pathlib import Path

import pytest

from monitors.common import fmt_est_sigma
from monitors.live import LatestStore
from radical_rt.contract.conventions import DEG_PER_HR, PPM
from radical_rt.contract.flags import Flag
from tests.support.packets import large_packet


@pytest.fixture
def MonitorApp():
    pytest.importorskip("textual", reason="pip install textual (monitor tui)")
    from monitors.tui import MonitorApp

    return MonitorApp


def text_of(widget) -> str:
    """Plain text of a Static widget's content (rich renderables included)."""
    from rich.console import Console

    con = Console(width=200, file=io.StringIO(), record=True, color_system=None)
    con.print(widget.content if hasattr(widget, "content") else widget.render())
    return con.export_text()


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_tui_shows_parameters_flags_rates_and_age(MonitorApp):
    clock = FakeClock()
    store = LatestStore(clock=clock)
    for k in range(10):  # tlm/small at 10 Hz for 1 s
        clock.now = 100.0 + 0.1 * k
        store.put("sc1", "tlm/small", {"v": 1, "seq": k, "t": 1234.0 + 0.1 * k, "flags": 0,
                                       "q_body_from_inertial": [0, 0, 0, 1], "mode": "converging"})
    pkt = large_packet()
    store.put("sc1", "tlm/large", pkt)  # as a decoded dict: the in-memory source
    clock.now = 101.0

    async def go():
        app = MonitorApp(store, vehicle="sc1", refresh_s=0.05)
        async with app.run_test(size=(180, 50)) as pilot:
            await pilot.pause()
            params = app.query_one("#params")
            b_a = params.get_cell("b", "e0")
            assert b_a == fmt_est_sigma("b", 0.5026, 0.0022) == "0.5026 ± 0.00220"
            assert params.get_cell("λ", "e1") == "-261.4 ± 3.40"
            assert params.get_cell("δu", "e3") == "816.9 ± 0.70"
            assert params.get_cell("δa2 (ST2)", "e2") == "-430.20 ± 0.170"
            assert params.get_cell("δa2 (ST2)", "e3") == ""  # only 3 axes
            pk = app.query_one("#packets")
            assert pk.get_cell("tlm/small", "count") == "10"
            assert pk.get_cell("tlm/large", "count") == "1"
            assert pk.get_cell("tlm/large", "age") == "0.10"  # receiver monotonic clock
            assert math.isclose(float(pk.get_cell("tlm/small", "rate")), 10.0, rel_tol=0.15)
            status = text_of(app.query_one("#status"))
            assert "converging" in status and "vehicle sc1" in status and "flags -" in status
            clock_text = text_of(app.query_one("#clock"))
            assert "40.010 ppm" in clock_text and "2.900 ms" in clock_text
            res_text = text_of(app.query_one("#residuals"))
            assert "0.10 0.10 0.50 arcsec" in res_text  # attitude 1σ in arcsec
            assert "parity" in res_text and "NIS 1.90" in res_text
            assert "st1_used" in text_of(app.query_one("#counters"))

            # a fault message with a flag: shown by name in the status line and the fault log
            store.put("sc1", "fault", {"v": 1, "t": 1235.0, "flags": int(Flag.ST2_EDITED),
                                       "set": ["ST2_EDITED"], "cleared": [], "detail": {}})
            clock.now = 101.5
            await pilot.pause(0.2)
            status = text_of(app.query_one("#status"))
            assert "ST2_EDITED" in status
            assert "set: ST2_EDITED" in text_of(app.query_one("#faults"))

            # a new packet updates the table in place
            pkt2 = large_packet(seq=8, t=1235.5)
            pkt2["est"]["b"][0] = 0.6 * DEG_PER_HR
            store.put("sc1", "tlm/large", pkt2)
            await pilot.pause(0.2)
            assert params.get_cell("b", "e0") == "0.6000 ± 0.00220"
            assert pk.get_cell("tlm/large", "count") == "2"
            await pilot.press("q")

    asyncio.run(go())


def test_tui_waits_then_picks_first_vehicle(MonitorApp):
    store = LatestStore()

    async def go():
        app = MonitorApp(store, vehicle=None, refresh_s=0.05)
        async with app.run_test(size=(160, 48)) as pilot:
            await pilot.pause()
            assert "waiting" in text_of(app.query_one("#status"))
            store.put("zz9", "tlm/large", large_packet(flags=int(Flag.PARITY_ALARM)))
            await pilot.pause(0.2)
            assert app.vehicle == "zz9"
            assert "PARITY_ALARM" in text_of(app.query_one("#status"))
            assert app.query_one("#params").get_cell("μ", "e0") == "-17.7 ± 3.20"

    asyncio.run(go())


def rendered_lines(widget) -> list[str]:
    """The text of every line a widget renders on screen now (what the operator sees)."""
    return ["".join(seg.text for seg in widget.render_line(y)) for y in range(widget.size.height)]


def test_tui_started_before_data_renders_full_values_and_survives_resize(MonitorApp):
    """The natural order: the dashboard is up before the node publishes. The parameter table's
    columns must not stay sized for the "—" placeholders (issue #21: `λ ppm -183. -389. -1004 6`);
    cold-start values (4-digit estimates, 3-digit σ) render whole, before and after a resize."""
    clock = FakeClock()
    store = LatestStore(clock=clock)
    pkt = large_packet(flags=int(Flag.GYRO_C_FAILED | Flag.NOT_CONVERGED))
    pkt["mode"] = "converging"
    pkt["est"]["lam"] = [-183.2 * PPM, -389.5 * PPM, -1004.6 * PPM, 6.0 * PPM]
    pkt["sigma"]["lam"] = [350.0 * PPM] * 4
    pkt["est"]["b"][1] = -123.4567 * DEG_PER_HR
    pkt["sigma"]["b"] = [999.0 * DEG_PER_HR] * 4
    pkt["excluded"] = [3]
    want = ["-183.2 ± 350.00", "-389.5 ± 350.00", "-1004.6 ± 350.00", "6.0 ± 350.00",
            "-123.4567 ± 999.00000", "816.9 ± 0.70"]

    async def go():
        app = MonitorApp(store, vehicle="sc1", refresh_s=0.05, stale_s=2.0)
        async with app.run_test(size=(200, 50)) as pilot:
            await pilot.pause(0.2)  # several refreshes with no data: the table is laid out
            params = app.query_one("#params")
            assert params.get_cell("λ", "e0") == "—"
            store.put("sc1", "tlm/large", pkt)
            for _ in range(50):  # wait for the refresh timer to show the packet
                await pilot.pause(0.05)
                if params.get_cell("λ", "e2") != "—":
                    break
            screen = "\n".join(rendered_lines(params))
            for w in want:
                assert w in screen, f"{w!r} truncated or missing in:\n{screen}"
            gyro_row = next(line for line in rendered_lines(params) if "gyro status" in line)
            assert "FAILED" in gyro_row and "excluded" in gyro_row
            current = text_of(app.query_one("#current"))
            assert "tracker latency ± 1σ [ms]" in current and "117.00 ± 2.10" in current
            assert "Euler 3-2-1 yaw pitch roll [deg]" in current  # units shown, not eaten as markup
            assert "C FAILED" in current and "D excluded" in current
            assert "+0.000000 +0.000000 +0.000000 +1.000000" in current
            assert "+0.0573" in current  # ω_y = 1 mrad/s in deg/s
            await pilot.resize_terminal(230, 50)
            await pilot.pause(0.2)
            screen = "\n".join(rendered_lines(params))
            for w in want:
                assert w in screen, f"after resize: {w!r} truncated or missing in:\n{screen}"
            assert "STALE" not in text_of(app.query_one("#status"))
            artifacts = Path(__file__).parents[1] / "artifacts"
            artifacts.mkdir(exist_ok=True)
            if not (artifacts / ".gitignore").exists():  # keep screenshots out of git
                (artifacts / ".gitignore").write_text("*\n")
            app.save_screenshot(filename="monitor_tui.svg", path=str(artifacts))
            clock.now += 3.0  # no packet for 3 s of the receiver clock > stale_s = 2
            await pilot.pause(0.2)
            assert "STALE DATA" in text_of(app.query_one("#status"))

    asyncio.run(go())
