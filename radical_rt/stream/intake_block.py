"""The stream's block intake: a run of plain input messages through the intakes, the release
decisions and the engine's compiled release in one kernel call (issue #18, docs/engine.md §1.2).

:func:`intake_block` takes the messages ``next``..n−1 of a chunk (payload bytes ``buf``, per
message its topic code T_*, offset and size) and does for each, in order, what
:meth:`radical_rt.stream.processor.StreamProcessor.feed` does for it, with the same kernels and the
same arithmetic: a ``siru`` message through :func:`radical_rt.stream.siru_wire.siru_intake` (decoding,
time check, clock, gyro queue) and then the release of everything the new watermark passed; a
tracker message through :func:`radical_rt.stream.tracker_queue.tracker_intake` and, when its release
test says so, the release. A release is :func:`radical_rt.stream.tracker_queue.release_plan` and
one :func:`radical_rt.engine.loop.run_release` call with the inputs Python's shell gives it
(:meth:`radical_rt.engine.shell.LoopShell.release`): σ of the time line from the clock's state
(:func:`radical_rt.clock.clock_timing.tag_sigma`), the wake times of the stream's flags rule
(:func:`radical_rt.stream.stream_rules.stream_wake`, the rule of :meth:`radical_rt.stream.outputs.StreamOutputs.wake`), the FDI's
gyro and tracker histories appended in place.

It returns to Python (status B_*, with ``next`` the message concerned) wherever Python has work:

* B_END: every message taken;
* B_BAIL: message ``next`` is not taken (nothing changed): it is not plain, not an input topic,
  too large, refused, or would need Python's rules (a tracker in conflict, the queues' growth);
  the caller feeds it as usual;
* B_SIRU: the ``siru`` message ``next`` is done (its sample-triggered packets are Python's; one
  siru message a call, the room the caller made is for one);
* B_SIRU_GAP: its samples are taken in, and its first bus time is an input gap: the caller notes
  the gap, then releases as ``feed`` does;
* B_TRK_TAIL: a tracker sample was taken in closer than the minimum interval to the tracker's
  previous one (conflict evidence): the caller notes it, then releases when BI_CODE says so;
* B_RESUME: a release stopped for the window hook (or counted a gyro gap, which the guards must
  see first): the caller runs the hook and the rest of that release (BI_R*), then the message's
  own tail;

The caller (:mod:`radical_rt.stream.block_feed`) makes room first (gyro queue, clock buffers, FDI
histories) and reads the scalars back afterwards (BI_*, BF_* of
:mod:`radical_rt.stream.stream_layout`). Python keeps every rule a message outside the common case
needs; this kernel never decides anything ``feed`` would not.
"""

from __future__ import annotations

import math

from radical_rt._jit import kernel
from radical_rt.clock.clock_timing import tag_sigma
from radical_rt.contract.conventions import SIRU_TT_WRAP
from radical_rt.contract.flags import Flag
from radical_rt.engine.engine_layout import E_INDEX
from radical_rt.engine.loop import R_DONE, run_release
from radical_rt.engine.loop_layout import (
    CNT_GAPS,
    CNT_TRK_ADDED,
)
from radical_rt.fdi.fdi_bank_pack import bank_on, bank_set_end
from radical_rt.kernels.flat_views import borrow
from radical_rt.stream.packets import MAX_SIRU_BATCH
from radical_rt.stream.siru_wire import WIRE_OK, outside_window, siru_intake
from radical_rt.stream.stream_layout import (
    BF_INPUT_GAP,
    BF_LAST_TEMP,
    BF_LATENCY,
    BF_MIN_INTERVAL,
    BF_PREV,
    BF_SLACK,
    BF_T_IN,
    BF_T_NOW,
    BF_WAKE_FDI,
    BI_CHUNK,
    BI_CODE,
    BI_CONFLICT,
    BI_FINAL,
    BI_G_END,
    BI_GQ_END,
    BI_GQ_HEAD,
    BI_MAX_BRIDGE,
    BI_MAX_PAYLOAD,
    BI_N_GYRO,
    BI_NEW_SAMPLE,
    BI_NEXT,
    BI_RE,
    BI_RELEASED,
    BI_RESUME,
    BI_RK,
    BI_RN,
    BI_ROWS,
    BI_RPRED,
    BI_RREASON,
    BI_RSTAGE,
    BI_RZ,
    BI_SAMPLE_PACKETS,
    BI_SIRU_M,
    BI_STATUS,
    BI_TEMPS,
    BI_TOOK,
    BI_TRK_END,
    BI_TRK_SEQ,
    BI_WINDOW,
    SI_END,
    SI_HEAD,
    SS_LAST,
    SS_LAST_SIRU,
    SS_T_IN,
    SS_T_MAX,
)
from radical_rt.stream.stream_rules import siru_done, stream_wake
from radical_rt.stream.temp_wire import parse_temp
from radical_rt.stream.tracker_queue import IN_RELEASE, PLAN_GO, release_plan, tracker_intake

#: message topic codes (T_OTHER: anything else: always Python's)
T_SIRU, T_ST1, T_ST2, T_TEMP, T_OTHER = 0, 1, 2, 3, 4
#: why intake_block returned (module docstring)
B_END, B_BAIL, B_SIRU, B_SIRU_GAP, B_TRK_TAIL, B_RESUME = range(6)

_CLOCK_ANOMALY, _INPUT_REJECTED = int(Flag.CLOCK_ANOMALY), int(Flag.INPUT_REJECTED)
# positions in the engine's tuple of views (radical_rt.engine.engine_layout)
_Q, _OMEGA, _EXCLUDED = E_INDEX["q"], E_INDEX["omega"], E_INDEX["excluded"]
_XP, _A, _GP = E_INDEX["xp"], E_INDEX["A"], E_INDEX["Gp"]


@kernel
def _release(defer, bi, bf, ss, si, ev_f, ev_i, q_t, q_dt, q_dth, q_st, q_br, q_ve, acc_i, R1,
             R2, fb, ib, bb, lay, cfg, io, cnt, g_f, g_i, g_b, pred, cI, cF, bfb, bib, bbb, blay,
             trk_f, trk_i, fq):
    """The stream's release for the watermark t_max − latency − slack, or inf with BI_FINAL (the
    end of a stream) (StreamProcessor._release and LoopShell.release's first call). Returns False when that call stopped before the release
    was complete (BI_R* say where; the caller returns B_RESUME)."""
    pred[0] = 0.0  # no prediction from this release (yet)
    wm = math.inf if bi[BI_FINAL] != 0 else ss[SS_T_MAX] - bf[BF_LATENCY] - bf[BF_SLACK]
    a = bi[BI_GQ_HEAD]
    plan, e1, z = release_plan(ss, si, ev_f, q_t, a, bi[BI_GQ_END], wm, acc_i[0], bi[BI_WINDOW],
                               defer)
    if plan != PLAN_GO:
        return True
    bi[BI_GQ_HEAD] = z
    e = si[SI_HEAD]
    si[SI_HEAD] = e1
    ask = bi[BI_SAMPLE_PACKETS] != 0 and not defer
    if ask:
        pred[0], pred[1] = 1.0, bf[BF_T_NOW]
    g_end = bi[BI_G_END] if z > a else -1
    return _call(a, z, e, e1, g_end, ask, bi, bf, ss, ev_f, ev_i, q_t, q_dt, q_dth, q_st, q_br,
                 q_ve, R1, R2, fb, ib, bb, lay, cfg, io, cnt, g_f, g_i, g_b, pred, cI, cF, bfb,
                 bib, bbb, blay, trk_f, trk_i, fq)


@kernel
def _call(k, z, e, n_ev, g_end, ask, bi, bf, ss, ev_f, ev_i, q_t, q_dt, q_dth, q_st, q_br, q_ve,
          R1, R2, fb, ib, bb, lay, cfg, io, cnt, g_f, g_i, g_b, pred, cI, cF, bfb, bib, bbb, blay,
          trk_f, trk_i, fq):
    """One run_release call of a release (gyro samples k..z−1, tracker rows e..n_ev−1; g_end ≥ 0:
    copy the samples to the FDI's history from that row first; ask: the sample packets'
    prediction) with the shell's inputs (LoopShell._calls) and its bookkeeping after the call.
    Returns False when the call stopped before the release was complete (BI_R* say where; the
    caller returns B_RESUME), or counted a gyro gap (the guards must see it first)."""
    sig = tag_sigma(cI, cF)
    sig_t = sig if math.isfinite(sig) and sig > 0.0 else 0.0
    wake_t, wake_e = stream_wake(bi, bf, ss, io, cnt, cF)
    trk_end = bi[BI_TRK_END]
    trk_seq = bi[BI_TRK_SEQ] if trk_end >= 0 else 0
    q_end = bi[BI_GQ_END] if ask else 0
    gaps0 = cnt[CNT_GAPS]
    if g_end >= 0 and bank_on(bib, blay):  # a running bank reads the rows this call appends
        bank_set_end(bib, blay, g_end + z - k)
    reason, k_stop, e_stop, stage = run_release(
        q_t, q_dt, q_dth, q_st, q_br, q_ve, k, z, ev_f, ev_i, e, n_ev, R1, R2, fb, ib, bb, lay,
        cfg, io, cnt, g_f, g_i, g_b, g_end, pred, q_end, cI, cF, bfb, bib, bbb, blay, sig_t,
        wake_t, wake_e, bf[BF_WAKE_FDI], fq, trk_f, trk_i, trk_end, trk_seq)
    bi[BI_RELEASED] = 1
    if g_end >= 0:
        bi[BI_G_END] += z - k
    added = cnt[CNT_TRK_ADDED]
    if added:
        cnt[CNT_TRK_ADDED] = 0
        bi[BI_TRK_END] += added
        bi[BI_TRK_SEQ] += added
    if reason == R_DONE and cnt[CNT_GAPS] == gaps0:
        return True
    bi[BI_RK], bi[BI_RZ], bi[BI_RE], bi[BI_RN] = k_stop, z, e_stop, n_ev
    bi[BI_RSTAGE], bi[BI_RREASON], bi[BI_RPRED] = stage, reason, 1 if ask else 0
    return False


@kernel
def _room(siru, bi, si, w_tbus, q_t, g_f, trk_f):
    """Whether the room the caller made holds what the next message can add: a siru message's
    reads (at most the decoder's capacity, each with its bridged reads) in the gyro queue, the
    samples and tracker rows a release can copy to the FDI's histories."""
    new = w_tbus.shape[0] * (bi[BI_MAX_BRIDGE] + 1) if siru else 0
    pending = bi[BI_GQ_END] - bi[BI_GQ_HEAD] + new
    if bi[BI_GQ_END] + new > q_t.shape[0]:
        return False
    if bi[BI_G_END] >= 0 and bi[BI_G_END] + pending > g_f.shape[0]:
        return False
    rows = si[SI_END] - si[SI_HEAD] + (0 if siru else 1)
    return not (bi[BI_TRK_END] >= 0 and bi[BI_TRK_END] + rows > trk_f.shape[0])


@kernel
def _temp(p, bi, bf, ss, temp_f):
    """A temp message (payload p) taken in as StreamProcessor.feed takes it: decoded into row
    BI_TEMPS of temp_f, its t_bus inside the plausibility window and after the previous temp
    message's (BF_LAST_TEMP), then the newest bus time. False (nothing changed): Python's (not
    plain, a time jump, a repeat or a step back, no room)."""
    m = bi[BI_TEMPS]
    if m >= temp_f.shape[0] or not parse_temp(p, temp_f[m]):
        return False
    t = temp_f[m, 0]
    if outside_window(ss, SS_T_MAX, t, t, 0.0) or not t > bf[BF_LAST_TEMP]:
        return False
    bf[BF_LAST_TEMP] = t
    ss[SS_T_MAX] = max(ss[SS_T_MAX], t)
    bi[BI_TEMPS] = m + 1
    return True


@kernel
def intake_block(buf, topic, off, size, n, bi, bf, w_tbus, w_tt, w_dth, w_st, ss, si, ev_f, ev_i,
                 q_work, last_q, cI, cF, OF, OI, tags, q_t, q_dt, q_dth, q_st, q_br, q_ve, acc_i,
                 R1, R2, fb, ib, bb, lay, cfg, io, cnt, g_f, g_i, g_b, pred, bfb, bib, bbb, blay,
                 trk_f, trk_i, sp_f, sp_i, rows_f, rows_i, fq, temp_f):
    """Messages bi[BI_NEXT]..n−1 (buf uint8: their payloads back to back; topic (≥ n,) T_*,
    off, size (≥ n,) int64: each payload's place in buf) through the stream (module docstring),
    until one needs Python. w_*: the siru decoder's column buffers; ss, si, ev_f, ev_i, q_work:
    the tracker queue's; last_q (3, 4): the quaternion of the last sample taken in per tracker
    (row j, with BI_TOOK[j] = 1); cI, cF, OF, OI, tags: the clock's state and buffers; q_*: the
    gyro queue's arrays (BI_GQ_HEAD, BI_GQ_END); acc_i: the engine's window counters; the rest:
    run_release's (g_*: the FDI's gyro history, BI_G_END; trk_*: its tracker history, BI_TRK_END,
    BI_TRK_SEQ; pred: the sample packets' prediction). With BI_ROWS_OK, up to BI_SIRU_LEFT siru
    messages, each one's sample-triggered packets as rows (:func:`radical_rt.stream.stream_rules.
    sample_rows`; sp_f, sp_i:
    their schedule); else one. fq: the FDI's array of the parity sums it takes in the loop
    (:mod:`radical_rt.fdi.fdi_quiet`). temp_f (m, TEMP_COLS): a row per temp message taken in
    (:func:`radical_rt.stream.temp_wire.parse_temp`; BI_TEMPS of them, the caller puts them into
    the stream's temperatures; BF_LAST_TEMP its last t_bus). Sets BI_STATUS and BI_NEXT. The array
    arguments are used as views that own no memory (:func:`radical_rt.kernels.flat_views.borrow`:
    the kernels it calls pass them on without atomic reference counting)."""
    buf, topic, off, size, bi = borrow(buf), borrow(topic), borrow(off), borrow(size), borrow(bi)
    bf, w_tbus, w_tt, w_dth = borrow(bf), borrow(w_tbus), borrow(w_tt), borrow(w_dth)
    w_st, ss, si, ev_f, ev_i = borrow(w_st), borrow(ss), borrow(si), borrow(ev_f), borrow(ev_i)
    q_work, last_q, cI, cF, OF = borrow(q_work), borrow(last_q), borrow(cI), borrow(cF), borrow(OF)
    OI, tags, q_t, q_dt, q_dth = borrow(OI), borrow(tags), borrow(q_t), borrow(q_dt), borrow(q_dth)
    q_st, q_br, q_ve, acc_i = borrow(q_st), borrow(q_br), borrow(q_ve), borrow(acc_i)
    R1, R2, fb, ib, bb = borrow(R1), borrow(R2), borrow(fb), borrow(ib), borrow(bb)
    lay, cfg, io, cnt, g_f = borrow(lay), borrow(cfg), borrow(io), borrow(cnt), borrow(g_f)
    g_i, g_b, pred, bfb, bib = borrow(g_i), borrow(g_b), borrow(pred), borrow(bfb), borrow(bib)
    bbb, blay, trk_f, trk_i = borrow(bbb), borrow(blay), borrow(trk_f), borrow(trk_i)
    sp_f, sp_i, rows_f, rows_i = borrow(sp_f), borrow(sp_i), borrow(rows_f), borrow(rows_i)
    fq, temp_f = borrow(fq), borrow(temp_f)
    bi[BI_RELEASED] = 0
    bi[BI_TEMPS] = 0
    bi[BI_ROWS] = 0
    bi[BI_SIRU_M] = -1
    for j in range(3):
        bi[BI_TOOK + j] = 0
    i = bi[BI_NEXT]
    status = B_END
    if bi[BI_RESUME] != 0:  # the rest of message i's release after its window hook (Python's)
        bi[BI_RESUME] = 0
        if not _call(bi[BI_RK], bi[BI_RZ], bi[BI_RE], bi[BI_RN], -1, bi[BI_RPRED] != 0, bi, bf,
                     ss, ev_f, ev_i, q_t, q_dt, q_dth, q_st, q_br, q_ve, R1, R2, fb, ib, bb, lay,
                     cfg, io, cnt, g_f, g_i, g_b, pred, cI, cF, bfb, bib, bbb, blay, trk_f, trk_i,
                     fq):
            bi[BI_STATUS] = B_RESUME
            return
        if i < n and topic[i] == T_SIRU:
            if siru_done(bi, bf, ss, io, cnt, cI, cF, pred, sp_f, sp_i, rows_f, rows_i, q_dth, q_dt,
                         q_st, fb, ib, bb, lay):
                status = B_SIRU
        if status == B_END:
            i += 1
    elif bi[BI_FINAL] != 0:  # the end of the stream: everything released (no message)
        if not _release(False, bi, bf, ss, si, ev_f, ev_i, q_t, q_dt, q_dth, q_st, q_br, q_ve,
                        acc_i, R1, R2, fb, ib, bb, lay, cfg, io, cnt, g_f, g_i, g_b, pred, cI, cF,
                        bfb, bib, bbb, blay, trk_f, trk_i, fq):
            bi[BI_STATUS] = B_RESUME
            return
    while i < n and status == B_END:
        code = topic[i]
        if code == T_OTHER or size[i] > bi[BI_MAX_PAYLOAD] or (
                (code == T_ST1 or code == T_ST2) and bi[BI_CONFLICT + code] != 0):
            status = B_BAIL
            break
        if not _room(code == T_SIRU, bi, si, w_tbus, q_t, g_f, trk_f):
            status = B_BAIL
            break
        p = buf[off[i]:off[i] + size[i]]
        done = True
        if code == T_SIRU:
            prev = ss[SS_LAST_SIRU]
            wire, _k, m = siru_intake(p, bi[BI_N_GYRO], w_tbus, w_tt, w_dth, w_st, MAX_SIRU_BATCH,
                                      SIRU_TT_WRAP, ss, SS_LAST_SIRU, SS_T_MAX, cI, cF,
                                      bi[BI_CHUNK], OF, OI, bi[BI_GQ_END], q_t, q_dt, q_dth, q_st,
                                      q_br, q_ve, tags)
            if wire != WIRE_OK:
                status = B_BAIL
                break
            bi[BI_GQ_END] += m
            bi[BI_SIRU_M] = m
            bi[BI_NEW_SAMPLE] = 1 if m > 0 else 0
            if m > 0:
                bf[BF_T_NOW] = q_t[bi[BI_GQ_END] - 1]
            t0 = w_tbus[0]
            if t0 - prev > bf[BF_INPUT_GAP] and prev > -math.inf:
                bf[BF_T_IN], bf[BF_PREV] = t0, prev
                status = B_SIRU_GAP
                break
            done = _release(False, bi, bf, ss, si, ev_f, ev_i, q_t, q_dt, q_dth, q_st, q_br, q_ve,
                            acc_i, R1, R2, fb, ib, bb, lay, cfg, io, cnt, g_f, g_i, g_b, pred, cI,
                            cF, bfb, bib, bbb, blay, trk_f, trk_i, fq)
            if not done:
                status = B_RESUME
                break
            if siru_done(bi, bf, ss, io, cnt, cI, cF, pred, sp_f, sp_i, rows_f, rows_i, q_dth, q_dt,
                         q_st, fb, ib, bb, lay):
                status = B_SIRU
                break
        elif code == T_TEMP:
            if not _temp(p, bi, bf, ss, temp_f):
                status = B_BAIL
                break
            done = _release(True, bi, bf, ss, si, ev_f, ev_i, q_t, q_dt, q_dth, q_st, q_br, q_ve,
                            acc_i, R1, R2, fb, ib, bb, lay, cfg, io, cnt, g_f, g_i, g_b, pred, cI,
                            cF, bfb, bib, bbb, blay, trk_f, trk_i, fq)
            if not done:
                status = B_RESUME
                break
        else:
            j = code
            prev = ss[SS_LAST + j]
            r = tracker_intake(p, j, bf[BF_LATENCY], bf[BF_SLACK], ss, si, ev_f, ev_i, q_t,
                               bi[BI_GQ_HEAD], bi[BI_GQ_END], acc_i[0], bi[BI_WINDOW], q_work)
            if r < 0:
                status = B_BAIL
                break
            for c in range(4):
                last_q[j, c] = q_work[c]
            bi[BI_TOOK + j] = 1
            bi[BI_CODE] = r
            t_in = ss[SS_T_IN]
            if abs(t_in - prev) < bf[BF_MIN_INTERVAL]:
                bf[BF_T_IN], bf[BF_PREV] = t_in, prev
                status = B_TRK_TAIL
                break
            if r == IN_RELEASE:
                done = _release(True, bi, bf, ss, si, ev_f, ev_i, q_t, q_dt, q_dth, q_st, q_br,
                                q_ve, acc_i, R1, R2, fb, ib, bb, lay, cfg, io, cnt, g_f, g_i, g_b,
                                pred, cI, cF, bfb, bib, bbb, blay, trk_f, trk_i, fq)
                if not done:
                    status = B_RESUME
                    break
        i += 1
    bi[BI_NEXT] = i
    bi[BI_STATUS] = status
