"""The picture of a simulated drive: what the system does, at a glance.

Left: the city's streets, the true and the estimated path, the 2-sigma ellipse along the way,
the landmarks, and where a landmark fix happened. Right: the 2-sigma major axis against the
distance driven: it grows with wheel odometry and drops at each landmark fix (the paper's
point). Matplotlib with the Agg backend (no display).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from guidance.tools.plotting import covariance_patch


@dataclass
class DriveTrace:
    """What a drive records for its picture."""

    truth: list[tuple[float, float]] = field(default_factory=list)
    est: list[tuple[float, float]] = field(default_factory=list)
    ellipses: list[tuple[float, float, list[list[float]]]] = field(default_factory=list)
    """(x, y, 2x2 position covariance) every so many metres."""
    axis: list[tuple[float, float]] = field(default_factory=list)
    """(distance driven m, full 2-sigma major axis m) about once a second and at each fix."""
    fixes: list[tuple[float, float, float, int]] = field(default_factory=list)
    """(distance driven m, estimated x, y, landmark id) of each accepted landmark fix."""


def _ellipse_patch(x: float, y: float, P: list[list[float]], label: str | None) -> Any:
    return covariance_patch(x, y, P, ec="tab:red", lw=0.8, alpha=0.7, label=label)


def plot_drive(path: str, world: Any, trace: DriveTrace, outcome: str, opts: Any) -> None:
    """Write the PNG (see the module docstring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.collections import LineCollection

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 6.5), dpi=110,
                                  gridspec_kw={"width_ratios": [1.25, 1.0]})  # fmt: skip
    segs = [((a, b), (c, d)) for a, b, c, d in world.streets()]
    ax.add_collection(LineCollection(segs, colors="0.85", linewidths=0.8, zorder=0))
    if trace.truth:
        t = np.array(trace.truth)
        ax.plot(t[:, 0], t[:, 1], "-", color="tab:blue", lw=1.6, label="true path")
    if trace.est:
        e = np.array(trace.est)
        ax.plot(e[:, 0], e[:, 1], "--", color="tab:orange", lw=1.2, label="estimated path")
    for i, (x, y, P) in enumerate(trace.ellipses):
        ax.add_patch(_ellipse_patch(x, y, P, "2σ ellipse" if i == 0 else None))
    lm = world.lm_xy
    if len(lm):
        ax.scatter(lm[:, 0], lm[:, 1], marker="^", s=30, c="tab:green", label="landmarks")
    if trace.fixes:
        f = np.array([(x, y) for _, x, y, _ in trace.fixes])
        ax.scatter(f[:, 0], f[:, 1], marker="o", s=70, facecolors="none", edgecolors="tab:purple",
                   lw=1.5, zorder=5, label="landmark fix")  # fmt: skip
    sx, sy, _ = world.start_pose
    gx, gy = world.goal_xy
    ax.plot([sx], [sy], "o", ms=9, color="black", label="start")
    ax.plot([gx], [gy], "*", ms=15, color="gold", mec="black", label="goal")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    comp = "no compass" if opts.compass_deg is None else f"compass ±{opts.compass_deg:g}° (2σ)"
    ax.set_title(
        f"guidance sim: seed {opts.seed}, {opts.method}, {comp}\n"
        f"{opts.density_per_km2:g} landmarks/km², detection {opts.detection_rate:.0%}: {outcome}"
    )
    pts = np.array([*trace.truth, *trace.est, (sx, sy), (gx, gy)])
    margin = 250.0
    ax.set_xlim(pts[:, 0].min() - margin, pts[:, 0].max() + margin)
    ax.set_ylim(pts[:, 1].min() - margin, pts[:, 1].max() + margin)
    ax.set_aspect("equal", adjustable="box")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, lw=0.3, alpha=0.5)

    if trace.axis:
        d = np.array(sorted(trace.axis))
        ax2.plot(d[:, 0] / 1000.0, d[:, 1], "-", color="tab:red", lw=1.4,
                 label="2σ major axis of the position")  # fmt: skip
    for i, (dist, _x, _y, _lid) in enumerate(trace.fixes):
        ax2.axvline(dist / 1000.0, color="tab:purple", lw=0.8, ls=":",
                    label="landmark fix" if i == 0 else None)  # fmt: skip
    ax2.set_xlabel("distance driven (km)")
    ax2.set_ylabel("2σ major axis (m)")
    ax2.set_ylim(bottom=0.0)
    ax2.set_title("position uncertainty: grows with odometry,\nshrinks at each landmark fix")
    ax2.grid(True, lw=0.3, alpha=0.5)
    if trace.axis or trace.fixes:
        ax2.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
