"""Chunked simulation of one scenario: SIRU clock and reads, gyro outputs, trackers, temperatures,
truth; produces the archive messages (CONTRACT §3, §4) and the true counters.

Everything runs on bus ticks ``j`` (``t = t_start + j·bus_period``, ``0 ≤ j < n_ticks``): SIRU
reads at every tick j ≥ 1, trackers / temperatures / truth on ticks that are multiples of their
period. Chunks are whole multiples of every period and of the /siru batch, and every random
stream is drawn in sample order, so the output does not depend on the chunk size. Data gaps drop
every message with a time in [start, end); with ``split_at_gaps`` the parts between gaps go to
separate archives (their counters restart).
"""

from __future__ import annotations

import math
import zlib

import numpy as np

from radical_rt.contract.conventions import t_to_ns

from .clock import BusReads, SiruClock, latest_sample, read_counts
from .siru import SiruModel
from .trackers import Thermal, Tracker, st_from_inertial

#: Order of topics with equal log times.
TOPIC_ORDER = {"/siru": 0, "/st1": 1, "/st2": 2, "/temp": 3, "/truth/attitude": 4,
               "/truth/params": 5, "/truth/siru_time": 6}
TIMING_KEYS = ("n", "lead_sum_ns", "lead_sq_sum_ns2", "n_late", "n_clipped")
COUNT_KEYS = ("n_samples", "n_reads", "n_repeated", "n_missing", "n_distinct", "n_tt_wraps",
              "n_tt_resets", "st1_sent", "st1_valid", "st2_sent", "st2_valid")


def stream(seed: int, name: str) -> np.random.Generator:
    """The independent random stream ``name`` of a scenario seed."""
    ss = np.random.SeedSequence(seed, spawn_key=(zlib.crc32(name.encode()),))
    return np.random.Generator(np.random.PCG64(ss))


class Layout:
    """Bus-tick bookkeeping: tick period P (s), stream divisors, chunks, gaps and archive parts."""

    def __init__(self, cfg: dict):
        self.P = cfg["siru"]["bus_period_s"]
        self.t0 = cfg["t_start_s"]
        self.n_ticks = int(round(cfg["duration_s"] / self.P))
        rates = {"/st": cfg["trackers"]["rate_hz"], "/temp": cfg["thermal"]["rate_hz"],
                 "/truth/attitude": cfg["output"]["attitude_hz"],
                 "/truth/params": cfg["output"]["params_hz"]}
        self.div = {k: int(round(1.0 / (hz * self.P))) for k, hz in rates.items()}
        self.block = max(1, int(round(1.0 / self.P)))  # reads per /truth/siru_time block
        lcm = math.lcm(cfg["siru"]["batch"], self.block, *self.div.values())
        self.chunk_ticks = lcm * max(1, math.ceil(cfg["output"]["chunk_s"] / self.P / lcm))
        self.gaps = sorted((self.t0 + f["start_s"], self.t0 + f["end_s"])
                           for f in cfg["faults"] if f["kind"] == "gap")
        self.split = bool(cfg["output"]["split_at_gaps"] and self.gaps)
        self.n_parts = len(self.gaps) + 1 if self.split else 1
        self.t_end = self.t0 + self.n_ticks * self.P

    def chunks(self):
        """Tick ranges [j0, j1) covering [0, n_ticks)."""
        for j0 in range(0, self.n_ticks, self.chunk_ticks):
            yield j0, min(j0 + self.chunk_ticks, self.n_ticks)

    def ticks(self, j0: int, j1: int, key: str) -> np.ndarray:
        """Ticks (m,) in [j0, j1) of the stream ``key`` (multiples of its divisor)."""
        d = self.div[key]
        return np.arange(-(-j0 // d) * d, j1, d)

    def time(self, j: np.ndarray) -> np.ndarray:
        return self.t0 + j * self.P

    def keep(self, t: np.ndarray) -> np.ndarray:
        """Mask (m,) of times outside every data gap."""
        ok = np.ones(t.shape, dtype=bool)
        for a, b in self.gaps:
            ok &= ~((t >= a) & (t < b))
        return ok

    def after_gaps(self, t: np.ndarray) -> np.ndarray:
        """Times (m,) with those inside a data gap moved to the gap's end."""
        out = np.array(t, dtype=float)
        for a, b in self.gaps:
            out[(out >= a) & (out < b)] = b
        return out

    def part(self, t: np.ndarray) -> np.ndarray:
        """Archive part (m,) of each time: number of gaps ended at or before it (0 if not split)."""
        if not self.split:
            return np.zeros(t.shape, dtype=int)
        return np.searchsorted(np.array([b for _, b in self.gaps]), t, side="right")


def timing_summary(sums: dict) -> dict:
    """Read-timing truth of one archive part from :attr:`Simulator.timing`'s sums: reads, mean
    and standard deviation of the read's lead on its tag ``t_bus − t_read`` (s), late reads and
    (tick mode) reads clipped to their tag. The leads are summed in whole ns, exactly, so the
    result does not depend on the chunking."""
    n = max(sums["n"], 1)
    var = max(sums["lead_sq_sum_ns2"] * n - sums["lead_sum_ns"] ** 2, 0) / (n * n)
    return {"n_reads": int(sums["n"]), "read_lead_mean_s": sums["lead_sum_ns"] / n * 1e-9,
            "read_lead_std_s": math.sqrt(var) * 1e-9,
            "n_late_reads": int(sums["n_late"]), "n_clipped_reads": int(sums["n_clipped"])}


def _runs(*keys: np.ndarray) -> list[slice]:
    """Slices of the maximal runs over which every key (m,) is constant."""
    if keys[0].size == 0:
        return []
    change = np.zeros(keys[0].size - 1, dtype=bool)
    for k in keys:
        change |= k[1:] != k[:-1]
    edges = [0, *(np.flatnonzero(change) + 1).tolist(), keys[0].size]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]


class Simulator:
    """One pass over a scenario. ``full=False`` runs only the clock and tracker flags (counts).

    ``chunk(j0, j1)`` returns the messages of ticks [j0, j1) as (part, log_ns, order, topic, msg),
    sorted; ``counts[part]`` accumulates the true counters (COUNT_KEYS).
    """

    def __init__(self, sc, full: bool = True):
        cfg, seed = sc.cfg, sc.seed
        self.cfg, self.full = cfg, full
        self.lay = Layout(cfg)
        t0 = cfg["t_start_s"]
        self.clock = SiruClock(cfg["siru"], t0, stream(seed, "siru.sample_jitter"))
        self.reads = BusReads(cfg["siru"], t0, stream(seed, "siru.read_jitter"),
                              lambda name: stream(seed, name))
        self.profile = sc.profile()
        self.thermal = Thermal(cfg["thermal"], t0, sc.truth["phi2"])
        self.trackers = {}
        for name in ("st1", "st2"):
            if cfg["trackers"][name]:
                out = [(t0 + f["start_s"], t0 + f["end_s"]) for f in cfg["faults"]
                       if f["kind"] == "tracker_outage" and f["tracker"] == name]
                rngs = {k: stream(seed, f"{name}.{k}")
                        for k in ("stars", "noise", "valid", "drop", "corrupt")}
                self.trackers[name] = Tracker(name, cfg["trackers"], out, rngs)
        if full:
            self.siru = SiruModel(cfg, sc.truth, self.profile,
                                  {k: stream(seed, f"siru.{k}")
                                   for k in ("arw", "bias_rw", "burst", "bias_flicker")})
            self.temp_rng = stream(seed, "temp")
        self.truth = sc.truth
        self.last: tuple | None = None  # (k, t, tt, dtheta (n,), status) of the latest sample
        self.tt_last: int | None = None
        self.k_read_last: list[int | None] = [None] * self.lay.n_parts
        self.counts = [dict.fromkeys(COUNT_KEYS, 0) for _ in range(self.lay.n_parts)]
        #: per part: bus-read timing truth (TIMING_KEYS; sums, see :func:`timing_summary`)
        self.timing = [dict.fromkeys(TIMING_KEYS, 0) for _ in range(self.lay.n_parts)]
        self.pending: list[tuple] = []

    def chunk(self, j0: int, j1: int) -> list[tuple]:
        """Messages of bus ticks [j0, j1), sorted by (log time, topic): tuples (part, log_ns,
        order, topic, msg, t_bus). Messages dated later (truth records held to a gap's end) are
        kept back until their chunk."""
        msgs: list[tuple] = self.pending
        self._siru(j0, j1, msgs)
        self._trackers(j0, j1, msgs)
        if self.full:
            self._temps(j0, j1, msgs)
            if self.cfg["output"]["truth"]:
                self._truth(j0, j1, msgs)
        msgs.sort(key=lambda m: (m[1], m[2]))
        if j1 >= self.lay.n_ticks:
            self.pending = []
            return msgs
        cut = t_to_ns(self.lay.t0 + (j1 - 0.5) * self.lay.P)
        n = next((i for i, m in enumerate(msgs) if m[1] >= cut), len(msgs))
        self.pending = msgs[n:]
        return msgs[:n]

    def _add(self, msgs: list, parts: np.ndarray, times: list, topic: str, items: list) -> None:
        for p, t, m in zip(parts.tolist(), times, items, strict=True):
            msgs.append((p, t_to_ns(t), TOPIC_ORDER[topic], topic, m, t))

    # ------------------------------------------------------------------------------------ SIRU
    def _siru(self, j0: int, j1: int, msgs: list) -> None:
        rd = self.reads.read(j0, j1)
        tau, t_read = rd.t_bus, rd.t_read  # tags; read instants (the same array in read mode)
        if tau.size == 0:
            return
        j = np.arange(j1 - tau.size, j1)
        smp = self.clock.take_through(float(t_read[-1]))
        if self.full:
            dth, status = self.siru.outputs(smp.t_prev, smp.t)
        else:
            dth, status = np.zeros((smp.k.size, 1)), np.zeros(smp.k.size, dtype=np.int64)
        self._siru_time(smp, t_read, tau, j, msgs)
        k_all, t_all, tt_all, d_all, s_all = self._with_last(smp, dth, status)
        pos = latest_sample(t_all, t_read)
        ok = (pos >= 0) & self.lay.keep(tau)
        part = self.lay.part(tau)
        for p in range(self.lay.n_parts):
            sel = ok & (part == p)
            lead = np.round((tau[sel] - t_read[sel]) * 1e9).astype(np.int64)  # ns: exact sums
            tm = self.timing[p]
            tm["n"] += int(lead.size)
            tm["lead_sum_ns"] += int(lead.sum())
            tm["lead_sq_sum_ns2"] += int(np.sum(lead * lead))
            tm["n_late"] += int(rd.late[sel].sum())
            tm["n_clipped"] += int(rd.clipped[sel].sum())
            c = self.counts[p]
            n, rep, miss = read_counts(k_all[pos[sel]], self.k_read_last[p])
            c["n_reads"] += n
            c["n_repeated"] += rep
            c["n_missing"] += miss
            c["n_distinct"] += n - rep
            if n:
                self.k_read_last[p] = int(k_all[pos[sel]][-1])
        if self.full:
            self._siru_msgs(j[ok], tau[ok], part[ok], pos[ok], tt_all, d_all, s_all, msgs)

    def _with_last(self, smp, dth, status) -> list[np.ndarray]:
        """Sample columns (k, t, tt, dtheta, status) with the latest earlier sample prepended,
        so that a read can return a sample of the previous chunk."""
        cols = [smp.k, smp.t, smp.tt, dth, status]
        if self.last is not None:
            cols = [np.concatenate([np.asarray(p)[None], c])
                    for p, c in zip(self.last, cols, strict=True)]
        if cols[0].size:
            self.last = tuple(c[-1] for c in cols)
        return cols

    def _siru_time(self, smp, t_read: np.ndarray, tau: np.ndarray, j: np.ndarray,
                   msgs: list) -> None:
        """Truth of every SIRU sample, dated by the tag of the first read that can see it (moved
        to the end of a data gap when that read falls in one), in blocks of one second of reads."""
        if smp.tt.size == 0:
            return
        first = np.searchsorted(t_read, smp.t, side="left")  # first read instant ≥ t_k
        t_log = self.lay.after_gaps(tau[first])
        keep = t_log < self.lay.t_end
        part = self.lay.part(t_log)
        prev = smp.tt[0] if self.tt_last is None else self.tt_last
        dec = np.diff(np.concatenate([[prev], smp.tt])) < 0  # counter went backwards
        self.tt_last = int(smp.tt[-1])
        for p in range(self.lay.n_parts):
            sel = keep & (part == p)
            self.counts[p]["n_samples"] += int(sel.sum())
            self.counts[p]["n_tt_resets"] += int((smp.reset & sel).sum())
            self.counts[p]["n_tt_wraps"] += int((dec & ~smp.reset & sel).sum())
        if not (self.full and self.cfg["output"]["truth"]):
            return
        block, pk = j[first][keep] // self.lay.block, part[keep]
        tt, tr, tl = smp.tt[keep].tolist(), smp.t[keep].tolist(), t_log[keep].tolist()
        for s in _runs(block, pk):
            msg = {"v": 1, "t_bus": tl[s][-1], "tt": tt[s], "t_true": tr[s]}
            msgs.append((int(pk[s.start]), t_to_ns(tl[s][-1]), TOPIC_ORDER["/truth/siru_time"],
                         "/truth/siru_time", msg, tl[s][-1]))

    def _siru_msgs(self, j, tau, part, pos, tt_all, d_all, s_all, msgs) -> None:
        """Columnar /siru batches of ``batch`` bus ticks (split at parts)."""
        t_l, tt_l = tau.tolist(), tt_all[pos].tolist()
        d_l, s_l = d_all[pos].tolist(), s_all[pos].tolist()
        for s in _runs(j // self.cfg["siru"]["batch"], part):
            msg = {"v": 1, "t_bus": t_l[s], "tt": tt_l[s], "dtheta": d_l[s], "status": s_l[s]}
            msgs.append((int(part[s.start]), t_to_ns(t_l[s][-1]), 0, "/siru", msg, t_l[s][-1]))

    # -------------------------------------------------------------------------------- trackers
    def _trackers(self, j0: int, j1: int, msgs: list) -> None:
        t = self.lay.time(self.lay.ticks(j0, j1, "/st"))
        if t.size == 0:
            return
        part = self.lay.part(t)
        lat = self.cfg["trackers"]["latency_s"]
        q_bi = self.profile.truth_attitude(t - lat)[0] if self.full else None
        for name, trk in self.trackers.items():
            if q_bi is not None:
                phi2 = self.thermal.phi2(t - lat) if name == "st2" else None
                q, stars, valid, sent = trk.measure(t, st_from_inertial(name, q_bi, phi2))
            else:
                valid, sent = trk.flags(t)
            sent &= self.lay.keep(t)
            for p in range(self.lay.n_parts):
                self.counts[p][f"{name}_sent"] += int((sent & (part == p)).sum())
                self.counts[p][f"{name}_valid"] += int((sent & valid & (part == p)).sum())
            if self.full:
                items = [{"v": 1, "t_bus": tb, "q": qq, "n_stars": ns, "valid": vv}
                         for tb, qq, ns, vv in zip(t[sent].tolist(), q[sent].tolist(),
                                                   stars[sent].tolist(), valid[sent].tolist(),
                                                   strict=True)]
                self._add(msgs, part[sent], t[sent].tolist(), f"/{name}", items)

    # ---------------------------------------------------------------------- temperatures, truth
    def _temps(self, j0: int, j1: int, msgs: list) -> None:
        t = self.lay.time(self.lay.ticks(j0, j1, "/temp"))
        temps = self.thermal.temps(t)
        noise = self.temp_rng.standard_normal((t.size, 3)) * self.cfg["thermal"]["sensor_noise_C"]
        cols = [(temps[n] + noise[:, i]).tolist() for i, n in enumerate(("st1", "st2", "siru"))]
        keep = self.lay.keep(t)
        items = [{"v": 1, "t_bus": tb, "st1_baseplate_C": a, "st2_baseplate_C": b, "siru_C": c}
                 for tb, a, b, c, k in zip(t.tolist(), *cols, keep.tolist(), strict=True) if k]
        self._add(msgs, self.lay.part(t[keep]), t[keep].tolist(), "/temp", items)

    def _truth(self, j0: int, j1: int, msgs: list) -> None:
        t = self.lay.time(self.lay.ticks(j0, j1, "/truth/attitude"))
        t = t[self.lay.keep(t)]
        q, w = self.profile.truth_attitude(t)
        items = [{"v": 1, "t_bus": tb, "q_body_from_inertial": qq, "omega_body": ww}
                 for tb, qq, ww in zip(t.tolist(), q.tolist(), w.tolist(), strict=True)]
        self._add(msgs, self.lay.part(t), t.tolist(), "/truth/attitude", items)
        t = self.lay.time(self.lay.ticks(j0, j1, "/truth/params"))
        t = t[self.lay.keep(t)]
        cols = {"b": self.siru.bias(t), "lam": self.siru.lam(t),
                "mu": np.tile(self.truth["mu"], (t.size, 1)),
                "du": np.tile(self.truth["du"], (t.size, 1)),
                "dv": np.tile(self.truth["dv"], (t.size, 1)), "phi2": self.thermal.phi2(t)}
        lists = {k: v.tolist() for k, v in cols.items()}
        extra = {"siru_eps": self.cfg["siru"]["eps_ppm"] * 1e-6,
                 "latency_st": self.cfg["trackers"]["latency_s"]}
        items = [{"v": 1, "t_bus": tb, **{k: lists[k][i] for k in lists}, **extra}
                 for i, tb in enumerate(t.tolist())]
        self._add(msgs, self.lay.part(t), t.tolist(), "/truth/params", items)
