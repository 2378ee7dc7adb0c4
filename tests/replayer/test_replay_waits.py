"""`radical replay` (replayer.replay) and its node: waiting for the vehicle's filter node (CLI
and API), the one-line errors when there is none or nothing to connect to, and stopping on a
signal with a summary. Real Zenoh sessions on loopback (free ports, multicast scouting off)."""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time

import pytest

from radical_rt.apps.cli import main as cli_main
from radical_rt.io.archive import ArchiveReader
from replayer.publish import replay
from replayer.sessions import ReplayError, wait_for_node
from tests.support.replay_bus import ROOT, VEH, cli, ep, inputs_of, session


@pytest.mark.zenoh
def test_wait_node_times_out_with_clear_error(archives, capsys):
    t0 = time.monotonic()
    rc = cli_main(["replay", str(archives["a"]), "--vehicle", VEH, "--listen", ep(),
                   "--wait-node", "1", "--no-progress"])
    dt = time.monotonic() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1, err
    assert "no filter node" in err[0] and f"radical/{VEH}/alive/filter" in err[0]
    assert "within 1 s" in err[0]
    assert 1.0 <= dt < 5.0


@pytest.mark.zenoh
@pytest.mark.parametrize("wait", [[], ["--wait-node", "1"]])
def test_connect_to_nothing_clear_error(archives, capsys, wait):
    """A tool that only connects is a Zenoh client: with no node at the endpoint it fails at once
    (or after --wait-node) with one line, exit status 1."""
    e = ep()
    t0 = time.monotonic()
    rc = cli_main(["replay", str(archives["a"]), "--vehicle", VEH, "--connect", e, *wait,
                   "--no-progress"])
    dt = time.monotonic() - t0
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 1
    assert len(err) == 1, err
    assert err[0].startswith("radical replay: error: cannot ") and f"connecting to {e}" in err[0]
    assert "radical node --vehicle" in err[0]
    assert dt < (3.0 if not wait else 4.0)
    if wait:
        assert dt >= 0.8 and "within 1 s" in err[0]


@pytest.mark.zenoh
def test_default_requires_a_node_for_the_vehicle(archives, capsys, monkeypatch):
    """Issue #21: a node serving another vehicle is not enough. By default replay waits (here
    1 s instead of 10) for the vehicle's token and fails in one line naming what is served;
    with the right vehicle it proceeds; --no-wait-node skips the check."""
    from replayer import replay as rp

    monkeypatch.setattr(rp, "DEFAULT_WAIT_S", 1.0)
    e = ep()
    with session(listen=e) as node:
        node.declare_subscriber("radical/**", lambda s: None)
        tok = node.liveliness().declare_token("radical/v1/alive/filter")
        args = [str(archives["a"]), "--connect", e, "--fast", "--end", "2", "--no-progress",
                "--linger", "0.2"]
        t0 = time.monotonic()
        rc = cli_main(["replay", *args, "--vehicle", "v2"])
        dt = time.monotonic() - t0
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 1 and len(err) == 1, err
        assert "no filter node for vehicle 'v2'" in err[0] and "serve: v1" in err[0], err
        assert 0.9 <= dt < 6.0
        assert cli_main(["replay", *args, "--vehicle", "v1"]) == 0, capsys.readouterr().err
        assert "alive" in capsys.readouterr().err
        assert cli_main(["replay", *args, "--vehicle", "v2", "--no-wait-node"]) == 0
        tok.undeclare()


@pytest.mark.zenoh
def test_wait_node_proceeds_when_token_appears(archives, capsys):
    """A fake node (token declared 0.7 s late, subscribers on the four inputs): replay waits,
    then publishes everything in the window."""
    e = ep()
    got: list[str] = []
    with session(listen=e) as node:
        for t in ("siru", "st1", "st2", "temp"):
            node.declare_subscriber(f"radical/{VEH}/{t}", lambda s: got.append(str(s.key_expr)))
        box: dict = {}
        timer = threading.Timer(0.7, lambda: box.update(
            tok=node.liveliness().declare_token(f"radical/{VEH}/alive/filter")))
        timer.start()
        t0 = time.monotonic()
        rc = cli_main(["replay", str(archives["a"]), "--vehicle", VEH, "--connect", e,
                       "--wait-node", "15", "--fast", "--end", "5", "--no-progress"])
        dt = time.monotonic() - t0
        time.sleep(0.3)
        timer.join()
        box["tok"].undeclare()
    err = capsys.readouterr().err
    assert rc == 0, err
    t_a = ArchiveReader(archives["a"]).start_ns
    want = sum(map(len, inputs_of(archives["a"], None, t_a + 5 * 10**9).values()))
    assert len(got) == want
    assert dt >= 0.6
    assert "alive" in err and f"replayed {want} messages" in err


@pytest.mark.zenoh
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_cli_signal_stops_replay_with_summary(archives, sig):
    proc = subprocess.Popen(cli("replay", str(archives["a"]), "--vehicle", VEH, "--listen", ep(),
                                "--no-wait-node", "--json"), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=ROOT)
    try:
        time.sleep(2.0)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    res = json.loads(out)
    assert res["stopped"] and 0 < res["messages"] < 1858
    assert "(stopped early)" in err and "t_bus 10" in err  # the progress bar was there


@pytest.mark.zenoh
def test_wait_for_node_api_present_token():
    e = ep()
    with session(listen=e) as node, session(connect=e) as zs:
        tok = node.liveliness().declare_token(f"radical/{VEH}/alive/filter")
        assert wait_for_node(zs, VEH, 10.0) < 10.0
        tok.undeclare()
        with pytest.raises(ReplayError, match="not seen within 0.3 s"):
            wait_for_node(zs, "othercraft", 0.3)


@pytest.mark.zenoh
def test_replay_without_subscribers_raises_when_asked_to_wait(archives):
    with session(listen=ep()) as zs:
        with pytest.raises(ReplayError, match="no subscriber for radical/"):
            replay([archives["a"]], VEH, zs, rate=None, wait_subscribers=0.3)
