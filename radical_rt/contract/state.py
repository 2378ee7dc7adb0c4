"""The error-state layout, declared once: named blocks → slices, attitude first.

Order (CONTRACT, notes §3.1): ``att`` 3 (rad, body), ``b`` n (rad/s), ``lam`` n, ``mu`` n,
``du`` n (rad), ``dv`` n (rad), ``phi2`` 3 (rad, body). With n = 4 gyros, N_STATES = 26 (the
contract's states). The engine appends one extension state, ``lat`` 1 (s): the residual tracker
latency (true − configured), see docs/engine.md §5 — ``StateLayout(n, latency=True)``.
Attitude first means the trailing parameter block's covariance is stored on its own in the UD
factors, so warm start and the structured time update are cheap (notes §11.5–11.6).
Code writes ``x[B.slice]`` (or ``x[LAYOUT['b']]``), never literal index ranges.
"""

from __future__ import annotations

from dataclasses import dataclass

#: Parameter groups in state order (everything after the attitude).
PARAM_GROUPS = ("b", "lam", "mu", "du", "dv", "phi2")
#: Groups sized by the number of gyros.
GYRO_GROUPS = ("b", "lam", "mu", "du", "dv")


@dataclass(frozen=True)
class Block:
    """One named state block: ``start`` index and ``size``."""

    name: str
    start: int
    size: int

    @property
    def stop(self) -> int:
        return self.start + self.size

    @property
    def slice(self) -> slice:
        return slice(self.start, self.stop)


class StateLayout:
    """Ordered state blocks for n gyros; iterable, indexable by name."""

    def __init__(self, n_gyro: int = 4, latency: bool = False) -> None:
        if n_gyro < 4:
            raise ValueError(f"need at least 4 gyros, got {n_gyro}")
        self.n_gyro = n_gyro
        self.latency = latency
        sizes = [("att", 3)] + [(g, n_gyro) for g in GYRO_GROUPS] + [("phi2", 3)]
        if latency:
            sizes.append(("lat", 1))
        blocks, start = [], 0
        for name, size in sizes:
            blocks.append(Block(name, start, size))
            start += size
        self.blocks: tuple[Block, ...] = tuple(blocks)
        self.n_states = start
        self._by_name = {b.name: b for b in self.blocks}

    def __contains__(self, name: str) -> bool:
        return name in self._by_name

    def __getitem__(self, name: str) -> slice:
        return self._by_name[name].slice

    def block(self, name: str) -> Block:
        return self._by_name[name]

    def __iter__(self):
        return iter(self.blocks)

    @property
    def n_params(self) -> int:
        """Number of parameter states (everything after the attitude)."""
        return self.n_states - 3

    @property
    def gyro_params(self) -> slice:
        """Slice covering b, lam, mu, du, dv (the gyro calibration, 5n states)."""
        return slice(self._by_name["b"].start, self._by_name["dv"].stop)


LAYOUT = StateLayout(4)
N_STATES = LAYOUT.n_states
ATT = LAYOUT.block("att")
B = LAYOUT.block("b")
LAM = LAYOUT.block("lam")
MU = LAYOUT.block("mu")
DU = LAYOUT.block("du")
DV = LAYOUT.block("dv")
PHI2 = LAYOUT.block("phi2")
