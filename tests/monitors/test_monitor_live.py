"""Monitors' live-data layer: latest-value store, the web hub, the Zenoh feeder on loopback, the
CLI's option checks, and the rule that monitors import only contract-level modules."""

from __future__ import annotations

import ast
import math
import time
from pathlib import Path

import msgpack
import pytest

from monitors.cli import run as cli_run
from monitors.live import LatestStore, ZenohSource, pick_vehicle
from radical_rt.contract.conventions import ARCSEC, DEG_PER_HR
from radical_rt.contract.flags import Flag
from radical_rt.io import zconfig
from tests.support.packets import large_packet

# radical_rt.io.outpaths: the one output-path policy of every command (argparse types, no engine)
ROOT = Path(__file__).resolve().parents[2]
ALLOWED_RADICAL = {"radical_rt.contract.conventions", "radical_rt.contract.paper_table",
                   "radical_rt.contract.flags", "radical_rt.io.zconfig", "radical_rt.io.outpaths",
                   "radical_rt.io.zauth",  # session security profiles (--auth), like zconfig
                   "radical_rt.io.archive", "radical_rt.contract.schemas",
                   "radical_rt", "radical_rt.__version__"}  # the package itself: its version
ALLOWED_REPLAYER: set[str] = set()  # the archive layer is radical_rt.io.archive


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_monitors_import_only_contract_modules():
    for path in sorted((ROOT / "monitors").glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                package = (ROOT / node.module.replace(".", "/")).is_dir()
                names = ([f"{node.module}.{a.name}" for a in node.names] if package
                         else [node.module])  # from a package: its modules are what is imported
            for n in names:
                if n.startswith("radical_rt"):
                    assert n in ALLOWED_RADICAL, (path, n)
                if n.startswith("replayer"):
                    assert n in ALLOWED_REPLAYER, (path, n)


def test_latest_store_keeps_only_the_newest_and_measures_on_receiver_clock():
    clk = Clock()
    s = LatestStore(clock=clk, rate_window_s=2.0, fault_keep=3)
    assert s.latest("v1", "tlm/large").msg is None and s.vehicles() == []
    for k in range(21):  # 10 Hz for 2 s, raw msgpack like Zenoh delivers
        clk.now = 10.0 + 0.1 * k
        s.put("v1", "tlm/small", msgpack.packb({"seq": k, "t": 5000.0 + k, "flags": 0}))
    clk.now = 12.5
    snap = s.latest("v1", "tlm/small")
    assert snap.msg["seq"] == 20 and snap.count == 21  # older ones are gone
    assert snap.age_s == pytest.approx(0.5)  # 12.5 − 12.0, not bus time 5020
    assert snap.rate_hz == pytest.approx(7.5, rel=0.1)  # 15 in the last 2 s
    s.put("v1", "tlm/large", b"\xc1not msgpack")
    assert s.latest("v1", "tlm/large").msg is None and s.latest("v1", "tlm/large").bad == 1
    for k in range(5):
        s.put("v1", "fault", {"t": float(k), "flags": 1 << k, "set": [], "cleared": []})
    held = s.faults("v1")
    assert [n for n, _t, _m in held] == [3, 4, 5]  # bounded history
    assert [n for n, _t, _m in s.faults("v1", after=4)] == [5]
    clk.now = 13.0
    s.put("v1", "tlm/small", {"seq": 99, "flags": int(Flag.GYRO_GAP)})
    assert s.last_flags("v1") == (int(Flag.GYRO_GAP), "tlm/small")
    s.set_alive("v2", True)
    assert s.vehicles() == ["v1", "v2"] and pick_vehicle(s, None) == "v2"
    assert pick_vehicle(s, "v1") == "v1"


def test_hub_rows_rollover_and_flags():
    pytest.importorskip("bokeh")
    from monitors.web import Hub

    clk = Clock()
    s = LatestStore(clock=clk)
    hub = Hub(s, keep=5)
    for k in range(8):
        s.put("v", "tlm/large", large_packet(seq=k, t=100.0 + k,
                                             flags=int(Flag.NOT_CONVERGED) if k < 4 else 0))
        hub.poll()
        hub.poll()  # idempotent
    rows, total = hub.rows_since("v", 0)
    assert total == 8 and len(rows) == 5 and rows[-1]["t"] == 107.0  # rollover keeps 5
    assert rows[-1]["b0"] == pytest.approx(0.5026)  # deg/hr
    assert rows[-1]["att_z"] == pytest.approx(0.5)  # arcsec
    assert rows[-1]["st1_x"] == pytest.approx(1e-6 / ARCSEC)
    assert rows[-1]["st1_x_sn"] == pytest.approx(-2e-5 / ARCSEC)
    assert math.isnan(rows[-1]["st2_x"])  # no st2 residual in the packet
    assert rows[-1]["clk_tag_ms"] == pytest.approx(2.9)
    assert hub.rows_since("v", 8) == ([], 8)
    assert len(hub.rows_since("v", 6)[0]) == 2
    fl, n = hub.flags_since("v", 0)
    assert n == 4 and {f[1] for f in fl} == {"NOT_CONVERGED"}
    s.put("v", "fault", {"t": 107.5, "flags": int(Flag.PARITY_ALARM | Flag.GYRO_B_FAILED),
                         "set": ["PARITY_ALARM", "GYRO_B_FAILED"], "cleared": []})
    hub.poll()
    fl, n = hub.flags_since("v", 4)
    assert n == 6 and sorted(f[1] for f in fl) == ["GYRO_B_FAILED", "PARITY_ALARM"]
    assert all(f[2] == "fault" for f in fl)


def test_hub_keeps_every_packet_between_polls():
    """Issue #21: the history kept only the newest packet per poll. 50 packets arriving between
    two polls (a loaded UI) all become rows, in order; the store's ring bounds the backlog."""
    pytest.importorskip("bokeh")
    from monitors.web import Hub

    s = LatestStore(clock=Clock(), history_keep=40)
    hub = Hub(s, keep=1000)
    for k in range(10):
        s.put("v", "tlm/large", msgpack.packb(large_packet(seq=k, t=100.0 + k)))
    hub.poll()
    for k in range(10, 60):  # 50 more before the next poll
        s.put("v", "tlm/large", msgpack.packb(large_packet(seq=k, t=100.0 + k)))
    hub.poll()
    rows, total = hub.rows_since("v", 0)
    # all 10 of the first poll, then the 40 of the next 50 still in the store's ring of 40
    assert total == 50 and [r["t"] for r in rows] == [100.0 + k for k in [*range(10),
                                                                          *range(20, 60)]]
    assert [n for n, _m in s.since("v", "tlm/large", 59)] == [60]  # numbered 1.. on arrival
    hub.poll()
    assert hub.rows_since("v", 50) == ([], 50)  # nothing new, nothing repeated


def test_hub_draws_overlapping_streams_apart():
    """Issue #21: two streams whose bus times overlap (both start at 0) are drawn one after the
    other on one axis, by the packets' ``stream`` field or, without it, at the backwards step;
    a fault message lands on its own stream's segment."""
    pytest.importorskip("bokeh")
    from monitors.view import StreamAxis
    from monitors.web import Hub

    for tagged in (True, False):
        s = LatestStore(clock=Clock(), history_keep=100)
        hub = Hub(s, keep=100)
        for k, (stream, t) in enumerate([(0, 0.0), (0, 10.0), (0, 20.0), (1, 5.0), (1, 15.0)]):
            m = large_packet(seq=k, t=t)
            if tagged:
                m["stream"] = stream
            s.put("v", "tlm/large", msgpack.packb(m))
        s.put("v", "fault", {"t": 6.0, "flags": int(Flag.PARITY_ALARM), "set": ["PARITY_ALARM"],
                             "cleared": [], **({"stream": 1} if tagged else {})})
        hub.poll()
        xs = [r["t"] for r in hub.rows_since("v", 0)[0]]
        assert xs == [0.0, 10.0, 20.0, 50.0, 60.0], (tagged, xs)  # 20 + 30 s pad, then +10
        fl, _n = hub.flags_since("v", 0)
        assert [f[0] for f in fl if f[2] == "fault"] == [51.0], (tagged, fl)
    ax = StreamAxis(pad_s=5.0)  # a stream seen again keeps its segment; NaN leaves no trace
    assert [ax.x(t, k) for t, k in [(100.0, 0), (3.0, 1), (math.nan, 1), (4.0, 1)]] == [
        100.0, 105.0, pytest.approx(math.nan, nan_ok=True), 106.0]
    assert ax.at(101.0, 0) == 101.0 and ax.at(101.0, 7) == 203.0


def test_web_nis_plot_with_chi2_bounds():
    """Issue #21: the live page plots each residual kind's NIS with its 95 % χ² bounds (dof 3 per
    tracker, the parity residual's dimension for parity); a missing NIS stays NaN."""
    pytest.importorskip("bokeh")
    from bokeh.document import Document
    from bokeh.models import Span
    from scipy.stats import chi2

    from monitors.view import tlm_row, tlm_shape
    from monitors.web import Hub, make_document_factory

    pkt = large_packet(seq=1, t=100.0)
    row = tlm_row(pkt, tlm_shape(pkt))
    assert (row["st1_nis"], row["par_nis"]) == (2.3, 1.9) and math.isnan(row["st2_nis"])
    clk = Clock()
    s = LatestStore(clock=clk)
    doc = Document()
    make_document_factory(Hub(s), "v", 250, stale_s=2.0)(doc)
    (cb,) = list(doc.session_callbacks)
    for k in range(3):
        s.put("v", "tlm/large", large_packet(seq=k, t=100.0 + k))
        clk.now += 0.3
        cb.callback()
    fig = doc.get_model_by_name("nis")
    spans = {sp.name: [] for sp in fig.center if isinstance(sp, Span)}
    for sp in fig.center:
        if isinstance(sp, Span):
            spans[sp.name].append(sp.location)
    lo3, hi3 = chi2.ppf(0.025, 3), chi2.ppf(0.975, 3)
    assert sorted(spans["chi2_st1"]) == pytest.approx([lo3, hi3]) == sorted(spans["chi2_st2"])
    assert sorted(spans["chi2_par"]) == pytest.approx([chi2.ppf(0.025, 1), chi2.ppf(0.975, 1)])
    assert list(doc.get_model_by_name("tlm").data["st1_nis"]) == [2.3, 2.3, 2.3]


def test_robust_range_clips_the_transient_and_current_values_table():
    pytest.importorskip("bokeh")
    import numpy as np

    from monitors.web import current_html, stale_html
    from monitors.web_figs import robust_range

    rng = np.random.default_rng(1)
    converged = rng.normal(0.0, 2.0, 290)  # arcsec
    transient = np.linspace(-3000.0, 3000.0, 10)  # the first packets of a cold start
    lo, hi = robust_range(np.concatenate([transient, converged]))
    assert -15.0 < lo < -3.0 and 3.0 < hi < 15.0  # the converged residuals fill the plot
    assert robust_range(np.array([math.nan, math.nan])) is None
    lo, hi = robust_range(np.full(5, 7.0))
    assert lo < 7.0 < hi  # a flat line still gets a span

    pkt = large_packet(flags=int(Flag.GYRO_B_FAILED))
    pkt["latency"] = {"estimate_s": 0.117, "sigma_s": 0.0021}
    pkt["excluded"] = [2]
    page = current_html(pkt, int(Flag.GYRO_B_FAILED))
    for want in ("q body←inertial [x y z w]", "+0.000000 +0.000000 +0.000000 +1.000000",
                 "Euler 3-2-1 yaw pitch roll [deg]", "rate ω body x y z [deg/s]",
                 "117.00 ± 2.10", "reconstruct, locked, +40.010 ppm", "GYRO_B_FAILED",
                 "B FAILED", "C excluded", "λ [ppm]", "-261.4 ± 3.40", "δa2 (ST2) [arcsec]",
                 "b [deg/hr]", "0.5026 ± 0.00220", "✗ FAILED", "✗ excluded"):
        assert want in page, want
    assert "stream" not in page  # no stream field: no row
    pkt["stream"] = 2
    assert "<th style='text-align:left;padding-right:8px'>stream</th><td>2</td>" in current_html(
        pkt, None)
    assert current_html(None, None).startswith("<i>no tlm")
    assert stale_html(None, 5.0) == "" and stale_html(4.9, 5.0) == ""
    assert "STALE DATA: no packet for 7 s" in stale_html(7.0, 5.0)


def test_web_document_robust_axes_zoom_hold_and_stale_alarm():
    """The page's server side without a browser: the document's periodic callback driven by hand,
    the receiver clock faked. The cold-start transient (3000″ on the ST2 boresight) does not set
    the boresight axis; an operator's zoom is held until reset; the stale alarm follows the
    receiver clock."""
    pytest.importorskip("bokeh")
    from bokeh.document import Document

    from monitors.web import Hub, make_document_factory

    clk = Clock()
    s = LatestStore(clock=clk)
    doc = Document()
    make_document_factory(Hub(s), "v", 250, stale_s=2.0)(doc)
    (cb,) = list(doc.session_callbacks)
    pump = cb.callback

    def put(k: int, bs: float) -> None:
        pkt = large_packet(seq=k, t=100.0 + k)
        pkt["residuals"]["st2"] = {"innov": [1e-6, 1e-6, bs], "sigma": [2e-5, 2e-5, 1.9e-4],
                                   "nis": 1.0, "nis_mean": 1.0}
        s.put("v", "tlm/large", pkt)

    for k in range(200):  # 3 transient packets, then converged ones
        put(k, 0.0145 if k < 3 else 1e-5 * ((k % 5) - 2))
        clk.now += 0.2
        pump()
    rng = doc.get_model_by_name("res_st2_bs").y_range
    assert -200.0 < rng.start < -30.0 and 30.0 < rng.end < 200.0  # σ ≈ 39″, not ±3000″
    src = doc.get_model_by_name("tlm")
    assert len(src.data["t"]) == 200 and max(src.data["st2_z"]) > 2900.0  # data kept whole
    assert doc.get_model_by_name("stale").text == ""
    assert "117.00 ± 2.10" in doc.get_model_by_name("current").text

    rng.start, rng.end = -5000.0, 5000.0  # the operator zooms out to see the transient
    for k in range(200, 220):
        put(k, 3e-4)  # new values that would move the automatic range
        pump()
    assert (rng.start, rng.end) == (-5000.0, 5000.0)  # held
    rng.start, rng.end = rng.reset_start, rng.reset_end  # what the reset tool does
    for _ in range(8):
        pump()
    assert (rng.start, rng.end) != (-5000.0, 5000.0) and rng.end < 200.0  # automatic again
    moved = rng.end

    clk.now += 3.0  # no packet for 3 s of the receiver clock > stale_s = 2
    for _ in range(4):  # one second of ticks at 250 ms
        pump()
    assert "STALE DATA: no packet for 3 s" in doc.get_model_by_name("stale").text
    put(300, 1e-5)
    for _ in range(4):
        pump()
    assert doc.get_model_by_name("stale").text == ""  # cleared by the next packet
    assert rng.end == pytest.approx(moved, rel=0.5)


@pytest.mark.zenoh
@pytest.mark.timeout(60)
def test_zenoh_source_on_loopback():
    import zenoh

    ep = f"tcp/127.0.0.1:{zconfig.free_port()}"
    pub = zenoh.open(zconfig.make_config("peer", listen=[ep]))
    store = LatestStore()
    src = ZenohSource(store, vehicle=None, connect=ep).start()
    try:
        token = pub.liveliness().declare_token("radical/sc9/alive/filter")
        pkt = large_packet(seq=3)
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and store.latest("sc9", "tlm/large").msg is None:
            pub.put("radical/sc9/tlm/large", msgpack.packb(pkt))
            pub.put("radical/sc9/siru", b"ignored: not a monitor topic")
            time.sleep(0.1)
        snap = store.latest("sc9", "tlm/large")
        assert snap.msg is not None and snap.msg["seq"] == 3
        assert snap.msg["est"]["b"][0] == pytest.approx(0.5026 * DEG_PER_HR)
        assert store.latest("sc9", "siru").count == 0
        t0 = time.monotonic()
        while store.alive("sc9") is not True and time.monotonic() - t0 < 10:
            time.sleep(0.05)
        assert store.alive("sc9") is True
        token.undeclare()
        t0 = time.monotonic()
        while store.alive("sc9") is not False and time.monotonic() - t0 < 10:
            time.sleep(0.05)
        assert store.alive("sc9") is False
    finally:
        src.close()
        pub.close()
    with pytest.raises(ValueError):
        ZenohSource(store, vehicle="Bad Name")


def test_monitor_cli_rejects_bad_options(capsys):
    import argparse

    from monitors.cli import add_arguments

    p = argparse.ArgumentParser()
    add_arguments(p)
    for argv, text in ((["web", "--vehicle", "BAD!"], "--vehicle"),
                       (["tui", "--connect", "tcp/10.0.0.1:7448"], "not a loopback"),
                       (["web", "--port", "0"], "--port"),
                       (["web", "--period-ms", "1000"], "≥ 2 Hz"),
                       (["web", "--stale-s", "0"], "--stale-s must be > 0"),
                       (["tui", "--stale-s", "-1"], "--stale-s must be > 0"),
                       ([], "choose a dashboard")):
        assert cli_run(p.parse_args(argv)) == 2
        assert text in capsys.readouterr().err
