"""Output paths (issue #21 item 3): every command creates missing parent directories before it
starts, or refuses at once with one line (usage error, exit 2) — never after the work."""

from __future__ import annotations

import argparse
import json

import pytest

from monitors import compare
from radical_rt.apps.cli import build_parser, main
from radical_rt.io.outpaths import OutputPathError, output_dir, output_file, prepare_output
from replayer.synth.api import synthesize


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    d = tmp_path_factory.mktemp("outp")
    a = d / "a.mcap"
    synthesize({"base": "2005301"}, a, seed=3, duration=20.0)
    return a


def test_prepare_output_creates_parents_or_refuses(tmp_path):
    f = tmp_path / "a" / "b" / "c.json"
    assert prepare_output(f) == f and f.parent.is_dir() and not f.exists()
    d = tmp_path / "x" / "y"
    prepare_output(d, directory=True)
    assert d.is_dir()
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(OutputPathError, match="in the way|not a directory"):
        prepare_output(blocker / "s.json")
    with pytest.raises(OutputPathError, match="not a directory"):
        prepare_output(blocker, directory=True)
    with pytest.raises(OutputPathError, match="is a directory"):
        prepare_output(tmp_path)
    with pytest.raises(argparse.ArgumentTypeError):
        output_file(str(blocker / "s.json"))
    with pytest.raises(argparse.ArgumentTypeError):
        output_dir(str(blocker))


def test_process_creates_the_summary_directory_first(short, tmp_path):
    out, summ = tmp_path / "o" / "p.mcap", tmp_path / "missing" / "dir" / "s.json"
    assert main(["process", str(short), "-o", str(out), "--summary", str(summ), "--quiet"]) == 0
    assert out.stat().st_size > 0 and json.loads(summ.read_text())["schema"] == "radical.summary/1"


def test_impossible_path_refused_before_the_run(short, tmp_path, capsys):
    blocker = tmp_path / "f"
    blocker.write_text("")
    out = tmp_path / "p.mcap"
    with pytest.raises(SystemExit) as exc:
        main(["process", str(short), "-o", str(out), "--summary", str(blocker / "s.json")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--summary" in err and "Traceback" not in err
    assert not out.exists(), "the run must not have started"


@pytest.mark.parametrize("argv", [
    ["synth", "2005301", "-o", "{d}/a/s.mcap"],
    ["record", "-o", "{d}/a/r.mcap", "--vehicle", "v1"],
    ["export", "IN.mcap", "-o", "{d}/a/e.mcap"],
    ["report", "IN.mcap", "-o", "{d}/a/rep"],
    ["allan", "IN.mcap", "-o", "{d}/a/al"],
    ["design", "2006216", "--json", "{d}/a/d.json"],
    ["node", "--vehicle", "v1", "--checkpoint", "{d}/a/c.ckpt"],
    ["bench", "--out", "{d}/a/bench"],
])
def test_every_command_prepares_its_outputs_while_parsing(argv, tmp_path):
    """Parsing alone (nothing runs) creates the missing parents, or refuses the path."""
    parser = build_parser()
    parser.parse_args([a.format(d=tmp_path) for a in argv])
    assert (tmp_path / "a").is_dir()
    blocker = tmp_path / "b"
    blocker.write_text("")
    with pytest.raises(SystemExit):
        parser.parse_args([a.format(d=blocker) for a in argv])


def test_compare_out_in_missing_directory(short, tmp_path):
    summ = tmp_path / "s.json"
    assert main(["process", str(short), "--summary", str(summ), "--quiet"]) == 0
    out = tmp_path / "no" / "such" / "t.md"
    assert compare.main([str(short), str(summ), "--out", str(out)]) == 0
    assert "b" in out.read_text()
