"""Output packets as the node publishes them, for the monitor tests."""

from __future__ import annotations

from radical_rt.contract.conventions import ARCSEC, DEG_PER_HR, PPM


def large_packet(seq: int = 7, t: float = 1234.5, flags: int = 0) -> dict:
    """A tlm/large packet as the node publishes it (SI units)."""
    return {
        "v": 1, "seq": seq, "t": t, "q_body_from_inertial": [0.0, 0.0, 0.0, 1.0], "flags": flags,
        "mode": "converging", "omega_body": [0.0, 0.001, 0.0],
        "est": {"b": [0.5026 * DEG_PER_HR, -0.0997 * DEG_PER_HR, 0.0871 * DEG_PER_HR,
                      -0.0711 * DEG_PER_HR],
                "lam": [326.4 * PPM, -261.4 * PPM, 602.8 * PPM, 358.7 * PPM],
                "mu": [-17.7 * PPM, 10.6 * PPM, -1.5 * PPM, -27.5 * PPM],
                "du": [489.9 * ARCSEC, 482.6 * ARCSEC, 862.6 * ARCSEC, 816.9 * ARCSEC],
                "dv": [335.9 * ARCSEC, -304.6 * ARCSEC, -315.5 * ARCSEC, 318.2 * ARCSEC],
                "phi2": [1331.2 * ARCSEC, -635.5 * ARCSEC, -430.2 * ARCSEC]},
        "sigma": {"b": [0.0022 * DEG_PER_HR] * 4, "lam": [3.4 * PPM] * 4, "mu": [3.2 * PPM] * 4,
                  "du": [0.7 * ARCSEC] * 4, "dv": [0.9 * ARCSEC] * 4,
                  "phi2": [0.06 * ARCSEC, 0.06 * ARCSEC, 0.17 * ARCSEC]},
        "att_sigma": [0.1 * ARCSEC, 0.1 * ARCSEC, 0.5 * ARCSEC],
        "residuals": {"st1": {"innov": [1e-6, -2e-6, 5e-5], "sigma": [2e-5, 2e-5, 1.9e-4],
                              "nis": 2.3, "nis_mean": 3.0},
                      "parity": {"innov": [3e-8], "sigma": [2.4e-8], "nis": 1.9, "nis_mean": 0.96}},
        "clock": {"mode": "reconstruct", "locked": True, "anomaly": False,
                  "freq_offset_ppm": 40.01, "offset_s": 0.0049, "tag_error_sigma_s": 0.0029,
                  "counters": {"samples": 1000, "repeated": 3, "missing": 2}},
        "counters": {"siru_samples": 1000, "st1_used": 99, "st2_used": 98, "input_rejected": 0},
        "latency": {"configured_s": 0.115, "residual_s": 0.002, "estimate_s": 0.117,
                    "sigma_s": 0.0021},
    }
