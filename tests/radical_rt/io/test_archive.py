"""Archive round trips (radical_rt.io.archive): MCAP records per the contract, index-based topic
and time filters, writer times and errors, bad files, CRC checks, time-ordered chunks. Schemas:
test_archive_schemas.py; truncated archives and recovery: test_archive_truncated.py."""

from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import mcap.reader
import msgpack
import numpy as np
import pytest
from jsonschema import Draft202012Validator
from mcap.reader import make_reader

from radical_rt.contract.conventions import t_to_ns
from radical_rt.contract.schemas import SCHEMAS, schema_name, validate
from radical_rt.io.archive import (
    AUDIT_TOPICS,
    ArchiveError,
    ArchiveReader,
    ArchiveWriter,
    read_scenario,
)
from tests.support.archive_stream import (
    SCENARIO,
    expected_raw,
    siru_msg,
    strict_reader,
    write_stream,
)

ROOT = Path(__file__).resolve().parents[3]


# ------------------------------------------------------------------------------- round trip
def test_round_trip(archive, stream):
    with strict_reader(archive) as r:
        assert not r.truncated
        raw = list(r.iter_raw())
        assert raw == expected_raw(stream)  # bytes identical, log_time order
        decoded = list(r.iter_messages())
        assert [m for _, _, m in decoded] == [msgpack.unpackb(d) for _, _, d in raw]
        counts = Counter(topic for topic, _, _ in stream)
        assert r.message_counts == dict(counts)
        assert set(r.topics) == set(counts)
        assert r.start_ns == raw[0][1] and r.end_ns == raw[-1][1]
        assert r.scenario == SCENARIO
        # every topic of the stream (no audit record in it) has its schema; the unknown one none
        assert set(r.schemas) == set(SCHEMAS) - set(AUDIT_TOPICS)
        for topic, s in r.schemas.items():
            Draft202012Validator.check_schema(s)
            assert s == SCHEMAS[topic]
        r.require_inputs()
    by_topic = {}
    for topic, m, _t in stream:
        by_topic.setdefault(topic, []).append(m)
    with ArchiveReader(archive) as r:
        for topic in ("/siru", "/tlm/large", "/custom/thing"):
            assert [m for _, _, m in r.iter_messages(topic)] == sorted(
                by_topic[topic], key=lambda m: m.get("t_bus", m.get("t")) if topic != "/siru"
                else m["t_bus"][-1])
    assert read_scenario(archive) == SCENARIO


def test_mcap_records_follow_contract(archive):
    with open(archive, "rb") as f:
        rd = make_reader(f)
        summary = rd.get_summary()
        assert len(summary.chunk_indexes) > 5
        seqs: dict[str, list[int]] = {}
        for schema, ch, msg in rd.iter_messages(log_time_order=False):
            assert ch.message_encoding == "msgpack"
            assert msg.publish_time == msg.log_time
            seqs.setdefault(ch.topic, []).append(msg.sequence)
            if ch.topic in SCHEMAS:
                assert schema.encoding == "jsonschema" and schema.name == schema_name(ch.topic)
            else:
                assert ch.schema_id == 0 and schema is None
        assert all(s == list(range(len(s))) for s in seqs.values())  # per-channel sequences
        meta = list(rd.iter_metadata())
        assert [m.name for m in meta] == ["radical.scenario"]


def test_topic_and_time_filters_use_index(archive, stream, monkeypatch):
    exp = expected_raw(stream)
    chunks_read = []
    orig = mcap.reader.breakup_chunk
    monkeypatch.setattr(mcap.reader, "breakup_chunk",
                        lambda c, **kw: chunks_read.append(c) or orig(c, **kw))
    with ArchiveReader(archive) as r:
        n_chunks = len(r._summary.chunk_indexes)
        assert list(r.iter_raw(["/st1", "/st2"])) == [e for e in exp if e[0] in ("/st1", "/st2")]
        assert list(r.iter_raw("/temp")) == [e for e in exp if e[0] == "/temp"]
        chunks_read.clear()
        a, b = t_to_ns(1002.25), t_to_ns(1002.75)  # [a, b): includes a, excludes b
        got = list(r.iter_raw(start_ns=a, end_ns=b))
        assert got == [e for e in exp if a <= e[1] < b]
        assert got[0][1] == a and all(e[1] != b for e in got)
        assert 0 < len(chunks_read) < n_chunks / 2  # only the overlapping chunks were read
        got = list(r.iter_raw(["/siru", "/st1"], start_ns=a, end_ns=b))
        assert got == [e for e in exp if a <= e[1] < b and e[0] in ("/siru", "/st1")]
        assert list(r.iter_raw(start_ns=b, end_ns=a)) == []
        assert list(r.iter_raw("/nothing")) == []


def test_writer_times_numpy_and_errors(tmp_path):
    p = tmp_path / "w.mcap"
    w = ArchiveWriter(p)
    siru = {"v": 1, "t_bus": np.array([5.0, 5.01]), "tt": np.array([1, 10001], dtype=np.uint32),
            "dtheta": np.arange(8.0).reshape(2, 4) * 1e-6, "status": np.zeros(2, dtype=np.int8)}
    w.write("/siru", siru)  # log time = last t_bus
    w.write("/st1", {"v": 1, "t_bus": 4.0, "q": [0, 0, 0, 1], "n_stars": 9, "valid": True},
            t_bus=4.5)  # explicit t_bus wins
    w.write("/tlm/small", {"v": 1, "t": np.float64(6.0)})
    w.write("/truth/siru_time", {"v": 1, "tt": [1, 10001], "t_true": [4.999, 5.009]})
    w.write_raw("/raw", b"\xc0", 7_000_000_000, publish_time_ns=7_000_000_001)
    for bad, match in (({"v": 1}, "no t_bus"), ({"t_bus": []}, "non-empty"),
                       ({"t": -1.0}, "not a valid MCAP time"), ({"t": float("nan")}, "valid")):
        with pytest.raises(ArchiveError, match=match):
            w.write("/diag", bad)
    with pytest.raises(TypeError):
        w.write("/diag", {"t": 1.0, "obj": object()})
    w.write("/diag", {"v": 1, "t": 8.0})  # the packer recovers from a failed encode
    w.close()
    w.close()  # idempotent
    with pytest.raises(ArchiveError, match="after close"):
        w.write("/diag", {"t": 1.0})
    with strict_reader(p) as r:
        got = list(r.iter_messages())
        assert [(tp, t) for tp, t, _ in got] == [("/st1", 4_500_000_000),
                                                 ("/truth/siru_time", 5_009_000_000),
                                                 ("/siru", 5_010_000_000),
                                                 ("/tlm/small", 6_000_000_000),
                                                 ("/raw", 7_000_000_000),
                                                 ("/diag", 8_000_000_000)]
        assert got[-1][2] == {"v": 1, "t": 8.0}
        s = got[2][2]
        assert s["dtheta"] == siru["dtheta"].tolist() and s["tt"] == [1, 10001]
        assert validate("/siru", s) == []
        assert r.scenario == {}
    with pytest.raises(ArchiveError, match="compression"):
        ArchiveWriter(tmp_path / "x.mcap", compression="gzip")
    with pytest.raises(ArchiveError, match=re.escape(str(tmp_path / "no" / "x.mcap"))):
        ArchiveWriter(tmp_path / "no" / "x.mcap")


def test_scenario_defaults_and_exception_in_context(tmp_path):
    p = tmp_path / "s.mcap"
    with pytest.raises(RuntimeError), ArchiveWriter(p, scenario={"name": "n", "seed": 3}) as w:
        w.write("/siru", siru_msg(np.random.default_rng(0), 1.0, 3, 0))
        raise RuntimeError("boom")
    with strict_reader(p) as r:  # closed properly on the exception
        assert r.message_counts == {"/siru": 1}
        assert r.scenario == {"name": "n", "seed": "3", "vehicle": "", "generator": "radical-rt"}


def test_empty_archive(tmp_path):
    p = tmp_path / "empty.mcap"
    ArchiveWriter(p, scenario=SCENARIO).close()
    with strict_reader(str(p)) as r:
        assert (r.topics, r.message_counts, r.start_ns, r.end_ns) == ([], {}, None, None)
        assert r.scenario == SCENARIO and list(r.iter_raw()) == []
        with pytest.raises(ArchiveError, match="missing required channel /siru"):
            r.require_inputs()


# --------------------------------------------------------------------------------- bad files
@pytest.mark.parametrize("kind", ["text", "empty", "missing", "directory", "short"])
def test_bad_files_raise_one_line(tmp_path, kind):
    p = tmp_path / f"bad_{kind}.mcap"
    if kind == "text":
        p.write_text("t_bus,q\n1.0,0 0 0 1\n")
    elif kind == "empty":
        p.write_bytes(b"")
    elif kind == "directory":
        p.mkdir()
    elif kind == "short":
        p.write_bytes(b"\x89MC")
    with pytest.raises(ArchiveError) as ei:
        ArchiveReader(p)
    msg = str(ei.value)
    assert str(p) in msg and "\n" not in msg
    with pytest.raises(ArchiveError):
        read_scenario(p)


def test_require_inputs(tmp_path):
    rng = np.random.default_rng(3)
    st = {"v": 1, "t_bus": 1.0, "q": [0, 0, 0, 1], "n_stars": 9, "valid": True}
    cases = {"st1_only": [("/st1", st)], "siru_only": [("/siru", siru_msg(rng, 1.0, 5, 0))],
             "siru_st2": [("/siru", siru_msg(rng, 1.0, 5, 0)), ("/st2", st)]}
    for name, msgs in cases.items():
        with ArchiveWriter(tmp_path / f"{name}.mcap") as w:
            for topic, m in msgs:
                w.write(topic, m)
    with ArchiveReader(tmp_path / "st1_only.mcap") as r, pytest.raises(ArchiveError) as ei:
        r.require_inputs()
    assert str(ei.value) == f"{tmp_path / 'st1_only.mcap'}: missing required channel /siru"
    with ArchiveReader(tmp_path / "siru_only.mcap") as r, pytest.raises(ArchiveError) as ei:
        r.require_inputs()
    assert str(ei.value).endswith(": no tracker channel (/st1 or /st2)")
    with ArchiveReader(tmp_path / "siru_st2.mcap") as r:
        r.require_inputs()


def test_crc_validation_detects_corruption(tmp_path, stream):
    p = write_stream(tmp_path / "c.mcap", stream[:200], compression="none")
    data = bytearray(p.read_bytes())
    with strict_reader(p) as r:
        off = r._summary.chunk_indexes[1].chunk_start_offset + 200
    data[off] ^= 0xFF
    p.write_bytes(bytes(data))
    with ArchiveReader(p, validate_crcs=True) as r, pytest.raises(ArchiveError, match="crc"):
        list(r.iter_raw())


def test_time_ordered_chunks_read_without_merge(tmp_path, stream, archive):
    """An archive whose chunks do not overlap in time is read chunk by chunk (stable sort inside
    each); the result equals the mcap reader's log-time merge, with filters and ties."""
    ordered = sorted(stream, key=lambda e: e[2])  # stable: same-time messages keep their order
    ordered += [("/st1", dict(m, note="tie"), t) for topic, m, t in ordered[-3:] if topic == "/st1"]
    path = write_stream(tmp_path / "ordered.mcap", ordered, chunk_size=512)
    with ArchiveReader(path) as r:
        assert r._ordered_chunks() is not None and len(r._summary.chunk_indexes) > 3
        ref = [(ch.topic, m.log_time, m.data) for _s, ch, m in r._reader.iter_messages()]
        assert list(r.iter_raw()) == ref == expected_raw(ordered)
        a, b = t_to_ns(1002.25), t_to_ns(1002.75)
        got = list(r.iter_raw(["/siru", "/st1"], start_ns=a, end_ns=b))
        assert got and got == [e for e in ref if a <= e[1] < b and e[0] in ("/siru", "/st1")]
    with ArchiveReader(archive) as r:  # written out of time order: chunks overlap, merged read
        assert r._ordered_chunks() is None
    # the chunk-by-chunk read checks chunk CRCs too
    flat = write_stream(tmp_path / "flat.mcap", ordered[:200], compression="none", chunk_size=512)
    data = bytearray(flat.read_bytes())
    with strict_reader(flat) as r:
        assert r._ordered_chunks() is not None
        off = r._summary.chunk_indexes[1].chunk_start_offset + 200
    data[off] ^= 0xFF
    flat.write_bytes(bytes(data))
    with ArchiveReader(flat, validate_crcs=True) as r, pytest.raises(ArchiveError, match="crc"):
        list(r.iter_raw())


def _flatten(blocks):
    return [(b.topic(i), int(b.log_ns[i]), b.payload(i)) for b in blocks for i in range(len(b))]


def test_blocks_hold_the_messages_of_iter_raw(tmp_path, stream, archive):
    """iter_blocks (the batch read: a chunk's bytes and its message records as arrays) gives
    iter_raw's messages in iter_raw's order: chunk by chunk when the chunks do not overlap in
    time (ties kept in file order), one merged block when they do; CRCs checked; a record that
    runs past its chunk's end is an ArchiveError."""
    ordered = sorted(stream, key=lambda e: e[2])
    ordered += [("/st1", dict(m, note="tie"), t) for topic, m, t in ordered[-3:] if topic == "/st1"]
    path = write_stream(tmp_path / "ordered.mcap", ordered, chunk_size=512)
    topics = ["/siru", "/st1"]
    with ArchiveReader(path) as r:
        blocks = list(r.iter_blocks(topics))
        assert len(blocks) == len(r._summary.chunk_indexes) > 3
        assert _flatten(blocks) == list(r.iter_raw(topics))
        assert sum(len(b) for b in blocks) == sum(1 for e in ordered if e[0] in topics)
    with ArchiveReader(archive) as r:  # chunks overlap in time: one block of the merged read
        blocks = list(r.iter_blocks(topics))
        assert len(blocks) == 1 and _flatten(blocks) == list(r.iter_raw(topics))
    flat = write_stream(tmp_path / "flat.mcap", ordered[:200], compression="none", chunk_size=512)
    data = bytearray(flat.read_bytes())
    with strict_reader(flat) as r:
        c = r._summary.chunk_indexes[1]
    bad = bytearray(data)
    bad[c.chunk_start_offset + 200] ^= 0xFF
    (tmp_path / "crc.mcap").write_bytes(bytes(bad))
    with ArchiveReader(tmp_path / "crc.mcap", validate_crcs=True) as r, \
            pytest.raises(ArchiveError, match="crc"):
        list(r.iter_blocks(topics))
    # the first record of chunk 1 claims more bytes than the chunk holds (chunk header: opcode,
    # length, start and end time, uncompressed size and CRC, compression string, records length)
    first = c.chunk_start_offset + 9 + 8 + 8 + 8 + 4 + 4 + len("") + 8
    long = bytearray(data)
    long[first + 1:first + 9] = (1 << 40).to_bytes(8, "little")
    (tmp_path / "long.mcap").write_bytes(bytes(long))
    with ArchiveReader(tmp_path / "long.mcap") as r, pytest.raises(ArchiveError, match="past"):
        list(r.iter_blocks(topics))
