"""Every command of CONTRACT §3.2 over the in-memory transport: valid ones act, invalid ones change
nothing, all are applied in the filter loop between filter steps."""

from __future__ import annotations

import math
import threading

import msgpack
import numpy as np
import pytest

from radical_rt.apps import commands
from radical_rt.contract.flags import Flag
from radical_rt.io.checkpoint import read
from tests.support.node import MemNode, feed_archive, input_messages


@pytest.fixture(scope="module")
def all_msgs(archives):  # noqa: F811
    return input_messages(archives["a60"])


@pytest.fixture(scope="module")
def warm_msgs(all_msgs):
    return [m for m in all_msgs if m[1] < 1020e9]  # 20 s: attitude initialized, converging


@pytest.fixture()
def mn(warm_msgs):
    node = MemNode()
    feed_archive(node, "v1", warm_msgs)
    assert node.sp().engine.att_valid
    yield node
    node.close()


def assert_unchanged(mn, request, match):
    before = mn.state()
    reply = mn.cmd(**request)
    assert reply["ok"] is False, reply
    assert match in reply["error"], reply["error"]
    assert mn.state() == before, f"{request} changed the state"
    return reply


# ------------------------------------------------------------------------------ malformed requests
@pytest.mark.parametrize("payload, match", [
    (b"\xc1", "not valid msgpack"),
    (msgpack.packb([1, 2]), "must be a msgpack map"),
    (msgpack.packb({"x": 1}), "needs a string 'cmd'"),
    (msgpack.packb({"cmd": 5}), "needs a string 'cmd'"),
    (msgpack.packb({"cmd": "fly"}), "unknown command 'fly'"),
    (b"", "not valid msgpack"),
])
def test_malformed_requests(mn, payload, match):
    before = mn.state()
    [raw] = mn.client.get("radical/v1/cmd", payload)
    reply = msgpack.unpackb(raw)
    assert reply["ok"] is False and match in reply["error"], reply
    assert mn.state() == before


def test_unknown_fields_are_errors_and_id_is_echoed(mn):
    assert_unchanged(mn, {"cmd": "cold_start", "force": True}, "unknown field(s) ['force']")
    r = mn.cmd(cmd="status", id="req-7", v=1)
    assert r["ok"] and r["id"] == "req-7"


# ------------------------------------------------------------------------------ each command
def test_status(mn):
    r = mn.cmd(cmd="status")
    e = mn.sp().engine
    assert r["ok"] and r["cmd"] == "status" and r["vehicle"] == "v1"
    assert r["t"] == e.t and r["mode"] == e.mode and r["est"] == e.estimates()
    assert r["flags"] == mn.sp().flags and isinstance(r["flag_names"], list)
    assert r["summary"]["schema"] == "radical.summary/1"
    assert r["node"]["received"] == r["node"]["fed"]
    assert_unchanged(mn, {"cmd": "status", "verbose": 1}, "takes no arguments")


def test_get_params(mn):
    r = mn.cmd(cmd="get_params")
    assert r["params"] == mn.sp().engine.table.as_dict() == r["default"]
    assert_unchanged(mn, {"cmd": "get_params", "which": "x"}, "unknown field")


def test_set_params_and_reset(mn):
    e = mn.sp().engine
    r = mn.cmd(cmd="set_params", params={"st_sigma_cross_arcsec": 4.0, "bump_lam_ppm": [1, 2, 3, 4]})
    assert r["ok"] and r["params"] == {"st_sigma_cross_arcsec": 4.0, "bump_lam_ppm": [1, 2, 3, 4]}
    assert e.table.active.st_sigma_cross_arcsec == 4.0
    assert e.si.st_sigma[0] == pytest.approx(4.0 * math.pi / 648000)  # params_changed() ran
    assert e.table.default.st_sigma_cross_arcsec == 3.2
    r = mn.cmd(cmd="reset_params")
    assert r["ok"] and e.table.active.st_sigma_cross_arcsec == 3.2
    assert e.si.st_sigma[0] == pytest.approx(3.2 * math.pi / 648000)


@pytest.mark.parametrize("params, match", [
    ({"no_such": 1.0}, "unknown parameter 'no_such'"),
    ({"st_sigma_cross_arcsec": "big"}, "expected a number"),
    ({"st_sigma_cross_arcsec": -1.0}, "must be in [0.001, 3600]"),
    ({"st_sigma_cross_arcsec": float("nan")}, "must be finite"),
    ({"bump_lam_ppm": [1, 2, 3]}, "list of 4"),
    ({"bump_mode": "double"}, "must be one of"),
    ({"edit_enabled": 1}, "true/false"),
    ({"parity_window": 2.5}, "integer"),
    ({"st_sigma_cross_arcsec": 4.0, "gate_st_nis": -3}, "gate_st_nis"),  # all-or-nothing
    ({}, "non-empty map"),
    ([1, 2], "non-empty map"),
])
def test_set_params_invalid(mn, params, match):
    assert_unchanged(mn, {"cmd": "set_params", "params": params}, match)


def test_bump_add_and_scale(mn):
    e = mn.sp().engine
    var0 = e.variances()
    s = 1e-7
    r = mn.cmd(cmd="bump", sigma={"b": [s] * 4}, mode="add")
    assert r["ok"] and r["mode"] == "add"
    var1 = e.variances()
    np.testing.assert_allclose(var1[3:7], var0[3:7] + s * s, rtol=1e-9)
    np.testing.assert_allclose(var1[7:], var0[7:], rtol=1e-9)  # other groups untouched
    r = mn.cmd(cmd="bump", sigma={"phi2": [1e-5, 0.0, 2e-5]}, mode="scale")
    var2 = e.variances()
    phi2 = e.layout["phi2"]
    np.testing.assert_allclose(var2[phi2], var1[phi2] + np.array([1e-10, 0.0, 4e-10]), rtol=1e-9)
    r = mn.cmd(cmd="bump", sigma={"lam": [0.0, 0.0, 0.0, 0.0]})  # mode from the table
    assert r["ok"] and r["mode"] == e.table.active.bump_mode


def test_bump_in_paper_units_both_ways(mn):
    """Names with the paper unit (as set_params' bump_* names) in the request and the reply; the
    bare group name is the contract's SI form and bumps exactly the same."""
    from radical_rt.contract.conventions import ARCSEC, DEG_PER_HR, PPM

    e = mn.sp().engine
    var0 = e.variances()
    r = mn.cmd(cmd="bump", sigma={"b_deg_hr": [0.5] * 4, "du_arcsec": [20.0] * 4}, mode="add")
    assert r["ok"], r
    var1 = e.variances()
    b, du = e.layout["b"], e.layout["du"]
    np.testing.assert_allclose(var1[b], var0[b] + (0.5 * DEG_PER_HR) ** 2, rtol=1e-9)
    np.testing.assert_allclose(var1[du], var0[du] + (20.0 * ARCSEC) ** 2, rtol=1e-9)
    assert set(r["sigma"]) == {"b_deg_hr", "lam_ppm", "mu_ppm", "du_arcsec", "dv_arcsec",
                               "phi2_arcsec"}
    np.testing.assert_allclose(r["sigma"]["b_deg_hr"], np.sqrt(var1[b]) / DEG_PER_HR, rtol=1e-12)
    np.testing.assert_allclose(r["sigma"]["lam_ppm"], np.array(e.sigmas()["lam"]) / PPM,
                               rtol=1e-12)  # (the engine's lam states are not the contract's)
    # the same bump in SI under the bare name: the same variances
    mn.cmd(cmd="bump", sigma={"mu_ppm": [3.0] * 4}, mode="add")
    var2 = e.variances()
    mn.cmd(cmd="bump", sigma={"mu": [3.0 * PPM] * 4}, mode="add")
    mu = e.layout["mu"]
    np.testing.assert_allclose(var2[mu] - var1[mu], e.variances()[mu] - var2[mu], rtol=1e-9)


@pytest.mark.parametrize("request_, match", [
    ({"sigma": {"b_deg_hr": [0.1] * 4, "b": [1e-7] * 4}}, "given twice"),
    ({"sigma": {"b_deg_hr": [4000.0] * 4}}, "numbers in [0, 3600] (deg/hr)"),
    ({"sigma": {"phi2_arcsec": [1.0] * 4}}, "list of 3"),
    ({"sigma": {"b_rad_s": [1e-7] * 4}}, "b_deg_hr, lam_ppm"),
    ({"sigma": {"b": [1.0] * 4}}, "(SI)"),
])
def test_bump_paper_units_invalid(mn, request_, match):
    assert_unchanged(mn, {"cmd": "bump", **request_}, match)


@pytest.mark.parametrize("request_, match", [
    ({"sigma": {"bias": [1e-7] * 4}}, "unknown group 'bias'"),
    ({"sigma": {"b": [1e-7] * 3}}, "list of 4"),
    ({"sigma": {"phi2": [1e-7] * 4}}, "list of 3"),
    ({"sigma": {"b": [1e-7, -1e-7, 0, 0]}}, "numbers in [0, "),
    ({"sigma": {"b": [1e-7, float("inf"), 0, 0]}}, "numbers in [0, "),
    ({"sigma": {"b": [True, 0, 0, 0]}}, "numbers in [0, "),
    ({"sigma": {"b": [1e-7] * 4}, "mode": "multiply"}, "mode must be"),
    ({"sigma": {}}, "non-empty map"),
    ({}, "non-empty map"),
    ({"sigma": {"b": [1e-7] * 4, "du": "x"}}, "list of 4"),  # nothing of a half-valid bump
])
def test_bump_invalid(mn, request_, match):
    assert_unchanged(mn, {"cmd": "bump", **request_}, match)


def test_warm_start(mn):
    e = mn.sp().engine
    est, sig = e.estimates(), e.sigmas()
    r = mn.cmd(cmd="warm_start", bump=False)
    assert r["ok"] and r["mode"] == "init" and not e.att_valid
    assert e.estimates() == est and e.sigmas() == sig  # parameters kept, no bump
    r = mn.cmd(cmd="warm_start")
    assert r["ok"] and e.sigmas()["lam"][1] > sig["lam"][1]  # the table's bump
    assert_unchanged(mn, {"cmd": "warm_start", "bump": "yes"}, "true or false")


def test_cold_start(mn):
    e = mn.sp().engine
    r = mn.cmd(cmd="cold_start")
    assert r["ok"] and r["mode"] == "init"
    assert all(v == 0.0 for g in e.estimates().values() for v in g)
    assert_unchanged(mn, {"cmd": "cold_start", "now": 1}, "takes no arguments")


def test_exclude_include_gyro(mn):
    e = mn.sp().engine
    assert mn.cmd(cmd="exclude_gyro", gyro=2)["excluded"] == [2]
    assert e.excluded.tolist() == [False, False, True, False]
    assert mn.cmd(cmd="exclude_gyro", gyro=2)["excluded"] == [2]  # idempotent
    assert_unchanged(mn, {"cmd": "exclude_gyro", "gyro": 0}, "at least 3 gyros")
    for bad in (4, -1, "1", True, 1.0, None):
        assert_unchanged(mn, {"cmd": "exclude_gyro", "gyro": bad}, "integer 0..3")
        assert_unchanged(mn, {"cmd": "include_gyro", "gyro": bad}, "integer 0..3")
    assert_unchanged(mn, {"cmd": "include_gyro"}, "integer 0..3")
    assert mn.cmd(cmd="include_gyro", gyro=2)["excluded"] == []
    assert not e.excluded.any()


def test_excluded_gyro_degrades_the_mode(mn, all_msgs):
    mn.cmd(cmd="exclude_gyro", gyro=1)
    feed_archive(mn, "v1", [m for m in all_msgs if 1020e9 <= m[1] < 1025e9])
    e = mn.sp().engine
    assert e.mode == "degraded" and e.excluded[1]
    assert np.all(np.isfinite(e.xp)) and not e.flags & Flag.NUMERIC
    mn.cmd(cmd="include_gyro", gyro=1)
    feed_archive(mn, "v1", [m for m in all_msgs if 1025e9 <= m[1] < 1027e9])
    assert mn.sp().engine.mode in ("converging", "converged")


def test_set_packets(mn):
    sp = mn.sp()
    seq = sp.packets["small"].seq
    r = mn.cmd(cmd="set_packets", packets={"small": {"period_s": 0.5, "fields": ["seq", "t", "flags"]},
                                          "large": {"decimation": 20}})
    assert r["ok"] and r["packets"]["small"] == {"fields": ["seq", "t", "flags"], "period_s": 0.5,
                                                 "trigger": "sample"}
    assert r["packets"]["large"]["decimation"] == 20
    assert sp.packets["small"].period_s == 0.5 and sp.packets["small"].seq == seq


@pytest.mark.parametrize("packets, match", [
    ({"huge": {"period_s": 1}}, "unknown packet 'huge'"),
    ({"small": {"fields": ["t", "nope"]}}, "unknown field(s) ['nope']"),
    ({"small": {"period_s": 1, "decimation": 2}}, "not both"),
    ({"small": {"period_s": -1}}, "period_s must be a number in"),
    ({"small": {"rate": 1}}, "unknown setting"),
    ({}, "non-empty map"),
])
def test_set_packets_invalid(mn, packets, match):
    assert_unchanged(mn, {"cmd": "set_packets", "packets": packets}, match)


def test_checkpoint_without_path_is_an_error(mn):
    assert_unchanged(mn, {"cmd": "checkpoint"}, "--checkpoint PATH")


def test_checkpoint_command(warm_msgs, tmp_path):
    mn = MemNode(checkpoint_path=str(tmp_path / "n.ckpt"))
    try:
        feed_archive(mn, "v1", warm_msgs[:500])
        r = mn.cmd(cmd="checkpoint")
        assert r["ok"] and r["path"] == str(tmp_path / "n.ckpt")
        doc = read(r["path"])
        assert doc["vehicles"]["v1"]["t"] == mn.sp().engine.t
        assert_unchanged(mn, {"cmd": "checkpoint", "path": "/tmp/x"}, "takes no arguments")
    finally:
        mn.close()


def test_end_stream(mn):
    e = mn.sp().engine
    r = mn.cmd(cmd="end_stream", next="cold")
    assert r["ok"] and r["next"] == "cold" and r["summary"]["t_end"] >= 1019.0
    assert e.mode == "init" and all(v == 0.0 for v in e.estimates()["b"])
    assert_unchanged(mn, {"cmd": "end_stream", "next": "later"}, "next must be")


# ------------------------------------------------------------------------------ loop semantics
def test_commands_are_applied_in_the_filter_loop(mn, monkeypatch):
    threads = []
    real = commands.apply

    def spy(cmd, target):
        threads.append(threading.current_thread().name)
        return real(cmd, target)

    monkeypatch.setattr(commands, "apply", spy)
    mn.cmd(cmd="status")
    mn.cmd(cmd="bump", sigma={"b": [0.0] * 4})
    assert threads == ["radical-filter", "radical-filter"]


def test_timed_out_command_is_never_applied(warm_msgs):
    mn = MemNode(command_timeout_s=0.2)
    try:
        feed_archive(mn, "v1", warm_msgs[:200])
        sp = mn.sp()
        gate, entered = threading.Event(), threading.Event()
        real_feed = sp.feed

        def slow_feed(topic, data):  # stall the filter loop inside a filter step
            entered.set()
            gate.wait(5)
            return real_feed(topic, data)

        sp.feed = slow_feed
        mn.publish("v1", *warm_msgs[200][::2])
        assert entered.wait(5)
        cold = sp.engine.counters["cold_starts"]
        r = mn.cmd(cmd="cold_start")
        assert r["ok"] is False and "did not take the command" in r["error"]
        gate.set()
        sp.feed = real_feed
        mn.idle()
        assert mn.cmd(cmd="status")["ok"]
        assert sp.engine.counters["cold_starts"] == cold  # cancelled, not applied late
    finally:
        mn.close()



def test_checkpoint_keeps_packet_triggers():
    from radical_rt.apps.batch import make_processor
    from radical_rt.io.checkpoint import capture, restore
    from radical_rt.stream.telemetry import parse_packets

    src = make_processor()
    src.packets = parse_packets({"small": {"trigger": "window"}, "large": {"trigger": "sample"}})
    dst = make_processor()
    restore(dst, msgpack.unpackb(msgpack.packb(capture(src), use_bin_type=True), raw=False))
    assert {n: s.trigger for n, s in dst.packets.items()} == {
        "small": "window", "medium": "window", "large": "sample"}
