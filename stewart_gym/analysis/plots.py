"""Figures of the analyses (matplotlib, Agg backend, PNG files; axes labelled with units)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from stewart_gym.outputs import make_parent

__all__ = ["plot_conditioning", "plot_height_map", "plot_planar", "plot_sensitivity", "plot_sweep",
           "plot_trajectory"]  # fmt: skip


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_height_map(hm: Any, path: str | Path, title: str) -> None:
    """Largest and smallest reachable z over the x–y grid, as filled contours (source 002's chart)."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6))
    for ax, data, label in ((axes[0], hm.z_max, "largest reachable z"), (axes[1], hm.z_min, "smallest reachable z")):
        cs = ax.contourf(hm.x * 1e3, hm.y * 1e3, data * 1e3, levels=20, cmap="viridis", extend="both")
        fig.colorbar(cs, ax=ax, label="z from home [mm]")
        ax.set(xlabel="x [mm]", ylabel="y [mm]", title=label, aspect="equal")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(make_parent(path), dpi=110)
    plt.close(fig)


def plot_trajectory(res: dict[str, Any], path: str | Path, title: str) -> None:
    """Actuators and pulse widths over time against their limits; unreachable samples shaded."""
    plt = _plt()
    rotary = res["kind"] == "rotary"
    fig, axes = plt.subplots(2 if rotary else 1, 1, figsize=(10, 7 if rotary else 4), sharex=True, squeeze=False)
    t, act = res["t"], res["actuators"]
    ax = axes[0, 0]
    scale, unit = (180 / math.pi, "servo angle [°]") if rotary else (1e3, "leg length [mm]")
    for i in range(6):
        ax.plot(t, act[:, i] * scale, lw=1, label=f"{'servo' if rotary else 'leg'} {i}")
    for lim in res["actuator_limits"]:
        ax.axhline(lim * scale, color="r", ls="--", lw=1)
    ax.set(ylabel=unit)
    ax.legend(ncol=6, fontsize=8)
    if rotary:
        ax2 = axes[1, 0]
        w = res["pulses_us"]
        for i in range(6):
            ax2.plot(t, w[:, i], lw=1)
        lo, hi = res["pulse_limits_us"]
        ax2.axhline(float(np.min(lo)), color="r", ls="--", lw=1)
        ax2.axhline(float(np.max(hi)), color="r", ls="--", lw=1)
        ax2.set(ylabel="pulse width [µs]")
    bad = ~res["reachable"]
    for a in axes[:, 0]:
        if bad.any():
            a.fill_between(t, 0, 1, where=bad, transform=a.get_xaxis_transform(), color="r", alpha=0.1,
                           label="unreachable")  # fmt: skip
        a.grid(alpha=0.3)
    axes[-1, 0].set(xlabel="time [s]")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(make_parent(path), dpi=110)
    plt.close(fig)


def plot_sensitivity(x: np.ndarray, y: np.ndarray, position_step: np.ndarray, angle_step: np.ndarray,
                     path: str | Path, title: str) -> None:  # fmt: skip
    """Where the platform is least precise: position and angle change per servo step over x–y."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6))
    for ax, data, label in ((axes[0], position_step * 1e3, "translation per servo step [mm]"),
                            (axes[1], np.degrees(angle_step), "rotation per servo step [°]")):  # fmt: skip
        cs = ax.contourf(x * 1e3, y * 1e3, data, levels=20, cmap="magma", extend="both")
        fig.colorbar(cs, ax=ax, label=label)
        ax.set(xlabel="x [mm]", ylabel="y [mm]", aspect="equal")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(make_parent(path), dpi=110)
    plt.close(fig)


def plot_conditioning(x: np.ndarray, y: np.ndarray, cond: np.ndarray, near: np.ndarray, path: str | Path,
                      title: str) -> None:  # fmt: skip
    """Condition number of the Jacobian over x–y (log colour scale); near-singular poses marked."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.2, 5))
    cs = ax.contourf(x * 1e3, y * 1e3, np.log10(cond), levels=20, cmap="cividis", extend="both")
    fig.colorbar(cs, ax=ax, label="log10 cond(J)")
    gx, gy = np.meshgrid(x, y)
    if near.any():
        ax.plot(gx[near] * 1e3, gy[near] * 1e3, "rx", ms=3, label="near-singular")
        ax.legend()
    ax.set(xlabel="x [mm]", ylabel="y [mm]", title=title, aspect="equal")
    fig.tight_layout()
    fig.savefig(make_parent(path), dpi=110)
    plt.close(fig)


def plot_planar(poses: np.ndarray, params: dict[str, float], path: str | Path) -> None:
    """Each pose of the 3-RPR platform as a triangle with its three struts."""
    from stewart_gym.analysis.planar import planar_vertices

    plt = _plt()
    n = max(1, len(poses))
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n, 3.8), squeeze=False)
    anchors = np.array([[0, 0], [params["x1"], 0], [params["x2"], params["y2"]]])
    for k in range(n):
        ax = axes[0, k]
        ax.plot(*anchors.T, "ks", ms=6)
        if len(poses):
            v = planar_vertices(poses[k], params["L2"], params["L3"], params["gamma"])
            ax.fill(*v.T, color="tab:blue", alpha=0.3)
            ax.plot(*np.vstack([v, v[:1]]).T, color="tab:blue")
            for a, b in zip(anchors, v):
                ax.plot([a[0], b[0]], [a[1], b[1]], color="tab:orange")
            ax.set_title(f"x={poses[k, 0]:.3f}, y={poses[k, 1]:.3f}, θ={poses[k, 2]:.3f}", fontsize=9)
        ax.set(xlabel="x", ylabel="y", aspect="equal")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(make_parent(path), dpi=110)
    plt.close(fig)


def plot_sweep(values: np.ndarray, counts: np.ndarray, strut: str, changes: list, path: str | Path) -> None:
    """Number of poses against one strut length, with the lengths where it changes."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.step(values, counts, where="mid")
    for length, _, _ in changes:
        ax.axvline(length, color="0.6", ls=":", lw=1)
    ax.set(xlabel=f"strut {strut} length", ylabel="number of poses", yticks=range(0, int(max(counts, default=0)) + 2, 2))
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(make_parent(path), dpi=110)
    plt.close(fig)
