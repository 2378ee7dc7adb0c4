"""The message records of a decompressed MCAP chunk as arrays, in one compiled pass (the batch
read of :meth:`radical_rt.io.archive.ArchiveReader.iter_blocks`).

An MCAP chunk's records are ``opcode`` (uint8), ``length`` (uint64 LE) and ``length`` bytes; a
message record's body is channel id (uint16), sequence (uint32), log_time and publish_time
(uint64 ns), then the payload. :func:`split_messages` walks them once and returns, for the message
records of the wanted channels, their channel ids, log times and the payload's offset and size in
the chunk: what the stream's block intake takes directly, with no Python object per message.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radical_rt._jit import kernel

OP_MESSAGE = 0x05  # (mcap.opcode.Opcode.MESSAGE)


@kernel
def _le(buf, p, n):
    """The little-endian unsigned integer of n bytes at p (n ≤ 8; uint64 as int64 bits)."""
    v = np.uint64(0)
    for k in range(n - 1, -1, -1):
        v = (v << np.uint64(8)) | np.uint64(buf[p + k])
    return v


@kernel
def split_messages(buf, want, cid, log_ns, off, size):
    """The message records of chunk bytes ``buf`` (uint8 (n,)) whose channel id c has want[c]
    (bool, ids beyond it are not wanted): in file order, cid, log_ns (int64 [ns]), off, size
    (int64: the payload's place in buf) filled from row 0 (room for every record: n // 31).
    Returns the number of rows, or −1 if a record runs past the end (a damaged chunk: the
    caller reads it the slow way, which names the problem)."""
    n = buf.shape[0]
    pos = 0
    r = 0
    while pos < n:
        if pos + 9 > n:
            return -1
        op = buf[pos]
        length = np.int64(_le(buf, pos + 1, 8))
        pos += 9
        if length < 0 or pos + length > n:
            return -1
        if op == OP_MESSAGE:
            if length < 22:
                return -1
            c = np.int64(_le(buf, pos, 2))
            if c < want.shape[0] and want[c]:
                cid[r] = c
                log_ns[r] = np.int64(_le(buf, pos + 6, 8))
                off[r] = pos + 22
                size[r] = length - 22
                r += 1
        pos += length
    return r


@dataclass(frozen=True)
class Block:
    """Messages as arrays (:meth:`ArchiveReader.iter_blocks`): message i is topic
    names[tidx[i]] at log_time log_ns[i] [ns] with payload buf[off[i]:off[i] + size[i]]."""

    buf: np.ndarray
    names: list[str]
    tidx: np.ndarray
    log_ns: np.ndarray
    off: np.ndarray
    size: np.ndarray

    @staticmethod
    def of(messages: list[tuple[str, int, bytes]]) -> Block:
        """The block of (topic, log_time [ns], payload) messages."""
        names = sorted({t for t, _ns, _d in messages})
        k = {t: i for i, t in enumerate(names)}
        size = np.array([len(d) for _t, _ns, d in messages], np.int64)
        off = np.zeros(len(size), np.int64)
        np.cumsum(size[:-1], out=off[1:])
        return Block(np.frombuffer(b"".join(d for _t, _ns, d in messages), np.uint8), names,
                     np.array([k[t] for t, _ns, _d in messages], np.int64),
                     np.array([ns for _t, ns, _d in messages], np.int64), off, size)

    def __len__(self) -> int:
        return len(self.tidx)

    def topic(self, i: int) -> str:
        return self.names[self.tidx[i]]

    def payload(self, i: int) -> bytes:
        return self.buf[self.off[i]:self.off[i] + self.size[i]].tobytes()
