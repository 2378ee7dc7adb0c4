"""Figures of :mod:`monitors.report_ops`: ``ops_<label>.png`` (Matplotlib) and ``report.html``
(Bokeh, inline resources: :mod:`monitors.report_ops_html`). x axis: streams on one common axis (minutes), dashed boundaries."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from monitors.common import FLAG_BITS
from monitors.report_ops import OpsData, chi2_bounds, markers

DOF = {"st1": 3, "st2": 3, "parity": 1}


#: Marker style per kind of :func:`monitors.report_ops.markers` (colour, dash); PNG and HTML.
MARK_STYLE = {"boundary": ("black", "dashed"), "isolation": ("#d62728", "solid"),
              "fault": ("#ff7f0e", "solid"), "clear": ("#2ca02c", "dotted")}


def _marks(ax: Any, d: OpsData, text: bool = False) -> None:
    for x, kind, label in markers(d):
        color, dash = MARK_STYLE[kind]
        ax.axvline(x, color=color, ls=dash, lw=0.9 if kind == "boundary" else 0.6, alpha=0.7)
        if text and kind == "boundary":
            ax.text(x, 1.0, " " + label, transform=ax.get_xaxis_transform(), fontsize=6,
                    va="bottom")


def _per_stream(ax: Any, d: OpsData, y: np.ndarray, labels: list[str], **kw: Any) -> None:
    """Plot each column of y, broken between streams (no line joins two streams)."""
    for i in range(y.shape[1]):
        for j, (_xb, k) in enumerate(d.boundaries):
            m = d.stream == k
            ax.plot(d.x[m], y[m, i], color=f"C{i}", label=labels[i] if j == 0 else None, **kw)


def figure_ops(d: OpsData, path: Path) -> None:
    """Attitude, rates, attitude error, latency, clock, NIS with χ² bounds, flag timeline."""
    import matplotlib.pyplot as plt

    rows = 7
    fig, axes = plt.subplots(rows, 1, figsize=(12, 2.2 * rows + 1), sharex=True)
    _per_stream(axes[0], d, d.q, ["q1", "q2", "q3", "q4"], lw=1)
    axes[0].set_ylabel("q body←inertial")
    _per_stream(axes[1], d, d.omega, ["ωx", "ωy", "ωz"], lw=1)
    axes[1].set_ylabel("body rate [deg/s]")
    if d.att_err is not None:
        _per_stream(axes[2], d, d.att_err, ["x", "y", "z"], lw=1)
        axes[2].set_title("attitude error vs /truth/attitude", fontsize=8, loc="left")
    else:
        axes[2].text(0.5, 0.5, "no /truth/attitude in archive", transform=axes[2].transAxes,
                     ha="center")
    axes[2].set_ylabel("att. error [arcsec]")
    _per_stream(axes[3], d, d.lat[:, :1], ["latency estimate"], lw=1)
    for _xb, k in d.boundaries:
        m = d.stream == k
        axes[3].fill_between(d.x[m], d.lat[m, 0] - d.lat[m, 1], d.lat[m, 0] + d.lat[m, 1],
                             color="C0", alpha=0.25)
    axes[3].set_ylabel("tracker latency [ms] ±1σ")
    _per_stream(axes[4], d, d.clk[:, :1], ["SIRU freq offset [ppm]"], lw=1)
    tw = axes[4].twinx()
    tw.step(d.x, d.clk[:, 1], color="0.4", lw=0.8, where="post", label="locked")
    tw.plot(d.x, d.clk[:, 2], color="tab:purple", lw=0.8, label="repeated")
    tw.plot(d.x, d.clk[:, 3], color="tab:brown", lw=0.8, label="missing")
    tw.legend(fontsize=6, loc="lower right")
    axes[4].set_ylabel("clock [ppm]")
    for i, (kind, v) in enumerate(d.nis.items()):
        axes[5].semilogy(d.x, np.where(v > 0, v, np.nan), ".", ms=1.5, color=f"C{i}",
                         label=f"{kind} NIS")
        lo, hi = chi2_bounds(DOF.get(kind, 3))
        axes[5].axhline(hi, color=f"C{i}", ls=":", lw=0.8)
        axes[5].axhline(lo, color=f"C{i}", ls=":", lw=0.8)
    axes[5].set_ylabel("NIS (χ² 95 %)")
    for b, _name in FLAG_BITS:
        on = (d.flags >> b) & 1
        if on.any():
            axes[6].fill_between(d.x, b - 0.4 * on, b + 0.4 * on, step="post", color="tab:red")
    axes[6].set_yticks([b for b, _ in FLAG_BITS], [n for _, n in FLAG_BITS], fontsize=5)
    axes[6].set_ylabel("flags")
    axes[6].set_xlabel("time on the common stream axis [min]")
    for i, ax in enumerate(axes):
        _marks(ax, d, text=i == 0)
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=6, loc="upper right", ncol=4)
    fig.suptitle(f"Operations view: {d.label} ({len(d.boundaries)} stream(s))", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    fig.savefig(path, dpi=80)
    plt.close(fig)
