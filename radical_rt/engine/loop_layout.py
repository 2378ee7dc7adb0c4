"""Layout of the compiled release's three small argument arrays (:func:`radical_rt.engine.loop.
run_release`), declared once with :class:`radical_rt.contract.layout.Fields`.

``cfg`` (float64): the engine's scalar configuration, rebuilt after every parameter change
(``LoopShell._loop_config``); ``io`` (float64): the engine's scalar state (kept here between
calls: the engine's ``t``, ``mode``, ``att_valid``, ``locked_since`` are views of it), the
collaborators' inputs of a call and the outputs of a tracker update; ``cnt`` (int64): the flags
(``Engine.flags``), then counters and status codes that accumulate until Python takes them
(``LoopShell._drain``: CNT_USED..CNT_END−1 back to 0, CNT_MASKED to −1).
``IO_LAST_ST + j`` is the last valid epoch of tracker j = 1, 2; ``X_ST + j − 1`` the per-tracker
fields of size 2.
"""

from __future__ import annotations

from radical_rt.contract.layout import Fields

CFG = Fields("loop.cfg", "float64")
CFG_PROP_WINDOW = CFG.add("prop_window", doc="samples per time-update window")
CFG_ARW_VAR = CFG.add("arw_var", unit="rad^2/s", doc="angle random walk variance rate")
CFG_QUANT_VAR = CFG.add("quant_var", unit="rad^2", doc="quantization variance per sample")
CFG_REGRESSOR_K = CFG.add("regressor_k", doc="regressor reliability threshold (sigmas)")
CFG_PARITY_WINDOW = CFG.add("parity_window", doc="samples per parity sum")
CFG_GYRO_GAP = CFG.add("gyro_gap", unit="s", doc="a longer gyro interval is a gap")
CFG_PARITY_LAG = CFG.add("parity_lag", unit="s", doc="age at which a queued parity sum is due")
CFG_ST_STALE = CFG.add("st_stale", unit="s", doc="tracker stale after this long without data")
CFG_TIMING_CONSIDER = CFG.add("timing_consider", unit="s",
                              doc="time-line sigma above which the calibration is considered")
CFG_N_GYRO = CFG.add("n_gyro", doc="number of gyros")
CFG_ST_REF_STARS = CFG.add("st_ref_stars", doc="star count of the nominal tracker noise")
CFG_GATE_NIS = CFG.add("gate_nis", doc="chi-square(3) gate of a tracker update")
CFG_EDIT = CFG.add("edit", doc="1: residual editing on")
CFG_PHI_COL = CFG.add("phi_col", doc="state column of the ST2 misalignment phi2 (-1: none)")
CFG_LAT_COL = CFG.add("lat_col", doc="state column of the tracker latency tau (-1: none)")
CFG_PHI_P = CFG.add("phi_p", doc="index of phi2 in xp")
CFG_LAT_P = CFG.add("lat_p", doc="index of tau in xp")
CFG_ST_MIN_STARS = CFG.add("st_min_stars", doc="fewer stars: the sample is not used")
CFG_GATE_PARITY = CFG.add("gate_parity", doc="chi-square gate of a parity update")
CFG_ATT_INIT_SCALE = CFG.add("att_init_scale", doc="initial attitude sigma / tracker sigma")
CFG_FDI_ON = CFG.add("fdi_on", doc="1: the FDI statistic of every queued parity sum is computed")
CFG_HOOK_SUM = CFG.add("hook_sum",
                       doc="1: the window hook has work after every close that queued a sum")
CFG.freeze()

IO = Fields("loop.io", "float64")
IO_T = IO.add("t", unit="s", doc="engine time (in/out)")
IO_LOCKED_SINCE = IO.add("locked_since", unit="s", doc="lock latch (in/out; inf: not locked)")
IO_SIG_T = IO.add("sig_t", unit="s", doc="sigma of the time line")
IO_WAKE_T = IO.add("wake_t", unit="s", doc="event time from which the window hook has work")
IO_WAKE_E = IO.add("wake_e", unit="s", doc="engine time from which the window hook has work")
IO_WAKE_FDI = IO.add("wake_fdi", unit="s", doc="engine time from which the FDI's bookkeeping is "
                                               "due (in/out: a sum taken for it moves it)")
IO_EX_NEXT = IO.add("ex_next", unit="s", doc="engine time of the excitation monitor's next step "
                                             "(inf: none; caller)")
IO_GEN0 = IO.add("gen0", doc="gaps + attitude inits counted (CNT_GAPS + CNT_ATT_INITS) when the "
                             "FDI last looked (caller)")
IO_LAST_ST1 = IO.add("last_st1", unit="s", doc="last valid ST1 epoch (-inf: none)")
IO_LAST_ST2 = IO.add("last_st2", unit="s", doc="last valid ST2 epoch (-inf: none)")
IO_MODE = IO.add("mode", doc="the engine's mode code (MODE_*; -1: init)")
IO_NIS = IO.add("nis", doc="NIS of the tracker update (out)")
IO_ATT_VALID = IO.add("att_valid", doc="1: the attitude is initialized (in/out)")
IO_PAR_NU = IO.add("par_nu", doc="FDI: normalized innovation of the last queued sum (out)")
IO_PAR_RHO = IO.add("par_rho", doc="FDI: innovation variance / measurement noise (out)")
IO_PAR_T0 = IO.add("par_t0", unit="s", doc="FDI: first sample of the last queued sum (out)")
IO_PAR_Z = IO.add("par_z", unit="rad", doc="FDI: innovation of the last queued sum (out)")
IO_PAR_NIS = IO.add("par_nis", doc="NIS of the last parity update (out)")
IO_NIS_SUM_PAR = IO.add("nis_sum_par", doc="sum of the NIS of the used parity updates (in/out)")
IO_WAKE_EVERY = IO.add("wake_every",
                       doc="1: the window hook has work after every tracker sample (caller)")
IO_NIS_SUM_ST = IO.add("nis_sum_st", 2, doc="per tracker: sum of the NIS of its used updates "
                                            "(in/out)")
IO_NIS_LOCKED_ST = IO.add("nis_locked_st", 2, doc="per tracker: the same sum over the updates "
                                                  "made while the time line was locked (in/out)")
IO_DIAG_ST1 = IO.add("diag_st1", 7, unit="-, rad, rad",
                     doc="ST1's last update: NIS, innovation (3,), its 1 sigma (3,) (out)")
IO_DIAG_ST2 = IO.add("diag_st2", 7, unit="-, rad, rad", doc="the same for ST2 (out)")
IO_NIS_LOCKED_PAR = IO.add("nis_locked_par", doc="sum of the NIS of the parity updates used "
                                                 "while the time line was locked (in/out)")
IO_TRK_SEQ0 = IO.add("trk_seq0", doc="sequence number of the last sample in the FDI's tracker "
                                     "history when the call began (set by the call)")
IO.freeze()
IO_LAST_ST = IO_LAST_ST1 - 1  # IO_LAST_ST + j: tracker j

CNT = Fields("loop.cnt", "int64")
CNT_FLAGS = CNT.add("flags", doc="the engine's flags (in/out)")
CNT_FLAGS0 = CNT.add("flags0", doc="the engine's flags at the start of the call")
CNT_USED = CNT.add("used", doc="samples propagated (+=)")
CNT_UNDETERMINED = CNT.add("undetermined", doc="undetermined windows (+=)")
CNT_MASKED = CNT.add("masked", doc="PROP_MASKED of the last propagate call (caller sets -1)")
CNT_STATUS = CNT.add("status", doc="kernel status (out)")
CNT_EDITED = CNT.add("edited", doc="1: the tracker sample was edited (out)")
CNT_UPDATED = CNT.add("updated", doc="1: a tracker update ran (out)")
CNT_CONSIDER = CNT.add("consider", doc="1: the gyro calibration was a consider state (out)")
CNT_INVALID_ST1 = CNT.add("invalid_st1", doc="invalid ST1 samples skipped (+=)")
CNT_INVALID_ST2 = CNT.add("invalid_st2", doc="invalid ST2 samples skipped (+=)")
CNT_PRE_INIT = CNT.add("pre_init", doc="gyro samples before the attitude is initialized (+=)")
CNT_GAPS = CNT.add("gaps", doc="gyro gaps (warm starts without bump) (+=)")
CNT_ATT_INITS = CNT.add("att_inits", doc="attitude initializations from a tracker (+=)")
CNT_RESETS = CNT.add("resets", doc="attitude resets (begin_attitude_init) (+=)")
CNT_NUMERIC = CNT.add("numeric", doc="numeric faults (+=)")
CNT_NUMERIC_CODE = CNT.add("numeric_code",
                           doc="last numeric fault: UD status code, -1 geometry singular (out)")
CNT_PAR_USED = CNT.add("par_used", doc="parity updates used (+=)")
CNT_PAR_EDITED = CNT.add("par_edited", doc="parity updates edited (+=)")
CNT_PAR_SUMS = CNT.add("par_sums", doc="parity sums queued (+=)")
CNT_PAR_STAT = CNT.add("par_stat", doc="1: the FDI statistic of the last queued sum is valid")
CNT_PAR_EARLY = CNT.add("par_early", doc="queued sums updated early, the queue being full (+=)")
CNT_USED_ST = CNT.add("used_st", 2, doc="per tracker: updates used (+=)")
CNT_EDITED_ST = CNT.add("edited_st", 2, doc="per tracker: updates edited (+=)")
CNT_CONSIDER_ST = CNT.add("consider_st", 2, doc="per tracker: updates with the gyro calibration "
                                                "considered (+=)")
CNT_LOCKED_ST = CNT.add("locked_st", 2, doc="per tracker: used updates while the time line was "
                                            "locked (+=)")
CNT_DIAG_ST = CNT.add("diag_st", 2, doc="per tracker: 1 when IO_DIAG_ST<j> was written")
CNT_FIRST_UPDATED = CNT.add("first_updated", doc="tracker of the call's first update (0: none)")
CNT_FIRST_VALID = CNT.add("first_valid", doc="tracker of the call's first valid sample (0: none)")
CNT_TRK_ADDED = CNT.add("trk_added", doc="valid tracker samples appended to the FDI history (+=)")
CNT_LOCKED_PAR = CNT.add("locked_par", doc="parity updates used while the time line was locked "
                                           "(+=)")
CNT.freeze()
CNT_END = CNT.end  # the per-call counters are CNT_USED..CNT_END−1
CNT_INVALID_ST = CNT_INVALID_ST1 - 1  # CNT_INVALID_ST + j: tracker j
