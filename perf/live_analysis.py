"""The analysis of a live session (:func:`analyse`; definitions in :mod:`perf.live`): service,
reaction and inclusion latencies per vehicle after the warm-up, the node's internal split, where
the late messages' time went and the node's garbage collections, RSS and CPU; latencies as
percentiles in ms (:func:`pct`) and deadline misses against the 10 ms SIRU period
(:func:`misses`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from perf.live_stream import INCLUSION_TOL_S, INPUT_TOPICS, KINDS, sample_times

if TYPE_CHECKING:
    from perf.live import NodeRun

DEADLINE_NS = 10_000_000  # the SIRU sample period


def pct(x: np.ndarray, scale: float = 1e-6) -> dict[str, Any]:
    """p50/p90/p99/p99.9/max/mean of ns values, in ms (scale 1e-6), and n."""
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0:
        return {"n": 0}
    q = np.percentile(x, [50, 90, 99, 99.9])
    return {"n": int(x.size), "p50": q[0] * scale, "p90": q[1] * scale, "p99": q[2] * scale,
            "p99_9": q[3] * scale, "max": float(x.max()) * scale, "mean": float(x.mean()) * scale}


def misses(x: np.ndarray, deadline_ns: int = DEADLINE_NS) -> dict[str, Any]:
    x = np.asarray(x)
    n = int((x > deadline_ns).sum())
    return {"n": int(x.size), "misses": n, "frac": n / x.size if x.size else float("nan")}

def analyse(run: NodeRun, stream: dict[str, Any], warmup_s: float, measure_s: float,
            samples: tuple[np.ndarray, np.ndarray] | None = None) -> dict[str, Any]:
    """Latency figures of one session (see the module docstring), warm-up reported apart."""
    d = run.drive
    topics = np.asarray(stream["topics"], dtype=np.int64)
    t_rel = np.asarray(stream["t"], dtype=np.float64)
    n_msg = int(d["n_msg"])
    nv = run.n_vehicles
    # publication time of (vehicle, message); 0 where not published
    pub = np.zeros((nv, n_msg), dtype=np.int64)
    pub[d["veh"], d["msg"]] = d["pub_ns"]
    lateness = d["pub_ns"] - d["due_ns"]
    t_end = warmup_s + measure_s
    in_meas = (t_rel[:n_msg] >= warmup_s) & (t_rel[:n_msg] < t_end)
    in_warm = t_rel[:n_msg] < warmup_s
    out: dict[str, Any] = {"vehicles": nv, "messages_published": int(d["pub_ns"].size),
                           "pacing_late_ms": pct(lateness)}

    # ---- node timing: map each record to its (vehicle, message)
    tm = run.timing
    svc, svc_w, node_tot, node_q, node_sp, node_pub, hop_in = [], [], [], [], [], [], []
    node_pkt: list[np.ndarray] = []
    siru_stamps: list[np.ndarray] = []  # (pub, recv, start, fed, done) of measured SIRU messages
    react, react_w, hop_out = [], [], []
    complete = True
    if tm is not None:
        for v in range(nv):
            sel = np.nonzero(tm["vehicle"] == v)[0]
            msg_of_rec = np.full(sel.size, -1, dtype=np.int64)
            for code in range(len(INPUT_TOPICS)):
                recs = sel[tm["topic"][sel] == code]
                msgs = np.nonzero(topics[:n_msg] == code)[0]
                msgs = msgs[pub[v, msgs] > 0]
                if recs.size != msgs.size:
                    complete = False
                k = min(recs.size, msgs.size)
                msg_of_rec[np.searchsorted(sel, recs[:k])] = msgs[:k]
            ok = msg_of_rec >= 0
            r, m = sel[ok], msg_of_rec[ok]
            siru = topics[m] == 0
            meas, warm = in_meas[m], in_warm[m]
            p = pub[v, m]
            done, recv = tm["done_ns"][r], tm["recv_ns"][r]
            svc.append((done - p)[siru & meas])
            siru_stamps.append(np.stack([p, recv, tm["start_ns"][r], tm["fed_ns"][r], done],
                                        axis=1)[siru & meas])
            svc_w.append((done - p)[siru & warm])
            node_tot.append((done - recv)[meas])
            node_pkt.append((done - recv)[meas & (tm["tlm"][r] > 0)])
            node_q.append((tm["start_ns"][r] - recv)[meas])
            node_sp.append((tm["fed_ns"][r] - tm["start_ns"][r])[meas])
            node_pub.append((done - tm["fed_ns"][r])[meas])
            hop_in.append((recv - p)[meas])
            # packets → the record that built them (per kind, by sequence number)
            for k in range(len(KINDS)):
                cnt = (tm["tlm"][sel] >> (8 * k)) & 0xFF
                cum = np.cumsum(cnt)
                pk = np.nonzero((d["rx_veh"] == v) & (d["rx_kind"] == k) & (d["rx_seq"] > 0))[0]
                if pk.size == 0:
                    continue
                ri = np.searchsorted(cum, d["rx_seq"][pk], side="left")
                good = ri < sel.size
                pk, ri = pk[good], ri[good]
                mm = msg_of_rec[ri]
                good = mm >= 0
                pk, ri, mm = pk[good], ri[good], mm[good]
                lat = d["rx_ns"][pk] - pub[v, mm]
                react.append(lat[in_meas[mm]])
                react_w.append(lat[in_warm[mm]])
                hop_out.append((d["rx_ns"][pk] - tm["fed_ns"][sel[ri]])[in_meas[mm]])
        cat = np.concatenate
        out["node_timing_complete"] = complete
        out["records"] = int(tm["vehicle"].size)
        out["service_ms"] = pct(cat(svc))
        out["service_misses"] = misses(cat(svc))
        out["service_warmup_ms"] = pct(cat(svc_w))
        out["hop_in_ms"] = pct(cat(hop_in))
        out["node_total_ms"] = pct(cat(node_tot))
        out["node_queue_ms"] = pct(cat(node_q))
        out["node_feed_ms"] = pct(cat(node_sp))
        out["node_publish_ms"] = pct(cat(node_pub))
        # taken from the FIFO → packet published, for the messages that published tlm packets
        out["node_to_packet_ms"] = pct(cat(node_pkt))
        out["reaction_ms"] = pct(cat(react) if react else np.zeros(0))
        out["reaction_misses"] = misses(cat(react) if react else np.zeros(0))
        out["reaction_warmup_ms"] = pct(cat(react_w) if react_w else np.zeros(0))
        out["hop_out_ms"] = pct(cat(hop_out) if hop_out else np.zeros(0))
        out.update(_late_and_gc(cat(siru_stamps), tm, int(d["t_base_ns"]) + int(warmup_s * 1e9),
                                int(d["t_base_ns"]) + int((warmup_s + measure_s) * 1e9)))

    # ---- inclusion: first packet with t ≥ the sample's reconstructed time
    if samples is None:
        samples = sample_times(stream)
    s_t, s_msg = samples
    keep = s_msg < n_msg
    s_t, s_msg = s_t[keep], s_msg[keep]
    s_meas = in_meas[s_msg]
    s_warm = in_warm[s_msg]
    inc, inc_w, never = [], [], 0
    for v in range(nv):
        pk = np.nonzero((d["rx_veh"] == v) & np.isfinite(d["rx_t"]))[0]
        if pk.size == 0:
            never += int(s_meas.sum())
            continue
        o = np.argsort(d["rx_t"][pk], kind="stable")
        pt = d["rx_t"][pk][o]
        pr = d["rx_ns"][pk][o]
        suffix_min = np.minimum.accumulate(pr[::-1])[::-1]
        # a packet includes a sample when its t is that sample's time or later; the t of a
        # sample-triggered packet is the clock's *prediction* for the newest read (one period
        # after the last released sample), which differs from the time reconstructed later by
        # µs, so a packet is matched to a sample within half a sample period
        j = np.searchsorted(pt, s_t - INCLUSION_TOL_S, side="left")
        has = j < pt.size
        rec = np.where(has, suffix_min[np.minimum(j, pt.size - 1)], 0)
        lat = rec - pub[v, s_msg]
        ok = has & (pub[v, s_msg] > 0)
        never += int((~ok & s_meas).sum())
        inc.append(lat[ok & s_meas])
        inc_w.append(lat[ok & s_warm])
    cat = np.concatenate
    out["inclusion_ms"] = pct(cat(inc))
    out["inclusion_misses"] = misses(cat(inc))
    out["inclusion_warmup_ms"] = pct(cat(inc_w))
    out["samples_never_included"] = never
    out["packets_received"] = {k: int((d["rx_kind"] == i).sum()) for i, k in enumerate(KINDS)}

    # ---- node process: RSS and CPU over the measured window
    rss = run.rss
    t0 = int(d["t_base_ns"]) + int(warmup_s * 1e9)
    t1 = int(d["t_base_ns"]) + int(t_end * 1e9)
    if rss.size:
        before = rss[rss[:, 0] <= int(d["t_base_ns"])]
        during = rss[(rss[:, 0] >= t0) & (rss[:, 0] <= t1)]
        out["rss_ready_mb"] = float(before[-1, 1]) / 1024 if len(before) else None
        out["rss_mb"] = float(np.median(during[:, 1])) / 1024 if len(during) else None
        out["rss_at_warmup_end_mb"] = float(during[0, 1]) / 1024 if len(during) else None
        out["rss_max_mb"] = float(rss[:, 1].max()) / 1024
        if len(during) >= 2:
            out["node_cpu_pct"] = 100.0 * (during[-1, 2] - during[0, 2]) / ((during[-1, 0] - during[0, 0]) * 1e-9)
    out["node_jit_s"] = run.jit_s
    out["node_exit_code"] = run.node_rc
    return out


def _late_and_gc(st: np.ndarray, tm: dict[str, np.ndarray], t0: int, t1: int) -> dict[str, Any]:
    """Where the time of the late SIRU messages went, and the node's garbage collections.

    st: (n, 5) publish, taken, loop start, fed, done stamps of the measured SIRU messages.
    """
    out: dict[str, Any] = {}
    late = st[(st[:, 4] - st[:, 0]) > DEADLINE_NS]
    if late.size:
        d = np.diff(late, axis=1)  # hop in, queue wait, feed, publish
        out["late_breakdown_ms"] = {name: float(np.median(d[:, i])) * 1e-6 for i, name in
                                    enumerate(("hop_in", "queue", "feed", "publish"))}
    if "gc_start_ns" in tm:
        gs, ge, gg = tm["gc_start_ns"], tm["gc_stop_ns"], tm["gc_generation"]
        inside = (ge >= t0) & (gs <= t1)
        gc_out: dict[str, Any] = {}
        for g in (0, 1, 2):
            dur = (ge - gs)[inside & (gg == g)]
            gc_out[f"gen{g}"] = {"n": int(dur.size),
                                 "max_ms": float(dur.max()) * 1e-6 if dur.size else 0.0,
                                 "total_ms": float(dur.sum()) * 1e-6}
        out["node_gc"] = gc_out
        if late.size:  # late messages in flight during a collection
            hit = np.zeros(len(late), bool)
            for a, b in zip(gs[inside], ge[inside], strict=True):
                hit |= (late[:, 0] <= b) & (late[:, 4] >= a)
            out["late_during_gc"] = int(hit.sum())
    out["late_messages"] = int(len(late))
    return out
