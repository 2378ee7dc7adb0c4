"""A lean MCAP writer: byte for byte the file of ``mcap.writer.Writer`` (mcap 1.x) as the archive
layer configures it, at a fraction of its cost per message.

The archives' settings only: chunked (zstd, lz4 or no compression), every index (chunk, message,
metadata; an empty attachment index group), chunk CRCs on, no data-section CRC, schemas,
channels, statistics and summary offsets repeated in the summary. The rare records (header,
schema, channel, metadata, chunk, summary) are the mcap library's own record classes; a message
is one :mod:`struct` header appended to the open chunk, and a chunk's message indexes are packed
with numpy (the library builds a dataclass and a dozen buffer writes per message, about 10 µs).
``tests/radical_rt/io/test_mcap_write.py`` checks the files equal the library's byte for byte.
"""

from __future__ import annotations

import struct
import zlib
from typing import BinaryIO

import numpy as np
from mcap import records as mr
from mcap.data_stream import RecordBuilder
from mcap.exceptions import UnsupportedCompressionError
from mcap.opcode import Opcode

from radical_rt.io.archive_scan import MAGIC

_MESSAGE = struct.Struct("<BQHIQQ")  # opcode, length, channel id, sequence, log, publish time
_INDEX_HEAD = struct.Struct("<BQHI")  # opcode, length, channel id, bytes of (time, offset) pairs
_FOOTER_HEAD = struct.Struct("<BQQQ")  # opcode, length, summary start, summary offset start
_OP_MESSAGE = int(Opcode.MESSAGE)


def _compressor(compression: str):
    """The chunk compression function of ``compression`` ("zstd", "lz4" or "": none)."""
    if compression == "zstd":
        try:
            import zstandard
        except ImportError:
            raise UnsupportedCompressionError("zstandard") from None
        return zstandard.compress
    if compression == "lz4":
        try:
            import lz4.frame
        except ImportError:
            raise UnsupportedCompressionError("lz4") from None
        return lz4.frame.compress
    return bytes


class McapWriter:
    """Write an MCAP file to the open binary stream ``out`` (see the module docstring).

    The calls of ``mcap.writer.Writer`` that the archive layer uses, with its arguments:
    :meth:`start`, :meth:`register_schema`, :meth:`register_channel`, :meth:`add_metadata`,
    :meth:`add_message`, :meth:`flush`, :meth:`finish` (which does not close ``out``)."""

    def __init__(self, out: BinaryIO, *, chunk_size: int = 1 << 20,
                 compression: str = "zstd") -> None:
        self._out, self._chunk_size = out, chunk_size
        self._compression, self._compress = compression, _compressor(compression)
        self._schemas: list[mr.Schema] = []
        self._channels: list[mr.Channel] = []
        self._chunk = bytearray()  # the open chunk's records
        self._index: dict[int, tuple[list[int], list[int]]] = {}  # channel -> times, offsets
        self._chunk_indexes: list[mr.ChunkIndex] = []
        self._metadata_indexes: list[mr.MetadataIndex] = []
        self._counts: dict[int, int] = {}  # messages per channel, in order of the first
        self._times: list[int] = []  # [first, last] log time of all messages

    def _put(self, record: mr.McapRecord) -> int:
        """Write one record to the file; return its length in bytes."""
        rb = RecordBuilder()
        record.write(rb)
        return self._out.write(rb.end())

    def start(self, profile: str = "", library: str = "") -> None:
        """The magic and the header record."""
        self._out.write(MAGIC)
        self._put(mr.Header(profile=profile, library=library))

    def _add_to_chunk(self, record: mr.McapRecord) -> None:
        rb = RecordBuilder()
        record.write(rb)
        self._chunk += rb.end()
        if len(self._chunk) > self._chunk_size:
            self._finalize_chunk()

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """A new schema (written into the open chunk); returns its id (1, 2, ...)."""
        schema = mr.Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        self._add_to_chunk(schema)
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int,
                         metadata: dict[str, str] | None = None) -> int:
        """A new channel (written into the open chunk); returns its id (1, 2, ...)."""
        channel = mr.Channel(id=len(self._channels) + 1, topic=topic, schema_id=schema_id,
                             message_encoding=message_encoding, metadata=dict(metadata or {}))
        self._channels.append(channel)
        self._add_to_chunk(channel)
        return channel.id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record, outside chunks (indexed)."""
        offset = self._out.tell()
        length = self._put(mr.Metadata(name=name, metadata=data))
        self._metadata_indexes.append(mr.MetadataIndex(offset=offset, length=length, name=name))

    def add_message(self, channel_id: int, log_time: int, data: bytes, publish_time: int,
                    sequence: int = 0) -> None:
        """Append a message record to the open chunk (closed once over ``chunk_size`` bytes)."""
        chunk = self._chunk
        idx = self._index.get(channel_id)
        if idx is None:
            idx = self._index[channel_id] = ([], [])
        idx[0].append(log_time)
        idx[1].append(len(chunk))
        chunk += _MESSAGE.pack(_OP_MESSAGE, 22 + len(data), channel_id, sequence, log_time,
                               publish_time)
        chunk += data
        if len(chunk) > self._chunk_size:
            self._finalize_chunk()

    def _finalize_chunk(self) -> None:
        """Write the open chunk (if it holds a message) and its message indexes."""
        if not self._index:
            return
        data = bytes(self._chunk)
        t0 = min(min(times) for times, _ in self._index.values())
        t1 = max(max(times) for times, _ in self._index.values())
        packed = self._compress(data)
        start = self._out.tell()
        length = self._put(mr.Chunk(
            message_start_time=t0, message_end_time=t1, uncompressed_size=len(data),
            uncompressed_crc=zlib.crc32(data), compression=self._compression, data=packed))
        offsets, pos = {}, start + length
        for cid, (times, offs) in self._index.items():
            pairs = np.empty((len(times), 2), dtype="<u8")
            pairs[:, 0], pairs[:, 1] = times, offs
            offsets[cid] = pos
            pos += self._out.write(_INDEX_HEAD.pack(Opcode.MESSAGE_INDEX, 6 + pairs.nbytes, cid,
                                                    pairs.nbytes))
            pos += self._out.write(pairs.tobytes())
            self._counts[cid] = self._counts.get(cid, 0) + len(times)
        self._chunk_indexes.append(mr.ChunkIndex(
            message_start_time=t0, message_end_time=t1, chunk_start_offset=start,
            chunk_length=length, message_index_offsets=offsets,
            message_index_length=pos - start - length, compression=self._compression,
            compressed_size=len(packed), uncompressed_size=len(data)))
        self._times = [min(self._times[0], t0), max(self._times[1], t1)] if self._times \
            else [t0, t1]
        self._chunk.clear()
        self._index = {}

    def flush(self) -> None:
        """Close the open chunk and flush the stream (no fsync)."""
        self._finalize_chunk()
        self._out.flush()

    def finish(self) -> None:
        """The last chunk, the data end, the summary, the footer and the closing magic."""
        self._finalize_chunk()
        self._put(mr.DataEnd(data_section_crc=0))
        summary_start = self._out.tell()
        rb, offsets = RecordBuilder(), []
        t0, t1 = self._times or (0, 0)
        stats = mr.Statistics(
            message_count=sum(self._counts.values()), schema_count=len(self._schemas),
            channel_count=len(self._channels), attachment_count=0,
            metadata_count=len(self._metadata_indexes), chunk_count=len(self._chunk_indexes),
            message_start_time=t0, message_end_time=t1, channel_message_counts=self._counts)
        for opcode, group in ((Opcode.SCHEMA, self._schemas), (Opcode.CHANNEL, self._channels),
                              (Opcode.STATISTICS, [stats]),
                              (Opcode.CHUNK_INDEX, self._chunk_indexes),
                              (Opcode.ATTACHMENT_INDEX, []),
                              (Opcode.METADATA_INDEX, self._metadata_indexes)):
            begin = rb.count
            for record in group:
                record.write(rb)
            offsets.append(mr.SummaryOffset(group_opcode=opcode, group_start=summary_start + begin,
                                            group_length=rb.count - begin))
        offset_start = summary_start + rb.count
        for offset in offsets:
            offset.write(rb)
        summary = rb.end()
        crc = zlib.crc32(_FOOTER_HEAD.pack(Opcode.FOOTER, 20, summary_start, offset_start),
                         zlib.crc32(summary))
        self._out.write(summary)
        self._put(mr.Footer(summary_start=summary_start, summary_offset_start=offset_start,
                            summary_crc=crc))
        self._out.write(MAGIC)
