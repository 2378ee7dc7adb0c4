"""Parity fault detection, isolation and reconfiguration (radical_rt/fdi/monitor.py, docs/fdi.md).

* The detector's thresholds against their design false-alarm rate (seeded Monte Carlo), the CUSUM
  run length against Siegmund's formula, the convergence guard and the onset estimate.
* Engine runs on the seeded 2006216 scenario (1 h: cold start, x and z slews, +360° y slew). The
  nominal run raises no alarm. Fault runs continue from an exact copy of the nominal processor at
  2390 s (the fault archives are checked equal to the nominal one before that) with one fault at
  2400 s; each must be detected and isolated to the right gyro, the gyro excluded, and for the rest
  of the run the remaining gyros' parameters (and φ2) must stay within 3σ of /truth/params and the
  attitude consistent with /truth/attitude.
* The node (in-memory transport) takes the same decisions as the batch shell, and the operator's
  exclude_gyro / include_gyro keep working around the monitor.
"""

from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest
from scipy.stats import chi2

from perf.fdi_cases import FAULT_T, KINDS, SPLIT_T, Run, evaluate, fault_toml, synth
from radical_rt.apps.batch import process
from radical_rt.contract.flags import Flag, flag_names
from radical_rt.fdi.monitor import (
    CUSUM_SHIFT,
    PERSIST_M,
    ParityDetector,
    chi2_1_isf,
    chi2_isf,
    cusum_arl0,
    thresholds,
)
from tests.support.node import MemNode, feed_archive, input_messages


# ------------------------------------------------------------------------------ detector math
def test_chi2_quantiles():
    for a in (0.3, 1e-3, 4.6e-8, 1e-12):
        assert chi2_1_isf(a) == pytest.approx(chi2.isf(a, 1), rel=1e-9)
    for dof, rel in ((3, 0.04), (30, 0.004), (3000, 1e-5), (300000, 1e-7)):
        assert chi2_isf(1e-4, dof) == pytest.approx(chi2.isf(1e-4, dof), rel=rel)


def test_thresholds_follow_the_false_alarm_budget():
    th = thresholds(1e-3, 3600.0)
    a = 1e-3 / 3.0 / 3600.0
    assert th.t_inst == pytest.approx(chi2.isf(a, 1))
    assert th.t_persist == pytest.approx(chi2.isf(a ** (1.0 / PERSIST_M), 1))
    assert th.cusum_k == 0.5 * CUSUM_SHIFT
    assert cusum_arl0(th.cusum_h, th.cusum_k) == pytest.approx(6.0 * 3600.0 / 1e-3, rel=1e-6)
    assert 5.0 < math.sqrt(th.t_inst) < 6.0 and 10.0 < th.cusum_h < 20.0


def test_cusum_run_length_matches_siegmund():
    rng = np.random.default_rng(2)
    h, k, runs = 4.0, 0.5, []
    for _ in range(400):
        s, n = 0.0, 0
        while s < h:
            n += 1
            s = max(0.0, s + rng.standard_normal() - k)
        runs.append(n)
    mean, se = np.mean(runs), np.std(runs) / math.sqrt(len(runs))
    assert abs(mean - cusum_arl0(h, k)) < 3.5 * se, (mean, se, cusum_arl0(h, k))


def test_detector_false_alarm_rate_matches_design():
    """200 h of white N(0, 1) innovations at a design rate of 3.6 alarms per hour (large enough to
    count): the whole detector and each test within their binomial bounds, never far above."""
    lam, n_h, hours = 3.6, 3600.0, 200.0
    det = ParityDetector(thresholds(lam, n_h), guard_ratio=4.0)
    nu = np.random.default_rng(1).standard_normal(int(hours * n_h))
    count: dict[str, int] = {}
    for i, v in enumerate(nu):
        hit = det.update(float(v), 1.0, float(i))
        if hit:
            count[hit[0]] = count.get(hit[0], 0) + 1
            det.reset()
    total, expect = sum(count.values()), lam * hours
    assert 0.8 * expect < total < expect + 3.5 * math.sqrt(expect), count
    for test in ("instant", "persistence", "cusum"):
        assert 0.6 * expect / 3 < count[test] < expect / 3 + 3.5 * math.sqrt(expect / 3), count


def test_guard_and_onset():
    th = thresholds(1e-3, 3600.0)
    det = ParityDetector(th, guard_ratio=4.0)
    # calibration-dominated (σ² = 100 R): a persistent 4σ innovation is calibration, not a fault
    assert all(det.update(4.0, 100.0, float(i)) is None for i in range(200))
    assert det.guarded and det.s_pos == 0.0
    # ... unless it is overwhelming against the calibration part as well
    assert det.update(math.sqrt(th.t_inst * 100.0 / 4.0) * 1.01, 100.0, 200.0) == ("instant", 200.0)
    det.reset()
    # converged: a 1.5σ mean shift from sum 100 on is found by the CUSUM, onset near 100
    rng = np.random.default_rng(5)
    hit = None
    for i in range(400):
        hit = det.update(float(rng.standard_normal() + (1.5 if i >= 100 else 0.0)), 1.0, float(i))
        if hit:
            break
    assert hit is not None and hit[0] in ("cusum", "persistence"), hit
    assert 90.0 <= hit[1] <= 115.0 and i < 140, (hit, i)


# ------------------------------------------------------------------------------ engine runs
CASES = {  # name → (gyro, fault, max detection delay, max isolation delay, first test)
    "bias_0.5": (2, KINDS["bias 0.5 deg/hr"], 3.0, 30.0, "instant"),
    "zero": (0, KINDS["zero output"], 2.0, 5.0, "instant"),
    "noise": (3, KINDS['noise 0.1"/sample'], 3.0, 30.0, "instant"),
    "ramp": (1, {"kind": "bias_ramp", "rate_deg_hr_per_hr": 2.0}, 120.0, 240.0, "cusum"),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("fdi")
    nominal = synth(fault_toml(None), d / "nominal.mcap")
    base = Run()
    base.feed_archive(nominal, t_to=SPLIT_T)
    out = {}
    h_nom = hashlib.sha256()
    nom = base.fork()
    nom.feed_archive(nominal, t_from=SPLIT_T, prefix_hash=h_nom)
    nom.finish()
    out["nominal"] = (nom, evaluate(nom, None))
    for name, (g, fault, *_rest) in CASES.items():
        path = synth(fault_toml({**fault, "gyro": g, "start_s": FAULT_T}), d / f"{name}.mcap")
        run = base.fork()
        h = hashlib.sha256()
        run.feed_archive(path, t_from=SPLIT_T, prefix_hash=h)
        assert h.digest() == h_nom.digest(), f"{name}: archive differs before the split"
        run.finish()
        out[name] = (run, evaluate(run, FAULT_T))
    return out


def _seen_flags(run) -> set[str]:
    return {name for f in run.faults for name in f["set"]}


def test_nominal_run_has_no_alarm(runs):
    run, ev = runs["nominal"]
    assert ev["alarms"] == [] and ev["isolations"] == [], ev["alarms"]
    assert ev["counts"]["sums"] > 3400  # every 1-s parity sum of the hour was tested
    assert not _seen_flags(run) & {"PARITY_ALARM", *(f"GYRO_{c}_FAILED" for c in "ABCD")}
    assert ev["excluded"] == [] and run.sp.engine.mode in ("converging", "converged")


@pytest.mark.parametrize("name", list(CASES))
def test_fault_detected_isolated_and_reconfigured(runs, name):
    gyro, _fault, max_det, max_iso, test = CASES[name]
    run, ev = runs[name]
    e = run.sp.engine
    assert len(ev["alarms"]) == 1 and ev["alarms"][0]["test"] == test, ev["alarms"]
    assert 0.0 < ev["detect_delay_s"] <= max_det, ev["detect_delay_s"]
    assert ev["isolated_gyro"] == gyro and len(ev["isolations"]) == 1, ev["isolations"]
    assert ev["detect_delay_s"] < ev["isolate_delay_s"] <= max_iso
    # the onset estimate: near the step; for the ramp, after its start (the CUSUM excursion begins
    # once the mean exceeds k); the bank always starts from a snapshot before the estimate
    alarm = ev["alarms"][0]
    assert FAULT_T - 25.0 <= alarm["t_onset_est"] <= (alarm["t_alarm"] if name == "ramp"
                                                       else FAULT_T + 25.0), alarm
    assert alarm["t_snapshot"] < alarm["t_onset_est"]
    # flags: PARITY_ALARM published first, then GYRO_x_FAILED with the alarm cleared
    bit = f"GYRO_{'ABCD'[gyro]}_FAILED"
    alarm_msg = next(f for f in run.faults if "PARITY_ALARM" in f["set"])
    fail_msg = next(f for f in run.faults if bit in f["set"])
    assert alarm_msg["t"] < fail_msg["t"] and "PARITY_ALARM" in fail_msg["cleared"]
    assert alarm_msg["detail"]["fdi"]["state"] == "alarm"
    assert fail_msg["detail"]["fdi"]["last_isolation"]["gyro"] == gyro
    assert flag_names(e.flags).count(bit) == 1 and not e.flags & Flag.PARITY_ALARM
    assert ev["excluded"] == [gyro] and e.mode == "degraded" and ev["state"] == "three-gyro"
    assert e.counters["parity_used"] > 0  # (before the fault; none with three gyros)


@pytest.mark.parametrize("name", list(CASES))
def test_after_isolation_estimates_stay_consistent_with_truth(runs, name):
    """Remaining gyros' parameters and φ2 within 3σ of truth at every 60-s check until the end;
    attitude error per body axis beyond 3σ in at most 1 % of the 1-Hz samples (0.27 % expected of
    a consistent Gaussian) and never beyond 5σ."""
    _run, ev = runs[name]
    p, att = ev["params"], ev["att"]
    assert p["checks"] >= 15 and p["n_states"] == 18
    assert p["max_abs_z"] <= 3.0, p
    assert att["n"] > 1000 and att["frac_over_3"] <= 0.01 and att["max_abs_z"] < 5.0, att


# ------------------------------------------------------------------------------ node and commands
def test_node_takes_the_batch_decisions(short_fault, tmp_path):
    from radical_rt.io.archive import ArchiveReader
    out = tmp_path / "out.mcap"
    ref = process([str(short_fault)], str(out))
    with ArchiveReader(out) as r:
        want = [m for _t, _ns, m in r.iter_messages(["/fault"])]
    assert "GYRO_B_FAILED" in ref["flags"] and "PARITY_ALARM" not in ref["flags"]
    mn = MemNode(block_outputs=True)
    try:
        feed_archive(mn, "v1", input_messages(short_fault))
        got = [m for k, m in mn.outputs if k.endswith("/fault")]
        s = mn.cmd(cmd="end_stream", next="none")["summary"]
    finally:
        mn.close()
    assert got == want and any("GYRO_B_FAILED" in m["set"] for m in got)
    assert all(np.array_equal(s[k][g], ref[k][g]) for k in ("estimate", "sigma") for g in s[k])


def test_manual_exclude_include_around_the_monitor(short_fault):
    msgs = input_messages(short_fault)
    mn = MemNode()
    try:
        feed_archive(mn, "v1", msgs, until_ns=int(1200e9))
        st = mn.cmd(cmd="status")
        assert st["excluded"] == [1] and "GYRO_B_FAILED" in st["flag_names"]
        # the operator trusts gyro B again: the failure flag clears at once
        r = mn.cmd(cmd="include_gyro", gyro=1)
        assert r["ok"] and r["excluded"] == []
        assert "GYRO_B_FAILED" not in mn.cmd(cmd="status")["flag_names"]
        # a manual exclusion is not a failure declaration
        assert mn.cmd(cmd="exclude_gyro", gyro=1)["excluded"] == [1]
        assert mn.cmd(cmd="exclude_gyro", gyro=0)["ok"] is False  # three gyros must stay
        feed_archive(mn, "v1", [m for m in msgs if 1200e9 <= m[1] < 1250e9])
        st = mn.cmd(cmd="status")
        assert st["excluded"] == [1] and "GYRO_B_FAILED" not in st["flag_names"]
        assert mn.sp().engine.fdi.state == "three-gyro"
        # included again while still faulty: the monitor finds it again
        assert mn.cmd(cmd="include_gyro", gyro=1)["excluded"] == []
        feed_archive(mn, "v1", [m for m in msgs if m[1] >= 1250e9])
        st = mn.cmd(cmd="status")
        fdi = mn.sp().engine.fdi
        assert st["excluded"] == [1] and "GYRO_B_FAILED" in st["flag_names"]
        assert [r["gyro"] for r in fdi.isolations] == [1, 1]
        assert fdi.isolations[1]["t_isolated"] < 1250.0 + 30.0
    finally:
        mn.close()


def test_flag_only_when_auto_exclude_is_off(short_fault):
    from radical_rt.contract.params import ParamTable
    table = ParamTable()
    table.set({"fdi_auto_exclude": False})
    s = process([str(short_fault)], None, table=table)
    assert "GYRO_B_FAILED" in s["flags"] and "PARITY_ALARM" in s["flags"]
    assert s["mode"] != "degraded"  # nothing excluded: the operator decides


def test_disabled_monitor_stays_silent(short_fault):
    from radical_rt.contract.params import ParamTable
    table = ParamTable()
    table.set({"fdi_enabled": False})
    s = process([str(short_fault)], None, table=table)
    assert not {"PARITY_ALARM", "GYRO_B_FAILED"} & set(s["flags"]) and s["mode"] != "degraded"


def test_bookkeeping_runs_at_each_hooked_sum_and_at_least_every_check_max(short_fault, monkeypatch):
    """Outside an alarm the monitor's bookkeeping runs at the window close of each parity sum
    that goes to the window hook (the compiled loop takes the others, radical_rt.fdi.fdi_quiet,
    with the snapshot that is due at one: at least one every SNAPSHOT_PERIOD_S either way) and,
    with no sums (three gyros after the isolation), every CHECK_MAX_S of engine time."""
    from radical_rt.fdi.monitor import CHECK_MAX_S, SNAPSHOT_PERIOD_S, FaultMonitor
    from tests.support.fdi_records import record_snapshots
    runs, sums = [], []
    orig_gen, orig_sum = FaultMonitor._check_gen, FaultMonitor.on_parity_sum

    def check_gen(self, eng):
        runs.append((float(eng.t), self.state))
        return orig_gen(self, eng)

    def on_sum(self, eng, *a):
        sums.append(float(eng.t))
        return orig_sum(self, eng, *a)

    monkeypatch.setattr(FaultMonitor, "_check_gen", check_gen)
    monkeypatch.setattr(FaultMonitor, "on_parity_sum", on_sum)
    snaps = record_snapshots(monkeypatch)
    s = process([str(short_fault)], None)
    assert "GYRO_B_FAILED" in s["flags"]
    t_run = np.array([t for t, _ in runs])
    # before the fault: a bookkeeping at each hooked sum's own window close (an excitation step
    # due: every 10 s) and none other; a snapshot at least every snapshot period (plus one sum
    # of 1 s and one window of slack)
    early = [t for t in sums if 1010.0 < t < 1100.0]
    assert len(early) >= 90.0 / 12.0
    assert all(np.min(np.abs(t_run - t)) < 1e-9 for t in early)
    assert sum(1 for t in t_run if 1010.0 < t < 1100.0) <= len(early) + 2
    t_snap = [rec[0] for rec in snaps if 1010.0 < rec[0] < 1100.0]
    assert len(t_snap) >= 90.0 / (SNAPSHOT_PERIOD_S + 1.0)
    assert np.diff(t_snap).min() >= SNAPSHOT_PERIOD_S
    assert np.diff(t_snap).max() <= SNAPSHOT_PERIOD_S + 1.0 + 0.1 * (1 + 1e-3)
    three = [t for t, st in runs if st == "three-gyro"]
    assert len(three) > 20 and np.median(np.diff(three)) == pytest.approx(CHECK_MAX_S, abs=0.11)
    assert np.diff(three).max() <= CHECK_MAX_S + 0.1 * (1 + 1e-3)
