"""The end-of-stream marker (a contract extension, docs/contract_extensions.md).

A publisher of input messages (``radical replay``) ends each stream it publishes with one message
on ``radical/<vehicle>/eos``, after the stream's last input message and on the same session, so
it arrives in the node's input FIFO behind them::

    {"v": 1, "next": "none" | "warm" | "cold", "counts": {"siru": n, "st1": n, ...},
     "t_bus": last t_bus of the stream [s] (optional), "source": str (optional)}

``counts``: the input messages the publisher sent in this stream, per topic (without the slash).
The node then releases everything it holds for reordering (as ``radical process`` does at the
end of its input: :meth:`radical_rt.stream.processor.StreamProcessor.end_stream`), compares ``counts`` with
what it received since the previous marker (the difference is counted as lost:
``input_reported_lost``, ``INPUT_GAP``) and, with ``next`` "warm" / "cold", prepares the next
stream as between two archives. A marker that does not decode is a counted rejection
(``bad_eos``) that changes nothing.
"""

from __future__ import annotations

from typing import Any

EOS_TOPIC = "eos"
NEXT = ("none", "warm", "cold")
MAX_COUNT = 1 << 53


def decode_eos(payload: bytes | dict,
               topics: tuple[str, ...]) -> tuple[str, dict[str, int], str | None]:
    """Marker → (next, counts per input topic, source or None). InputError (reason ``bad_eos``)
    if invalid; a ``source`` that is not a string is ignored (at most 512 characters kept)."""
    from radical_rt.stream.packets import (  # (publishers import this module without Numba)
        InputError,
        unpack,
    )

    try:
        msg = unpack(payload)
    except InputError as exc:
        raise InputError("bad_eos", f"end-of-stream marker: {exc}") from None
    if msg.get("v") != 1:
        raise InputError("bad_eos", "end-of-stream marker: v must be 1")
    nxt = msg.get("next", "none")
    if nxt not in NEXT:
        raise InputError("bad_eos", f"end-of-stream marker: next must be one of {NEXT}, "
                                    f"got {nxt!r}")
    raw = msg.get("counts", {})
    if not isinstance(raw, dict):
        raise InputError("bad_eos", "end-of-stream marker: counts must be a map")
    counts: dict[str, int] = {}
    for k, v in raw.items():
        if k not in topics:
            continue  # a topic this node does not take: ignored
        if type(v) is not int or not 0 <= v <= MAX_COUNT:
            raise InputError("bad_eos", f"end-of-stream marker: counts[{k!r}] must be an "
                                        f"integer in 0..2**53, got {v!r}")
        counts[k] = v
    source = msg.get("source")
    return nxt, counts, source[:512] if isinstance(source, str) else None


def make_eos(counts: dict[str, int], next_start: str = "none", **extra: Any) -> dict[str, Any]:
    """The marker map (for publishers)."""
    return {"v": 1, "next": next_start, "counts": {k.lstrip("/"): int(n) for k, n in counts.items()},
            **extra}
