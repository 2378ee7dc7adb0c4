"""Index layout of the SIRU clock's parameter and state arrays (shared by kernel and wrapper).

Everything the clock knows lives in two numpy arrays: ``I`` (int64 state and counters) and ``F``
(float64: parameters, float state, the feasibility polygon and its workspace, the two held
increment rows). The coarse line is the polygon (:mod:`radical_rt.clock.clock_timing`), the fine line a
Kalman filter on the sawtooth crossings (:mod:`radical_rt.clock.clock_line`). Two arrays rather than many keep Numba's per-call reference counting out of the
per-read loop; a checkpoint is a plain copy of them. Offsets below index ``F`` / ``I`` directly;
they are declared once, in order, with :class:`radical_rt.contract.layout.Fields` (the tables ``PRM``,
``STATE``, ``WORK`` of ``F`` and ``INT`` of ``I`` give names, checks and docs).
"""

from __future__ import annotations

from radical_rt.contract.layout import Fields

#: counters of ``I`` (exposed by :attr:`radical_rt.clock.siru_clock.SiruClock.counters`; the first seven are
#: the interface's)
COUNTER_NAMES = ("samples", "repeated", "missing", "bridged", "anomalies", "wraps", "resets",
                 "gaps", "tt_glitches", "tbus_glitches", "time_jumps", "timing_outliers",
                 "relocks", "unexplained", "repeat_mismatch", "rejected", "tt_jumps",
                 "margin_grows", "crossings", "read_glitches", "crossings_rejected")

# ---- F[0:NPRM]: float64 parameters (from ClockConfig) -----------------------------------------
PRM = Fields("clock.F parameters", "float64")
P_T = PRM.add("t", doc='nominal sample period [s]')
P_TICKS = PRM.add("ticks", doc='time-tag ticks per sample')
P_WRAP = PRM.add("wrap", doc='time-tag modulus')
P_NAIVE = PRM.add("naive", doc='1.0 = naive timing')
P_DELTA = PRM.add("delta", doc='initial jitter margin of every timing constraint [s]')
P_NS = PRM.add("ns", doc='slope scale N_s [samples]')
P_READ_TOL = PRM.add("read_tol", doc='bus-read tick regularity tolerance, at least [s]')
P_BUS_T = PRM.add("bus_t", doc='bus read period [s]')
P_CHECK_TICKS = PRM.add("check_ticks", doc='1.0 = check bus-read regularity')
P_MAX_BRIDGE = PRM.add("max_bridge", doc='most consecutive misses bridged')
P_SIG_ALPHA = PRM.add("sig_alpha", doc='angular-acceleration sigma for bridged samples [rad/s^2]')
P_HOLD = PRM.add("hold", doc='CLOCK_ANOMALY hold time [s]')
P_GROSS = PRM.add("gross", doc='a timing-constraint violation above this raises CLOCK_ANOMALY [s]')
P_RELOCK = PRM.add("relock", doc='consecutive rejected reads before re-acquiring the phase')
P_RESET_TICKS = PRM.add("reset_ticks", doc='a tt restart below this many ticks is a counter reset (else a jump)')
P_INFL_DT = PRM.add("infl_dt", doc='drift inflation interval [s]')
P_PHASE_WANDER = PRM.add("phase_wander", doc='phase wander bound [s/s]')
P_FREQ_WANDER = PRM.add("freq_wander", doc='frequency wander bound [1/s]')
P_Y_LO = PRM.add("y_lo", doc='prior slope range, y units [s per N_s samples]')
P_Y_HI = PRM.add("y_hi", doc='')
P_MAX_JUMP = PRM.add("max_jump", doc='largest tt step accepted as a miss run [samples]')
P_LOCK_SIGMA = PRM.add("lock_sigma", doc='locked when the tag-error sigma is below this [s]')
P_TIME_TOL = PRM.add("time_tol", doc='extra tolerance of the tt-vs-bus-time consistency check [s]')
P_DELTA_MAX = PRM.add("delta_max", doc='the jitter margin may grow up to this [s]')
P_LINE_QX = PRM.add("line_qx", doc='fine line: phase random-walk variance rate [s^2/s]')
P_LINE_QY = PRM.add("line_qy", doc='fine line: slope random-walk variance rate [(s per N_s samples)^2 / s]')
P_SPATE_WMIN = PRM.add("spate_wmin", doc='a spate ends after at least this many reads on one level [reads]')
P_LINE_FLOOR = PRM.add("line_floor", doc="fine line: floor of a crossing's 1-sigma [s]")
P_LINE_GATE = PRM.add("line_gate", doc='a crossing farther than this many sigma from the line is rejected')
P_SPATE_MAX = PRM.add("spate_max", doc='a spate longer than this is abandoned [reads]')
NPRM = PRM.freeze().size

# ---- I: int64 state --------------------------------------------------------------------------
INT = Fields("clock.I", "int64")
I_HAVE_A = INT.add("have_a", doc='a sample has been accepted in this stream')
I_K_A = INT.add("k_a", doc='unwrapped index of the last accepted sample')
I_TT_A = INT.add("tt_a", doc='its time tag')
I_ST_A = INT.add("st_a", doc='its status bits')
I_HAVE_P = INT.add("have_p", doc='a read is pending (one-read look-ahead)')
I_TT_P = INT.add("tt_p", doc='')
I_ST_P = INT.add("st_p", doc='')
I_NV = INT.add("nv", doc='polygon vertex count')
I_K_REF = INT.add("k_ref", doc='polygon reference sample')
I_K_ANCHOR = INT.add("k_anchor", doc='sample index at which fst[F_TAU_ANCHOR] anchors the nominal line')
I_ACQ = INT.add("acq", doc='1 = the timing polygon exists')
I_HAVE_OUT = INT.add("have_out", doc='a sample has been released in this stream')
I_CONSEC_REJ = INT.add("consec_rej", doc='consecutive rejected reads')
I_NET = INT.add("net", doc='repeats - misses (signed running sum)')
I_NET_HI = INT.add("net_hi", doc='')
I_NET_LO = INT.add("net_lo", doc='')
I_K_OUT = INT.add("k_out", doc='index of the last released sample')
I_NG = INT.add("ng", doc='number of gyros')
# --- the bus-tick grid and the spate tracker (radical_rt.clock.clock_line)
I_GRID = INT.add("grid", doc='1 = the bus-tick grid is anchored (F_GRID0)')
I_GRID_N = INT.add("grid_n", doc='reads folded into F_GRID_DEV')
I_J_PREV = INT.add("j_prev", doc='tick index of the last timed read')
I_D_PREV = INT.add("d_prev", doc='its level d = k - j')
I_LEVEL = INT.add("level", doc='settled level d between spates')
I_SP_ON = INT.add("sp_on", doc='1 = inside a spate')
I_SP_J0 = INT.add("sp_j0", doc="tick index of the spate's first read off the level")
I_SP_N = INT.add("sp_n", doc='ticks counted in the spate so far')
I_SP_A = INT.add("sp_a", doc='sum of (d - d_before) over them')
I_SP_N0 = INT.add("sp_n0", doc='N and A when the current run of equal levels began')
I_SP_A0 = INT.add("sp_a0", doc='')
I_SP_RV = INT.add("sp_rv", doc='level of the current run')
I_SP_RL = INT.add("sp_rl", doc='length of the current run [reads]')
I_SP_DB = INT.add("sp_db", doc='level before the spate')
# --- the fine line (Kalman filter on the crossings)
I_KAL = INT.add("kal", doc='1 = the fine line has a phase (at least one crossing since the last phase loss)')
I_KMEM = INT.add("kmem", doc='1 = F_KY / F_KCYY hold a frequency kept across a phase loss')
I_NCROSS = INT.add("ncross", doc='crossings folded since the phase was (re)initialised')
# counters (names in radical_rt.clock.siru_clock.COUNTER_NAMES, same order)
C0 = INT.add("counters", len(COUNTER_NAMES), doc="COUNTER_NAMES, in order")
C_SAMPLES = C0 + COUNTER_NAMES.index("samples")
C_REPEATED = C0 + COUNTER_NAMES.index("repeated")
C_MISSING = C0 + COUNTER_NAMES.index("missing")
C_BRIDGED = C0 + COUNTER_NAMES.index("bridged")
C_ANOMALIES = C0 + COUNTER_NAMES.index("anomalies")
C_WRAPS = C0 + COUNTER_NAMES.index("wraps")
C_RESETS = C0 + COUNTER_NAMES.index("resets")
C_GAPS = C0 + COUNTER_NAMES.index("gaps")
C_TT_GLITCHES = C0 + COUNTER_NAMES.index("tt_glitches")
C_TBUS_GLITCHES = C0 + COUNTER_NAMES.index("tbus_glitches")
C_TIME_JUMPS = C0 + COUNTER_NAMES.index("time_jumps")
C_TIMING_OUTLIERS = C0 + COUNTER_NAMES.index("timing_outliers")
C_RELOCKS = C0 + COUNTER_NAMES.index("relocks")
C_UNEXPLAINED = C0 + COUNTER_NAMES.index("unexplained")
C_REPEAT_MISMATCH = C0 + COUNTER_NAMES.index("repeat_mismatch")
C_REJECTED = C0 + COUNTER_NAMES.index("rejected")
C_TT_JUMPS = C0 + COUNTER_NAMES.index("tt_jumps")
C_MARGIN_GROWS = C0 + COUNTER_NAMES.index("margin_grows")
C_CROSSINGS = C0 + COUNTER_NAMES.index("crossings")
C_READ_GLITCHES = C0 + COUNTER_NAMES.index("read_glitches")
C_CROSS_REJECTED = C0 + COUNTER_NAMES.index("crossings_rejected")
NCOUNT = len(COUNTER_NAMES)
NI = INT.freeze().end

# ---- F[NPRM:NPRM + NF]: float64 state -------------------------------------------------------
STATE = PRM.follow("clock.F state")
F_TAU_ANCHOR = STATE.add("tau_anchor", doc='nominal line: t_base(k) = tau_anchor + T (k - k_anchor)')
F_TAU_A_FIRST = STATE.add("tau_a_first", doc='bus time of the first read of the last accepted sample')
F_TAU_A_LAST = STATE.add("tau_a_last", doc='bus time of its latest read')
F_TAU_P = STATE.add("tau_p", doc="pending read's bus time")
F_T_OUT = STATE.add("t_out", doc='last released sample time')
F_CX = STATE.add("cx", doc='the line in use (x, y): the fine line once it has a phase, else the centroid')
F_CY = STATE.add("cy", doc='')
F_LAST_INFL = STATE.add("last_infl", doc='bus time of the last drift inflation')
F_ANOM_UNTIL = STATE.add("anom_until", doc='CLOCK_ANOMALY raised while bus time < this')
F_TAU_NOW = STATE.add("tau_now", doc='latest bus time seen')
F_MAX_VIOL = STATE.add("max_viol", doc='largest rejected-constraint violation seen [s] (diagnostic)')
F_Y_LO = STATE.add("y_lo", doc='slope range kept across a phase re-acquisition')
F_Y_HI = STATE.add("y_hi", doc='')
F_E_LAST = STATE.add("e_last", doc='estimated tag error of the latest timed read [s]')
F_T_LINE = STATE.add("t_line", doc='reconstructed time of the last accepted sample (unclamped)')
F_DELTA = STATE.add("delta", doc='current jitter margin [s] (grows when reads violate it)')
F_RJ2 = STATE.add("rj2", doc='running mean square of the bus-read tick deviation [s^2]')
F_GRID0 = STATE.add("grid0", doc='bus time of tick 0 of the read grid [s]')
F_GRID_DEV = STATE.add("grid_dev", doc="running mean of the reads' deviation from the grid [s]")
F_KX = STATE.add("kx", doc='fine line state (x, y) in polygon coordinates, and its covariance')
F_KY = STATE.add("ky", doc='')
F_KCXX = STATE.add("kcxx", doc='')
F_KCXY = STATE.add("kcxy", doc='')
F_KCYY = STATE.add("kcyy", doc='')
F_KTAU = STATE.add("ktau", doc="bus time to which the fine line's covariance is propagated [s]")
F_SIG_READ = STATE.add("sig_read", doc="read jitter (1 sigma) estimated from the spates' widths [s]")
F_PCX = STATE.add("pcx", doc='polygon centroid (x, y)')
F_PCY = STATE.add("pcy", doc='')
F_T_LOCK = STATE.add("t_lock", doc='bus time at which the line first locked (-inf: never) [s]')
NF = STATE.freeze().size
# ---- polygon and workspace, then the held increments (A: last accepted sample, P: pending read)
VMAX = 128  # storage per polygon array (>= 2 * clock_poly.VHIGH + 4)
WORK = STATE.follow("clock.F polygon")
OX = WORK.add("poly_x", VMAX, unit="polygon x", doc="feasibility polygon, vertex x")
OY = WORK.add("poly_y", VMAX, unit="polygon y", doc="vertex y")
WX = WORK.add("work_x", VMAX, doc="clipping workspace x")
WY = WORK.add("work_y", VMAX, doc="clipping workspace y")
DA = WORK.freeze().end  # F[DA:DA+n]: increments of the last accepted sample, then the pending read


def f_size(n_gyro: int) -> int:
    """Length of F for n gyros."""
    return DA + 2 * n_gyro
