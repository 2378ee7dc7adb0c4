"""Link loss (issue 23, "losses visible"): a vehicle whose stream was active and from which no
input has arrived for ``stale_after_s`` of wall time has lost its link (a stopped or partitioned
publisher, a router down, a broken session): LINK_LOSS (bit 19) is raised and published at once,
``link_losses`` counts the losses and ``link_lost_s`` their total length; the flag clears with the
next input. A stream is active from its first input until its end-of-stream marker (after a
marker, silence is expected). docs/node.md "Losses and bounds", docs/contract_extensions.md.

Input gaps inside the stream (INPUT_GAP, bit 18) are seen in the bus times once input resumes;
LINK_LOSS is the wall-time view, raised while the input is still missing.
"""

from __future__ import annotations

import logging

log = logging.getLogger("radical.node")


class LinkWatch:
    """One vehicle's link state (filter loop thread only)."""

    def __init__(self, stale_after_s: float) -> None:
        if not stale_after_s > 0:
            raise ValueError("stale_after_s must be > 0")
        self.stale_after_s = stale_after_s
        self.active = False  # a stream is running (input seen since the last end-of-stream)
        self.lost = False
        self.last_mono = 0.0
        self.lost_since = 0.0

    def seen(self, now: float) -> float | None:
        """An input arrived at ``now``; the length of the loss it ends [s], or None."""
        self.active, self.last_mono = True, now
        if not self.lost:
            return None
        self.lost = False
        return now - self.lost_since

    def ended(self) -> None:
        """The stream ended with a marker: silence is expected from now."""
        self.active = False

    def check(self, now: float) -> bool:
        """True when the link is found lost now (once per loss)."""
        if self.active and not self.lost and now - self.last_mono >= self.stale_after_s:
            self.lost, self.lost_since = True, self.last_mono
            return True
        return False


def input_seen(node, v, now: float) -> None:
    """Filter loop: an input of vehicle ``v`` arrived; a loss it ends is cleared and published."""
    w = v.link
    if w is None:
        return
    dt = w.seen(now)
    if dt is not None:
        v.sp.note_link_loss(False, dt)
        node.publish(v, v.sp.fault_now())
        log.warning("%s: input again after %.3g s: link restored", v.name, dt)


def check_links(node, now: float) -> None:
    """Filter loop, between messages and on idle ticks: raise and publish the losses found."""
    for v in node.vehicles.values():
        w = v.link
        if w is not None and w.check(now):
            v.sp.note_link_loss(True)
            node.publish(v, v.sp.fault_now())
            log.warning("%s: no input for %.3g s: link lost", v.name, now - w.last_mono)
