"""Index layout of the SIRU clock's parameter and state arrays (shared by kernel and wrapper).

Everything the clock knows lives in two numpy arrays: ``I`` (int64 state and counters) and ``F``
(float64: parameters, float state, the feasibility polygon and its workspace, the two held
increment rows). The coarse line is the polygon (:mod:`radical_rt.clock_timing`), the fine line a
Kalman filter on the sawtooth crossings (:mod:`radical_rt.clock_line`). Two arrays rather than many keep Numba's per-call reference counting out of the
per-read loop; a checkpoint is a plain copy of them. Offsets below index ``F`` directly.
"""

from __future__ import annotations

# ---- F[0:NPRM]: float64 parameters (from ClockConfig) -------------------------------------------------
P_T = 0  # nominal sample period [s]
P_TICKS = 1  # time-tag ticks per sample
P_WRAP = 2  # time-tag modulus
P_NAIVE = 3  # 1.0 = naive timing
P_DELTA = 4  # initial jitter margin of every timing constraint [s]
P_NS = 5  # slope scale N_s [samples]
P_READ_TOL = 6  # bus-read tick regularity tolerance, at least [s]
P_BUS_T = 7  # bus read period [s]
P_CHECK_TICKS = 8  # 1.0 = check bus-read regularity
P_MAX_BRIDGE = 9  # most consecutive misses bridged
P_SIG_ALPHA = 10  # angular-acceleration sigma for bridged samples [rad/s^2]
P_HOLD = 11  # CLOCK_ANOMALY hold time [s]
P_GROSS = 12  # a timing-constraint violation above this raises CLOCK_ANOMALY [s]
P_RELOCK = 13  # consecutive rejected reads before re-acquiring the phase
P_RESET_TICKS = 14  # a tt restart below this many ticks is a counter reset (else a jump)
P_INFL_DT = 15  # drift inflation interval [s]
P_PHASE_WANDER = 16  # phase wander bound [s/s]
P_FREQ_WANDER = 17  # frequency wander bound [1/s]
P_Y_LO = 18  # prior slope range, y units [s per N_s samples]
P_Y_HI = 19
P_MAX_JUMP = 20  # largest tt step accepted as a miss run [samples]
P_LOCK_SIGMA = 21  # locked when the tag-error sigma is below this [s]
P_TIME_TOL = 22  # extra tolerance of the tt-vs-bus-time consistency check [s]
P_DELTA_MAX = 23  # the jitter margin may grow up to this [s]
P_LINE_QX = 24  # fine line: phase random-walk variance rate [s^2/s]
P_LINE_QY = 25  # fine line: slope random-walk variance rate [(s per N_s samples)^2 / s]
P_SPATE_WMIN = 26  # a spate ends after at least this many reads on one level [reads]
P_LINE_FLOOR = 27  # fine line: floor of a crossing's 1-sigma [s]
P_LINE_GATE = 28  # a crossing farther than this many sigma from the line is rejected
P_SPATE_MAX = 29  # a spate longer than this is abandoned [reads]
NPRM = 30

# ---- I: int64 state ------------------------------------------------------------------------------
I_HAVE_A = 0  # a sample has been accepted in this stream
I_K_A = 1  # unwrapped index of the last accepted sample
I_TT_A = 2  # its time tag
I_ST_A = 3  # its status bits
I_HAVE_P = 4  # a read is pending (one-read look-ahead)
I_TT_P = 5
I_ST_P = 6
I_NV = 7  # polygon vertex count
I_K_REF = 8  # polygon reference sample
I_K_ANCHOR = 9  # sample index at which fst[F_TAU_ANCHOR] anchors the nominal line
I_ACQ = 10  # 1 = the timing polygon exists
I_HAVE_OUT = 11  # a sample has been released in this stream
I_CONSEC_REJ = 12  # consecutive rejected reads
I_NET = 13  # repeats - misses (signed running sum)
I_NET_HI = 14
I_NET_LO = 15
I_K_OUT = 16  # index of the last released sample
I_NG = 17  # number of gyros
# --- the bus-tick grid and the spate tracker (radical_rt.clock_line)
I_GRID = 18  # 1 = the bus-tick grid is anchored (F_GRID0)
I_GRID_N = 19  # reads folded into F_GRID_DEV
I_J_PREV = 20  # tick index of the last timed read
I_D_PREV = 21  # its level d = k - j
I_LEVEL = 22  # settled level d between spates
I_SP_ON = 23  # 1 = inside a spate
I_SP_J0 = 24  # tick index of the spate's first read off the level
I_SP_N = 25  # ticks counted in the spate so far
I_SP_A = 26  # sum of (d - d_before) over them
I_SP_N0 = 27  # N and A when the current run of equal levels began
I_SP_A0 = 28
I_SP_RV = 29  # level of the current run
I_SP_RL = 30  # length of the current run [reads]
I_SP_DB = 31  # level before the spate
# --- the fine line (Kalman filter on the crossings)
I_KAL = 32  # 1 = the fine line has a phase (at least one crossing since the last phase loss)
I_KMEM = 33  # 1 = F_KY / F_KCYY hold a frequency kept across a phase loss
I_NCROSS = 34  # crossings folded since the phase was (re)initialised
# counters (names in radical_rt.clock.COUNTER_NAMES, same order)
C0 = 35
C_SAMPLES = C0 + 0
C_REPEATED = C0 + 1
C_MISSING = C0 + 2
C_BRIDGED = C0 + 3
C_ANOMALIES = C0 + 4
C_WRAPS = C0 + 5
C_RESETS = C0 + 6
C_GAPS = C0 + 7
C_TT_GLITCHES = C0 + 8
C_TBUS_GLITCHES = C0 + 9
C_TIME_JUMPS = C0 + 10
C_TIMING_OUTLIERS = C0 + 11
C_RELOCKS = C0 + 12
C_UNEXPLAINED = C0 + 13
C_REPEAT_MISMATCH = C0 + 14
C_REJECTED = C0 + 15
C_TT_JUMPS = C0 + 16
C_MARGIN_GROWS = C0 + 17
C_CROSSINGS = C0 + 18
C_READ_GLITCHES = C0 + 19
C_CROSS_REJECTED = C0 + 20
NCOUNT = 21
NI = C0 + NCOUNT

# ---- F[NPRM:NPRM + NF]: float64 state ---------------------------------------------------------
F_TAU_ANCHOR = NPRM + 0  # nominal line: t_base(k) = tau_anchor + T (k - k_anchor)
F_TAU_A_FIRST = NPRM + 1  # bus time of the first read of the last accepted sample
F_TAU_A_LAST = NPRM + 2  # bus time of its latest read
F_TAU_P = NPRM + 3  # pending read's bus time
F_T_OUT = NPRM + 4  # last released sample time
F_CX = NPRM + 5  # the line in use (x, y): the fine line once it has a phase, else the centroid
F_CY = NPRM + 6
F_LAST_INFL = NPRM + 7  # bus time of the last drift inflation
F_ANOM_UNTIL = NPRM + 8  # CLOCK_ANOMALY raised while bus time < this
F_TAU_NOW = NPRM + 9  # latest bus time seen
F_MAX_VIOL = NPRM + 10  # largest rejected-constraint violation seen [s] (diagnostic)
F_Y_LO = NPRM + 11  # slope range kept across a phase re-acquisition
F_Y_HI = NPRM + 12
F_E_LAST = NPRM + 13  # estimated tag error of the latest timed read [s]
F_T_LINE = NPRM + 14  # reconstructed time of the last accepted sample (unclamped)
F_DELTA = NPRM + 15  # current jitter margin [s] (grows when reads violate it)
F_RJ2 = NPRM + 16  # running mean square of the bus-read tick deviation [s^2]
F_GRID0 = NPRM + 17  # bus time of tick 0 of the read grid [s]
F_GRID_DEV = NPRM + 18  # running mean of the reads' deviation from the grid [s]
F_KX = NPRM + 19  # fine line state (x, y) in polygon coordinates, and its covariance
F_KY = NPRM + 20
F_KCXX = NPRM + 21
F_KCXY = NPRM + 22
F_KCYY = NPRM + 23
F_KTAU = NPRM + 24  # bus time to which the fine line's covariance is propagated [s]
F_SIG_READ = NPRM + 25  # read jitter (1 sigma) estimated from the spates' widths [s]
F_PCX = NPRM + 26  # polygon centroid (x, y)
F_PCY = NPRM + 27
F_T_LOCK = NPRM + 28  # bus time at which the line first locked (-inf: never) [s]
NF = 29
# ---- polygon and workspace, then the held increments (A: last accepted sample, P: pending read)
VMAX = 128  # storage per polygon array (>= 2 * clock_poly.VHIGH + 4)
OX = NPRM + NF
OY = OX + VMAX
WX = OY + VMAX
WY = WX + VMAX
DA = WY + VMAX  # F[DA:DA+n]


def f_size(n_gyro: int) -> int:
    """Length of F for n gyros."""
    return DA + 2 * n_gyro
