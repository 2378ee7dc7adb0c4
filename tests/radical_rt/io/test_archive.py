"""MCAP archive layer (radical_rt.io.archive) and message schemas (radical_rt.contract.schemas):
CONTRACT.md §3-§4."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import warnings
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
    INPUT_TOPICS,
    OUTPUT_TOPICS,
    TRUTH_TOPICS,
    ArchiveError,
    ArchiveReader,
    ArchiveWriter,
    TruncatedArchiveWarning,
    read_scenario,
    recover,
)

ROOT = Path(__file__).resolve().parents[3]
SCENARIO = {"name": "unit", "vehicle": "sc1", "seed": "7", "generator": "tests", "extra": "x"}
PARAM_KEYS = ("b", "lam", "mu", "du", "dv", "phi2")


def _quat(rng):
    q = rng.normal(size=4)
    return (q / np.linalg.norm(q)).tolist()


def _params(rng, scale=1e-6):
    return {k: rng.normal(0, scale, 3 if k == "phi2" else 4).tolist() for k in PARAM_KEYS}


def _siru(rng, t0, k, i0):
    return {"v": 1, "t_bus": [t0 + 0.01 * i + 0.0031 for i in range(k)],
            "tt": [((i0 + i) * 10000) % (1 << 32) for i in range(k)],
            "dtheta": rng.normal(0, 1e-5, (k, 4)).tolist(), "status": [0] * k}


def make_stream(seed=1, seconds=6):
    """(topic, msg, t_bus) in write order: every topic of the contract plus an unknown one.

    SIRU alternates one 100-sample batch and 100 one-sample batches per second; trackers and
    temperatures are written after the batch that covers them (out of log_time order)."""
    rng = np.random.default_rng(seed)
    out = []
    i0 = (1 << 32) - 30000  # tt wraps during the first second
    for s in range(seconds):
        t0 = 1000.0 + s
        if s % 2 == 0:
            m = _siru(rng, t0, 100, i0)
            out.append(("/siru", m, m["t_bus"][-1]))
        else:
            for i in range(100):
                m = _siru(rng, t0 + 0.01 * i, 1, i0 + i)
                out.append(("/siru", m, m["t_bus"][-1]))
        out.append(("/truth/siru_time", {"v": 1, "tt": [((i0 + i) * 10000) % (1 << 32) for i in
                                                          range(100)],
                                         "t_true": [t0 + 0.01 * i for i in range(100)]},
                    t0 + 0.99))
        i0 += 100
        for j, dt in ((1, 0.25), (2, 0.30), (1, 0.75), (2, 0.80)):
            out.append((f"/st{j}", {"v": 1, "t_bus": t0 + dt, "q": _quat(rng), "n_stars": 9,
                                    "valid": bool(dt < 0.5)}, t0 + dt))
        out.append(("/temp", {"v": 1, "t_bus": t0 + 0.5, "st1_baseplate_C": 20.0 + s,
                              "siru_C": 25.5}, t0 + 0.5))
        for k in range(10):
            t = t0 + 0.1 * k
            out.append(("/truth/attitude", {"v": 1, "t_bus": t, "q_body_from_inertial": _quat(rng),
                                            "omega_body": rng.normal(0, 1e-3, 3).tolist()}, t))
        out.append(("/truth/params", {"v": 1, "t_bus": t0, **_params(rng)}, t0))
        small = {"v": 1, "seq": s, "t": t0 + 0.9, "q_body_from_inertial": _quat(rng),
                 "flags": 1 << 13, "mode": "converging"}
        medium = {**small, "omega_body": [0.0, 1e-3, 0.0], "est": _params(rng)}
        large = {**medium, "sigma": {k: np.abs(v).tolist() for k, v in _params(rng).items()},
                 "att_sigma": [1e-5, 1e-5, 2e-5], "counters": {"siru_samples": 100 * s},
                 "clock": {"eps": 3e-5}}
        for topic, m in (("/tlm/small", small), ("/tlm/medium", medium), ("/tlm/large", large)):
            out.append((topic, m, m["t"]))
        out.append(("/fault", {"v": 1, "t": t0 + 0.9, "flags": 1 << 13, "set": ["NOT_CONVERGED"],
                               "cleared": [], "detail": {}}, t0 + 0.9))
        out.append(("/diag", {"v": 1, "t": t0 + 0.9, "nis": [1.2, 0.8]}, t0 + 0.9))
        out.append(("/custom/thing", {"t": t0 + 0.95, "x": b"\x00\x01"}, t0 + 0.95))
    return out


def expected_raw(stream):
    raw = [(topic, t_to_ns(t), msgpack.packb(m, use_bin_type=True)) for topic, m, t in stream]
    return sorted(raw, key=lambda r: r[1])  # stable: ties keep write order


def write_stream(path, stream, *, flush_every=None, **kw):
    with ArchiveWriter(path, scenario=SCENARIO, chunk_size=kw.pop("chunk_size", 8192), **kw) as w:
        for n, (topic, m, _t) in enumerate(stream):
            w.write(topic, m)  # time from the message itself
            if flush_every and n % flush_every == flush_every - 1:
                w.flush()
    return path


@pytest.fixture(scope="module")
def stream():
    return make_stream()


@pytest.fixture(scope="module")
def archive(tmp_path_factory, stream):
    return write_stream(tmp_path_factory.mktemp("arc") / "a.mcap", stream)


def _no_warnings_reader(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return ArchiveReader(path, **kw)


# --------------------------------------------------------------------------------- schemas
def test_schema_names_and_meta_schemas():
    assert set(SCHEMAS) == set(INPUT_TOPICS + OUTPUT_TOPICS + TRUTH_TOPICS + AUDIT_TOPICS)
    assert schema_name("/siru") == "radical.siru"
    assert schema_name("/tlm/small") == "radical.tlm.small"
    assert schema_name("/truth/attitude") == "radical.truth.attitude"

    def described(node, where):
        for name, sub in node.get("properties", {}).items():
            assert sub.get("description"), f"{where}.{name} has no description"
            described(sub, f"{where}.{name}")

    for topic, s in SCHEMAS.items():
        Draft202012Validator.check_schema(s)
        assert s["title"] == schema_name(topic)
        assert "v" in s["required"] and s["properties"]["v"]["const"] == 1
        described(s, topic)
    assert set(SCHEMAS["/tlm/small"]["required"]) == {"v", "seq", "t", "q_body_from_inertial",
                                                      "flags", "mode"}


def test_stream_messages_validate(stream):
    for topic, m, _t in stream:
        if topic in SCHEMAS:
            assert validate(topic, m) == [], (topic, m)
    # numpy-valued messages (as a simulator builds them) validate too
    siru = {"v": 1, "t_bus": np.array([1.0, 1.01]), "tt": np.array([5, 10005], dtype=np.uint32),
            "dtheta": np.zeros((2, 4)), "status": np.zeros(2, dtype=np.int64)}
    assert validate("/siru", siru) == []


@pytest.mark.parametrize("topic, msg, pattern", [
    ("/st1", {"v": 1, "t_bus": 1.0, "n_stars": 9, "valid": True}, "'q' is a required"),
    ("/st1", {"v": 1, "t_bus": 1.0, "q": [0, 0, 1], "n_stars": 9, "valid": True}, "too short"),
    ("/st2", {"v": 1, "t_bus": 1.0, "q": [0, 0, 0, 1, 0], "n_stars": 9, "valid": True},
     "too long"),
    ("/st1", {"v": 2, "t_bus": 1.0, "q": [0, 0, 0, 1], "n_stars": 9, "valid": True},
     "1 was expected"),
    ("/siru", {"v": 1, "t_bus": [1.0], "tt": [1], "dtheta": [[0.0, 0.0, 0.0]], "status": [0]},
     "too short"),
    ("/siru", {"v": 1, "t_bus": [1.0, 1.01], "tt": [1], "dtheta": [[0.0] * 4], "status": [0]},
     "columns differ"),
    ("/siru", {"v": 1, "t_bus": [], "tt": [], "dtheta": [], "status": []}, "should be non-empty"),
    ("/siru", {"v": 1, "t_bus": [1.0], "tt": [1 << 32], "dtheta": [[0.0] * 4], "status": [0]},
     "maximum"),
    ("/tlm/small", {"v": 1, "seq": 0, "t": 1.0, "q_body_from_inertial": [0, 0, 0, 1],
                    "flags": 0, "mode": "sleeping"}, "is not one of"),
    ("/tlm/medium", {"v": 1, "seq": 0, "t": 1.0, "q_body_from_inertial": [0, 0, 0, 1],
                     "flags": 0, "mode": "init", "est": {"b": [0.0] * 4}}, "required"),
    ("/truth/params", {"v": 1, "t_bus": 0.0, "b": [0.0] * 4, "lam": [0.0] * 4, "mu": [0.0] * 4,
                       "du": [0.0] * 4, "dv": [0.0] * 4, "phi2": [0.0] * 4}, "too long"),
    ("/temp", {"v": 1, "t_bus": 1.0, "siru_C": "warm"}, "not of type 'number'"),
])
def test_bad_messages_give_errors(topic, msg, pattern):
    errs = validate(topic, msg)
    assert errs and any(re.search(pattern, e) for e in errs), errs
    assert all(e.startswith(topic + ": ") for e in errs)


def test_validate_unknown_topic_and_extensions():
    assert len(validate("/nope", {"v": 1})) == 1
    ok = {"v": 1, "seq": 3, "t": 1.0, "q_body_from_inertial": [0, 0, 0, 1], "flags": 0,
          "mode": "converged", "custom_field": [1, 2, 3]}
    assert validate("/tlm/small", ok) == []
    assert validate("/tlm/large", ok) == []  # configurable packets: only the small defaults required
    assert validate("/temp", {"v": 1, "t_bus": 2.0}) == []  # all temperatures optional


# ------------------------------------------------------------------------------- round trip
def test_round_trip(archive, stream):
    with _no_warnings_reader(archive) as r:
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
    with _no_warnings_reader(p) as r:
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
        w.write("/siru", _siru(np.random.default_rng(0), 1.0, 3, 0))
        raise RuntimeError("boom")
    with _no_warnings_reader(p) as r:  # closed properly on the exception
        assert r.message_counts == {"/siru": 1}
        assert r.scenario == {"name": "n", "seed": "3", "vehicle": "", "generator": "radical-rt"}


def test_empty_archive(tmp_path):
    p = tmp_path / "empty.mcap"
    ArchiveWriter(p, scenario=SCENARIO).close()
    with _no_warnings_reader(str(p)) as r:
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
    cases = {"st1_only": [("/st1", st)], "siru_only": [("/siru", _siru(rng, 1.0, 5, 0))],
             "siru_st2": [("/siru", _siru(rng, 1.0, 5, 0)), ("/st2", st)]}
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
    with _no_warnings_reader(p) as r:
        off = r._summary.chunk_indexes[1].chunk_start_offset + 200
    data[off] ^= 0xFF
    p.write_bytes(bytes(data))
    with ArchiveReader(p, validate_crcs=True) as r, pytest.raises(ArchiveError, match="crc"):
        list(r.iter_raw())


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
    with _no_warnings_reader(out) as r2:
        assert not r2.truncated
        assert list(r2.iter_raw()) == got
        assert r2.message_counts == {k: v for k, v in r.message_counts.items()}
        if size > 1000:
            assert r2.scenario == SCENARIO


def test_recover_complete_file_in_place(tmp_path, stream):
    p = write_stream(tmp_path / "ok.mcap", stream[:300])
    with _no_warnings_reader(p) as r:
        before = list(r.iter_raw())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert recover(p, p) == 300
    with _no_warnings_reader(p) as r:
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
    with _no_warnings_reader(tmp_path / "rec.mcap") as r2:
        assert r2.message_counts == {"/siru": n}


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
    with _no_warnings_reader(flat) as r:
        assert r._ordered_chunks() is not None
        off = r._summary.chunk_indexes[1].chunk_start_offset + 200
    data[off] ^= 0xFF
    flat.write_bytes(bytes(data))
    with ArchiveReader(flat, validate_crcs=True) as r, pytest.raises(ArchiveError, match="crc"):
        list(r.iter_raw())
