"""SIRU gyro increments per CONTRACT §1.5, with drifts and injected faults.

For sample k covering the true interval (t_{k−1}, t_k] with body rotation vector theta_k (body axes):

    g_i = w̃_i · theta_k,   w̃_i = normalize(w_i − du_i·v_i − dv_i·u_i)
    dtheta_i,k = (1 + lam_i + mu_i·sgn(g_i))·g_i + b_i(t_mid)·(t_k − t_{k−1}) + ARW + bursts

then the running sum of dtheta is quantized (quantum q) and the outputs are its differences, so
quantization error does not accumulate. b(t) = b0 + bias random walk (piecewise linear on 1 s knots)
+ bias instability (flicker, 1/f, on 0.1 s knots) + bias faults; lam(t) = lam0 + scale-factor faults. Stuck/zero faults act on the output;
invalid-status faults set status bit i. Arrays: (m,) per sample, (m, n) per sample and gyro; SI.
"""

from __future__ import annotations

import numpy as np

from radical_rt.contract.conventions import ARCSEC, DEG, DEG_PER_HR, PPM
from radical_rt.contract.geometry import U_NOM, V_NOM, W_NOM

#: Bias random-walk knot spacing (s).
KNOT_S = 1.0
#: Bias-instability (flicker) knot spacing (s): the discrete flicker's Allan deviation follows the
#: 1/f law from a few knots on (7 % high at 2 knots, 1 % at 5), i.e. from τ ≈ 0.5 s.
FLICKER_KNOT_S = 0.1


def true_axes(du: np.ndarray, dv: np.ndarray, W=W_NOM, U=U_NOM, V=V_NOM) -> np.ndarray:
    """True sense axes (3, n): columns normalize(w_i − du_i·v_i − dv_i·u_i) (du, dv in rad)."""
    wt = W - V * du[None, :] - U * dv[None, :]
    return wt / np.linalg.norm(wt, axis=0, keepdims=True)


def flicker_bias(n_knots: int, n: int, b_rad_s: float, rng) -> np.ndarray:
    """Flicker (1/f) bias (n_knots, n) rad/s on equally spaced knots, bias instability ``b_rad_s``.

    IEEE Std 952 bias instability B: two-sided rate PSD S(f) = B²/(2π|f|), whose Allan variance
    plateau is σ² = (2 ln 2/π)·B² (σ ≈ 0.664·B). Generated with Kasdin & Walter's filter (Proc.
    IEEE FCS 1992): x = h ∗ w with h_0 = 1, h_k = h_{k−1}·(k − 1 + α/2)/k, α = 1, and white w of
    variance Q_d, whose PSD is Q_d·Δ/|2 sin(π f Δ)|^α ≈ Q_d/(2π f); hence Q_d = B². The linear
    convolution is done by FFT (zero-padded, no wrap-around).
    """
    k = np.arange(1, n_knots, dtype=float)
    h = np.concatenate([[1.0], np.cumprod((k - 0.5) / k)])
    w = rng.standard_normal((n_knots, n)) * b_rad_s
    nfft = 1 << int(np.ceil(np.log2(2 * n_knots)))
    x = np.fft.irfft(np.fft.rfft(h, nfft)[:, None] * np.fft.rfft(w, nfft, axis=0), nfft, axis=0)
    return x[:n_knots]


def _active(f: dict, t: np.ndarray, t_start: float) -> np.ndarray:
    """Mask (m,) of times inside a fault's [start, end) window (times from run start in f)."""
    end = f.get("end_s", np.inf)
    return (t >= t_start + f["start_s"]) & (t < t_start + end)


class SiruModel:
    """Generates SIRU outputs sample by sample, in order, chunk after chunk.

    ``cfg``: full scenario config; ``truth``: SI parameters at the run start; ``profile``: truth
    attitude (:class:`~replayer.synth.maneuver.Profile`); ``rngs``: dict of streams 'arw',
    'bias_rw', 'burst'.
    """

    def __init__(self, cfg: dict, truth: dict, profile, rngs: dict):
        s = cfg["siru"]
        self.t_start = cfg["t_start_s"]
        self.profile = profile
        self.b0, self.lam0, self.mu = truth["b"], truth["lam"], truth["mu"]
        self.du, self.dv = truth["du"], truth["dv"]
        self.axes = true_axes(self.du, self.dv)
        self.n = self.axes.shape[1]
        self.arw = s["arw_deg_sqrt_hr"] * DEG / 60.0  # rad/√s
        self.q = s["quantum_arcsec"] * ARCSEC
        self.rngs = rngs
        self.faults = [f for f in cfg["faults"] if f["kind"] not in ("tracker_outage", "gap")]
        n_knots = int(np.ceil(cfg["duration_s"] / KNOT_S)) + 3
        steps = rngs["bias_rw"].standard_normal((n_knots, self.n)) * s["bias_rw_rad_s_sqrt_s"]
        steps[0] = 0.0
        self.rw = np.cumsum(steps * np.sqrt(KNOT_S), axis=0)  # (n_knots, n) rad/s
        bi = s.get("bias_instability_deg_hr", 0.0) * DEG_PER_HR
        self.flicker = None  # drawn only when on: scenarios without it keep their exact outputs
        if bi > 0.0:
            n_fk = int(np.ceil(cfg["duration_s"] / FLICKER_KNOT_S)) + 3
            self.flicker = flicker_bias(n_fk, self.n, bi, rngs["bias_flicker"])
        self.sum = np.zeros(self.n)  # running sum of the continuous increments (rad)
        self.count = np.zeros(self.n)  # quantized running sum, in quanta
        self.last_out = np.zeros(self.n)
        self.held: dict[int, np.ndarray] = {}

    def bias(self, t: np.ndarray) -> np.ndarray:
        """True bias (m, n) rad/s at bus times t (m,): b0 + random walk + bias faults."""
        x = np.clip((t - self.t_start) / KNOT_S, 0.0, self.rw.shape[0] - 1.000001)
        i = x.astype(int)
        w = (x - i)[:, None]
        b = self.b0[None, :] + (1.0 - w) * self.rw[i] + w * self.rw[i + 1]
        if self.flicker is not None:
            x = np.clip((t - self.t_start) / FLICKER_KNOT_S, 0.0, self.flicker.shape[0] - 1.000001)
            i = x.astype(int)
            w = (x - i)[:, None]
            b += (1.0 - w) * self.flicker[i] + w * self.flicker[i + 1]
        for f in self.faults:
            g = f.get("gyro")
            if f["kind"] == "bias_step":
                b[:, g] += np.where(_active(f, t, self.t_start), f["bias_deg_hr"] * DEG_PER_HR, 0.0)
            elif f["kind"] == "bias_ramp":
                t0 = self.t_start + f["start_s"]
                dt = np.clip(t, t0, self.t_start + f.get("end_s", np.inf)) - t0
                b[:, g] += f["rate_deg_hr_per_hr"] * DEG_PER_HR / 3600.0 * dt
        return b

    def lam(self, t: np.ndarray) -> np.ndarray:
        """True symmetric scale factors (m, n) at bus times t (m,), scale-factor jumps included."""
        lam = np.tile(self.lam0, (t.size, 1))
        for f in self.faults:
            if f["kind"] == "scale_jump":
                lam[:, f["gyro"]] += np.where(_active(f, t, self.t_start), f["lam_ppm"] * PPM, 0.0)
        return lam

    def continuous(self, t_prev: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Unquantized increments (m, n) rad over (t_prev, t] (model + ARW + noise bursts)."""
        theta = self.profile.rotation_increment(t_prev, t)
        g = theta @ self.axes
        mid = 0.5 * (t_prev + t)
        dt = t - t_prev
        inc = (1.0 + self.lam(mid) + self.mu[None, :] * np.sign(g)) * g + self.bias(mid) * dt[:, None]
        inc += self.rngs["arw"].standard_normal(g.shape) * (self.arw * np.sqrt(dt))[:, None]
        for f in self.faults:
            if f["kind"] == "noise_burst":
                on = np.nonzero(_active(f, t, self.t_start))[0]
                inc[on, f["gyro"]] += self.rngs["burst"].standard_normal(on.size) * (
                    f["sigma_arcsec"] * ARCSEC)
        return inc

    def quantize(self, inc: np.ndarray) -> np.ndarray:
        """Outputs (m, n): differences of the quantized running sum of inc (m, n)."""
        if self.q <= 0.0 or inc.shape[0] == 0:
            return inc.copy()
        run = self.sum[None, :] + np.cumsum(inc, axis=0)
        counts = np.round(run / self.q)
        out = np.diff(np.vstack([self.count[None, :], counts]), axis=0) * self.q
        self.sum, self.count = run[-1], counts[-1]
        return out

    def outputs(self, t_prev: np.ndarray, t: np.ndarray):
        """SIRU outputs for samples (t_prev, t] (m,): (dtheta (m, n) rad, status (m,) int64)."""
        out = self.quantize(self.continuous(t_prev, t))
        status = np.zeros(t.size, dtype=np.int64)
        for idx, f in enumerate(self.faults):
            on = _active(f, t, self.t_start)
            g = f.get("gyro")
            if f["kind"] == "zero":
                out[on, g] = 0.0
            elif f["kind"] == "invalid_status":
                status[on] |= 1 << g
            elif f["kind"] == "stuck" and np.any(on):
                first = int(np.argmax(on))
                if idx not in self.held:
                    self.held[idx] = out[first - 1, g] if first > 0 else self.last_out[g]
                out[on, g] = self.held[idx]
        if t.size:
            self.last_out = out[-1].copy()
        return out, status
