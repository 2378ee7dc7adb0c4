"""SIRU model (CONTRACT §1.5): slew sums against the contract formula, quantization, noise
statistics (chi-square bounds), faults, and the sums recovered from an archive's bus stream."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from radical_rt.contract.geometry import U_NOM, V_NOM, W_NOM
from radical_rt.io.archive import ArchiveReader
from replayer.synth import load_scenario, synthesize
from replayer.synth.simulator import stream
from replayer.synth.siru import SiruModel, true_axes

ARCSEC = np.pi / 648000
DEG_HR = np.pi / 648000
QUIET = {"arw_deg_sqrt_hr": 0.0, "bias_rw_rad_s_sqrt_s": 0.0, "quantum_arcsec": 0.0}


def chi2_ok(sum_sq_normalized: float, dof: int, p: float = 1e-3) -> bool:
    """Two-sided chi-square test at level p (sum of dof squared standard normals)."""
    return chi2.ppf(p / 2, dof) <= sum_sq_normalized <= chi2.ppf(1 - p / 2, dof)


def make_model(siru=None, faults=(), profile="messenger", duration=7200.0, seed=3):
    sc = load_scenario({"base": "2006216", "seed": seed, "duration_s": duration,
                        "siru": dict(siru or {}), "maneuver": {"profile": profile},
                        "faults": list(faults)})
    rngs = {k: stream(sc.seed, f"siru.{k}") for k in ("arw", "bias_rw", "burst")}
    return sc, SiruModel(sc.cfg, sc.truth, sc.profile(), rngs)


def run_model(m, t_edges, chunk=1000):
    """Outputs for samples on the time grid t_edges (m+1,), fed in chunks (state carried)."""
    outs, stats = [], []
    for a in range(0, t_edges.size - 1, chunk):
        b = min(a + chunk, t_edges.size - 1)
        o, s = m.outputs(t_edges[a:b], t_edges[a + 1:b + 1])
        outs.append(o)
        stats.append(s)
    return np.vstack(outs), np.concatenate(stats)


def test_true_axes_formula():
    rng = np.random.default_rng(0)
    du, dv = rng.uniform(-0.02, 0.02, 4), rng.uniform(-0.02, 0.02, 4)
    wt = true_axes(du, dv)
    for i in range(4):
        raw = W_NOM[:, i] - du[i] * V_NOM[:, i] - dv[i] * U_NOM[:, i]
        assert np.allclose(wt[:, i], raw / np.linalg.norm(raw), atol=1e-15)
    assert np.allclose(true_axes(np.zeros(4), np.zeros(4)), W_NOM)


@pytest.mark.parametrize("noise", [False, True])
def test_rest_to_rest_slew_sum_matches_contract(noise):
    """Σ dtheta_i over the +10° x slew = (1 + lam + mu·sgn)·w̃ᵀθ + b·T (noise: within bounds)."""
    sc, m = make_model(siru=None if noise else QUIET)
    t = np.arange(295.0, 360.0 + 1e-9, 0.01)  # rest → +10° about x → rest
    out, _ = run_model(m, t)
    theta = m.profile.rotation_increment(t[:1], t[-1:])[0]
    assert np.allclose(theta, [10 * np.pi / 180, 0, 0], atol=1e-12)
    tr = sc.truth
    raw = W_NOM - V_NOM * tr["du"] - U_NOM * tr["dv"]
    g = theta @ (raw / np.linalg.norm(raw, axis=0))
    T = t[-1] - t[0]
    expect = (1 + tr["lam"] + tr["mu"] * np.sign(g)) * g + tr["b"] * T
    if not noise:
        assert np.max(np.abs(out.sum(0) - expect)) < 1e-13
    else:
        s = sc.cfg["siru"]
        arw = s["arw_deg_sqrt_hr"] * np.pi / 180 / 60 * np.sqrt(T)
        rw = s["bias_rw_rad_s_sqrt_s"] * T**1.5 / np.sqrt(3)  # σ of ∫ of the bias walk
        tol = s["quantum_arcsec"] * ARCSEC + 5 * np.hypot(arw, rw)
        assert np.all(np.abs(out.sum(0) - expect) < tol)


def test_quantization_does_not_accumulate():
    _, m = make_model()
    q = m.q
    rng = np.random.default_rng(1)
    inc = rng.normal(3e-7, 2e-7, (50000, 4))
    out = np.vstack([m.quantize(inc[a:a + 777]) for a in range(0, inc.shape[0], 777)])
    assert np.allclose(out / q, np.round(out / q), atol=1e-6)  # whole quanta
    err = np.cumsum(out, axis=0) - np.cumsum(inc, axis=0)
    assert np.max(np.abs(err)) <= q / 2 + 1e-12


def test_angle_random_walk_variance():
    _, m = make_model(siru={"bias_rw_rad_s_sqrt_s": 0.0, "quantum_arcsec": 0.0}, profile="none")
    t = 10.0 + np.arange(20001) * 0.01
    out, _ = run_model(m, t)
    resid = out - m.b0[None, :] * 0.01
    sigma = m.arw * np.sqrt(0.01)
    assert chi2_ok(float(np.sum((resid / sigma) ** 2)), resid.size)


def test_bias_random_walk_steps():
    _, m = make_model(siru={"bias_rw_rad_s_sqrt_s": 1e-9}, duration=20000.0)
    steps = np.diff(m.rw, axis=0)[1:]  # knots 1 s apart
    assert chi2_ok(float(np.sum((steps / 1e-9) ** 2)), steps.size)


# The original profile's +90° x slew starts at 200 s (all gyros see motion). Fault edges sit a
# quarter sample off the 10 ms grid so that "sample end in window" and "sample midpoint in
# window" select the same samples.
T0 = 200.0025
FAULTS = [
    {"kind": "bias_step", "gyro": 0, "start_s": T0 + 10, "end_s": T0 + 20, "bias_deg_hr": 2.0},
    {"kind": "bias_ramp", "gyro": 1, "start_s": T0 + 5, "end_s": T0 + 15,
     "rate_deg_hr_per_hr": 3600.0},
    {"kind": "scale_jump", "gyro": 2, "start_s": T0 + 8, "lam_ppm": 1000.0},
    {"kind": "stuck", "gyro": 3, "start_s": T0 + 12, "end_s": T0 + 18},
    {"kind": "zero", "gyro": 0, "start_s": T0 + 12, "end_s": T0 + 18},
    {"kind": "noise_burst", "gyro": 1, "start_s": T0 + 10, "end_s": T0 + 25, "sigma_arcsec": 0.5},
    {"kind": "invalid_status", "gyro": 2, "start_s": T0 + 3, "end_s": T0 + 4},
]


@pytest.mark.parametrize("fault", FAULTS, ids=[f["kind"] for f in FAULTS])
def test_fault_effects(fault):
    """Faulted minus unfaulted run (same seed, same noise): only the fault's effect remains."""
    siru = {"quantum_arcsec": 0.0}
    _, clean = make_model(siru=siru, profile="original")
    _, bad = make_model(siru=siru, faults=[fault], profile="original")
    t = 200.0 + np.arange(3001) * 0.01
    a, sa = run_model(clean, t)
    b, sb = run_model(bad, t)
    g, mid, dt = fault.get("gyro"), 0.5 * (t[1:] + t[:-1]), np.diff(t)
    on = (t[1:] >= fault["start_s"]) & (t[1:] < fault.get("end_s", np.inf))
    others = [i for i in range(4) if i != g]
    assert np.array_equal(a[:, others], b[:, others])
    d = b[:, g] - a[:, g]
    kind = fault["kind"]
    if kind == "bias_step":
        assert np.allclose(d, np.where(on, 2.0 * DEG_HR * dt, 0.0), atol=1e-18)
    elif kind == "bias_ramp":
        ramp = np.clip(mid, T0 + 5, T0 + 15) - (T0 + 5)
        assert np.allclose(d, DEG_HR * ramp * dt, atol=1e-18, rtol=1e-9)
    elif kind == "scale_jump":
        gi = clean.profile.rotation_increment(t[:-1], t[1:]) @ clean.axes[:, g]
        assert np.all(np.abs(gi[on]) > 1e-6)
        assert np.allclose(d, np.where(on, 1e-3 * gi, 0.0), atol=1e-18, rtol=1e-9)
    elif kind == "stuck":
        first = int(np.argmax(on))
        assert np.all(b[on, g] == a[first - 1, g]) and np.all(d[~on] == 0)
    elif kind == "zero":
        assert np.all(b[on, g] == 0) and np.all(d[~on] == 0)
    elif kind == "noise_burst":
        assert np.all(d[~on] == 0)
        assert chi2_ok(float(np.sum((d[on] / (0.5 * ARCSEC)) ** 2)), int(on.sum()))
    elif kind == "invalid_status":
        assert np.array_equal(sb, np.where(on, 1 << g, 0)) and np.array_equal(a, b)
    assert np.all(sa == 0) and on.sum() > 50


def test_slew_sum_from_archive_bus_stream(tmp_path):
    """From the archive alone (+ truth): received increments over a slew, with repeats and
    misses in the bus stream, sum to the model over the received samples."""
    eps_cfg = {"eps_ppm": 500.0, "read_jitter_s": 1e-4}  # sawtooth period 20 s: spates in window
    res = synthesize({"base": "2006216", "duration_s": 380.0, "siru": eps_cfg}, tmp_path / "a.mcap")
    sc = res.scenario
    r = ArchiveReader(res.path)
    siru = [m for _, _, m in r.iter_messages(topics=["/siru"])]
    truth = [m for _, _, m in r.iter_messages(topics=["/truth/siru_time"])]
    tt = np.concatenate([m["tt"] for m in siru])
    d = np.concatenate([m["dtheta"] for m in siru])
    _, first = np.unique(tt, return_index=True)
    first.sort()
    tt_d, d_d = tt[first], d[first]  # distinct samples in read order
    tt_true = np.concatenate([m["tt"] for m in truth])
    t_true = np.concatenate([m["t_true"] for m in truth])
    idx = np.searchsorted(tt_true, tt_d)  # counter does not wrap in 380 s from tt0 = 0
    assert np.array_equal(tt_true[idx], tt_d)
    win = (t_true[idx] > 290.0) & (t_true[idx] < 365.0)
    assert np.all(idx[win] > 0)
    n_runs = 1 + int(np.sum(np.diff(idx[win]) > 1))
    assert res.truth_counts[0]["n_repeated"] > 0 and n_runs > 1  # the window has spates
    theta = sc.profile().rotation_increment(t_true[idx[win] - 1], t_true[idx[win]])
    tr = sc.truth
    raw = W_NOM - V_NOM * tr["du"] - U_NOM * tr["dv"]
    g = theta @ (raw / np.linalg.norm(raw, axis=0))
    dt = (t_true[idx[win]] - t_true[idx[win] - 1])[:, None]
    expect = ((1 + tr["lam"] + tr["mu"] * np.sign(g)) * g + tr["b"] * dt).sum(0)
    s = sc.cfg["siru"]
    T = float(dt.sum())
    sig = np.hypot(s["arw_deg_sqrt_hr"] * np.pi / 180 / 60 * np.sqrt(T),
                   s["bias_rw_rad_s_sqrt_s"] * 380.0**1.5)
    tol = n_runs * s["quantum_arcsec"] * ARCSEC + 5 * sig
    assert np.all(np.abs(d_d[win].sum(0) - expect) < tol)
