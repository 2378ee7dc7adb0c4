"""Figures 4–8 of ``radical report`` (matplotlib, PNG): per archive, attitude 1σ, residuals ±1σ
and ST2 alignment (:func:`figure4`) and estimates with σ per group (:func:`figure_groups`,
Figures 5 and 6); with two or more archives, groups side by side on common y limits
(:func:`figure_side_by_side`, Figures 7 and 8). The x axis is elapsed minutes with stream breaks
(jumps of the packet time over ``GAP_S``) collapsed and marked.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from monitors.common import GROUP_LABELS, PAPER_UNITS, element_names
from monitors.report_data import ArchiveData

GAP_S = 60.0  # larger jumps of the packet time are stream breaks, collapsed in the figures
GYRO_COLORS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown",
               "tab:pink", "tab:gray"]


def _elapsed_min(t: np.ndarray, t0: float) -> tuple[np.ndarray, list[float]]:
    """Minutes since t0 with stream breaks (jumps > GAP_S) collapsed; break positions (min)."""
    if len(t) == 0:
        return t, []
    dt = np.diff(t, prepend=t[0])
    step = float(np.median(dt[1:])) if len(dt) > 1 else 0.0
    big = dt > max(GAP_S, 10 * step)
    dt = np.where(big, step, dt)
    x = (t[0] - t0 + np.cumsum(dt)) / 60.0
    return x, [float(v) for v in x[big]]


class _Clock:
    """Maps bus times of one archive to its figure x axis (elapsed minutes, breaks collapsed)."""

    def __init__(self, t: np.ndarray) -> None:
        self.t = t
        self.t0 = float(t[0]) if len(t) else 0.0
        self.x, self.breaks = _elapsed_min(t, self.t0)

    def __call__(self, ts: np.ndarray) -> np.ndarray:
        if len(self.t) < 2:
            return (ts - self.t0) / 60.0
        return np.interp(ts, self.t, self.x, left=np.nan, right=np.nan) if len(ts) else ts


def _mark_breaks(ax: Any, clock: _Clock) -> None:
    for b in clock.breaks:
        ax.axvline(b, color="k", lw=0.8, ls="--", alpha=0.6)


def _lines(ax: Any, x: np.ndarray, y: np.ndarray, names: list[str], *, log: bool = False,
           truth: tuple[np.ndarray, np.ndarray] | None = None, legend: bool = True) -> None:
    if not np.isfinite(y).any():
        ax.text(0.5, 0.5, "not in telemetry", ha="center", va="center", transform=ax.transAxes,
                color="0.4")
        return
    for i in range(y.shape[1]):
        c = GYRO_COLORS[i % len(GYRO_COLORS)]
        ax.plot(x, y[:, i], color=c, lw=1.1, label=names[i] if i < len(names) else str(i))
        if truth is not None and i < truth[1].shape[1]:
            ax.plot(truth[0], truth[1][:, i], color=c, lw=0.9, ls=":", alpha=0.9)
    if log:
        ax.set_yscale("log")
    ax.grid(True, which="both" if log else "major", alpha=0.3)
    if legend and y.shape[1] > 1:
        ax.legend(fontsize=7, ncol=min(y.shape[1], 4), loc="best", framealpha=0.7)


def _robust_ylim(ax: Any, x: np.ndarray, ys: list[Any]) -> None:
    """Estimates: leave out the first 5 % of the run when it dwarfs the rest (cold-start
    transients), so the converged part stays readable; the transient is then clipped.
    ys: arrays on x, or (x_i, y_i) pairs on their own x."""
    if len(x) < 20:
        return
    x0, x1 = x[0], x[0] + 0.05 * (x[-1] - x[0])
    full, tail = [], []
    for item in ys:
        xi, yi = item if isinstance(item, tuple) else (x, item)
        yi = np.asarray(yi).reshape(len(xi), -1)
        ok = np.isfinite(yi) & np.isfinite(np.asarray(xi))[:, None]
        full.append(yi[ok])
        late = ok & (np.asarray(xi) >= x1)[:, None] & (np.asarray(xi) >= x0)[:, None]
        tail.append(yi[late])
    f, t = np.concatenate(full), np.concatenate(tail)
    if not len(f) or not len(t):
        return
    lo, hi = float(t.min()), float(t.max())
    span_full, span = float(f.max() - f.min()), hi - lo
    if span > 0 and span_full > 4 * span:
        pad = 0.08 * span
        ax.set_ylim(lo - pad, hi + pad)
        ax.text(0.01, 0.03, "initial transient clipped", transform=ax.transAxes, ha="left",
                va="bottom", fontsize=7, color="0.4")


def _est_sigma_pair(axe: Any, axs: Any, d: ArchiveData, g: str, clock: _Clock, tag: str) -> None:
    names = element_names(g, d.est[g].shape[1])
    unit = PAPER_UNITS[g]
    tr = None
    if g in d.truth and len(d.truth_t):
        tr = (clock(d.truth_t), d.truth[g])
    _lines(axe, clock.x, d.est[g], names, truth=tr)
    _robust_ylim(axe, clock.x, [d.est[g]] + ([tr] if tr else []))
    axe.set_ylabel(f"{GROUP_LABELS[g]} [{unit}]")
    axe.set_title(f"({tag[0]}) {GROUP_LABELS[g]} estimates" + (" (dotted: truth)" if tr else ""),
                  fontsize=9, loc="left")
    sig = d.sig[g]
    pos = np.where(sig > 0, sig, np.nan)
    _lines(axs, clock.x, pos, names, log=bool(np.isfinite(pos).any()), legend=False)
    axs.set_ylabel(f"σ {GROUP_LABELS[g]} [{unit}]")
    axs.set_title(f"({tag[1]}) {GROUP_LABELS[g]} standard deviations", fontsize=9, loc="left")
    for ax in (axe, axs):
        _mark_breaks(ax, clock)


def _residual_panel(fig: Any, cell: Any, d: ArchiveData, kind: str, clock: _Clock, title: str) -> None:
    r = d.resid.get(kind)
    if r is None:
        ax = fig.add_subplot(cell)
        ax.text(0.5, 0.5, f"no {kind} residuals in telemetry", ha="center", va="center",
                transform=ax.transAxes, color="0.4")
        ax.set_title(title, fontsize=9, loc="left")
        ax.set_xlabel("time [min]")
        return
    m = r["innov"].shape[1]
    groups = [list(range(m))] if m != 3 else [[0, 1], [2]]  # cross-boresight x, y | boresight z
    sub = cell.subgridspec(len(groups), 1, hspace=0.08)
    labels = ["x", "y", "z"] if m == 3 else [f"p{i + 1}" for i in range(m)]
    axes: list[Any] = []
    for j, comps in enumerate(groups):
        ax = fig.add_subplot(sub[j], sharex=axes[0] if axes else None)
        axes.append(ax)
        for i in comps:
            c = GYRO_COLORS[i % len(GYRO_COLORS)]
            ax.plot(clock.x, r["innov"][:, i], ".", ms=1.6, color=c, alpha=0.6,
                    label=f"{labels[i]} residual")
            ax.plot(clock.x, r["sigma"][:, i], color=c, lw=0.9)
            ax.plot(clock.x, -r["sigma"][:, i], color=c, lw=0.9)
        _robust_ylim(ax, clock.x, [r["sigma"][:, comps], -r["sigma"][:, comps],
                                   r["innov"][:, comps]])
        ax.grid(True, alpha=0.3)
        ax.set_ylabel("arcsec")
        ax.legend(fontsize=7, loc="upper right", markerscale=4, ncol=len(comps), framealpha=0.7)
        _mark_breaks(ax, clock)
        if j < len(groups) - 1:
            ax.tick_params(labelbottom=False)
    axes[0].set_title(title + " and ±1σ bounds", fontsize=9, loc="left")
    axes[-1].set_xlabel("time [min]")


def _title(fig: Any, text: str, d: ArchiveData | None = None) -> None:
    sub = ""
    if d is not None:
        sub = f"\n{d.label}: {os.path.basename(d.path)}, {len(d.t)} of {d.n_packets} {d.topic} " \
              f"packets, t = {d.t[0]:.1f}…{d.t_end:.1f} s"
    fig.suptitle(text + sub, fontsize=10)


def figure4(d: ArchiveData, path: Path) -> None:
    """Figure 4 analog of one archive: attitude 1σ [arcsec]; parity, ST1 and ST2 residuals ±1σ
    [arcsec]; ST2 alignment δa2 estimates and σ; written to ``path`` (PNG)."""
    import matplotlib.pyplot as plt

    clock = _Clock(d.t)
    fig = plt.figure(figsize=(12, 12.5))
    gs = fig.add_gridspec(3, 2, hspace=0.32, wspace=0.22, left=0.07, right=0.98, top=0.92,
                          bottom=0.05)
    ax = fig.add_subplot(gs[0, 0])
    att = np.where(d.att_sigma > 0, d.att_sigma, np.nan)
    _lines(ax, clock.x, att, ["x", "y", "z"], log=bool(np.isfinite(att).any()))
    ax.set_title("(a) attitude 1σ bounds", fontsize=9, loc="left")
    ax.set_ylabel("arcsec")
    ax.set_xlabel("time [min]")
    _mark_breaks(ax, clock)
    _residual_panel(fig, gs[0, 1], d, "parity", clock, "(b) null-space (parity) residual")
    _residual_panel(fig, gs[1, 0], d, "st1", clock, "(c) ST1 residuals")
    _residual_panel(fig, gs[1, 1], d, "st2", clock, "(d) ST2 residuals")
    if "phi2" in d.est:
        _component_axes(fig, gs[2, 0], d, "phi2", clock, "(e) ST2 alignment δa2 estimates")
        _sigma_axes(fig.add_subplot(gs[2, 1]), d, "phi2", clock,
                    "(f) ST2 alignment δa2 standard deviations")
    _title(fig, "Figure 4 analog: attitude, residuals and ST2 alignment", d)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def figure_groups(d: ArchiveData, groups: list[str], path: Path, title: str) -> None:
    """One archive's estimates (dotted: truth) and σ per group, one row per group, paper units;
    written to ``path`` (PNG)."""
    import matplotlib.pyplot as plt

    groups = [g for g in groups if g in d.est]
    clock = _Clock(d.t)
    fig, axes = plt.subplots(max(len(groups), 1), 2, figsize=(12, 3.6 * max(len(groups), 1) + 0.8),
                             squeeze=False, sharex=True)
    tags = "abcdefghij"
    for i, g in enumerate(groups):
        _est_sigma_pair(axes[i, 0], axes[i, 1], d, g, clock, tags[2 * i:2 * i + 2])
    for a in axes[-1]:
        a.set_xlabel("time [min]")
    _title(fig, title, d)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _robust_range(x: np.ndarray, y: np.ndarray) -> tuple[float, float] | None:
    """Range of y after the first 5 % of the run (None if nothing finite)."""
    cut = x >= x[0] + 0.05 * (x[-1] - x[0]) if len(x) >= 20 else np.ones(len(x), bool)
    v = y[cut][np.isfinite(y[cut])]
    return (float(v.min()), float(v.max())) if len(v) else None


def _component_axes(fig: Any, cell: Any, d: ArchiveData, g: str, clock: _Clock, title: str,
                    temps: bool = False) -> list[Any]:
    """One stacked axes per element of group g (estimates, dotted truth), in a gridspec cell."""
    n = d.est[g].shape[1]
    names = element_names(g, n)
    sub = cell.subgridspec(n, 1, hspace=0.1)
    axes: list[Any] = []
    tr_x = clock(d.truth_t) if g in d.truth and len(d.truth_t) else None
    for i in range(n):
        ax = fig.add_subplot(sub[i], sharex=axes[0] if axes else None)
        axes.append(ax)
        c = GYRO_COLORS[i % len(GYRO_COLORS)]
        ax.plot(clock.x, d.est[g][:, i], color=c, lw=1.1, label=f"{names[i]} estimate")
        ys: list[Any] = [d.est[g][:, i]]
        if tr_x is not None:
            ax.plot(tr_x, d.truth[g][:, i], color="k", lw=0.9, ls=":", label="truth")
            ys.append((tr_x, d.truth[g][:, i]))
        _robust_ylim(ax, clock.x, ys)
        ax.grid(True, alpha=0.3)
        ax.set_ylabel(f"{names[i].split('-')[0]} [{PAPER_UNITS[g]}]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.yaxis.get_major_formatter().set_useOffset(False)
        if temps and "st2_baseplate_C" in d.temps:
            tw = ax.twinx()
            tw.plot(clock(d.temp_t), d.temps["st2_baseplate_C"], color="0.45", lw=0.9, ls="-.",
                    label="ST2 baseplate °C")
            tw.tick_params(labelsize=6, colors="0.45")
            if i == 0:
                tw.set_ylabel("°C", fontsize=7, color="0.45")
                tw.legend(fontsize=6, loc="lower right", framealpha=0.7)
        ax.legend(fontsize=6, loc="upper right", framealpha=0.7, ncol=2)
        _mark_breaks(ax, clock)
        if i < n - 1:
            ax.tick_params(labelbottom=False)
    axes[0].set_title(title, fontsize=9, loc="left")
    axes[-1].set_xlabel("time [min]")
    return axes


def _sigma_axes(ax: Any, d: ArchiveData, g: str, clock: _Clock, title: str) -> None:
    sig = np.where(d.sig[g] > 0, d.sig[g], np.nan)
    _lines(ax, clock.x, sig, element_names(g, sig.shape[1]), log=bool(np.isfinite(sig).any()))
    ax.set_ylabel(f"σ {GROUP_LABELS[g]} [{PAPER_UNITS[g]}]")
    ax.set_title(title, fontsize=9, loc="left")
    ax.set_xlabel("time [min]")
    _mark_breaks(ax, clock)


def figure_side_by_side(data: list[ArchiveData], groups: list[str], path: Path, title: str,
                        temps: bool = False) -> None:
    """One column per archive; per group a row of estimates and a row of σ, same y limits
    across the columns (ST2 misalignment: one stacked axes per axis, with the ST2 baseplate
    temperature when ``temps``)."""
    import matplotlib.pyplot as plt

    groups = [g for g in groups if any(g in d.est for d in data)]
    heights: list[float] = []
    for g in groups:
        heights += [3.0 if g != "phi2" else 5.4, 2.6]
    ncol = len(data)
    fig = plt.figure(figsize=(5.4 * ncol + 0.6, sum(heights) + 1.2))
    gs = fig.add_gridspec(len(heights), ncol, height_ratios=heights, hspace=0.42, wspace=0.25,
                          left=0.07, right=0.95, top=1 - 0.9 / (sum(heights) + 1.2), bottom=0.05)
    est_axes: dict[str, list[list[Any]]] = {g: [] for g in groups}
    sig_axes: dict[str, list[Any]] = {g: [] for g in groups}
    for j, d in enumerate(data):
        clock = _Clock(d.t)
        for i, g in enumerate(groups):
            if g not in d.est:
                ax = fig.add_subplot(gs[2 * i, j])
                ax.text(0.5, 0.5, f"no {GROUP_LABELS[g]} in {d.label}", transform=ax.transAxes,
                        ha="center")
                continue
            if g == "phi2":
                axes = _component_axes(fig, gs[2 * i, j], d, g, clock,
                                       f"{d.label}: {GROUP_LABELS[g]} estimates", temps=temps)
            else:
                ax = fig.add_subplot(gs[2 * i, j])
                tr = (clock(d.truth_t), d.truth[g]) if g in d.truth and len(d.truth_t) else None
                _lines(ax, clock.x, d.est[g], element_names(g, d.est[g].shape[1]), truth=tr)
                ax.set_ylabel(f"{GROUP_LABELS[g]} [{PAPER_UNITS[g]}]")
                ax.set_title(f"{d.label}: {GROUP_LABELS[g]} estimates"
                             + (" (dotted: truth)" if tr else ""), fontsize=9, loc="left")
                ax.set_xlabel("time [min]")
                _mark_breaks(ax, clock)
                axes = [ax]
            est_axes[g].append([clock.x, d.est[g], axes])
            sa = fig.add_subplot(gs[2 * i + 1, j])
            _sigma_axes(sa, d, g, clock, f"{d.label}: {GROUP_LABELS[g]} standard deviations")
            sig_axes[g].append(sa)
    for g in groups:  # same y limits across the columns: robust for estimates, full for σ
        cols = est_axes[g]
        if not cols:
            continue
        per_axis = len(cols[0][2])
        for k in range(per_axis):
            rng = [r for x, y, _a in cols
                   if (r := _robust_range(x, y if per_axis == 1 else y[:, k:k + 1])) is not None]
            if rng:
                lo, hi = min(r[0] for r in rng), max(r[1] for r in rng)
                pad = 0.08 * (hi - lo) if hi > lo else max(abs(lo) * 0.01, 1e-9)
                for _x, _y, axes in cols:
                    axes[k].set_ylim(lo - pad, hi + pad)
        logs = [a for a in sig_axes[g] if a.get_yscale() == "log"]
        lims = [a.get_ylim() for a in logs]
        lims = [v for v in lims if v[0] > 0 and v[1] > v[0]]
        if lims:
            for a in logs:
                a.set_ylim(min(v[0] for v in lims), max(v[1] for v in lims))
    fig.suptitle(title + "\n" + "  |  ".join(f"{d.label}: {os.path.basename(d.path)}" for d in data),
                 fontsize=10)
    fig.savefig(path, dpi=90)
    plt.close(fig)
