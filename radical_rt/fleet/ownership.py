"""Which worker owns which vehicle: rendezvous (highest-random-weight) hashing.

Every worker computes the same owner from the same set of live workers (their liveliness
tokens), with no coordinator and no message exchanged: the owner of a vehicle is the worker with
the highest score ``blake2b(worker, vehicle)``. When a worker joins, it takes over only the
vehicles it now scores highest on (about 1/N of them); when one leaves, only its own vehicles
move, each to the worker that scored second on it. (Thaler and Ravishankar, "Using name-based
mappings to increase hit rates", IEEE/ACM ToN 1998.)
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable


def score(worker: str, vehicle: str) -> int:
    """The worker's weight for the vehicle: 64 bits of BLAKE2b over both names."""
    h = hashlib.blake2b(f"{worker}\x00{vehicle}".encode(), digest_size=8)
    return int.from_bytes(h.digest(), "big")


def owner(vehicle: str, workers: Iterable[str]) -> str | None:
    """The vehicle's owner among ``workers`` (None if there is none); ties broken by name."""
    best: tuple[int, str] | None = None
    for w in workers:
        key = (score(w, vehicle), w)
        if best is None or key > best:
            best = key
    return best[1] if best is not None else None


def assign(vehicles: Iterable[str], workers: Iterable[str]) -> dict[str, str | None]:
    """vehicle → owner for every vehicle."""
    ws = sorted(set(workers))
    return {v: owner(v, ws) for v in vehicles}


def moves(vehicles: Iterable[str], before: Iterable[str],
          after: Iterable[str]) -> dict[str, tuple[str | None, str | None]]:
    """vehicle → (old owner, new owner) for the vehicles whose owner changes when the live
    workers go from ``before`` to ``after``."""
    vs = list(vehicles)
    a, b = assign(vs, before), assign(vs, after)
    return {v: (a[v], b[v]) for v in vs if a[v] != b[v]}
