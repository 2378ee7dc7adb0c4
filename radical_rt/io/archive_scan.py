"""Record-level scanning of MCAP archives, below :mod:`radical_rt.io.archive`'s reader.

* :func:`rebuild_summary` walks the records of a file whose summary/footer is missing or torn (its
  writer was killed) up to the end of its data or the tear, and rebuilds the summary (schemas,
  channels, metadata and chunk indexes, statistics) from what is readable; a torn chunk is dropped
  whole (bounds and chunk CRCs are checked). :class:`RebuiltIndexReader` reads the file through it.
* :func:`chunk_messages` splits a chunk's message records with :mod:`struct` (the fast batch read).

Only stdlib and the mcap library are imported.
"""

from __future__ import annotations

import io
import struct
from collections import Counter
from typing import Any, BinaryIO

from mcap import records as mr
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.stream_reader import StreamReader, breakup_chunk, get_chunk_data_stream
from mcap.summary import Summary

#: the MCAP magic bytes that open and close a file
MAGIC = b"\x89MCAP0\r\n"

_RECORD = struct.Struct("<BQ")  # opcode, content length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log_time, publish_time


def one_line(e: BaseException) -> str:
    """An exception as one line: ``Type: message`` with the whitespace collapsed."""
    text = " ".join(str(e).split())
    return f"{type(e).__name__}: {text}" if text else type(e).__name__


def _parse_record(raw: bytes) -> Any:  # one complete record: opcode, length, body
    return next(StreamReader(io.BytesIO(raw), skip_magic=True, emit_chunks=True).records)


class RebuiltIndexReader(SeekingReader):
    """A SeekingReader over a file without summary, using a summary rebuilt by scanning it."""

    def __init__(self, f: Any, summary: Summary, validate_crcs: bool) -> None:
        f.seek(0)
        super().__init__(f, validate_crcs=validate_crcs)
        self._rebuilt = summary

    def get_summary(self) -> Summary:
        return self._rebuilt

    def iter_messages(self, *args: Any, **kw: Any) -> Any:  # no chunks: nothing (never stream)
        return super().iter_messages(*args, **kw) if self._rebuilt.chunk_indexes else iter(())


def rebuild_summary(f: BinaryIO, size: int) -> tuple[Summary, str | None, int]:
    """Stream the records of the open file ``f`` (``size`` bytes, magic checked by the caller) up
    to the end of the data section or the tear. Returns the summary rebuilt from what is readable,
    why reading stopped early (None: data complete) and the number of good bytes before the tear."""
    pos, s = len(MAGIC), Summary()
    counts: Counter[int] = Counter()
    torn: str | None = "no summary/footer"
    while pos + 9 <= size:
        f.seek(pos)
        head = f.read(9)
        opcode, length = struct.unpack("<BQ", head)
        end = pos + 9 + length
        if end > size:
            torn = f"record at byte {pos} torn at byte {size}"
            break
        if opcode in (Opcode.DATA_END, Opcode.FOOTER):
            pos, torn = end, None
            break
        if opcode in (Opcode.CHUNK, Opcode.SCHEMA, Opcode.CHANNEL, Opcode.METADATA):
            try:
                rec = _parse_record(head + f.read(length))
                inner = breakup_chunk(rec, validate_crc=True) if isinstance(rec, mr.Chunk) else [rec]
            except Exception as e:  # any parse/CRC failure marks the tear
                torn = f"unreadable record at byte {pos}: {one_line(e)}"
                break
            times, cids = [], {}
            for r in inner:
                if isinstance(r, mr.Message) and r.channel_id in s.channels:
                    counts[r.channel_id] += 1
                    times.append(r.log_time)
                    cids[r.channel_id] = 0
                elif isinstance(r, mr.Schema | mr.Channel):
                    getattr(s, "schemas" if isinstance(r, mr.Schema) else "channels")[r.id] = r
                elif isinstance(r, mr.Metadata):
                    s.metadata_indexes.append(mr.MetadataIndex(pos, end - pos, r.name))
            if times and isinstance(rec, mr.Chunk):
                s.chunk_indexes.append(mr.ChunkIndex(
                    chunk_length=end - pos, chunk_start_offset=pos, compression=rec.compression,
                    compressed_size=len(rec.data), message_end_time=max(times),
                    message_index_length=0, message_index_offsets=cids,
                    message_start_time=min(times), uncompressed_size=rec.uncompressed_size))
        pos = end
    if torn is not None and pos + 9 > size > pos:
        torn = f"torn record header at byte {pos}"
    ci = s.chunk_indexes
    s.statistics = mr.Statistics(0, len(s.channels), counts, len(ci), sum(counts.values()),
                                 max((c.message_end_time for c in ci), default=0),
                                 min((c.message_start_time for c in ci), default=0),
                                 len(s.metadata_indexes), len(s.schemas))
    return s, torn, pos


def chunk_messages(chunk: mr.Chunk, validate_crc: bool, want: set[int],
                   topic_of: dict[int, str]) -> list[tuple[int, str, bytes]]:
    """``(log_time, topic, data)`` of the message records of a chunk whose channel is in
    ``want``, in file order. The chunk is decompressed (and its CRC checked) by the mcap library;
    the records are split here with :mod:`struct` (the library's record objects cost more than
    the rest of the batch read)."""
    stream, n = get_chunk_data_stream(chunk, validate_crc=validate_crc)
    buf = stream.read(n)
    out, pos, op_message = [], 0, int(Opcode.MESSAGE)
    while pos < n:
        op, length = _RECORD.unpack_from(buf, pos)
        pos += 9
        if op == op_message:
            cid, _seq, log_time, _pub = _MESSAGE.unpack_from(buf, pos)
            if cid in want:
                out.append((log_time, topic_of[cid], buf[pos + 22:pos + length]))
        pos += length
    return out
