"""PNG figures of the error report.

Matplotlib is imported inside the functions (importing ``pipeline.evaluation`` stays fast) and figures are
drawn on an explicit Agg canvas, never through ``pyplot``: no screen, no global backend switch.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

MAX_ID_LABELS = 60  # beyond this many landmarks the id labels are unreadable and are left out
AXES = ("x", "y", "z")
COLORS = ("tab:red", "tab:green", "tab:blue")


def _figure(rows: int, cols: int = 1, size: tuple[float, float] = (9.0, 6.0)):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False)
    return fig, axes


def _save(fig, path: Path) -> Path:
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def plot_trajectory_top(
    path: Path,
    est_xyz: np.ndarray,
    truth_xyz: np.ndarray,
    lm_est_ids: np.ndarray,
    lm_est_xyz: np.ndarray,
    lm_truth_ids: np.ndarray | None = None,
    lm_truth_xyz: np.ndarray | None = None,
    title: str = "Top view (x-y): aligned estimate vs ground truth",
    pair_xyz: np.ndarray | None = None,
    pair_error_m: np.ndarray | None = None,
    lm_error_m: np.ndarray | None = None,
) -> Path:
    """Top view of the aligned estimated trajectory and map over the true ones, landmarks labelled by id.

    With ``pair_xyz``/``pair_error_m`` the associated estimate positions are coloured by their APE (one colour
    scale, shared with the landmarks' errors ``lm_error_m``), so where the error grows is visible at a glance.
    """
    fig, axes = _figure(1, 1, (8.5, 8.0))
    ax = axes[0, 0]
    ax.plot(truth_xyz[:, 0], truth_xyz[:, 1], "-", color="0.3", lw=1.5, label="truth trajectory")
    colored = pair_xyz is not None and pair_error_m is not None and len(pair_error_m) > 0
    ax.plot(est_xyz[:, 0], est_xyz[:, 1], "-", color="tab:blue", lw=0.8 if colored else 1.2,
            alpha=0.5 if colored else 1.0, label="estimate (aligned)")
    norm = None
    if colored:
        from matplotlib.colors import Normalize

        finite = [np.nanmax(pair_error_m)]
        if lm_error_m is not None and np.isfinite(lm_error_m).any():
            finite.append(np.nanmax(lm_error_m))
        norm = Normalize(0.0, max(max(finite), 1e-12))
        sc = ax.scatter(pair_xyz[:, 0], pair_xyz[:, 1], c=pair_error_m, cmap="viridis", norm=norm, s=4, zorder=3,
                        label="associated estimate, colour = APE")
        fig.colorbar(sc, ax=ax, shrink=0.8, label="error [m]")
    if len(est_xyz):
        ax.plot(est_xyz[0, 0], est_xyz[0, 1], "o", color="tab:blue", ms=5, label="estimate start")
    if lm_truth_xyz is not None and len(lm_truth_xyz):
        ax.plot(lm_truth_xyz[:, 0], lm_truth_xyz[:, 1], "x", color="0.2", ms=8, mew=1.5, label="true landmarks")
    if len(lm_est_xyz):
        if norm is not None and lm_error_m is not None and np.isfinite(lm_error_m).any():
            ok = np.isfinite(lm_error_m)
            ax.scatter(lm_est_xyz[ok, 0], lm_est_xyz[ok, 1], c=lm_error_m[ok], cmap="viridis", norm=norm, s=70,
                       marker="o", edgecolors="tab:orange", linewidths=1.5, zorder=4,
                       label="estimated landmarks (aligned), colour = error")
            if (~ok).any():
                ax.plot(lm_est_xyz[~ok, 0], lm_est_xyz[~ok, 1], "o", mfc="none", color="tab:orange", ms=8, mew=1.5,
                        label="estimated landmarks without truth")
        else:
            ax.plot(lm_est_xyz[:, 0], lm_est_xyz[:, 1], "o", mfc="none", color="tab:orange", ms=8, mew=1.5,
                    label="estimated landmarks (aligned)")
        if len(lm_est_ids) <= MAX_ID_LABELS:
            for i, p in zip(lm_est_ids, lm_est_xyz):
                ax.annotate(str(int(i)), (p[0], p[1]), xytext=(4, 4), textcoords="offset points", fontsize=7,
                            color="tab:orange")
    if lm_truth_ids is not None and lm_truth_xyz is not None and 0 < len(lm_truth_ids) <= MAX_ID_LABELS:
        for i, p in zip(lm_truth_ids, lm_truth_xyz):
            ax.annotate(str(int(i)), (p[0], p[1]), xytext=(4, -10), textcoords="offset points", fontsize=7,
                        color="0.2")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    return _save(fig, path)


def plot_errors(
    path: Path,
    t_s: np.ndarray,
    position_error_m: np.ndarray,
    attitude_error_deg: np.ndarray,
    threshold_m: float | None = None,
    convergence_t_s: float | None = None,
    title: str = "Absolute pose error after SE(3) alignment",
) -> Path:
    """Aligned position and attitude error over time, with the convergence threshold and time if known."""
    fig, axes = _figure(2, 1, (9.0, 6.5))
    ax_p, ax_r = axes[0, 0], axes[1, 0]
    ax_p.plot(t_s, position_error_m, color="tab:blue", lw=1.0, label="‖position error‖")
    if threshold_m is not None:
        ax_p.axhline(threshold_m, color="tab:red", ls=":", lw=1.0, label=f"convergence threshold {threshold_m:g} m")
    ax_r.plot(t_s, attitude_error_deg, color="tab:purple", lw=1.0, label="attitude error angle")
    if convergence_t_s is not None:
        for ax in (ax_p, ax_r):
            ax.axvline(convergence_t_s, color="tab:green", ls="--", lw=1.0,
                       label=f"converged at {convergence_t_s:.2f} s")
    ax_p.set_title(title)
    ax_p.set_ylabel("position error [m]")
    ax_r.set_ylabel("attitude error [deg]")
    ax_r.set_xlabel("time since estimate start [s]")
    for ax, y in ((ax_p, position_error_m), (ax_r, attitude_error_deg)):
        # errors are >= 0; a near-constant error must not be drawn on the frame edge or read as "1e-12 + ..."
        top = float(np.max(y)) * 1.1 if len(y) and np.max(y) > 0 else 1.0
        if threshold_m is not None and ax is ax_p:
            top = max(top, 1.1 * threshold_m)
        ax.set_ylim(0.0, top)
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize=8)
    return _save(fig, path)


def plot_biases(
    path: Path,
    t_s: np.ndarray,
    gyro: np.ndarray,
    velocity: np.ndarray,
    gyro_truth: np.ndarray | None = None,
    velocity_truth: np.ndarray | None = None,
    window_start_s: float | None = None,
) -> Path:
    """Bias estimate histories per axis; true values dashed in the same colour when known; the stability
    window of the report shaded."""
    fig, axes = _figure(2, 1, (10.0, 6.5))
    panels = (
        (axes[0, 0], gyro, gyro_truth, "gyro bias b_Ω [rad/s]", "Gyro bias estimate"),
        (axes[1, 0], velocity, velocity_truth, "velocity bias b_V [m/s]", "Velocity bias estimate"),
    )
    for ax, est, truth, ylabel, title in panels:
        if len(t_s) == 0:
            ax.text(0.5, 0.5, "no bias estimates", ha="center", va="center", transform=ax.transAxes)
        for k in range(3):
            if len(t_s):
                ax.plot(t_s, est[:, k], color=COLORS[k], lw=1.0, label=f"{AXES[k]} estimate")
            if truth is not None:
                ax.axhline(float(truth[k]), color=COLORS[k], ls="--", lw=1.0, label=f"{AXES[k]} truth")
        if window_start_s is not None and len(t_s):
            ax.axvspan(window_start_s, float(t_s[-1]), color="0.85", alpha=0.5, lw=0, label="stability window")
        ax.set_title(title)
        ax.set_ylabel(ylabel)
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
    axes[1, 0].set_xlabel("time since estimate start [s]")
    return _save(fig, path)


def plot_landmark_errors(
    path: Path,
    ids: np.ndarray,
    error_traj_m: np.ndarray,
    error_map_m: np.ndarray | None = None,
) -> Path:
    """Error per landmark id: after the trajectory alignment and, if given, after the map-only alignment."""
    n = len(ids)
    fig, axes = _figure(1, 1, (max(6.0, min(0.3 * n + 3.0, 18.0)), 4.5))
    ax = axes[0, 0]
    x = np.arange(n)
    width = 0.4 if error_map_m is not None else 0.8
    ax.bar(x - (width / 2 if error_map_m is not None else 0.0), error_traj_m, width, color="tab:blue",
           label="after trajectory alignment")
    if error_map_m is not None:
        ax.bar(x + width / 2, error_map_m, width, color="tab:orange", label="after map-only alignment")
    if n <= MAX_ID_LABELS:
        ax.set_xticks(x, [str(int(i)) for i in ids], rotation=90 if n > 20 else 0, fontsize=7)
    ax.set_xlabel("landmark id")
    ax.set_ylabel("position error [m]")
    ax.set_title("Landmark map error per id")
    ax.grid(True, axis="y", alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    return _save(fig, path)
