"""A worker of a fleet of filter nodes (issue #19; docs/fleet.md).

Every worker of fleet ``F`` declares the liveliness token ``radical-fleet/F/worker/<id>`` and
watches the others'. Of the fleet's vehicles (its roster) it serves those it owns by rendezvous
hashing over the live workers (:mod:`radical_rt.fleet.ownership`), all in ONE filter loop
(:class:`~radical_rt.apps.fleet_node.FleetNode`: inputs, outputs, commands and the vehicle's
token exactly as a single node, one subscription per vehicle held or served), plus an ownership
token ``radical-fleet/F/owner/<V>/<id>`` per vehicle. Its checkpoints go to the fleet's replica
(:mod:`radical_rt.fleet.replica`) every ``checkpoint_every_s`` (staggered over the vehicles)
and when it lets a vehicle go.

When the live workers change (a join, a clean leave, a crash seen through the lease), every
worker recomputes the owners.

* **Handover** (clean join or leave): the next owner opens the vehicle's input FIFO without
  feeding it and declares ``radical-fleet/F/hold/<V>/<id>``; the old owner then stops at a cut
  (every input queued before it fed, none after), publishes the final checkpoint with the digest of the last input fed, and undeclares
  its ownership token; the next owner restores it as the *same* stream, drops the held inputs
  the old owner fed and serves. The result equals an uninterrupted run bit for bit. A leaving
  worker first undeclares its worker token so the others start holding.
* **Takeover** (crash, or no holder within ``handover_wait_s``): the new owner waits until no
  other worker serves or claims the vehicle, claims it (``radical-fleet/F/claim/<V>/<id>``),
  waits ``claim_settle_s`` and takes it only if no rival with a higher rendezvous score claims
  or serves it, from the newest replica as a new stream (warm start) or cold if there is none.
  What a crash lost (the wall time since that replica) is counted as an input gap, flagged
  (INPUT_GAP) and reported in ``diag.node.fleet`` and ``status``.

Outputs are published only under the ownership token, so two workers never serve one vehicle at
once. A worker that loses its link to every router stops serving (it can no longer tell who is
alive) until the link is back.
"""

from __future__ import annotations

import logging
import os
import re
import secrets
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from radical_rt.apps.fleet_node import FleetNode
from radical_rt.fleet.discovery import Discovery
from radical_rt.fleet.ownership import owner
from radical_rt.fleet.replica import CheckpointReplica, Replica, fleet_prefix
from radical_rt.fleet.roster import Roster
from radical_rt.fleet.view import KINDS, FleetView
from radical_rt.io import checkpoint as ckpt
from radical_rt.io.transport import Transport
from radical_rt.stream.processor import StreamProcessor

log = logging.getLogger("radical.fleet")
_NAME = re.compile(r"^[a-z0-9_-]+$")


def new_worker_id() -> str:
    """A worker id unique in the fleet: host, process id and a random suffix."""
    host = re.sub(r"[^a-z0-9-]", "-", socket.gethostname().lower())[:24] or "host"
    return f"{host}-{os.getpid()}-{secrets.token_hex(2)}"


class ReplicaSink:
    """A FilterNode's checkpoint target that publishes every state to the fleet's replica."""

    def __init__(self, replica: CheckpointReplica) -> None:
        self.replica = replica

    def __call__(self, states: dict[str, dict[str, Any]]) -> str:
        seqs = []
        for vehicle, state in states.items():
            try:
                seqs.append(f"{vehicle} #{self.replica.publish(vehicle, state).seq}")
            except Exception as exc:  # a closed or lost session: the node counts a failed write
                raise ckpt.CheckpointError(f"cannot publish {vehicle} to {self}: {exc}") from None
        return f"{self}: {', '.join(seqs)}"

    def __str__(self) -> str:
        return f"fleet replica {self.replica.key}"


class FleetWorker:
    """One worker of fleet ``fleet`` over ``transport`` (see the module docstring).

    vehicles: the static roster, edited by ``radical fleet add/remove`` through the fleet's
    shared :class:`~radical_rt.fleet.roster.Roster`. discover: an input topic whose keys add
    new vehicles when this worker is the fleet's discoverer (None: no discovery).
    make_processor(name) → a fresh StreamProcessor. node_kw: options of
    the worker's :class:`FleetNode` (those of FilterNode). checkpoint_every_s: wall seconds
    between two replica checkpoints of a vehicle. claim_settle_s: how long a claim waits for rival claims before the worker serves.
    handover_wait_s: how long a vehicle no longer owned waits for its next owner to hold its
    inputs before it is let go without a handover.
    """

    RECONCILE_S = 0.25  # the controller looks at least this often

    def __init__(self, transport: Transport, fleet: str, vehicles: list[str],
                 make_processor: Callable[[str], StreamProcessor], *,
                 worker_id: str | None = None, checkpoint_every_s: float = 10.0,
                 claim_settle_s: float = 0.3, handover_wait_s: float = 3.0,
                 node_kw: dict[str, Any] | None = None, discover: str | None = None) -> None:
        if not _NAME.match(fleet):
            raise ValueError(f"fleet name {fleet!r} must match [a-z0-9_-]+")
        self.t, self.fleet = transport, fleet
        self.id = worker_id or new_worker_id()
        self.make_processor, self.node_kw = make_processor, dict(node_kw or {})
        self.checkpoint_every_s = checkpoint_every_s
        self.claim_settle_s = claim_settle_s  # ≫ the time a token takes to reach every worker
        self.handover_wait_s = handover_wait_s
        self.resync_s = 1.0  # after a lost link: wait this long for the others' tokens
        self._resync_until = 0.0
        self.prefix = fleet_prefix(fleet)
        self.node: FleetNode | None = None  # the one filter loop (from start)
        self.serving: dict[str, Any] = {}  # vehicle → its ownership token
        self.holding: dict[str, Any] = {}  # inputs held: vehicle → its hold token
        self.takeovers: list[dict[str, Any]] = []
        self.fenced = False  # no router: serving nothing until the link is back
        self._wake = threading.Event()
        self.view = FleetView(self.id, self._wake.set)
        self.roster = Roster(transport, fleet, self.id, vehicles, on_change=self._wake.set)
        self.discovery = (Discovery(transport, self.roster, self.id, discover, self._wake.set)
                          if discover else None)
        self._unowned_since: dict[str, float] = {}
        self._owned_key: tuple[frozenset[str], tuple[str, ...]] | None = None
        self._owned: list[str] = []
        self._stop = threading.Event()
        self._decls: list[Any] = []
        self._token: Any = None
        self._thread: threading.Thread | None = None
        self.replica: CheckpointReplica | None = None

    @property
    def vehicles(self) -> list[str]:
        """The fleet's roster now (sorted)."""
        return self.roster.vehicles()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> FleetWorker:
        self.roster.start()
        self.replica = CheckpointReplica(self.t, self.fleet, self.id)
        self.node = FleetNode(self.t, inbox_key=self.prefix + f"inbox/{self.id}",
                              checkpoint_path=ReplicaSink(self.replica),
                              checkpoint_every_s=self.checkpoint_every_s, **self.node_kw)
        self.node.start()
        self._decls.append(self.t.liveliness_subscribe(self.prefix + "worker/*",
                                                       self.view.on_worker))
        for kind in KINDS:
            self._decls.append(self.t.liveliness_subscribe(self.prefix + f"{kind}/*/*",
                                                           self.view.on_token))
        self._token = self.t.liveliness_token(self.prefix + f"worker/{self.id}")
        self._thread = threading.Thread(target=self._run, name=f"fleet-{self.id}", daemon=True)
        self._thread.start()
        log.info("fleet %s: worker %s started (%d vehicles in the roster)", self.fleet, self.id,
                 len(self.vehicles))
        return self

    def stop(self) -> None:
        """Leave the fleet cleanly: say so (worker token undeclared), hand every vehicle to the
        worker that now owns it once it holds the inputs (or after handover_wait_s), leave."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self._token is not None:
            self._token.undeclare()
            self._token = None
        end = time.monotonic() + (self.handover_wait_s if self.serving else 0.0)
        for v in sorted(self.serving):
            while not self.view.others("hold", v) and time.monotonic() < end:
                time.sleep(0.02)
            self._release(v)
        for v in list(self.holding):
            self._drop_hold(v)
        if self.discovery is not None:
            self.discovery.stop()
        if self.node is not None:
            self.node.stop(drain_s=0.0, final_checkpoint=False)
        for d in reversed(self._decls):
            d.undeclare()
        self._decls.clear()
        if self.replica is not None:
            self.replica.close()
        self.roster.close()

    # ------------------------------------------------------------------ reconciling
    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(self.RECONCILE_S)
            self._wake.clear()
            if self._stop.is_set():
                break
            try:
                self.roster.sync(self.view.live())  # anti-entropy (roster edits missed)
                if self.discovery is not None:
                    self.discovery.follow(self.view.live())
                self.reconcile()
            except Exception:  # a bug: keep the worker alive, log it loudly
                log.exception("fleet %s: reconcile failed", self.fleet)

    def live_workers(self) -> set[str]:
        return self.view.live()

    def owned(self) -> list[str]:
        """The vehicles this worker should serve now (recomputed only when the live workers or
        the roster change: N vehicles × W workers scores, 20 ms for 1000 × 20)."""
        key = (frozenset(self.view.live()), tuple(self.vehicles))
        if key != self._owned_key:
            self._owned = [v for v in key[1] if owner(v, key[0]) == self.id]
            self._owned_key = key
        return list(self._owned)

    def reconcile(self) -> None:
        """One look at the fleet (controller thread): let go, hold, claim and take."""
        if not getattr(self.t, "connected", lambda: True)():
            self._fence()
            return
        if self.fenced:  # the link is back: let the others' tokens arrive before acting
            self.fenced = False
            self._resync_until = time.monotonic() + self.resync_s
            log.info("fleet %s: worker %s has its link again", self.fleet, self.id)
        if time.monotonic() < self._resync_until:
            return
        target = set(self.owned())
        self._let_go(target)
        for v in sorted(set(self.holding) - target):
            self._drop_hold(v)
        for v in sorted(target - set(self.serving) - set(self.holding)):
            if self.view.others("owner", v):  # served elsewhere: hold its inputs, then take it
                self._hold(v)
        free = [v for v in sorted(target - set(self.serving)) if not self.view.taken_by_others(v)]
        if not free:
            return
        # claim first, then look again: two workers that claimed at once (neither saw the
        # other yet) both see both claims after the settle time, and the higher score keeps it
        claims = {v: self.t.liveliness_token(self.prefix + f"claim/{v}/{self.id}") for v in free}
        self._stop.wait(self.claim_settle_s)
        for v, claim in claims.items():
            # never take a vehicle another worker serves; of rival claims the higher score wins
            if not (self._stop.is_set() or self.view.others("owner", v) or self.view.outranked(v)):
                self._take(v)
            claim.undeclare()  # (after the ownership token of a vehicle taken)

    def _let_go(self, target: set[str]) -> None:
        """Release the vehicles no longer owned: at a cut once the next owner holds their
        inputs, without one after handover_wait_s; at once when another worker serves it with a
        higher score (two owners after a healed partition: the lower one yields); at once when
        it left the roster (no worker will hold it)."""
        now = time.monotonic()
        roster = set(self.vehicles)
        for v in sorted(self.serving):
            rival = self.view.outranked(v, ("owner",))
            if v in target and not rival:
                self._unowned_since.pop(v, None)
                continue
            since = self._unowned_since.setdefault(v, now)
            if (self.view.others("hold", v) or rival or v not in roster
                    or now - since >= self.handover_wait_s):
                self._release(v)
                self._unowned_since.pop(v, None)

    def _fence(self) -> None:
        if not self.fenced:
            log.warning("fleet %s: worker %s lost its link: serving nothing until it is back",
                        self.fleet, self.id)
        self.fenced = True
        for v in sorted(self.serving):
            self._release(v, publish=False)
        for v in list(self.holding):
            self._drop_hold(v)

    # ------------------------------------------------------------------ one vehicle
    def _hold(self, vehicle: str) -> None:
        """Hold the inputs of a vehicle served elsewhere (subscribed, not fed), then say so."""
        assert self.node is not None
        self.node.hold(vehicle, self.make_processor(vehicle))
        self.holding[vehicle] = self.t.liveliness_token(self.prefix + f"hold/{vehicle}/{self.id}")
        log.info("fleet %s: %s holds the inputs of %s", self.fleet, self.id, vehicle)

    def _drop_hold(self, vehicle: str) -> None:
        assert self.node is not None
        self.holding.pop(vehicle).undeclare()
        self.node.drop(vehicle)

    def _take(self, vehicle: str) -> None:
        assert self.replica is not None and self.node is not None
        held = self.holding.pop(vehicle, None)
        if held is None:
            self.node.hold(vehicle, self.make_processor(vehicle))
        rep = self.replica.fetch(vehicle, timeout=1.0)
        info: dict[str, Any] = {"worker": self.id, "fleet": self.fleet, "taken_unix": time.time(),
                                "source": "cold", "replica_worker": None, "lost_s": None}
        digest = self._restore(vehicle, rep, info, held is not None) if rep is not None else None
        token = self.t.liveliness_token(self.prefix + f"owner/{vehicle}/{self.id}")
        dropped = self.node.serve_vehicle(vehicle, digest, info)  # outputs under the token
        if digest is not None:
            info["held_dropped"] = dropped  # those the old owner fed
        if held is not None:
            held.undeclare()
        self.serving[vehicle] = token
        self.takeovers.append({"vehicle": vehicle, **info})
        log.info("fleet %s: %s taken by %s (%s%s)", self.fleet, vehicle, self.id, info["source"],
                 f", {info['lost_s']:.1f} s lost" if info.get("loss_flagged") else "")

    def _restore(self, v: str, rep: Replica, info: dict[str, Any], held: bool) -> bytes | None:
        """Put the replica's state into the held vehicle; the digest of the last input the old
        owner fed when it is a handover (None otherwise)."""
        assert self.node is not None
        sp = self.node.processor(v)
        handover = bool(held and rep.final and rep.handover
                        and rep.worker == self.view.last_owner(v))
        age = max(0.0, time.time() - rep.t_wall)
        try:
            # a handover continues the stream (bit for bit); otherwise a new stream starts
            ckpt.restore(sp, rep.state(), new_stream=not handover)
        except ckpt.CheckpointError as exc:
            log.error("fleet %s: replica of %s unusable (%s): cold start", self.fleet, v, exc)
            self.node.replace_processor(v, self.make_processor(v))
            return None
        info.update(source="handover" if handover else "replica", replica_worker=rep.worker,
                    replica_seq=rep.seq, replica_age_s=age, lost_s=0.0, loss_flagged=False)
        if handover:
            return rep.cut or b""
        if not rep.final or rep.worker != self.view.last_owner(v):
            # not handed over (its owner crashed): the input since that checkpoint is lost
            sp.note_takeover_loss(age)
            info.update(lost_s=age, loss_flagged=True)
        return None

    def _release(self, vehicle: str, publish: bool = True) -> None:
        """Stop serving ``vehicle`` at a cut (every input queued now fed, none after). Then the
        final checkpoint goes to the replica (with the cut's digest when another worker holds
        its inputs: a handover), and only then the ownership token (the next owner waits for
        that)."""
        assert self.node is not None
        token = self.serving.pop(vehicle)
        handover = publish and bool(self.view.others("hold", vehicle))
        try:
            digest, cut = self.node.cut(vehicle), True
        except TimeoutError as exc:
            log.error("fleet %s: no cut for %s (%s): let go without a handover",
                      self.fleet, vehicle, exc)
            digest, cut = None, False
        if publish and cut and self.replica is not None:
            try:
                self.replica.publish(vehicle, ckpt.capture(self.node.processor(vehicle), vehicle),
                                     final=True, handover=handover, cut=digest if handover else None)
            except Exception as exc:  # the final checkpoint failed: the periodic one stands
                log.error("fleet %s: final checkpoint of %s failed: %s", self.fleet, vehicle, exc)
        token.undeclare()
        if cut:
            self.node.drop(vehicle)
        log.info("fleet %s: %s let go by %s%s", self.fleet, vehicle, self.id,
                 " at a cut (handover)" if handover else "")

    def status(self) -> dict[str, Any]:
        """The worker's view: live workers, owned/served vehicles, takeovers."""
        return {"worker": self.id, "fleet": self.fleet, "live_workers": sorted(self.live_workers()),
                "serving": sorted(self.serving), "holding": sorted(self.holding),
                "owned": self.owned(), "fenced": self.fenced,
                "takeovers": list(self.takeovers), "roster": self.roster.status(),
                "discovery": self.discovery.status() if self.discovery is not None else None,
                "replicas": {v: {"worker": r.worker, "seq": r.seq, "age_s": time.time() - r.t_wall}
                             for v, r in (self.replica.vehicles() if self.replica else {}).items()}}
