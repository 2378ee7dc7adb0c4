"""Stream index and per-stream records (issue #21): every output message carries ``stream``, the
summary lists each input stream with its span, start, bump and end estimates, and the node (end-of-
stream markers) agrees with ``radical process`` exactly."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from radical_rt.apps.batch import make_processor, process
from radical_rt.contract.params import ParamTable
from radical_rt.io import checkpoint as ckpt
from radical_rt.io.archive import ArchiveReader, ArchiveWriter
from radical_rt.stream.eos import decode_eos, make_eos
from tests.support.node import MemNode, feed_archive, input_messages

OUT_TOPICS = ["/tlm/small", "/tlm/medium", "/tlm/large", "/fault", "/diag"]


@pytest.fixture(scope="module")
def two(archives, tmp_path_factory):  # noqa: F811
    d = tmp_path_factory.mktemp("streams")
    a, b = str(archives["a60"]), str(archives["b60"])
    out = d / "p.mcap"
    return a, b, out, process([a, b], str(out))


def test_summary_lists_each_stream(two):
    a, b, _out, s = two
    st = s["streams"]
    assert [x["index"] for x in st] == [0, 1] and [x["source"] for x in st] == [a, b]
    assert [x["start"] for x in st] == ["cold", "warm"] and st[0]["bump"] is None
    bump = ParamTable().active  # the configured bump, paper units
    assert st[1]["bump"]["mode"] == bump.bump_mode
    assert st[1]["bump"]["sigma"]["b"] == pytest.approx(bump.bump_b_deg_hr, rel=1e-12)
    assert st[1]["bump"]["sigma"]["phi2"] == pytest.approx(bump.bump_phi2_arcsec, rel=1e-12)
    for x, path in zip(st, (a, b), strict=True):
        ns = [n for _t, n, _d in input_messages(path)]  # log time = t_bus of the inputs
        t0, t1 = x["t_bus"]
        assert abs(t0 - ns[0] * 1e-9) < 0.1 and t1 == pytest.approx(ns[-1] * 1e-9, abs=1e-6)
        assert set(x["estimate"]) == set(s["estimate"]) == set(x["sigma"])
    # the last stream ends where the run ends; the first one ended with its own estimates
    assert st[1]["estimate"] == s["estimate"] and st[1]["sigma"] == s["sigma"]
    assert st[1]["t_end"] == s["t_end"] and st[1]["mode"] == s["mode"]
    assert st[0]["estimate"]["b"] != st[1]["estimate"]["b"]
    assert st[0]["sigma"]["lam"] != st[1]["sigma"]["lam"]


def test_every_output_message_carries_the_stream_index(two):
    _a, _b, out, _s = two
    seen = {}
    with ArchiveReader(out) as r:
        for topic, _ns, m in r.iter_messages(OUT_TOPICS):
            assert isinstance(m.get("stream"), int), (topic, m)
            seen.setdefault(topic, []).append(m["stream"])
            if topic == "/diag":
                assert m["stream_info"]["index"] == m["stream"]
                assert m["stream_info"]["start"] == ("cold", "warm")[m["stream"]]
    for topic in ("/tlm/small", "/tlm/medium", "/tlm/large", "/diag"):
        assert set(seen[topic]) == {0, 1}, topic
    assert set(seen["/fault"]) <= {0, 1}


def test_process_prints_one_line_per_stream(archives, tmp_path, capsys):  # noqa: F811
    from radical_rt.apps.cli import main

    a, b = str(archives["a60"]), str(archives["b60"])
    assert main(["process", a, b, "--summary", str(tmp_path / "s.json")]) == 0
    out = capsys.readouterr().out
    assert f"stream 0 ({a}): cold start, t_bus" in out
    assert f"stream 1 ({b}): warm start + bump (add), t_bus" in out


def test_cold_streams(archives, tmp_path):  # noqa: F811
    s = process([str(archives["a60"]), str(archives["b60"])], None, cold=True)
    assert [x["start"] for x in s["streams"]] == ["cold", "cold"]
    assert [x["bump"] for x in s["streams"]] == [None, None]


def test_node_with_markers_equals_batch(two):
    """The node, fed the two archives each closed by an end-of-stream marker naming its source,
    publishes the same stream indices and reports the same stream records."""
    a, b, out, ref = two
    mn = MemNode()
    try:
        for path, nxt in ((a, "warm"), (b, "none")):
            msgs = list(input_messages(path))
            feed_archive(mn, "v1", msgs)
            counts = {}
            for topic, _ns, _d in msgs:
                counts[topic] = counts.get(topic, 0) + 1
            mn.publish("v1", "eos", msgpack.packb(make_eos(counts, nxt, source=path)))
            mn.idle()
        r = mn.cmd(cmd="end_stream", next="none")
        assert r["ok"], r
        streams = r["summary"]["streams"]
        got = sorted((k.split("/", 2)[2], m["t"], m["stream"]) for k, m in mn.outputs
                     if k.endswith(("tlm/small", "tlm/medium")))
    finally:
        mn.close()
    assert streams == ref["streams"]
    with ArchiveReader(out) as rd:
        want = sorted((t[1:], m["t"], m["stream"])
                      for t, _ns, m in rd.iter_messages(["/tlm/small", "/tlm/medium"]))
    assert got == want and {s for _k, _t, s in got} == {0, 1}


def test_eos_source_decoded():
    data = msgpack.packb(make_eos({"siru": 3}, "warm", source="a.mcap"))
    assert decode_eos(data, ("siru",)) == ("warm", {"siru": 3}, "a.mcap")
    assert decode_eos(msgpack.packb(make_eos({}, source=7)), ("siru",))[2] is None


def test_checkpoint_keeps_the_stream_index(archives):  # noqa: F811
    sp = make_processor()
    for topic, _ns, data in list(input_messages(archives["a60"]))[:2000]:
        sp.feed(topic, data)
    sp.end_stream("warm")
    state = msgpack.unpackb(msgpack.packb(ckpt.capture(sp, "v1")), raw=False,
                            strict_map_key=False)
    for new_stream, index in ((False, 1), (True, 2)):
        sp2 = make_processor()
        ckpt.restore(sp2, state, new_stream=new_stream)
        assert sp2.streams.index == index and sp2.streams.start == "warm"
        assert (sp2.streams.bump is not None) == (not new_stream)


def test_report_splits_by_the_stream_field(tmp_path):
    """Bus times that never step back: only the ``stream`` field can tell the streams apart."""
    pytest.importorskip("matplotlib")
    from monitors.report_ops import load_ops

    p = tmp_path / "x.mcap"
    w = ArchiveWriter(str(p), scenario={"name": "x", "generator": "test"})
    for i in range(40):
        t = 1.0 + i
        w.write("/tlm/large", {"v": 1, "stream": int(i >= 20), "seq": i + 1, "t": t,
                               "q_body_from_inertial": [0.0, 0.0, 0.0, 1.0], "flags": 0,
                               "mode": "converging", "omega_body": [0.0, 0.0, 0.0]}, t_bus=t)
    w.close()
    d = load_ops(str(p), "x")
    assert d.stream.tolist() == [0] * 20 + [1] * 20 and len(d.boundaries) == 2
    assert np.all(np.diff(d.x) > 0)
