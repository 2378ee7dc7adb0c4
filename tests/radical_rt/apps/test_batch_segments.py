"""`radical process` feeds an archive block in segments (radical_rt.apps.batch._feed_block): at
most SEGMENT messages a call, cut at each /truth/params message it copies into the output, and
without those messages when nothing is copied. The result does not depend on the cuts."""

from __future__ import annotations

import json

import pytest

from radical_rt.apps import batch
from radical_rt.io.archive import ArchiveReader
from radical_rt.stream.processor import StreamProcessor
from tests.support.streams import make_archive


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    return make_archive(tmp_path_factory.mktemp("seg"), "s40", seed=5, duration=40)


def _recorded(monkeypatch):
    """Per feed_arrays call: the topics of its messages."""
    calls: list[list[str]] = []
    real = StreamProcessor.feed_arrays

    def record(self, buf, names, tidx, off, size):
        calls.append([names[i] for i in tidx.tolist()])
        return real(self, buf, names, tidx, off, size)

    monkeypatch.setattr(StreamProcessor, "feed_arrays", record)
    return calls


def test_segments_bounded_and_truth_left_out(archive, monkeypatch, tmp_path):
    calls = _recorded(monkeypatch)
    monkeypatch.setattr(batch, "SEGMENT", 64)
    alone = batch.process([str(archive)], None)
    assert calls and max(len(c) for c in calls) <= 64
    assert not any("truth/params" in c for c in calls)
    fed = sum(len(c) for c in calls)
    with ArchiveReader(archive) as r:
        inputs = sum(r.message_counts.get(t, 0) for t in batch.INPUTS)
        truth = r.message_counts.get("/truth/params", 0)
    assert fed == inputs and truth > 10

    calls.clear()
    out = tmp_path / "out.mcap"
    written = batch.process([str(archive)], str(out), str(tmp_path / "s.json"))
    assert not any("truth/params" in c for c in calls)
    with ArchiveReader(out) as r:
        assert r.message_counts.get("/truth/params", 0) == truth  # copied, each at its place
    # the same filter whatever the cuts: estimates, σ and counters
    assert json.dumps(alone, sort_keys=True) == json.dumps(written, sort_keys=True)


def test_segment_size_does_not_change_the_result(archive, monkeypatch):
    results = []
    for seg in (7, 1 << 20):
        monkeypatch.setattr(batch, "SEGMENT", seg)
        results.append(json.dumps(batch.process([str(archive)], None), sort_keys=True))
    assert results[0] == results[1]
