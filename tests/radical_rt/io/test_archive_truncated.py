"""Truncated archives (radical_rt.io.archive): a cut file reads its prefix with a warning and
recovers; a complete file recovers in place; a killed writer leaves a readable prefix."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

from radical_rt.contract.schemas import SCHEMAS, validate
from radical_rt.io.archive import (
    ArchiveReader,
    TruncatedArchiveWarning,
    recover,
)
from tests.support.archive_stream import (
    SCENARIO,
    expected_raw,
    strict_reader,
    write_stream,
)

ROOT = Path(__file__).resolve().parents[3]


# ------------------------------------------------------------------------ truncated archives
@pytest.mark.parametrize("cut", [8, 40, 0.3, 0.6, 0.9, -100, -1])
def test_truncated_file_reads_prefix_and_recovers(tmp_path, stream, cut):
    full = write_stream(tmp_path / "full.mcap", stream, flush_every=37)
    data = full.read_bytes()
    size = cut if isinstance(cut, int) and cut > 0 else (
        len(data) + cut if isinstance(cut, int) else int(len(data) * cut))
    p = tmp_path / "cut.mcap"
    p.write_bytes(data[:size])
    with pytest.warns(TruncatedArchiveWarning, match=re.escape(str(p)) + ".*recovered"):
        r = ArchiveReader(p)
    with r:
        assert r.truncated
        got = list(r.iter_raw())
        n = sum(r.message_counts.values())
        assert len(got) == n
        # chunks hold consecutive writes: what survives is exactly the first n messages written
        assert got == expected_raw(stream[:n])
        if isinstance(cut, float):
            assert 0 < n and (n < len(stream) or cut > 0.8)
            assert r.scenario == SCENARIO and set(r.schemas) <= set(SCHEMAS)
        if cut in (-100, -1):  # summary/footer torn: every message is still there
            assert n == len(stream)
        if n:
            a, b = got[len(got) // 3][1], got[2 * len(got) // 3][1]
            assert list(r.iter_raw(["/st1", "/siru"], a, b)) == [
                g for g in got if a <= g[1] < b and g[0] in ("/st1", "/siru")]
            assert r.start_ns == min(g[1] for g in got) and r.end_ns == max(g[1] for g in got)
            decoded = list(r.iter_messages("/st2"))
            assert all(validate("/st2", m) == [] for _, _, m in decoded)
    out = tmp_path / "rec.mcap"
    with pytest.warns(TruncatedArchiveWarning):
        assert recover(p, out) == n
    with strict_reader(out) as r2:
        assert not r2.truncated
        assert list(r2.iter_raw()) == got
        assert r2.message_counts == {k: v for k, v in r.message_counts.items()}
        if size > 1000:
            assert r2.scenario == SCENARIO


def test_recover_complete_file_in_place(tmp_path, stream):
    p = write_stream(tmp_path / "ok.mcap", stream[:300])
    with strict_reader(p) as r:
        before = list(r.iter_raw())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert recover(p, p) == 300
    with strict_reader(p) as r:
        assert list(r.iter_raw()) == before and r.scenario == SCENARIO
    assert not list(tmp_path.glob("*recover-tmp"))


_KILLED_WRITER = """
import sys, time
from radical_rt.io.archive import ArchiveWriter
path, mode = sys.argv[1], sys.argv[2]
w = ArchiveWriter(path, scenario={"name": "killed"}, chunk_size=1 << 16,
                  flush_every_s=0.01 if mode == "auto" else None)
i = 0
while True:
    w.write("/siru", {"v": 1, "t_bus": [100.0 + 0.01 * i], "tt": [i * 10000],
                      "dtheta": [[1e-7 * i, 0.0, 0.0, 0.0]], "status": [0]})
    i += 1
    if i % 50 == 0:
        if mode == "explicit":
            w.flush()
        else:
            time.sleep(0.001)
        print(i, flush=True)
"""


@pytest.mark.parametrize("mode", ["explicit", "auto"])
def test_killed_writer_leaves_readable_prefix(tmp_path, mode):
    p = tmp_path / f"killed_{mode}.mcap"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", _KILLED_WRITER, str(p), mode], cwd=ROOT,
                            env=env, stdout=subprocess.PIPE, text=True)
    reported, deadline = 0, time.monotonic() + 60
    try:
        while reported < 3000 and time.monotonic() < deadline:
            line = proc.stdout.readline()
            assert line, "writer subprocess died"
            reported = int(line)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        proc.stdout.close()
    assert reported >= 3000
    with pytest.warns(TruncatedArchiveWarning, match=re.escape(str(p))):
        r = ArchiveReader(p)
    with r:
        assert r.truncated and r.scenario == {"name": "killed", "vehicle": "", "seed": "",
                                              "generator": "radical-rt"}
        msgs = [m for _, _, m in r.iter_messages()]
    n = len(msgs)
    assert n >= (reported if mode == "explicit" else 1)  # everything flushed survives
    assert [m["tt"][0] for m in msgs] == [i * 10000 for i in range(n)]  # an exact prefix
    with pytest.warns(TruncatedArchiveWarning):
        assert recover(p, tmp_path / "rec.mcap") == n
    with strict_reader(tmp_path / "rec.mcap") as r2:
        assert r2.message_counts == {"/siru": n}
