"""Layout of the stream processor's two small shared state arrays (read and written by the
compiled intakes :func:`radical_rt.stream.siru_wire.siru_intake` and
:func:`radical_rt.stream.tracker_queue.tracker_intake`, and by the stream in Python), declared once with
:class:`radical_rt.contract.layout.Fields`.

``ss`` (float64): the stream's times [s]; ``si`` (int64): the tracker queue's counters and row
range. ``SS_LAST + j`` is the last t_bus of tracker j = 1, 2.
"""

from __future__ import annotations

from radical_rt.contract.layout import Fields

SS = Fields("stream.ss", "float64")
SS_T_MAX = SS.add("t_max", unit="s", doc="newest t_bus of any input")
SS_RELEASED = SS.add("released", unit="s", doc="epoch up to which samples count as released")
SS_LAST_ST1 = SS.add("last_st1", unit="s", doc="last t_bus of tracker 1")
SS_LAST_ST2 = SS.add("last_st2", unit="s", doc="last t_bus of tracker 2")
SS_T_IN = SS.add("t_in", unit="s",
                 doc="t_bus of the last tracker sample taken in or refused (diagnostics)")
SS_LAST_SIRU = SS.add("last_siru", unit="s", doc="last t_bus of the previous siru batch")
SS_WINDOW = SS.add("window", unit="s",
                   doc="plausibility window W of both intakes (configuration; inf: off)")
SS.freeze()
SS_LAST = SS_LAST_ST1 - 1  # SS_LAST + j: tracker j

SI = Fields("stream.si", "int64")
SI_LATE = SI.add("late", doc="late tracker samples dropped")
SI_SEQ = SI.add("seq", doc="arrival counter")
SI_HEAD = SI.add("head", doc="first waiting row of the tracker queue")
SI_END = SI.add("end", doc="one past the last waiting row")
SI.freeze()

# The block intake's controls (radical_rt.stream.intake_block): what Python sets before a call and
# reads after it. BF: float64 (times [s]); BI: int64.
BF = Fields("stream.block_f", "float64")
BF_INPUT_GAP = BF.add("input_gap", unit="s", doc="a longer pause in the siru bus times is a gap")
BF_MIN_INTERVAL = BF.add("min_interval", unit="s", doc="tracker conflict: closer samples are evidence")
BF_LATENCY = BF.add("latency", unit="s", doc="tracker latency (the epoch is t_bus - latency)")
BF_SLACK = BF.add("slack", unit="s", doc="reorder slack of the watermark")
BF_LAST_REJECT = BF.add("last_reject", unit="s", doc="t_max at the last rejected input")
BF_REJECT_HOLD = BF.add("reject_hold", unit="s", doc="INPUT_REJECTED hold")
BF_WAKE_T = BF.add("wake_t", unit="s", doc="event time of the next window packet or diag")
BF_WAKE_E = BF.add("wake_e", unit="s", doc="engine time a held flag ends (the guards')")
BF_WAKE_FDI = BF.add("wake_fdi", unit="s", doc="engine time the FDI's hook has work")
BF_T_NOW = BF.add("t_now", unit="s", doc="newest gyro sample time taken in (in/out)")
BF_T_IN = BF.add("t_in", unit="s", doc="out: t_bus of the message stopped at (tails)")
BF_PREV = BF.add("prev", unit="s", doc="out: the previous t_bus of that message's source (tails)")
BF_LAST_TEMP = BF.add("last_temp", unit="s", doc="in/out: t_bus of the last temp message (-inf: none)")
BF.freeze()

BI = Fields("stream.block_i", "int64")
BI_NEXT = BI.add("next", doc="in/out: the next message to take")
BI_STATUS = BI.add("status", doc="out: why the call returned (B_*)")
BI_GQ_HEAD = BI.add("gq_head", doc="in/out: the gyro queue's first pending sample")
BI_GQ_END = BI.add("gq_end", doc="in/out: one past the gyro queue's last sample")
BI_G_END = BI.add("g_end", doc="in/out: end row of the FDI's gyro history (-1: no FDI)")
BI_TRK_END = BI.add("trk_end", doc="in/out: end row of the FDI's tracker history (-1: none)")
BI_TRK_SEQ = BI.add("trk_seq", doc="in/out: sequence number of the FDI's last tracker sample")
BI_LAST_FLAGS = BI.add("last_flags", doc="the flags of the last fault message (-1: none yet)")
BI_GUARD_FLAGS = BI.add("guard_flags", doc="the guards' flags (constant while none is live)")
BI_SAMPLE_PACKETS = BI.add("sample_packets", doc="1: sample-triggered packets are configured")
BI_CONFLICT = BI.add("conflict", size=3, doc="1 at [j]: tracker j is (or was) in conflict")
BI_MAX_PAYLOAD = BI.add("max_payload", doc="payload size bound [bytes]")
BI_WINDOW = BI.add("window", doc="gyro samples per time-update window")
BI_N_GYRO = BI.add("n_gyro", doc="gyros")
BI_CHUNK = BI.add("chunk", doc="the clock kernel's reads per call")
BI_MAX_BRIDGE = BI.add("max_bridge", doc="the clock's bridged reads per read at most")
BI_NEW_SAMPLE = BI.add("new_sample", doc="out: the last siru message appended samples")
BI_SIRU_M = BI.add("siru_m", doc="out: samples the last siru message appended")
BI_TOOK = BI.add("took", size=3, doc="out: 1 at [j]: a tracker j sample was taken in (last_q)")
BI_RELEASED = BI.add("released", doc="out: 1 if a compiled release ran")
BI_CODE = BI.add("code", doc="out: the tracker intake's code of the message stopped at")
BI_RK = BI.add("rk", doc="out (B_RESUME): next gyro sample of the release")
BI_RZ = BI.add("rz", doc="out (B_RESUME): end of the release's gyro samples")
BI_RE = BI.add("re", doc="out (B_RESUME): next tracker row of the release")
BI_RN = BI.add("rn", doc="out (B_RESUME): end of the release's tracker rows")
BI_RSTAGE = BI.add("rstage", doc="out (B_RESUME): stage of the call's return")
BI_RREASON = BI.add("rreason", doc="out (B_RESUME): reason of the call's return")
BI_RPRED = BI.add("rpred", doc="out (B_RESUME): 1 if the release asked for the prediction")
BI_ROWS_OK = BI.add("rows_ok", doc="1: the sample-triggered packets may be made as rows")
BI_SIRU_LEFT = BI.add("siru_left", doc="in/out: siru messages the call may still take")
BI_ROWS = BI.add("rows", doc="out: rows of sample-triggered packets made")
BI_RESUME = BI.add("resume", doc="in: 1: first the rest of message next's release (BI_R*)")
BI_FINAL = BI.add("final", doc="in: 1: release everything (watermark inf), no message")
BI_TEMPS = BI.add("temps", doc="out: temp messages taken in (their rows of the temp array)")
BI.freeze()
