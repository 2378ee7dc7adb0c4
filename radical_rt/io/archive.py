"""MCAP archives of RADICAL-RT telemetry (CONTRACT.md §4): writing, reading, truncated-file recovery.

Topics are the Zenoh topics with a leading slash; message encoding msgpack (data = the Zenoh
payload); jsonschema schemas ``radical.<topic>`` (:mod:`radical_rt.contract.schemas`); log_time =
publish_time = round(t_bus·1e9) ns; metadata ``radical.scenario``. A leaf I/O layer (stdlib, numpy,
msgpack, mcap, the contract's conventions and schemas) that the engine's batch shell, the simulator,
replay/record and the monitors share; :mod:`radical_rt.io.archive_scan` holds the record-level
scanning (a torn file's index, a chunk's messages).
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import numbers
import operator
import os
import time
import warnings
from collections import Counter
from collections.abc import Iterable, Iterator
from typing import Any

import msgpack
import numpy as np
from mcap import records as mr
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.stream_reader import get_chunk_data_stream

from radical_rt.contract.conventions import t_to_ns
from radical_rt.contract.schemas import SCHEMAS, schema_name
from radical_rt.io.archive_scan import (
    MAGIC,
    RebuiltIndexReader,
    chunk_messages,
    one_line,
    rebuild_summary,
)
from radical_rt.io.chunk_records import Block, split_messages
from radical_rt.io.mcap_write import McapWriter

log = logging.getLogger(__name__)
_first = operator.itemgetter(0)

INPUT_TOPICS = ("/siru", "/st1", "/st2", "/temp")
OUTPUT_TOPICS = ("/tlm/small", "/tlm/medium", "/tlm/large", "/fault", "/diag")
TRUTH_TOPICS = ("/truth/attitude", "/truth/params", "/truth/siru_time")
AUDIT_TOPICS = ("/cmd_log",)  # the node's audit trail (docs/security.md), recorded by radical record
SCENARIO_METADATA = "radical.scenario"

_COMPRESSION = {"zstd": "zstd", "lz4": "lz4", "none": "", "": ""}  # name -> MCAP chunk compression


class ArchiveError(Exception):
    """An archive cannot be written or read; ``str(e)`` is one line naming the file and problem."""


class TruncatedArchiveWarning(UserWarning):
    """A truncated archive (no valid summary/footer) was read up to its tear."""


def _np_default(obj: Any) -> Any:  # msgpack fallback: numpy arrays/scalars -> lists/scalars
    if isinstance(obj, np.ndarray | np.generic):
        return obj.tolist()
    raise TypeError(f"cannot msgpack-encode an object of type {type(obj).__name__}")


class ArchiveWriter:
    """Write one telemetry stream to an MCAP file (zstd chunks, all indexes, CRCs on).

    ``chunk_size``: uncompressed bytes per chunk; ``flush_every_s``: wall time (s) between automatic
    :meth:`flush` calls. ``scenario`` values are stored as strings, missing contract keys as ""
    (``generator``: ``library``). Sequence numbers count from 0 per channel. Not thread-safe."""

    def __init__(self, path: str | os.PathLike[str], *, scenario: dict[str, str] | None = None,
                 chunk_size: int = 1 << 20, compression: str = "zstd",
                 library: str = "radical-rt", flush_every_s: float | None = None) -> None:
        self.path = os.fspath(path)
        comp = _COMPRESSION.get(compression.lower())
        if comp is None:
            raise ArchiveError(f"{self.path}: unknown compression {compression!r} (zstd, lz4, none)")
        try:
            self._file = open(self.path, "wb")
            self._w = McapWriter(self._file, chunk_size=chunk_size, compression=comp)
            self._w.start(profile="", library=library)
            if scenario is not None:
                meta = {str(k): str(v) for k, v in scenario.items()}
                for k in ("name", "vehicle", "seed", "generator"):
                    meta.setdefault(k, library if k == "generator" else "")
                self._w.add_metadata(SCENARIO_METADATA, meta)
            self._file.flush()  # header (+ scenario) reach the file even if killed early
        except (OSError, McapError) as e:  # e.g. a missing directory, lz4 not installed
            if hasattr(self, "_file"):
                self._file.close()
            raise ArchiveError(f"{self.path}: cannot create archive: {one_line(e)}") from None
        self._packer = msgpack.Packer(use_bin_type=True, default=_np_default)
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}
        self._flush_every_s, self._last_flush = flush_every_s, time.monotonic()
        self._closed, self.message_count = False, 0

    def _channel(self, topic: str) -> int:
        cid = self._channels.get(topic)
        if cid is None:  # lazy registration; unknown topics get a schemaless (id 0) channel
            schema = SCHEMAS.get(topic)
            sid = 0 if schema is None else self._w.register_schema(
                schema_name(topic), "jsonschema", json.dumps(schema, sort_keys=True).encode())
            cid = self._channels[topic] = self._w.register_channel(topic, "msgpack", sid)
            self._seq[cid] = 0
        return cid

    def _msg_time(self, topic: str, msg: dict[str, Any]) -> float:
        """Bus time (s): ``t_bus`` (last element for a batch), else ``t``, else last ``t_true``."""
        key = next((k for k in ("t_bus", "t", "t_true") if k in msg), None)
        with contextlib.suppress(TypeError, IndexError, ValueError):
            v = msg[key] if key else None
            return float(v) if isinstance(v, numbers.Real | str) else float(v[-1])  # type: ignore[index]
        raise ArchiveError(f"{self.path}: {topic}: no t_bus given and no time (or non-empty list "
                           "of times) in the message's 't_bus', 't' or 't_true'")

    def write(self, topic: str, msg: dict[str, Any], t_bus: float | None = None) -> None:
        """msgpack-encode ``msg`` (numpy values become lists/scalars) and append it at
        log_time = publish_time = round(t_bus·1e9) ns; ``t_bus`` (s) defaults to the message's."""
        t = self._msg_time(topic, msg) if t_bus is None else float(t_bus)
        if not (math.isfinite(t) and 0.0 <= t < 1.8e10):
            raise ArchiveError(f"{self.path}: {topic}: bus time {t!r} s is not a valid MCAP time")
        self.write_raw(topic, self._packer.pack(msg), t_to_ns(t))

    def write_raw(self, topic: str, data: bytes, log_time_ns: int,
                  publish_time_ns: int | None = None) -> None:
        """Append an encoded payload (msgpack bytes) at ``log_time_ns`` (ns)."""
        if self._closed:
            raise ArchiveError(f"{self.path}: write to {topic} after close")
        pub = log_time_ns if publish_time_ns is None else publish_time_ns
        if not (0 <= log_time_ns < 1 << 64 and 0 <= pub < 1 << 64):
            raise ArchiveError(f"{self.path}: {topic}: time {log_time_ns}/{pub} ns not uint64")
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._channel(topic)
        seq = self._seq[cid]
        self._seq[cid] = (seq + 1) & 0xFFFFFFFF  # MCAP sequence is uint32
        self._w.add_message(cid, int(log_time_ns), data, int(pub), seq)
        self.message_count += 1
        if (self._flush_every_s is not None
                and time.monotonic() - self._last_flush >= self._flush_every_s):
            self.flush()

    def flush(self) -> None:
        """Close the chunk and flush the file (no fsync): a killed writer keeps all up to here."""
        if not self._closed:
            self._w.flush()
            self._file.flush()
        self._last_flush = time.monotonic()

    def close(self) -> None:
        """Write the summary and footer and close the file. Idempotent."""
        if not self._closed:
            self._closed = True
            try:
                self._w.finish()
            finally:
                self._file.close()

    def __enter__(self) -> ArchiveWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ArchiveReader:
    """Read an MCAP archive: metadata on open, then messages in log_time order.

    A complete file is read through its summary and chunk index. For a truncated one (no valid
    summary/footer: its writer was killed) the index is rebuilt from the records before the tear
    (bounds and chunk CRCs checked: a torn chunk is dropped whole), ``truncated`` is set and
    a :class:`TruncatedArchiveWarning` names the file and the messages recovered (the ``radical``
    command line prints it as one clean line).
    Times are log_time in ns, ranges ``[start_ns, end_ns)``; ``schemas``: topic -> jsonschema.
    """

    def __init__(self, path: str | os.PathLike[str], *, validate_crcs: bool = False) -> None:
        self.path = p = os.fspath(path)
        self.truncated, self._validate_crcs = False, validate_crcs
        self.topics: list[str] = []
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        self.scenario: dict[str, str] = {}
        self.schemas: dict[str, dict[str, Any]] = {}
        self.message_counts: dict[str, int] = {}
        try:
            self._f = open(p, "rb")
        except OSError as e:
            raise ArchiveError(f"{p}: cannot open: {e.strerror or e}") from None
        try:
            self._size = os.fstat(self._f.fileno()).st_size
            if (magic := self._f.read(len(MAGIC))) != MAGIC:
                what = "empty file" if self._size == 0 else f"bad magic bytes {magic!r}"
                raise ArchiveError(f"{p}: not an MCAP archive ({what})")
            self._load()
        except Exception as e:
            self._f.close()
            if isinstance(e, ArchiveError):
                raise
            raise ArchiveError(f"{p}: unreadable MCAP archive: {one_line(e)}") from e

    def _load(self) -> None:
        f, summary, footer_ok = self._f, None, False
        f.seek(max(self._size - len(MAGIC), 0))
        if self._size >= 2 * len(MAGIC) + 29 and f.read() == MAGIC:  # 29: footer record
            f.seek(0)
            self._reader = SeekingReader(f, validate_crcs=self._validate_crcs)
            try:
                summary, footer_ok = self._reader.get_summary(), True
            except Exception:  # torn or corrupt footer/summary: rebuild below
                pass
        if summary is None:
            summary, torn, self._good_bytes = rebuild_summary(f, self._size)
            self._reader = RebuiltIndexReader(f, summary, self._validate_crcs)
            torn = torn or (None if footer_ok else "no valid summary/footer after the data")
            if torn is not None:
                self.truncated, n = True, summary.statistics.message_count  # type: ignore[union-attr]
                text = (f"{self.path}: truncated MCAP archive ({torn}); recovered {n} messages "
                        f"from its first {self._good_bytes} of {self._size} bytes")
                warnings.warn(text, TruncatedArchiveWarning, stacklevel=3)  # (once: no log too)
        self._summary = summary
        self._header = None
        with contextlib.suppress(Exception):  # a torn header
            self._header = self._reader.get_header()
        self.metadata_records = list(self._reader.iter_metadata())  # mcap Metadata records
        stats = summary.statistics
        if stats is None:  # a foreign file without statistics: count
            counts = Counter(ch.id for _s, ch, _m in self._reader.iter_messages())
        else:
            counts = Counter(stats.channel_message_counts)
            if stats.message_count:
                self.start_ns, self.end_ns = stats.message_start_time, stats.message_end_time
        for cid, ch in sorted(summary.channels.items()):
            if ch.topic not in self.message_counts:
                self.topics.append(ch.topic)
            self.message_counts[ch.topic] = self.message_counts.get(ch.topic, 0) + counts[cid]
            sc = summary.schemas.get(ch.schema_id)
            if sc is not None and sc.encoding == "jsonschema" and ch.topic not in self.schemas:
                try:
                    self.schemas[ch.topic] = json.loads(sc.data)
                except ValueError:
                    log.warning("%s: schema %s of %s is not JSON", self.path, sc.name, ch.topic)
        for md in self.metadata_records:
            if md.name == SCENARIO_METADATA:
                self.scenario.update(md.metadata)

    def require_inputs(self) -> None:
        """Raise ArchiveError unless there are ``/siru`` and ``/st1`` or ``/st2`` messages."""
        if not self.message_counts.get("/siru"):
            raise ArchiveError(f"{self.path}: missing required channel /siru")
        if not (self.message_counts.get("/st1") or self.message_counts.get("/st2")):
            raise ArchiveError(f"{self.path}: no tracker channel (/st1 or /st2)")

    def iter_raw(self, topics: Iterable[str] | str | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[tuple[str, int, bytes]]:
        """``(topic, log_time_ns, data)`` in log_time order (ties in file order), [start, end)."""
        tset = None if topics is None else ({topics} if isinstance(topics, str) else set(topics))
        if start_ns is not None and end_ns is not None and end_ns <= start_ns:
            return
        chunks = self._ordered_chunks()
        try:
            if chunks is not None:
                yield from self._iter_chunks(chunks, tset, start_ns, end_ns)
                return
            for _schema, ch, m in self._reader.iter_messages(
                    topics=tset, starting_at=start_ns, ending_before=end_ns):
                yield ch.topic, m.log_time, m.data
        except Exception as e:
            raise ArchiveError(f"{self.path}: cannot read messages: {one_line(e)}") from e

    def _ordered_chunks(self) -> list[mr.ChunkIndex] | None:
        """The chunk indexes in file order when their time ranges do not overlap, else None. Then
        log_time order is chunk by chunk, each chunk's messages stably sorted by log_time (ties in
        file order), as the merge of the mcap reader gives it, without a heap over every message."""
        ci = sorted(self._summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
        if not ci or any(b.message_start_time < a.message_end_time
                         for a, b in zip(ci[:-1], ci[1:], strict=True)):
            return None
        return ci

    def _iter_chunks(self, chunks: list[mr.ChunkIndex], tset: set[str] | None,
                     start_ns: int | None, end_ns: int | None) -> Iterator[tuple[str, int, bytes]]:
        topic_of = {cid: ch.topic for cid, ch in self._summary.channels.items()}
        want = {cid for cid, t in topic_of.items() if tset is None or t in tset}
        lo = -1 if start_ns is None else start_ns
        hi = math.inf if end_ns is None else end_ns
        for c in chunks:
            if c.message_end_time < lo or c.message_start_time >= hi:
                continue
            self._f.seek(c.chunk_start_offset + 1 + 8)  # opcode, record length
            chunk = mr.Chunk.read(ReadDataStream(self._f))
            msgs = chunk_messages(chunk, self._validate_crcs, want, topic_of)
            msgs.sort(key=_first)
            for t, topic, data in msgs:
                if lo <= t < hi:
                    yield topic, t, data

    def iter_blocks(self, topics: Iterable[str]) -> Iterator[Block]:
        """The messages of :meth:`iter_raw` (same order) a chunk at a time, as arrays: a
        :class:`Block` per chunk (one for the whole file when the chunks' time ranges overlap).
        The batch shell's read: the stream takes the chunk's bytes directly
        (radical_rt.stream.block_feed.BlockFeed.feed_arrays)."""
        tset = set(topics)
        chunks = self._ordered_chunks()
        if chunks is None:
            yield Block.of(list(self.iter_raw(tset)))
            return
        names = sorted(tset)
        topic_of = {cid: ch.topic for cid, ch in self._summary.channels.items()}
        want = np.zeros(max(topic_of, default=0) + 1, np.bool_)
        idx = np.zeros(len(want), np.int64)
        for cid, t in topic_of.items():
            if t in tset:
                want[cid], idx[cid] = True, names.index(t)
        try:
            for c in chunks:
                self._f.seek(c.chunk_start_offset + 1 + 8)  # opcode, record length
                chunk = mr.Chunk.read(ReadDataStream(self._f))
                stream, n = get_chunk_data_stream(chunk, validate_crc=self._validate_crcs)
                buf = np.frombuffer(stream.read(n), np.uint8)
                rows = n // 31 + 1
                cid, t, off, size = (np.empty(rows, np.int64) for _ in range(4))
                m = split_messages(buf, want, cid, t, off, size)
                if m < 0:
                    raise ArchiveError(f"the chunk at byte {c.chunk_start_offset} has a record "
                                       "that runs past its end")
                order = np.argsort(t[:m], kind="stable")
                yield Block(buf, names, idx[cid[:m]][order], t[:m][order], off[:m][order],
                            size[:m][order])
        except ArchiveError as e:
            raise ArchiveError(f"{self.path}: cannot read messages: {e}") from e
        except Exception as e:
            raise ArchiveError(f"{self.path}: cannot read messages: {one_line(e)}") from e

    def iter_messages(self, topics: Iterable[str] | str | None = None,
                      start_ns: int | None = None,
                      end_ns: int | None = None) -> Iterator[tuple[str, int, dict[str, Any]]]:
        """:meth:`iter_raw`, decoded; a bad payload raises (use iter_raw to skip bad ones)."""
        for topic, t, data in self.iter_raw(topics, start_ns, end_ns):
            try:
                msg = msgpack.unpackb(data, raw=False, strict_map_key=False)
            except Exception as e:
                raise ArchiveError(f"{self.path}: {topic} at log_time {t} ns: undecodable "
                                   f"msgpack payload: {one_line(e)}") from None
            yield topic, t, msg

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> ArchiveReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_scenario(path: str | os.PathLike[str]) -> dict[str, str]:
    """The ``radical.scenario`` metadata of an archive ({} if absent)."""
    with ArchiveReader(path) as r:
        return dict(r.scenario)


def recover(path_in: str | os.PathLike[str], path_out: str | os.PathLike[str]) -> int:
    """Rewrite all that is readable in ``path_in`` into a complete archive ``path_out`` (may be
    the same path), in log_time order, keeping header, metadata, schemas, channels, times and
    sequence numbers. Returns the number of messages written."""
    out = os.fspath(path_out)
    tmp, n = out + ".recover-tmp", 0
    try:
        with ArchiveReader(path_in, validate_crcs=True) as r, open(tmp, "wb") as f:
            w = McapWriter(f)
            h = r._header
            w.start(profile=h.profile if h else "", library=h.library if h else "radical-rt")
            for md in r.metadata_records:
                w.add_metadata(md.name, dict(md.metadata))
            sids = {i: w.register_schema(s.name, s.encoding, s.data)
                    for i, s in sorted(r._summary.schemas.items())}
            cids = {i: w.register_channel(c.topic, c.message_encoding, sids.get(c.schema_id, 0),
                                          dict(c.metadata))
                    for i, c in sorted(r._summary.channels.items())}
            for _s, ch, m in r._reader.iter_messages():
                w.add_message(cids[ch.id], m.log_time, m.data, m.publish_time, m.sequence)
                n += 1
            w.finish()
        os.replace(tmp, out)
    except OSError as e:
        raise ArchiveError(f"{out}: cannot write recovered archive: {e.strerror or e}") from None
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    log.info("%s: recovered %d messages into %s", r.path, n, out)
    return n
