"""A worker of a fleet of filter nodes (issue #19; docs/fleet.md).

Every worker of fleet ``F`` declares the liveliness token ``radical-fleet/F/worker/<id>`` and
watches the others'. Of the fleet's vehicles (its roster) it serves those it owns by rendezvous
hashing over the live workers (:mod:`radical_rt.fleet.ownership`): each with a
:class:`~radical_rt.apps.node.FilterNode` of its own (inputs, outputs, commands and the
vehicle's token, exactly as a single node), plus an ownership token
``radical-fleet/F/owner/<V>/<id>``. Its checkpoints go to the fleet's replica
(:mod:`radical_rt.fleet.replica`) every ``checkpoint_every_s`` and when it lets a vehicle go.

When the live workers change (a join, a clean leave, a crash seen through the lease), every
worker recomputes the owners. A worker lets go of the vehicles it no longer owns (final
checkpoint published, then its ownership token undeclared) and takes the vehicles it now owns
once **no other worker serves or claims them**: it declares a claim token
(``radical-fleet/F/claim/<V>/<id>``), waits ``claim_settle_s`` and takes the vehicle (ownership
token first, then the node) only if no rival with a higher rendezvous score claims or serves it
(so two workers that claimed at once, each before seeing the other, agree on one),
from the newest replica (a new stream: warm start, clock phase forgotten) or
cold if there is none. What a takeover lost (the wall time since that replica was written) is
counted and reported in ``diag.node.fleet`` and ``status``. A worker that loses its link to
every router stops serving (it can no longer tell who is alive) until the link is back.
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

from radical_rt.apps.node import FilterNode
from radical_rt.fleet.ownership import owner, score
from radical_rt.fleet.replica import CheckpointReplica, fleet_prefix
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
    """A FilterNode's checkpoint target that publishes to the fleet's replica."""

    def __init__(self, replica: CheckpointReplica, vehicle: str) -> None:
        self.replica, self.vehicle = replica, vehicle

    def __call__(self, states: dict[str, dict[str, Any]]) -> str:
        try:
            rep = self.replica.publish(self.vehicle, states[self.vehicle])
        except Exception as exc:  # a closed or lost session: the node counts a failed write
            raise ckpt.CheckpointError(f"cannot publish to {self}: {exc}") from None
        return f"{self} #{rep.seq}"

    def __str__(self) -> str:
        return f"fleet replica {self.replica.key}{self.vehicle}"


class FleetWorker:
    """One worker of fleet ``fleet`` over ``transport`` (see the module docstring).

    vehicles: the roster. make_processor(name) → a fresh StreamProcessor. node_kw: FilterNode
    options for every vehicle. checkpoint_every_s: wall seconds between replica checkpoints.
    claim_settle_s: how long a claim waits for rival claims before the worker serves.
    """

    RECONCILE_S = 0.25  # the controller looks at least this often

    def __init__(self, transport: Transport, fleet: str, vehicles: list[str],
                 make_processor: Callable[[str], StreamProcessor], *,
                 worker_id: str | None = None, checkpoint_every_s: float = 10.0,
                 claim_settle_s: float = 0.3, node_kw: dict[str, Any] | None = None) -> None:
        if not _NAME.match(fleet):
            raise ValueError(f"fleet name {fleet!r} must match [a-z0-9_-]+")
        self.t, self.fleet, self.vehicles = transport, fleet, sorted(set(vehicles))
        self.id = worker_id or new_worker_id()
        self.make_processor, self.node_kw = make_processor, dict(node_kw or {})
        self.checkpoint_every_s = checkpoint_every_s
        self.claim_settle_s = claim_settle_s  # ≫ the time a token takes to reach every worker
        self.prefix = fleet_prefix(fleet)
        self.nodes: dict[str, tuple[FilterNode, Any]] = {}  # vehicle → (node, ownership token)
        self.takeovers: list[dict[str, Any]] = []
        self.fenced = False  # no router: serving nothing until the link is back
        self._lock = threading.Lock()
        self._members: set[str] = set()
        self._owners: dict[str, set[str]] = {}  # vehicle → workers serving it (owner tokens)
        self._claims: dict[str, set[str]] = {}  # vehicle → workers claiming it (claim tokens)
        self._last_owner: dict[str, str] = {}  # the last other worker seen owning each vehicle
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._decls: list[Any] = []
        self._thread: threading.Thread | None = None
        self.replica: CheckpointReplica | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> FleetWorker:
        self.replica = CheckpointReplica(self.t, self.fleet, self.id)
        self._decls.append(self.t.liveliness_subscribe(self.prefix + "worker/*", self._on_worker))
        self._decls.append(self.t.liveliness_subscribe(self.prefix + "owner/*/*", self._on_owner))
        self._decls.append(self.t.liveliness_subscribe(self.prefix + "claim/*/*", self._on_claim))
        self._decls.append(self.t.liveliness_token(self.prefix + f"worker/{self.id}"))
        self._thread = threading.Thread(target=self._run, name=f"fleet-{self.id}", daemon=True)
        self._thread.start()
        log.info("fleet %s: worker %s started (%d vehicles in the roster)", self.fleet, self.id,
                 len(self.vehicles))
        return self

    def stop(self) -> None:
        """Let every vehicle go (final checkpoints published), then leave the fleet."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        for v in sorted(self.nodes):
            self._release(v)
        for d in reversed(self._decls):
            d.undeclare()
        self._decls.clear()
        if self.replica is not None:
            self.replica.close()

    # ------------------------------------------------------------------ liveliness
    def _on_worker(self, key: str, alive: bool) -> None:
        wid = key.rsplit("/", 1)[-1]
        with self._lock:
            (self._members.add if alive else self._members.discard)(wid)
        self._wake.set()

    def _on_owner(self, key: str, alive: bool) -> None:
        vehicle, wid = key.split("/")[-2:]
        with self._lock:
            held = self._owners.setdefault(vehicle, set())
            (held.add if alive else held.discard)(wid)
            if alive and wid != self.id:
                self._last_owner[vehicle] = wid
        self._wake.set()

    def _on_claim(self, key: str, alive: bool) -> None:
        vehicle, wid = key.split("/")[-2:]
        with self._lock:
            held = self._claims.setdefault(vehicle, set())
            (held.add if alive else held.discard)(wid)
        self._wake.set()

    def live_workers(self) -> set[str]:
        with self._lock:
            return set(self._members) | {self.id}

    def _held_by_others(self, vehicle: str) -> set[str]:
        """The other workers that serve or claim ``vehicle``."""
        with self._lock:
            return (set(self._owners.get(vehicle, ())) | set(self._claims.get(vehicle, ()))) \
                - {self.id}

    # ------------------------------------------------------------------ reconciling
    def _run(self) -> None:
        while not self._stop.is_set():
            self._wake.wait(self.RECONCILE_S)
            self._wake.clear()
            if self._stop.is_set():
                break
            try:
                self.reconcile()
            except Exception:  # a bug: keep the worker alive, log it loudly
                log.exception("fleet %s: reconcile failed", self.fleet)

    def owned(self) -> list[str]:
        """The vehicles this worker should serve now."""
        live = self.live_workers()
        return [v for v in self.vehicles if owner(v, live) == self.id]

    def reconcile(self) -> None:
        """Let go of the vehicles no longer owned; take those owned and free (controller thread)."""
        connected = getattr(self.t, "connected", lambda: True)()
        if not connected:
            if not self.fenced:
                log.warning("fleet %s: worker %s lost its link: serving nothing until it is "
                            "back", self.fleet, self.id)
            self.fenced = True
            for v in sorted(self.nodes):
                self._release(v, publish=False)
            return
        self.fenced = False
        target = set(self.owned())
        for v in sorted(self.nodes):
            if v not in target or self._outranked(v):
                self._release(v)
        free = [v for v in sorted(target - set(self.nodes)) if not self._held_by_others(v)]
        if not free:
            return
        # claim first, then look again: two workers that claimed at once (neither saw the
        # other yet) both see both claims after the settle time, and the higher score keeps it
        claims = {v: self.t.liveliness_token(self.prefix + f"claim/{v}/{self.id}") for v in free}
        self._stop.wait(self.claim_settle_s)
        for v, claim in claims.items():
            if not (self._stop.is_set() or self._outranked(v)):
                self._take(v)
            claim.undeclare()  # (after the ownership token of a vehicle taken)

    def _outranked(self, vehicle: str) -> bool:
        """Another worker claims ``vehicle`` with a higher rendezvous score than ours."""
        mine = score(self.id, vehicle)
        return any(score(o, vehicle) > mine for o in self._held_by_others(vehicle))

    def _take(self, vehicle: str) -> None:
        assert self.replica is not None
        rep = self.replica.fetch(vehicle, timeout=1.0)
        sp = self.make_processor(vehicle)
        info: dict[str, Any] = {"worker": self.id, "fleet": self.fleet, "taken_unix": time.time(),
                                "source": "cold", "replica_worker": None, "lost_s": None}
        if rep is not None:
            try:
                ckpt.restore(sp, rep.state(), new_stream=True)
                age = max(0.0, time.time() - rep.t_wall)
                info.update(source="replica", replica_worker=rep.worker, replica_seq=rep.seq,
                            replica_age_s=age, lost_s=0.0, loss_flagged=False)
                if not rep.final or rep.worker != self._last_owner.get(vehicle, rep.worker):
                    # not handed over (its owner crashed): the input since then is lost
                    sp.note_takeover_loss(age)
                    info.update(lost_s=age, loss_flagged=True)
            except ckpt.CheckpointError as exc:
                log.error("fleet %s: replica of %s unusable (%s): cold start", self.fleet,
                          vehicle, exc)
                sp = self.make_processor(vehicle)
        node = FilterNode(self.t, {vehicle: sp}, checkpoint_path=ReplicaSink(self.replica, vehicle),
                          checkpoint_every_s=self.checkpoint_every_s, **self.node_kw)
        node.fleet_info = info
        token = self.t.liveliness_token(self.prefix + f"owner/{vehicle}/{self.id}")
        node.start()  # (outputs only under the ownership token)
        self.nodes[vehicle] = (node, token)
        self.takeovers.append({"vehicle": vehicle, **info})
        log.info("fleet %s: %s taken by %s (%s%s)", self.fleet, vehicle, self.id, info["source"],
                 f", {info['lost_s']:.1f} s since the replica" if info["lost_s"] is not None else "")

    def _release(self, vehicle: str, publish: bool = True) -> None:
        """Stop serving ``vehicle``: the node stops (what is queued is fed), the final checkpoint
        goes to the replica, then the ownership token goes (the next owner waits for that)."""
        node, token = self.nodes.pop(vehicle)
        node.stop(drain_s=0.5, final_checkpoint=False)
        if publish and self.replica is not None:
            try:
                self.replica.publish(vehicle, ckpt.capture(node.vehicles[vehicle].sp, vehicle),
                                     final=True)
            except Exception as exc:  # the final checkpoint failed: the periodic one stands
                log.error("fleet %s: final checkpoint of %s failed: %s", self.fleet, vehicle, exc)
        token.undeclare()
        log.info("fleet %s: %s let go by %s", self.fleet, vehicle, self.id)

    def status(self) -> dict[str, Any]:
        """The worker's view: live workers, owned/served vehicles, takeovers."""
        return {"worker": self.id, "fleet": self.fleet, "live_workers": sorted(self.live_workers()),
                "serving": sorted(self.nodes), "owned": self.owned(), "fenced": self.fenced,
                "takeovers": list(self.takeovers),
                "replicas": {v: {"worker": r.worker, "seq": r.seq, "age_s": time.time() - r.t_wall}
                             for v, r in (self.replica.vehicles() if self.replica else {}).items()}}
