"""The end of a vehicle's stream at the node (docs/node.md, "End of stream"): an end-of-stream
marker (:func:`end_of_stream`: losses counted, everything held released, the next stream
prepared) or, without one, no input for ``idle_release_s`` (:func:`release_idle`). Both run in
the filter loop of :class:`radical_rt.apps.node.FilterNode`.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from radical_rt.apps.node_vehicle import Vehicle, note_reject
from radical_rt.stream.eos import EOS_TOPIC, decode_eos
from radical_rt.stream.packets import InputError
from radical_rt.stream.processor import INPUT_TOPICS

if TYPE_CHECKING:
    from radical_rt.apps.node import FilterNode

log = logging.getLogger("radical.node")


def end_of_stream(node: FilterNode, v: Vehicle, data: bytes) -> None:
    """Filter loop: an end-of-stream marker of ``v`` (:mod:`radical_rt.stream.eos`): losses
    counted, everything held released (as at the end of ``radical process``), the next stream
    prepared."""
    try:
        nxt, counts, source = decode_eos(data, INPUT_TOPICS)
    except InputError as exc:
        note_reject(v.sp, EOS_TOPIC, exc.reason, str(exc))
        return
    with v.lock:
        received = dict(v.received)
    lost = sum(max(0, n - (received.get(t, 0) - v.at_eos.get(t, 0))) for t, n in counts.items())
    v.at_eos = received
    v.eos_seen += 1
    if v.link is not None:
        v.link.ended()
    if lost:
        v.reported_lost += lost
        v.sp.note_reported_loss(lost)
        log.warning("%s: end of stream: %d input message(s) sent were never received",
                    v.name, lost)
    node.publish(v, v.sp.end_stream(None, source=source) + v.sp.fault_now())
    if nxt != "none":
        node.publish(v, v.sp.end_stream(nxt))
    v.holding = False


def release_idle(node: FilterNode, now: float) -> None:
    """Filter loop, waiting for input (node with ``idle_release_s`` set; ``now``: its monotonic
    clock [s]): release what a vehicle holds for reordering once no input came for
    ``idle_release_s`` (wall time): the end of a stream without a marker ends as ``radical
    process`` ends."""
    idle_s = node.idle_release_s
    if idle_s is None:
        return
    for v in node.vehicles.values():
        if v.holding and now - v.last_input_mono >= idle_s:
            v.holding = False
            v.idle_releases += 1
            node.publish(v, v.sp.end_stream(None))
            log.info("%s: no input for %.3g s: held samples released", v.name,
                     now - v.last_input_mono)

