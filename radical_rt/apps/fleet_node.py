"""The node a fleet worker runs for one vehicle: a :class:`~radical_rt.apps.node.FilterNode`
that can hand its vehicle over without losing or repeating an input (docs/fleet.md, "Handover").

* It remembers the digest of the last input it fed (:func:`input_digest`).
* :meth:`FleetNode.cut` puts a cut marker at the end of its input FIFO and waits until the loop
  reaches it: every input queued before the marker is fed, none after. The digest at that moment
  goes with the final checkpoint to the next owner.
* The next owner opens its FIFO first (:meth:`FilterNode.open_inbox`: inputs held, not fed),
  restores the final checkpoint, drops the held inputs up to and including the one with that
  digest (:meth:`FleetNode.skip_through`; when none matches, the cut came before it began to
  hold, and every held input is new), then serves.

Why nothing is lost: the next owner declares its hold token only after its subscription, and
the old owner places its marker only after it has seen that token; a sample routed before the
new subscription reached the old owner before the token (one link, in order) and so lies before
the marker; a sample routed after it reaches both, and the digest removes the doubles.
"""

from __future__ import annotations

import hashlib
import threading
from typing import Any

from radical_rt.apps.node import FilterNode
from radical_rt.stream.eos import EOS_TOPIC
from radical_rt.stream.processor import INPUT_TOPICS

_FED = frozenset((*INPUT_TOPICS, EOS_TOPIC))


def input_digest(topic: str, payload: bytes) -> bytes:
    """16 bytes of BLAKE2b over an input's topic and payload (it identifies one message)."""
    return hashlib.blake2b(topic.encode() + b"\x00" + payload, digest_size=16).digest()


class FleetNode(FilterNode):
    """A FilterNode for one vehicle of a fleet (see the module docstring)."""

    CUT = "@cut"  # the marker's topic (no input topic starts with @)

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        if len(self.vehicles) != 1:
            raise ValueError("a fleet node serves exactly one vehicle")
        self.vehicle = next(iter(self.vehicles.values()))
        self.last_fed: bytes | None = None
        self._cut_seen = threading.Event()

    def take_input(self, key: str, data: bytes) -> None:
        topic = key[len(self.vehicle.prefix):]
        if topic == self.CUT:
            self._cut_seen.set()
            return
        if self._cut_seen.is_set():
            return  # after the cut: the next owner feeds it
        super().take_input(key, data)
        if topic in _FED:
            self.last_fed = input_digest(topic, data)

    def cut(self, timeout: float = 10.0) -> bytes | None:
        """Stop feeding at the end of what is queued now; the digest of the last input fed.
        TimeoutError if the loop does not reach the marker within ``timeout`` s."""
        box = self._inbox
        if box is None or not hasattr(box, "push"):
            raise RuntimeError("a fleet node needs a byte-bounded input FIFO (queue_bytes)")
        box.push(self.vehicle.prefix + self.CUT, b"")
        if not self._cut_seen.wait(timeout):
            raise TimeoutError(f"{self.vehicle.name}: the filter loop did not reach the cut")
        return self.last_fed

    def skip_through(self, digest: bytes | None) -> int:
        """Before :meth:`serve`: drop the held inputs up to and including the one the old owner
        fed last (``digest``); how many were dropped (0: none matched, all are new)."""
        box = self._inbox
        if digest is None or box is None:
            return 0
        prefix = self.vehicle.prefix

        def match(key: str, payload: bytes) -> bool:
            topic = key[len(prefix):]
            return topic in _FED and input_digest(topic, payload) == digest

        return box.drop_through(match) or 0
