"""The seeded case table of the clock robustness matrix (issue 17) and its scenarios.

Each :class:`Case` is the built-in ``2006216`` scenario (truth, maneuver, trackers) with one
bus-read timing setup: tag mode, constant read offset, read jitter (1σ and distribution), late
reads, the SIRU oscillator offset ε, 2**32 counter wraps, counter resets and data gaps. Times are
s from the run start (bus time 0 for 2006216), SI throughout; ε in ppm as in the scenario files.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

WRAP = 2**32
T = 0.01  # nominal SIRU sample period, s
PHASE_S = 0.0043  # the scenario's default time of sample 0, s


@dataclass(frozen=True)
class Case:
    """One matrix case (see the module docstring). ``wrap_s``: bus time of the 2**32 counter
    wrap (None: no wrap in the run); ``resets_s``: counter resets; ``gaps``: (start, end) data
    gaps, s; ``late_prob`` per read, ``late_max_s`` the largest delay of a late read."""

    name: str
    eps_ppm: float
    tag_mode: str = "tick"
    offset_s: float = 0.0
    jitter_s: float = 30e-6
    dist: str = "gaussian"
    dof: float = 3.0
    late_prob: float = 0.0
    late_max_s: float = 0.0
    wrap_s: float | None = None
    resets_s: tuple[float, ...] = ()
    gaps: tuple[tuple[float, float], ...] = ()
    duration_s: float = 3600.0
    seed: int = 17
    notes: str = field(default="", compare=False)

    @property
    def sawtooth_s(self) -> float:
        """Sawtooth period T(1+ε)/|ε| of the tag error, s."""
        eps = self.eps_ppm * 1e-6
        return T * (1 + eps) / abs(eps)

    @property
    def lock_limit_s(self) -> float:
        """The issue's lock aim: two sawtooth periods or 300 s, whichever is shorter."""
        return min(2.0 * self.sawtooth_s, 300.0)

    @property
    def events_s(self) -> list[float]:
        """Times of the injected real discontinuities (counter resets, gap ends), s."""
        return sorted([*self.resets_s, *(b for _, b in self.gaps)])

    def jitter_label(self) -> str:
        lab = f"{self.jitter_s * 1e6:g} µs"
        if self.dist == "student_t":
            lab += f" t{self.dof:g}"
        elif self.dist == "uniform":
            lab += " unif"
        if self.late_prob:
            lab += f" +late {self.late_prob * 100:g}%≤{self.late_max_s * 1e3:g}ms"
        return lab

    def disc_label(self) -> str:
        parts = []
        if self.wrap_s is not None:
            parts.append(f"wrap@{self.wrap_s:g}")
        parts += [f"reset@{r:g}" for r in self.resets_s]
        parts += [f"gap {b - a:g}s@{a:g}" for a, b in self.gaps]
        return ", ".join(parts) or "—"

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> Case:
        """The inverse of :meth:`to_dict`, also after a JSON round trip (lists → tuples)."""
        d = dict(d)
        d["resets_s"] = tuple(d.get("resets_s", ()))
        d["gaps"] = tuple(tuple(g) for g in d.get("gaps", ()))
        return cls(**d)


def scenario(case: Case) -> dict:
    """The synth scenario (TOML layout, as a mapping) of a case."""
    eps = case.eps_ppm * 1e-6
    siru = {"eps_ppm": case.eps_ppm, "read_jitter_s": case.jitter_s, "tag_mode": case.tag_mode,
            "read_jitter_dist": case.dist, "read_jitter_dof": case.dof}
    if case.tag_mode == "tick":
        siru["read_offset_s"] = case.offset_s
    if case.late_prob:
        siru.update(late_read_prob=case.late_prob, late_read_max_s=case.late_max_s)
    if case.wrap_s is not None:
        n = int((case.wrap_s - PHASE_S) / (T * (1 + eps)))  # samples before the wrap
        siru["tt0"] = WRAP - 10000 * n
    if case.resets_s:
        siru["tt_reset_s"] = list(case.resets_s)
    return {"base": "2006216", "name": f"clock-matrix-{case.name}", "seed": case.seed,
            "duration_s": case.duration_s, "siru": siru,
            "faults": [{"kind": "gap", "start_s": a, "end_s": b} for a, b in case.gaps]}


_R = "read"
#: The full matrix: offset {0, 0.3, 0.5 (the issue's), 0.9 ms} × jitter (2/30/100 µs Gaussian,
#: Student-t, uniform, late reads) × ε ∈ {−300, −100, −30, +10, +40, +100, +300} ppm × wraps,
#: resets and 1–60 s dropouts; mostly tick tags, the reference cases with read-instant tags.
CASES: tuple[Case, ...] = (
    Case("read-2us", +40, _R, jitter_s=2e-6, seed=101, notes="the issue's clean reference"),
    Case("read-20us", -100, _R, jitter_s=20e-6, wrap_s=1200, resets_s=(2400,), seed=102),
    Case("read-100us", +100, _R, jitter_s=100e-6, seed=103),
    Case("read-t3", -30, _R, dist="student_t", wrap_s=900, seed=104),
    Case("read-late", +300, _R, jitter_s=20e-6, late_prob=0.005, late_max_s=1e-3, seed=105),
    Case("read-30us-gap", -300, _R, resets_s=(2000,), gaps=((1000, 1030),), seed=106),
    Case("issue+40", +40, offset_s=0.5e-3, wrap_s=1200, seed=107, notes="issue 17's archive"),
    Case("issue-40", -40, offset_s=0.5e-3, wrap_s=1200, seed=108, notes="issue 17, fast SIRU"),
    Case("tick0-2us", +10, jitter_s=2e-6, seed=109),
    Case("tick0-30us", -300, wrap_s=1800, seed=110),
    Case("tick0-100us", +100, jitter_s=100e-6, resets_s=(1800,), seed=111),
    Case("tick.3-2us", -100, offset_s=0.3e-3, jitter_s=2e-6, wrap_s=600, seed=112),
    Case("tick.3-30us", +300, offset_s=0.3e-3, gaps=((1500, 1501),), seed=113),
    Case("tick.3-100us", -30, offset_s=0.3e-3, jitter_s=100e-6, wrap_s=1000, resets_s=(2500,),
         seed=114),
    Case("tick.3-t3", +40, offset_s=0.3e-3, dist="student_t", seed=115),
    Case("tick.3-unif", -100, offset_s=0.3e-3, dist="uniform", gaps=((2000, 2020),), seed=116),
    Case("tick.3-late", +100, offset_s=0.3e-3, jitter_s=20e-6, late_prob=0.01, late_max_s=2e-3,
         wrap_s=1500, seed=117),
    Case("tick.3-t5", +100, offset_s=0.3e-3, jitter_s=60e-6, dist="student_t", dof=5.0,
         resets_s=(1200,), gaps=((2400, 2410),), seed=118),
    Case("tick.5-gap60", -100, offset_s=0.5e-3, wrap_s=700, gaps=((1800, 1860),), seed=119),
    Case("tick.9-2us", +40, offset_s=0.9e-3, jitter_s=2e-6, resets_s=(2000,), seed=120),
    Case("tick.9-30us", -300, offset_s=0.9e-3, wrap_s=1200, seed=121),
    Case("tick.9-100us", +10, offset_s=0.9e-3, jitter_s=100e-6, seed=122),
    Case("tick.9-t3", -100, offset_s=0.9e-3, jitter_s=100e-6, dist="student_t",
         gaps=((1200, 1260),), seed=123),
    Case("tick.9-unif", +300, offset_s=0.9e-3, jitter_s=100e-6, dist="uniform", resets_s=(1000,),
         seed=124),
    Case("tick.9-late", -30, offset_s=0.9e-3, late_prob=0.005, late_max_s=2.5e-3, wrap_s=800,
         gaps=((2600, 2605),), seed=125),
    Case("tick.9-eps10", +10, offset_s=0.9e-3, wrap_s=1500, resets_s=(2700,), seed=126),
)

#: The shortened subset (tests/studies/test_clock_matrix.py): 300–600 s, sawtooth periods ≤ 100 s so
#: that two wraps fit.
QUICK: tuple[Case, ...] = (
    Case("q-read-2us", +300, _R, jitter_s=2e-6, wrap_s=150, duration_s=300, seed=201),
    Case("q-issue+100", +100, offset_s=0.5e-3, wrap_s=250, duration_s=600, seed=202),
    Case("q-tick.9-100us", -300, offset_s=0.9e-3, jitter_s=100e-6, resets_s=(200,),
         duration_s=300, seed=203),
    Case("q-tick.3-t3-late", -100, offset_s=0.3e-3, dist="student_t", late_prob=0.005,
         late_max_s=1e-3, gaps=((400, 405),), duration_s=600, seed=204),
)


def by_name(name: str) -> Case:
    """The case of the full or quick table with this name (KeyError if none)."""
    for c in (*CASES, *QUICK):
        if c.name == name:
            return c
    raise KeyError(f"no clock-matrix case named {name!r}; cases: "
                   + ", ".join(c.name for c in (*CASES, *QUICK)))
