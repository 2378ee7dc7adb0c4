"""Telemetry packets (tlm/small, tlm/medium, tlm/large), their field catalogue and schedule.

A packet is a list of fields from :data:`CATALOGUE` published every ``period_s`` of event time
(the engine's bus time line), so batch and streaming shells emit identical packets. Its
``trigger`` says when it is built:

* ``"window"``: at the filter's window closes. ``t``, the attitude and the rate are the filter's
  own estimate, which lags the newest data by the tracker latency plus the reorder slack (≈ 0.165 s
  by default), because trackers are processed at their measurement epoch.
* ``"sample"``: as soon as a SIRU message has been taken in. ``t`` is the newest gyro sample's
  time and ``q_body_from_inertial`` / ``omega_body`` are predicted from the filter's estimate
  through the samples it has not processed yet (gyro-only propagation with the current
  calibration); every other field is the filter's current value. This is the low-latency
  attitude output; ``tlm/small`` uses it by default.

Defaults follow CONTRACT §3; a TOML packet file changes them::

    [packets.small]
    period_s = 0.01        # every sample (100 Hz)
    trigger = "sample"
    fields = ["seq", "t", "q_body_from_inertial", "flags", "mode"]
    [packets.large]
    decimation = 10        # alternatively: every 10th window close (10 Hz base rate)
    fields = ["seq", "t", "est", "sigma"]
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

SMALL = ["seq", "t", "q_body_from_inertial", "flags", "mode"]
MEDIUM = SMALL + ["omega_body", "est"]
LARGE = MEDIUM + ["sigma", "att_sigma", "residuals", "clock", "counters", "latency"]

#: field → (description with units, getter(source) → value). source provides engine/stream state.
CATALOGUE: dict[str, tuple[str, Callable[[Any], Any]]] = {
    "seq": ("packet sequence number (per packet kind)", lambda s: None),
    "t": ("time of the estimate, bus time line [s]", lambda s: s.engine.t),
    "q_body_from_inertial": ("attitude estimate, scalar-last", lambda s: s.engine.q.tolist()),
    "flags": ("fault flag bits (CONTRACT §3.1)", lambda s: int(s.flags)),
    "mode": ("init | converging | converged | degraded", lambda s: s.engine.mode),
    "omega_body": ("body rate estimate [rad/s]", lambda s: s.engine.omega.tolist()),
    "est": ("parameter estimates per group, SI", lambda s: s.engine.estimates()),
    "sigma": ("parameter 1σ per group, SI", lambda s: s.engine.sigmas()),
    "att_sigma": ("attitude 1σ, body axes [rad]", lambda s: s.engine.att_sigma()),
    "residuals": ("last innovations, 1σ and NIS per kind (st1, st2 [rad]; parity [rad])",
                  lambda s: s.engine.residual_stats()),
    "clock": ("SIRU clock reconstruction state", lambda s: s.clock.telemetry()),
    "counters": ("engine and input counters", lambda s: s.counters()),
    "latency": ("tracker latency: configured_s, residual_s (estimated true − configured), "
                "estimate_s, sigma_s [s]", lambda s: s.engine.latency_estimate()),
    "excluded": ("excluded gyro indices", lambda s: [int(i) for i, e in enumerate(s.engine.excluded) if e]),
    "fdi": ("parity FDI: state, last ν, alarm and last isolation (docs/fdi.md)",
            lambda s: s.engine.fdi.detail() if s.engine.fdi is not None else None),
    "flag_names": ("names of the flags set", lambda s: s.flag_names()),
}


TRIGGERS = ("window", "sample")


class PacketError(ValueError):
    """Invalid packet configuration; the message names the packet and the problem."""


@dataclass
class PacketSpec:
    """One packet kind: name (small/medium/large), fields and rate (period or decimation)."""

    name: str
    fields: list[str]
    period_s: float | None = None
    decimation: int | None = None
    trigger: str = "window"  # "window" (filter window closes) or "sample" (each SIRU message)
    seq: int = 0
    next_t: float = field(default=float("-inf"))
    windows: int = 0

    def due(self, t: float) -> bool:
        """Whether the packet is due at event time t (called once per trigger event)."""
        if self.decimation is not None:
            self.windows += 1
            if self.windows >= self.decimation:
                self.windows = 0
                return True
            return False
        if self.trigger == "sample":
            # sample times are regular: schedule from the last packet, accepting a sample 5 % of
            # a period early, so that jitter or an oscillator offset never skips a packet
            if t >= self.next_t:
                self.next_t = t + 0.95 * float(self.period_s or 0.0)
                return True
            return False
        if t >= self.next_t:
            self.next_t = t + float(self.period_s or 0.0) if self.next_t == float("-inf") \
                else self.next_t + float(self.period_s or 0.0)
            if self.next_t <= t:  # fell behind (e.g. after a gap): re-anchor
                self.next_t = t + float(self.period_s or 0.0)
            return True
        return False


def default_packets() -> dict[str, PacketSpec]:
    """The contract's default packets: small 10 Hz (sample-triggered), medium 1 Hz, large 1 Hz."""
    return {"small": PacketSpec("small", list(SMALL), period_s=0.1, trigger="sample"),
            "medium": PacketSpec("medium", list(MEDIUM), period_s=1.0),
            "large": PacketSpec("large", list(LARGE), period_s=1.0)}


#: valid packet period [s] (NaN, ±inf and booleans are refused) and largest decimation
PERIOD_RANGE_S = (1e-3, 86400.0)
DECIMATION_MAX = 1_000_000


def parse_packets(doc: dict[str, Any]) -> dict[str, PacketSpec]:
    """Validate a packet configuration map {name: {fields, period_s | decimation}}; all-or-nothing."""
    if not isinstance(doc, dict):
        raise PacketError("packet configuration must be a map of packet name → settings")
    out = default_packets()
    for name, spec in doc.items():
        if name not in out:
            raise PacketError(f"unknown packet {name!r}; valid: small, medium, large")
        if not isinstance(spec, dict):
            raise PacketError(f"packet {name!r}: settings must be a map")
        unknown = set(spec) - {"fields", "period_s", "decimation", "trigger"}
        if unknown:
            raise PacketError(f"packet {name!r}: unknown setting(s) {sorted(map(str, unknown))}")
        fields_ = spec.get("fields", out[name].fields)
        if not isinstance(fields_, list) or not fields_ or len(fields_) > len(CATALOGUE):
            raise PacketError(f"packet {name!r}: fields must be a non-empty list of at most "
                              f"{len(CATALOGUE)} names")
        bad = [f for f in fields_ if not isinstance(f, str) or f not in CATALOGUE]
        if bad:
            raise PacketError(f"packet {name!r}: unknown field(s) {bad[:5]}; catalogue: {sorted(CATALOGUE)}")
        if len(set(fields_)) != len(fields_):
            raise PacketError(f"packet {name!r}: fields repeat")
        period, dec = spec.get("period_s"), spec.get("decimation")
        if period is not None and dec is not None:
            raise PacketError(f"packet {name!r}: give period_s or decimation, not both")
        if period is not None and (isinstance(period, bool) or not isinstance(period, (int, float))
                                   or not PERIOD_RANGE_S[0] <= period <= PERIOD_RANGE_S[1]):
            raise PacketError(f"packet {name!r}: period_s must be a number in "
                              f"[{PERIOD_RANGE_S[0]:g}, {PERIOD_RANGE_S[1]:g}] s, got {period!r}")
        if dec is not None and (not isinstance(dec, int) or isinstance(dec, bool)
                                or not 1 <= dec <= DECIMATION_MAX):
            raise PacketError(f"packet {name!r}: decimation must be an integer in "
                              f"[1, {DECIMATION_MAX}], got {dec!r}")
        if period is not None:
            period = float(period)
        if period is None and dec is None:
            period, dec = out[name].period_s, out[name].decimation
        trigger = spec.get("trigger", out[name].trigger)
        if trigger not in TRIGGERS:
            raise PacketError(f"packet {name!r}: trigger must be one of {', '.join(TRIGGERS)}, "
                              f"got {trigger!r}")
        out[name] = PacketSpec(name, list(fields_), period_s=period, decimation=dec, trigger=trigger)
    return out


def load_packets(path: str | Path) -> dict[str, PacketSpec]:
    """Load a TOML packet file ([packets.small], ...) with clear errors."""
    try:
        doc = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise PacketError(f"{path}: {exc}") from None
    try:
        return parse_packets(doc.get("packets", doc))
    except PacketError as exc:
        raise PacketError(f"{path}: {exc}") from None


def build(spec: PacketSpec, source: Any, override: dict[str, Any] | None = None,
          memo: dict[str, Any] | None = None) -> dict[str, Any]:
    """Build one packet map (with "v": 1 and the stream index ``stream``, whatever the packet's
    fields) from the source's current state; fields named in
    ``override`` take the given values instead (the predicted t, attitude and rate). ``memo``:
    field values already read from this same state (packets built at one event share them; the
    values are then shared objects, not copies), filled in as fields are read."""
    spec.seq += 1
    msg: dict[str, Any] = {"v": 1, "stream": source.streams.index}
    for name in spec.fields:
        if name == "seq":
            msg[name] = spec.seq
        elif override is not None and name in override:
            msg[name] = override[name]
        else:
            msg[name] = read_field(name, source, memo)
    return msg


#: fields the engine computes together in one compiled call (Engine.output_numbers): with a memo,
#: reading one of them reads all four
NUMBER_FIELDS = frozenset(("est", "sigma", "att_sigma", "latency"))


def read_field(name: str, source: Any, memo: dict[str, Any] | None = None) -> Any:
    """The value of catalogue field ``name`` from ``source``; with ``memo``, read at most once
    (the value is stored there and shared by every packet built from the same state; the
    :data:`NUMBER_FIELDS` are read together)."""
    if memo is None:
        return CATALOGUE[name][1](source)
    v = memo.get(name, _UNSET)
    if v is _UNSET:
        if name in NUMBER_FIELDS:
            memo.update(source.engine.output_numbers())
            return memo[name]
        v = memo[name] = CATALOGUE[name][1](source)
    return v


_UNSET = object()
