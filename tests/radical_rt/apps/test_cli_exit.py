"""`radical process` ends its process at once (radical_rt.apps.cli.exit_fast) and loses nothing:
the same output archive, summary, standard output, standard error and exit code as the same
command run through main() in-process, with stdout a pipe (block-buffered)."""

from __future__ import annotations

import subprocess
import sys
import warnings

import pytest

from radical_rt.apps.cli import main
from radical_rt.io.archive import ArchiveReader
from replayer.synth.api import synthesize

_RUN = ("import atexit, sys; atexit.register(lambda: print('ATEXIT', flush=True)); "
        "from radical_rt.apps.cli import main; sys.exit(main())")


def _radical(*args: str) -> subprocess.CompletedProcess:
    """The command line in a new interpreter (an atexit handler prints ATEXIT if it runs)."""
    return subprocess.run([sys.executable, "-c", _RUN, *args], capture_output=True, text=True,
                          timeout=300)


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    a = tmp_path_factory.mktemp("exit") / "a.mcap"
    synthesize({"base": "2005301"}, a, seed=5, duration=20.0)
    return a


def test_process_exits_fast_with_everything_written(short, tmp_path, capsys):
    ref_out, ref_sum = tmp_path / "ref.mcap", tmp_path / "ref.json"
    assert main(["process", str(short), "-o", str(ref_out), "--summary", str(ref_sum)]) == 0
    ref_stdout = capsys.readouterr().out
    out, summ = tmp_path / "out.mcap", tmp_path / "s.json"
    r = _radical("process", str(short), "-o", str(out), "--summary", str(summ))
    assert r.returncode == 0, r.stderr
    assert "ATEXIT" not in r.stdout  # the fast exit was taken
    assert r.stdout == ref_stdout and "mode " in r.stdout  # the table and lines, flushed
    assert out.read_bytes() == ref_out.read_bytes() and summ.read_text() == ref_sum.read_text()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # complete: no truncation warning
        with ArchiveReader(out) as rd:
            assert not rd.truncated and sum(rd.message_counts.values()) > 0


def test_process_error_and_warning_reach_stderr(short, tmp_path):
    r = _radical("process", str(tmp_path / "missing.mcap"), "--quiet")
    assert r.returncode == 2 and "ATEXIT" not in r.stdout
    assert r.stderr.startswith("radical process: ") and "missing.mcap" in r.stderr
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(short.read_bytes()[:-100])  # the summary torn off
    r = _radical("process", str(torn), "--summary", str(tmp_path / "s.json"), "--quiet")
    assert r.returncode == 0 and "ATEXIT" not in r.stdout
    assert [ln for ln in r.stderr.splitlines() if "truncated MCAP archive" in ln], r.stderr
    assert (tmp_path / "s.json").read_text().startswith("{")


def test_other_commands_exit_normally():
    r = _radical("synth", "--help")
    assert r.returncode == 0 and r.stdout.rstrip().endswith("ATEXIT")
