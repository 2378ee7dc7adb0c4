"""The lean MCAP writer (radical_rt.io.mcap_write) writes the mcap library's files byte for byte."""

from __future__ import annotations

import io

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, IndexType, Writer

from radical_rt.io.mcap_write import McapWriter

_LIBRARY_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                        "": CompressionType.NONE}


def _drive(w, seed: int, n: int, flush_at: int | None) -> None:
    """The same calls on either writer: metadata, schemas and channels (one registered late),
    messages of random sizes and times (out of order, ties), an optional flush."""
    rng = np.random.default_rng(seed)
    w.start(profile="", library="unit")
    w.add_metadata("radical.scenario", {"name": "unit", "seed": str(seed)})
    sid = w.register_schema("radical.a", "jsonschema", b'{"type": "object"}')
    cids = [w.register_channel("/a", "msgpack", sid), w.register_channel("/b", "msgpack", 0)]
    for i in range(n):
        if i == n // 2:
            cids.append(w.register_channel("/late", "msgpack", sid, {"vehicle": "sc1"}))
        cid = cids[int(rng.integers(len(cids)))]
        t = int(1_000_000_000 + 10_000_000 * i + rng.integers(-30_000_000, 30_000_000))
        data = rng.bytes(int(rng.integers(0, 600)))
        w.add_message(cid, t, data, t + int(rng.integers(0, 2)), i % 7)
        if i == flush_at:
            w.flush()
    w.add_metadata("extra", {"k": "v"})
    w.finish()


def _library_file(compression: str, chunk_size: int, **kw) -> bytes:
    buf = io.BytesIO()
    _drive(Writer(buf, chunk_size=chunk_size, compression=_LIBRARY_COMPRESSION[compression],
                  index_types=IndexType.ALL, enable_crcs=True), **kw)
    return buf.getvalue()


def _lean_file(compression: str, chunk_size: int, **kw) -> bytes:
    buf = io.BytesIO()
    _drive(McapWriter(buf, chunk_size=chunk_size, compression=compression), **kw)
    return buf.getvalue()


@pytest.mark.parametrize("compression", ["zstd", "lz4", ""])
@pytest.mark.parametrize("chunk_size, n, flush_at", [(4096, 800, 300), (1 << 20, 200, None),
                                                     (100, 50, 0), (4096, 0, None)])
def test_files_equal_the_library_writer(compression, chunk_size, n, flush_at):
    if compression == "lz4":
        pytest.importorskip("lz4")
    kw = {"seed": n + chunk_size, "n": n, "flush_at": flush_at}
    lean = _lean_file(compression, chunk_size, **kw)
    assert lean == _library_file(compression, chunk_size, **kw)
    reader = make_reader(io.BytesIO(lean), validate_crcs=True)
    assert reader.get_summary().statistics.message_count == n
    assert sum(1 for _ in reader.iter_messages()) == n
