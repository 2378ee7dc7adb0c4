"""Gyro noise from a static segment: overlapping Allan deviation and the IEEE Std 952 terms.

Used by ``radical allan`` (:mod:`monitors.allan`). All inputs and results are SI (rad, rad/s, s);
the paper/datasheet units (deg/√hr, deg/hr, deg/hr/√s, arcsec) are produced only by
:func:`paper_units`.

Data (:func:`load_segment`): the ``/siru`` samples of an archive (CONTRACT §3), repeated reads
(same ``tt``) dropped, missing samples (``tt`` steps of two or more sample periods) and samples a
gyro reports invalid (``status`` bit) filled with the segment's mean increment of that gyro, so
the accumulated angle keeps its time base. The sample period τ0 is the bus-time span divided by
the number of sample intervals.

Allan deviation (:func:`analyse`): ``allantools.oadev`` on the accumulated angle (phase data,
rad), so σ(τ) is in rad/s; equivalent degrees of freedom by Greenhall's algorithm
(``allantools.edf_greenhall``, overlapping, for the noise type that dominates at each τ) and 68 %
chi-square confidence intervals (``allantools.confidence_interval``).

Noise terms: σ²(τ) = 3Q²/τ² + N²/τ + (2 ln 2/π)·B² + K²τ/3 (IEEE Std 952-1997, Annex C:
quantization Q, angle random walk N, bias instability B, rate random walk K), fitted by
non-negative weighted least squares on σ̂²(τ) with weights edf/(2σ̂⁴) (the variance of σ̂²); 1σ
of each term from the fit covariance (the τ points treated as independent, so optimistic),
and, as a cross-check, the classic single-point readouts: N = σ(1 s) and B = min σ / 0.664.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from radical_rt.contract.conventions import ARCSEC, DEG, DEG_PER_HR, SIRU_TT_WRAP

BI_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # σ_floor = 0.6643·B
GYRO_NAMES = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"
TERMS = ("Q", "N", "B", "K")  # quantization, ARW, bias instability, RRW
#: Greenhall alpha (S_y ∝ f^alpha, y = rate) of each term
ALPHA = {"Q": 2, "N": 0, "B": -1, "K": -2}


class AllanError(Exception):
    """The analysis cannot be made; ``str(e)`` is one line."""


@dataclass
class Segment:
    """Gyro increments of one static segment."""

    dtheta: np.ndarray  # (m, n) rad, filled
    tau0: float  # s, sample period
    t0: float  # s, bus time of the first sample
    t1: float  # s, bus time of the last sample
    n_repeated: int = 0
    n_missing: int = 0
    n_invalid: int = 0
    max_rate_dev_deg_s: float = 0.0  # largest 10 s mean rate minus the median (deg/s)


def load_segment(path: str, t0: float | None = None, t1: float | None = None,
                 progress: bool = False) -> Segment:
    """The /siru samples of ``path`` with ``t0 <= t_bus <= t1`` (s; None = open); a progress
    bar on stderr with ``progress``."""
    import sys

    import msgpack
    from tqdm import tqdm

    from radical_rt.io.archive import ArchiveError, ArchiveReader

    tt: list[int] = []
    tb: list[float] = []
    dth: list[list[float]] = []
    st: list[int] = []
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            reader = ArchiveReader(path)
        with reader:
            if not reader.message_counts.get("/siru"):
                raise AllanError(f"{path}: no /siru messages (an input archive is needed)")
            start = None if t0 is None else int(round(t0 * 1e9))
            end = None if t1 is None else int(round(t1 * 1e9)) + 1
            for _topic, _ns, data in tqdm(reader.iter_raw("/siru", start, end),
                                          total=reader.message_counts["/siru"], unit="msg",
                                          desc="allan: /siru", disable=not progress,
                                          file=sys.stderr, leave=False):
                m = msgpack.unpackb(data, raw=False, strict_map_key=False)
                tt += m["tt"]
                tb += m["t_bus"]
                dth += m["dtheta"]
                st += m["status"]
    except ArchiveError as e:
        raise AllanError(str(e)) from None
    except (KeyError, TypeError, ValueError) as e:
        raise AllanError(f"{path}: malformed /siru message: {e}") from None
    if len(tt) < 1000:
        raise AllanError(f"{path}: only {len(tt)} SIRU samples in the segment (need ≥ 1000)")
    return _clean(np.array(tt, dtype=np.int64), np.array(tb), np.array(dth, dtype=float),
                  np.array(st, dtype=np.int64))


def _clean(tt: np.ndarray, tb: np.ndarray, dth: np.ndarray, st: np.ndarray) -> Segment:
    keep = np.ones(tt.size, dtype=bool)
    keep[1:] = tt[1:] != tt[:-1]  # a repeated read carries the same tt
    n_rep = int((~keep).sum())
    tt, tb, dth, st = tt[keep], tb[keep], dth[keep], st[keep]
    step = (np.diff(tt) % SIRU_TT_WRAP).astype(float)
    nominal = float(np.median(step))
    bus = np.diff(tb)
    tau_bus = float(np.median(bus))
    # samples per interval from tt; where tt jumps oddly (a counter reset), from the bus time
    k = np.rint(step / nominal)
    odd = (k < 1) | (k > 1000)
    k[odd] = np.maximum(np.rint(bus[odd] / tau_bus), 1)
    k = k.astype(np.int64)
    n = dth.shape[1]
    invalid = (st[:, None] >> np.arange(n)[None, :]) & 1 == 1
    good = dth[~invalid.any(axis=1)] if (~invalid.any(axis=1)).any() else dth
    mean = good.mean(axis=0)
    dth = np.where(invalid, mean[None, :], dth)
    idx = np.concatenate([[0], np.cumsum(k)])
    full = np.repeat(mean[None, :], int(idx[-1]) + 1, axis=0)
    full[idx] = dth
    tau0 = (tb[-1] - tb[0]) / idx[-1]
    w = max(1, int(round(10.0 / tau0)))  # 10 s means of the rate, for the static check
    nb = full.shape[0] // w
    rates = full[: nb * w].reshape(nb, w, n).mean(axis=1) / tau0
    dev = float(np.max(np.abs(rates - np.median(rates, axis=0)))) / DEG if nb else 0.0
    return Segment(dtheta=full, tau0=float(tau0), t0=float(tb[0]), t1=float(tb[-1]),
                   n_repeated=n_rep, n_missing=int((k - 1).sum()), n_invalid=int(invalid.sum()),
                   max_rate_dev_deg_s=dev)


def tau_grid(n_samples: int, tau0: float, per_decade: int = 12, max_fraction: float = 0.1
             ) -> np.ndarray:
    """Averaging times τ = m·τ0 (s), log-spaced, m from 1 to ``max_fraction``·n_samples."""
    m_max = max(2, int(n_samples * max_fraction))
    ms = np.unique(np.rint(np.logspace(0, math.log10(m_max),
                                       int(per_decade * math.log10(m_max)) + 1)).astype(int))
    return ms * tau0


def _design(tau: np.ndarray) -> np.ndarray:
    """Columns of σ²(τ) per coefficient (Q², N², B², K²)."""
    return np.column_stack([3.0 / tau**2, 1.0 / tau, np.full_like(tau, BI_FACTOR**2), tau / 3.0])


#: relative model error of σ²(τ) added to the statistical one in the fit weights: the σ² terms
#: are asymptotic forms (the quantization of a nearly constant rate beats, it is not white), so
#: no τ point, however many its degrees of freedom, is trusted to better than this.
MODEL_REL_ERROR = 0.05


def fit_terms(tau: np.ndarray, adev: np.ndarray, edf: np.ndarray,
              prior: dict[str, float] | None = None
              ) -> tuple[dict[str, float], dict[str, float]]:
    """Q, N, B, K and their 1σ (SI) from a weighted non-negative least-squares fit of σ²(τ).

    The weights are 1/sd(σ̂²) with sd taken relative to the model σ² of a previous fit
    (``prior``), else to the data (weights from the data favour points that fell low)."""
    from scipy.optimize import nnls

    A = _design(tau)
    y = adev**2
    ref = y if prior is None else A @ np.array([prior[t] ** 2 for t in TERMS])
    ref = np.where(ref > 0, ref, y)
    sw = 1.0 / (ref * np.sqrt(2.0 / edf + MODEL_REL_ERROR**2))  # 1 / sd(σ̂²)
    scale = np.max(np.abs(A * sw[:, None]), axis=0)
    scale[scale == 0] = 1.0
    As = A * sw[:, None] / scale
    c, _res = nnls(As, y * sw)
    coef = c / scale
    # covariance of the unconstrained weighted fit (all four terms): for a term fitted as 0 its
    # square root is a 1σ upper bound
    cov = np.linalg.pinv(As.T @ As) / np.outer(scale, scale)
    vals, sig = {}, {}
    for i, name in enumerate(TERMS):
        v = math.sqrt(coef[i]) if coef[i] > 0 else 0.0
        sd_c = math.sqrt(max(cov[i, i], 0.0))
        vals[name] = v
        # σ of sqrt(c): sd_c / (2 sqrt c); for c = 0 report the 1σ upper bound sqrt(sd_c)
        sig[name] = sd_c / (2.0 * v) if v > 0 else math.sqrt(sd_c)
    return vals, sig


def _dominant(tau: np.ndarray, vals: dict[str, float]) -> np.ndarray:
    A = _design(tau)
    parts = A * np.array([vals[t] ** 2 for t in TERMS])[None, :]
    return np.array([ALPHA[TERMS[j]] for j in np.argmax(parts, axis=1)])


@dataclass
class GyroResult:
    """Allan deviation and noise terms of one gyro (SI)."""

    name: str
    tau: np.ndarray  # s
    adev: np.ndarray  # rad/s
    lo: np.ndarray  # 68 % confidence interval (rad/s)
    hi: np.ndarray
    edf: np.ndarray
    terms: dict[str, float]  # Q rad, N rad/√s, B rad/s, K rad/s/√s
    sigma: dict[str, float]
    readout: dict[str, float] = field(default_factory=dict)  # N at τ=1 s, B = min σ/0.664


def analyse(seg: Segment, per_decade: int = 12, fit_min_m: int = 10) -> list[GyroResult]:
    """Allan deviation, confidence and noise terms for every gyro of a segment.

    The fit uses τ ≥ ``fit_min_m``·τ0: at the first few sample periods the quantization error of
    a nearly constant rate is periodic, not white, and the continuous-time σ²(τ) terms do not
    hold."""
    import allantools

    m_total = seg.dtheta.shape[0]
    taus = tau_grid(m_total, seg.tau0, per_decade)
    out = []
    for i in range(seg.dtheta.shape[1]):
        phase = np.concatenate([[0.0], np.cumsum(seg.dtheta[:, i])])
        tau, adev, _err, _n = allantools.oadev(phase, rate=1.0 / seg.tau0, data_type="phase",
                                               taus=taus)
        ok = np.isfinite(adev) & (adev > 0)
        tau, adev = tau[ok], adev[ok]
        ms = np.rint(tau / seg.tau0).astype(int)
        edf = np.array([allantools.edf_simple(phase.size, m, 0) for m in ms])
        f = ms >= fit_min_m
        vals, sig = fit_terms(tau[f], adev[f], edf[f])
        for _ in range(3):  # edf for the noise that dominates at each τ, model weights, refit
            alphas = _dominant(tau, vals)
            edf = np.array([_edf(int(a), int(m), phase.size) for a, m in zip(alphas, ms,
                                                                               strict=True)])
            vals, sig = fit_terms(tau[f], adev[f], edf[f], vals)
        lo, hi = np.array([allantools.confidence_interval(a, e) for a, e in zip(adev, edf,
                                                                                 strict=True)]).T
        j1 = int(np.argmin(np.abs(np.log(tau))))
        readout = {"N_at_1s": float(adev[j1] * math.sqrt(tau[j1])),
                   "B_from_min": float(adev.min() / BI_FACTOR),
                   "tau_min_s": float(tau[int(np.argmin(adev))])}
        out.append(GyroResult(GYRO_NAMES[i], tau, adev, lo, hi, edf, vals, sig, readout))
    return out


def _edf(alpha: int, m: int, n: int) -> float:
    import allantools

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            e = float(allantools.edf_greenhall(alpha=alpha, d=2, m=m, N=n, overlapping=True,
                                               modified=False))
    except (NotImplementedError, AssertionError, ValueError, ZeroDivisionError):
        e = float(allantools.edf_simple(n, m, alpha))
    return e if math.isfinite(e) and e > 0 else 1.0


#: SI per paper unit of each term: Q arcsec, N deg/√hr, B deg/hr, K deg/hr/√s
PAPER = {"Q": (ARCSEC, "arcsec"), "N": (DEG / 60.0, "deg/√hr"), "B": (DEG_PER_HR, "deg/hr"),
         "K": (DEG_PER_HR, "deg/hr/√s")}


def paper_units(values: dict[str, float]) -> dict[str, float]:
    """Terms in datasheet units (Q arcsec, N deg/√hr, B deg/hr, K deg/hr/√s)."""
    return {k: v / PAPER[k][0] for k, v in values.items() if k in PAPER}


def param_table(results: list[GyroResult]) -> dict[str, Any]:
    """The noise parameters in the parameter table's form (radical_rt.contract.params, ``[params]``):
    the worst gyro's ARW, the quantum q = √12·Q and the bias random walk density."""
    n = max(r.terms["N"] for r in results)
    q = max(r.terms["Q"] for r in results) * math.sqrt(12.0)
    k = max(r.terms["K"] for r in results)
    return {"arw_deg_sqrt_hr": n / PAPER["N"][0], "quant_arcsec": q / ARCSEC,
            "q_b_deg_hr_sqrt_s": k / DEG_PER_HR}
