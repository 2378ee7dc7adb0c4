"""What the operator reads (issue #21 item 4): --version, help without reStructuredText markup,
descriptions for every monitor, one clean line for an invalid endpoint and for a truncated
archive — no traceback, no Rust or Python source location."""

from __future__ import annotations

import re
import subprocess
import sys

import pytest

from radical_rt import __version__
from radical_rt.apps.cli import build_parser, main, plain_text
from radical_rt.io import zconfig
from radical_rt.io.zenoh_transport import _one_line
from replayer.synth.api import synthesize

MARKUP = re.compile(r"``|:[a-z]+:`|\.rs:\d+")
SUBCOMMANDS = [["synth"], ["process"], ["node"], ["replay"], ["record"], ["report"], ["bench"],
               ["export"], ["allan"], ["design"], ["monitor"], ["monitor", "tui"],
               ["monitor", "web"], ["monitor", "foxglove"]]


def _cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "radical_rt.apps.cli", *args], capture_output=True,
                          text=True, timeout=timeout)


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.strip() == f"radical {__version__}"


@pytest.mark.parametrize("argv", SUBCOMMANDS, ids=" ".join)
def test_help_is_plain_text_with_a_description(argv, capsys):
    with pytest.raises(SystemExit):
        main([*argv, "--help"])
    out = capsys.readouterr().out
    assert not MARKUP.search(out), MARKUP.search(out)
    lines = out.split("\n\n")
    assert len(lines) >= 3, "usage, a description and the options"


def test_plain_text_removes_markup():
    assert plain_text("``--cold`` :class:`~radical_rt.stream.processor.StreamProcessor` "
                      ":func:`radical_rt.x.f` text::") == \
        "--cold StreamProcessor radical_rt.x.f text:"


def test_invalid_port_is_one_clean_line():
    with pytest.raises(zconfig.ZenohConfigError, match="port must be 1..65535"):
        zconfig.check_endpoint("tcp/127.0.0.1:99999")
    assert zconfig.check_endpoint("tcp/127.0.0.1:65535")
    rust = Exception("invalid port value at /root/.cargo/git/checkouts/zenoh-9c/cc8/io/"
                     "zenoh-link-commons/src/lib.rs:62.")
    assert _one_line(rust) == "invalid port value"
    for argv in (["record", "-o", "/tmp/never.mcap", "--vehicle", "v1", "--duration", "1"],
                 ["node", "--vehicle", "v1", "--duration", "1"]):
        opt = "--connect" if argv[0] == "record" else "--listen"
        r = _cli(*argv, opt, "tcp/127.0.0.1:99999")
        assert r.returncode != 0, r
        err = [line for line in r.stderr.splitlines() if "99999" in line]
        assert len(err) == 1 and "port must be 1..65535" in err[0], r.stderr
        assert "Traceback" not in r.stderr and not MARKUP.search(r.stderr), r.stderr


def test_truncated_archive_warned_once_cleanly(tmp_path):
    a = tmp_path / "a.mcap"
    synthesize({"base": "2005301"}, a, seed=4, duration=200.0)
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(a.read_bytes()[: a.stat().st_size * 2 // 3])
    r = _cli("process", str(torn), "--summary", str(tmp_path / "s.json"), "--quiet")
    assert r.returncode == 0, r.stderr
    hits = [line for line in r.stderr.splitlines() if "truncated MCAP archive" in line]
    assert len(hits) == 1 and hits[0].startswith("radical: warning: "), r.stderr
    assert ".py:" not in r.stderr and "readers = " not in r.stderr, r.stderr


def test_every_subcommand_is_listed():
    names = set(build_parser()._subparsers._group_actions[0].choices)  # noqa: SLF001
    assert {a[0] for a in SUBCOMMANDS} <= names
