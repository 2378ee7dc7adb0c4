"""`radical record` (replayer.record): bus-time extraction, topic mapping (single vehicle and
wildcard), skipped keys, schemas, periodic flushing, clean stops, bad inputs. Round trips with
`radical replay` are in test_replay.py."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import msgpack
import pytest
from mcap.reader import make_reader

from radical_rt.apps.cli import main as cli_main
from radical_rt.contract.schemas import SCHEMAS
from radical_rt.io.archive import ArchiveReader, TruncatedArchiveWarning
from replayer.recorder import RecordError, bus_time_ns, parse_topics, record
from tests.support.replay_bus import ep, session

ROOT = Path(__file__).resolve().parents[2]


def pack(m: dict) -> bytes:
    return msgpack.packb(m, use_bin_type=True)


def wait_matching(pub, timeout: float = 10.0) -> None:
    t_end = time.monotonic() + timeout
    while not pub.matching_status.matching:
        assert time.monotonic() < t_end, "no matching subscriber"
        time.sleep(0.01)


# ------------------------------------------------------------------------------- no Zenoh
@pytest.mark.parametrize("msg, want", [
    ({"v": 1, "t_bus": 1000.25, "q": [0, 0, 0, 1]}, 1000_250_000_000),
    ({"v": 1, "t_bus": [1000.0, 1000.01, 1000.02], "tt": [1, 2, 3]}, 1000_020_000_000),
    ({"v": 1, "seq": 3, "big": {"a": list(range(100))}, "t": 1234.5}, 1234_500_000_000),
    ({"v": 1, "t": 7}, 7_000_000_000),
    ({"v": 1, "x": 1.0}, None),
    ({"v": 1, "t": True}, None),
    ({"v": 1, "t": -1.0}, None),
    ({"v": 1, "t": float("nan")}, None),
    ({"v": 1, "t_bus": []}, None),
    ({"v": 1, "t": "soon"}, None),
])
def test_bus_time_ns(msg, want):
    assert bus_time_ns(pack(msg)) == want


def test_bus_time_ns_not_a_map():
    assert bus_time_ns(pack([1, 2, 3])) is None
    assert bus_time_ns(b"\xc1garbage") is None
    assert bus_time_ns(b"") is None
    assert bus_time_ns(pack({"v": 1, "t": 5.0})[:-3]) is None


def test_parse_topics():
    assert parse_topics(None) is None
    assert parse_topics("siru, /tlm/small,,fault/") == ["siru", "tlm/small", "fault"]
    assert parse_topics(["tlm/*"]) == ["tlm/*"]
    for bad in ("alive/filter", "cmd", "tlm//small", ",", "a b"):
        with pytest.raises(RecordError):
            parse_topics(bad)


@pytest.mark.parametrize("out, needle", [("{tmp}/f/x.mcap", "in the way"),
                                         ("{tmp}", "is a directory")])
def test_cli_bad_output_refused_while_parsing(out, needle, tmp_path, capsys):
    """Output paths follow the one policy of radical_rt.io.outpaths: missing parents are created,
    an impossible path is a usage error before anything runs."""
    (tmp_path / "f").write_text("")
    with pytest.raises(SystemExit) as exc:
        cli_main(["record", "--vehicle", "v1", "-o", out.replace("{tmp}", str(tmp_path))])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "error:" in err[-1] and needle in err[-1] and "Traceback" not in "".join(err), err
    assert not (tmp_path / "x.mcap").exists()


@pytest.mark.parametrize("args, needle", [
    (["--vehicle", "V 1", "-o", "{tmp}/x.mcap"], "must match"),
    (["--vehicle", "v1", "-o", "{tmp}/x.mcap", "--topics", "alive"], "not recorded"),
    (["--vehicle", "v1", "-o", "{tmp}/x.mcap", "--duration", "-1"], "--duration"),
    (["--vehicle", "v1", "-o", "{tmp}/x.mcap", "--connect", "udp/127.0.0.1:7448"], "loopback"),
])
def test_cli_bad_inputs_one_line_exit_2(args, needle, tmp_path, capsys):
    rc = cli_main(["record", *[a.replace("{tmp}", str(tmp_path)) for a in args]])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("radical record: error:") and needle in err[0], err
    assert not (tmp_path / "x.mcap").exists()


# ------------------------------------------------------------------------------- real Zenoh
@pytest.mark.zenoh
def test_wildcard_vehicle_topics_schemas_times_and_skips(tmp_path):
    """--vehicle '*': topics keep the vehicle (/v1/tlm/small) with the contract schema and a
    'vehicle' channel metadata; log_time from t / t_bus (last), else receive time on the bus time
    line; liveliness and cmd keys are skipped."""
    e, out = ep(), tmp_path / "all.mcap"
    stop, ready, box = threading.Event(), threading.Event(), {}
    tlm = {"v": 1, "seq": 1, "t": 1001.5, "q_body_from_inertial": [0, 0, 0, 1], "flags": 0,
           "mode": "init"}
    siru = {"v": 1, "t_bus": [2.0, 2.01], "tt": [1, 2], "dtheta": [[0.0] * 4] * 2,
            "status": [0, 0]}
    with session(listen=e) as rs, session(connect=e) as ps:
        th = threading.Thread(target=lambda: box.update(record(
            out, "*", rs, stop_event=stop, ready_event=ready)))
        th.start()
        assert ready.wait(10)
        tok = ps.liveliness().declare_token("radical/v1/alive/filter")
        p = ps.declare_publisher("radical/v1/tlm/small")
        wait_matching(p)
        p.put(pack(tlm))
        ps.put("radical/v2/siru", pack(siru))
        ps.put("radical/v1/diag", pack({"v": 1, "nis": 0.5}))  # no time
        ps.put("radical/v1/alive/filter", b"x")
        ps.put("radical/v1/cmd", pack({"cmd": "status"}))
        ps.put("radical/v1/cmd/extra", b"y")
        ps.put("other/v1/siru", pack(siru))  # not under radical/
        time.sleep(0.5)
        stop.set()
        th.join(10)
        tok.undeclare()
    res = box
    assert res["counts"] == {"/v1/diag": 1, "/v1/tlm/small": 1, "/v2/siru": 1}
    assert res["skipped"] == 3 and res["dropped"] == 0 and res["time_fallbacks"] == 1
    with ArchiveReader(out) as r:
        msgs = {t: (ts, d) for t, ts, d in r.iter_raw()}
        assert r.schemas["/v1/tlm/small"] == SCHEMAS["/tlm/small"]
        assert r.schemas["/v2/siru"] == SCHEMAS["/siru"]
        assert "/v1/diag" in r.schemas
        assert r.scenario["vehicle"] == "*" and r.scenario["name"] == "record"
    assert msgs["/v1/tlm/small"] == (1001_500_000_000, pack(tlm))
    assert msgs["/v2/siru"] == (2_010_000_000, pack(siru))
    t_diag = msgs["/v1/diag"][0]  # anchored on v1's last bus time + elapsed receive time
    assert 1001_500_000_000 <= t_diag < 1001_500_000_000 + 2 * 10**9
    with open(out, "rb") as f:
        summ = make_reader(f).get_summary()
    chans = {c.topic: c for c in summ.channels.values()}
    assert chans["/v1/tlm/small"].metadata == {"vehicle": "v1"}
    assert chans["/v2/siru"].message_encoding == "msgpack"
    assert summ.schemas[chans["/v1/tlm/small"].schema_id].name == "radical.tlm.small"
    assert {s.name for s in summ.schemas.values()} >= {"radical.tlm.small", "radical.siru",
                                                        "radical.diag"}


@pytest.mark.zenoh
def test_cli_topics_filter_duration_single_vehicle(tmp_path, capsys):
    """--topics tlm/small,fault --duration: only those keys, contract topics (/tlm/small), a
    complete file when the duration ends."""
    e, out = ep(), tmp_path / "tlm.mcap"
    sent = {"tlm/small": [], "fault": [], "diag": [], "siru": []}

    def publisher() -> None:
        with session(connect=e) as ps:
            pubs = {k: ps.declare_publisher(f"radical/v1/{k}") for k in sent}
            wait_matching(pubs["tlm/small"])
            wait_matching(pubs["fault"])
            for i in range(20):
                for k, p in pubs.items():
                    m = pack({"v": 1, "t": 1000.0 + i * 0.1, "k": k})
                    p.put(m)
                    sent[k].append(m)
            ps.put("radical/v2/tlm/small", pack({"v": 1, "t": 5.0}))  # other vehicle
            time.sleep(0.3)

    th = threading.Thread(target=publisher)
    th.start()
    t0 = time.monotonic()
    rc = cli_main(["record", "-o", str(out), "--vehicle", "v1", "--listen", e, "--duration", "3",
                   "--topics", "tlm/small,fault", "--json"])
    dt = time.monotonic() - t0
    th.join(10)
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert 2.9 < dt < 8
    res = json.loads(cap.out)
    assert res["counts"] == {"/fault": 20, "/tlm/small": 20} and res["dropped"] == 0
    assert "recording radical/v1/{tlm/small,fault}" in cap.err
    with warnings.catch_warnings():
        warnings.simplefilter("error", TruncatedArchiveWarning)
        with ArchiveReader(out) as r:
            got = {t: [d for tt, _, d in r.iter_raw() if tt == t] for t in r.topics}
            assert set(r.schemas) == {"/tlm/small", "/fault"}
    assert got == {"/tlm/small": sent["tlm/small"], "/fault": sent["fault"]}


@pytest.mark.zenoh
def test_idle_recorder_flushes_a_readable_prefix(tmp_path):
    """Messages received and then silence: within ~flush_every_s they are on disk, readable from
    a copy of the (unfinished) file."""
    e, out = ep(), tmp_path / "live.mcap"
    stop, ready = threading.Event(), threading.Event()
    with session(listen=e) as rs, session(connect=e) as ps:
        th = threading.Thread(target=lambda: record(out, "v1", rs, stop_event=stop,
                                                    ready_event=ready, flush_every_s=0.3))
        th.start()
        assert ready.wait(10)
        p = ps.declare_publisher("radical/v1/st1")
        wait_matching(p)
        for i in range(30):
            p.put(pack({"v": 1, "t_bus": 1000.0 + i, "q": [0, 0, 0, 1], "n_stars": 9,
                        "valid": True}))
        time.sleep(1.0)
        snap = tmp_path / "snap.mcap"
        shutil.copyfile(out, snap)  # as a SIGKILL would leave it
        stop.set()
        th.join(10)
    with pytest.warns(TruncatedArchiveWarning):
        r = ArchiveReader(snap)
    assert r.message_counts == {"/st1": 30}
    r.close()


@pytest.mark.zenoh
def test_sigint_subprocess_closes_cleanly(tmp_path):
    e, out = ep(), tmp_path / "int.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "radical_rt.apps.cli", "record", "-o", str(out),
                             "--vehicle", "v1", "--listen", e], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        line = proc.stderr.readline()  # printed once the subscribers are declared
        assert "recording radical/v1/**" in line, line
        with session(connect=e) as ps:
            p = ps.declare_publisher("radical/v1/temp")
            wait_matching(p)
            for i in range(5):
                p.put(pack({"v": 1, "t_bus": 1000.0 + i, "siru_C": 20.0}))
            time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
        err = proc.communicate(timeout=20)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "wrote 5 messages (/temp 5)" in err
    with warnings.catch_warnings():
        warnings.simplefilter("error", TruncatedArchiveWarning)
        with ArchiveReader(out) as r:
            assert r.message_counts == {"/temp": 5}
            assert [t for _, t, _ in r.iter_raw()] == [(1000 + i) * 10**9 for i in range(5)]


@pytest.mark.zenoh
def test_connecting_recorder_waits_for_the_endpoint(tmp_path):
    """`radical record --connect EP` started before anything listens at EP: it says it waits,
    connects when EP comes up (a client retrying), and records."""
    e, out = ep(), tmp_path / "late.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "radical_rt.apps.cli", "record", "-o", str(out),
                             "--vehicle", "v1", "--connect", e], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        line = proc.stderr.readline()
        assert "waiting for the endpoint" in line and e in line, line
        with session(listen=e) as node:
            line = proc.stderr.readline()
            assert "recording radical/v1/**" in line, line
            p = node.declare_publisher("radical/v1/tlm/small")
            wait_matching(p)
            p.put(pack({"v": 1, "t": 1000.5}))
            time.sleep(0.3)
            proc.send_signal(signal.SIGTERM)
            err = proc.communicate(timeout=20)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    with ArchiveReader(out) as r:
        assert [(t, ts) for t, ts, _ in r.iter_raw()] == [("/tlm/small", 1000_500_000_000)]
