"""Monitors' live-data layer: latest-value store, the web hub, the Zenoh feeder on loopback, the
CLI's option checks, and the rule that monitors import only contract-level modules."""

from __future__ import annotations

import ast
import math
import time
from pathlib import Path

import msgpack
import pytest
from test_monitor_tui import large_packet

from monitors.cli import run as cli_run
from monitors.live import LatestStore, ZenohSource, pick_vehicle
from radical_rt import zconfig
from radical_rt.conventions import ARCSEC, DEG_PER_HR
from radical_rt.flags import Flag

# radical_rt.outpaths: the one output-path policy of every command (argparse types, no engine)
ALLOWED_RADICAL = {"radical_rt.conventions", "radical_rt.paper_table", "radical_rt.flags",
                   "radical_rt.zconfig", "radical_rt.outpaths", "radical_rt"}
ALLOWED_REPLAYER = {"replayer.archive"}


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_monitors_import_only_contract_modules():
    for path in sorted((Path(__file__).parents[1] / "monitors").glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + ([f"{node.module}.{a.name}" for a in node.names]
                                         if node.module == "radical_rt" else [])
            for n in names:
                if n.startswith("radical_rt"):
                    assert n in ALLOWED_RADICAL or n in {f"radical_rt.{m.split('.')[-1]}"
                                                          for m in ALLOWED_RADICAL}, (path, n)
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
                       ([], "choose a dashboard")):
        assert cli_run(p.parse_args(argv)) == 2
        assert text in capsys.readouterr().err
