"""What a fleet worker knows of the others, from their liveliness tokens (thread-safe).

Tokens under ``radical-fleet/<fleet>/``: ``worker/<id>`` (alive), ``claim/<V>/<id>`` (about to
take V), ``owner/<V>/<id>`` (serving V), ``hold/<V>/<id>`` (holding V's inputs for a handover).
"""

from __future__ import annotations

import threading

from radical_rt.fleet.ownership import score

KINDS = ("claim", "owner", "hold")


class FleetView:
    """Live workers and, per vehicle, who claims, serves or holds it; ``me`` excluded from the
    "others" queries. ``on_change()`` is called after every token change."""

    def __init__(self, me: str, on_change=lambda: None) -> None:
        self.me, self._on_change = me, on_change
        self._lock = threading.Lock()
        self._members: set[str] = set()
        self._tokens: dict[str, dict[str, set[str]]] = {k: {} for k in KINDS}
        self._last_owner: dict[str, str] = {}  # the last other worker seen serving a vehicle

    def on_worker(self, key: str, alive: bool) -> None:
        """Liveliness callback for ``worker/*``."""
        wid = key.rsplit("/", 1)[-1]
        with self._lock:
            (self._members.add if alive else self._members.discard)(wid)
        self._on_change()

    def on_token(self, key: str, alive: bool) -> None:
        """Liveliness callback for ``claim|owner|hold/*/*``."""
        kind, vehicle, wid = key.split("/")[-3:]
        with self._lock:
            held = self._tokens[kind].setdefault(vehicle, set())
            (held.add if alive else held.discard)(wid)
            if kind == "owner" and alive and wid != self.me:
                self._last_owner[vehicle] = wid
        self._on_change()

    def live(self) -> set[str]:
        with self._lock:
            return set(self._members) | {self.me}

    def others(self, kind: str, vehicle: str) -> set[str]:
        """The other workers that hold a ``kind`` token for ``vehicle``."""
        with self._lock:
            return set(self._tokens[kind].get(vehicle, ())) - {self.me}

    def taken_by_others(self, vehicle: str) -> set[str]:
        """The other workers that serve or claim ``vehicle``."""
        return self.others("owner", vehicle) | self.others("claim", vehicle)

    def outranked(self, vehicle: str, kinds: tuple[str, ...] = ("owner", "claim")) -> bool:
        """Another worker holds a token of ``kinds`` for ``vehicle`` with a higher rendezvous
        score than ours."""
        mine = score(self.me, vehicle)
        rivals = set().union(*(self.others(k, vehicle) for k in kinds))
        return any(score(o, vehicle) > mine for o in rivals)

    def last_owner(self, vehicle: str) -> str | None:
        with self._lock:
            return self._last_owner.get(vehicle)
