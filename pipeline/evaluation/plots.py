"""PNG figures of the error report.

Matplotlib is imported inside the functions (importing ``pipeline.evaluation`` stays fast) and figures are
drawn on an explicit Agg canvas, never through ``pyplot``: no screen, no global backend switch.

A figure is about a thousand pixels wide, so long logs are thinned before drawing (a one-hour run has
millions of samples, which took seconds to draw and looked the same): each time series keeps the first,
lowest and highest sample of each pixel-sized bucket (:func:`envelope`, spikes stay visible), paths and
scatters an evenly spaced subset (:func:`thin`, the largest error kept). Reports are computed from the
full data; only the drawing is thinned. Margins are fixed in inches (:func:`_figure`) rather than found by
matplotlib's constrained layout, which measured every text twice and took a third of the drawing time.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamobs.schemas import LENGTH_STEP_EXP

MAX_ID_LABELS = 60  # beyond this many landmarks the id labels are unreadable and are left out
SERIES_BUCKETS = 1000  # time-series buckets per line, about one per pixel (each keeps up to three samples)
PATH_POINTS = 10_000  # vertices of a drawn trajectory (overlapping laps of a long log stay smooth)
SCATTER_POINTS = 3000  # markers of a scatter
MAX_LOG_GROUPS = 12  # logs drawn side by side in a distribution figure (more are unreadable; the tables have all)
AXES = ("x", "y", "z")
COLORS = ("tab:red", "tab:green", "tab:blue")


def envelope(n: int, columns, buckets: int = SERIES_BUCKETS) -> np.ndarray:
    """Indices (ascending) of the first, lowest and highest sample of each of ``buckets`` runs of every
    column (an ``(n, k)`` array or a sequence of ``n``-long columns; each line keeps its own extremes); all
    indices when there are no more samples than that would keep (so thinned data passes unchanged)."""
    cols = list(np.asarray(columns).T) if isinstance(columns, np.ndarray) and columns.ndim == 2 else list(columns)
    if n <= buckets * (1 + 2 * len(cols)) + 1:
        return np.arange(n)
    edges = np.linspace(0, n, buckets + 1).astype(np.int64)
    keep = [edges[:-1]]
    for col in cols:  # fmin/fmax: NaN samples never hide a bucket's extremes
        col = np.asarray(col, dtype=np.float64)
        keep.append(edges[:-1] + _argreduce(np.fmin, col, edges))
        keep.append(edges[:-1] + _argreduce(np.fmax, col, edges))
    keep.append(np.array([n - 1]))
    return np.unique(np.concatenate(keep))


def _argreduce(op: np.ufunc, col: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Position within each bucket ``[edges[k], edges[k+1])`` of its minimum/maximum (first on ties, 0 when
    the bucket is all NaN)."""
    best = op.reduceat(col, edges[:-1])
    owner = np.repeat(np.arange(edges.shape[0] - 1), np.diff(edges))
    hit = np.flatnonzero(col == best[owner])
    first = np.full(edges.shape[0] - 1, -1, np.int64)
    first[owner[hit][::-1]] = hit[::-1]  # the last write per bucket is its first hit
    return np.maximum(first, edges[:-1]) - edges[:-1]


def thin(n: int, most: int, keep: int | None = None) -> np.ndarray:
    """About ``most`` evenly spaced indices of ``n`` (first and last included, and ``keep`` if given)."""
    if n <= most:
        return np.arange(n)
    idx = np.unique(np.linspace(0, n - 1, most).astype(np.int64))
    return idx if keep is None else np.union1d(idx, [keep])


def _figure(
    rows: int,
    cols: int = 1,
    size: tuple[float, float] = (9.0, 6.0),
    *,
    left: float = 0.85,
    right: float = 0.25,
    bottom: float = 0.6,
    top: float = 0.45,
    gap: float = 0.6,
):
    """A figure of ``size`` inches with a grid of axes; the margins around the grid and the ``gap`` between rows
    in inches (room for tick labels, axis labels and titles at the default font)."""
    import_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    width, height = size
    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False)
    row_height = (height - top - bottom - gap * (rows - 1)) / rows
    fig.subplots_adjust(
        left=left / width,
        right=1.0 - right / width,
        bottom=bottom / height,
        top=1.0 - top / height,
        hspace=gap / row_height,
    )
    return fig, axes


def import_matplotlib() -> None:
    """Import matplotlib's figure and Agg canvas (the modules every figure here uses come with them) without the
    text it generates for help() as each of its ~100 ``Artist`` classes is defined: the properties table of every
    class's docstring (``matplotlib.artist.kwdoc``) and the keyword signature of its ``set``. Nothing drawn reads
    them (``set`` itself and every property work as before; the PNG bytes are the same); they were ~0.1 s of a
    ~0.4 s import, which is on a short run's path wherever its figures are drawn in its own process (one core,
    a busy machine) and in the figure helper's start. Both are put back once the modules are imported, so
    classes defined later get them; a process that has imported the figure already is left as it is, and so is
    a matplotlib without these two names (imported as it comes)."""
    import sys

    if "matplotlib.figure" in sys.modules:
        return
    from matplotlib import artist

    kwdoc = getattr(artist, "kwdoc", None)
    update = artist.Artist.__dict__.get("_update_set_signature_and_docstring")
    if kwdoc is None or update is None:
        return
    artist.kwdoc = lambda _artist: ""
    artist.Artist._update_set_signature_and_docstring = classmethod(_mark_set_generated)
    try:
        import matplotlib.backends.backend_agg  # noqa: F401
        import matplotlib.figure  # noqa: F401
    finally:
        artist.kwdoc = kwdoc
        artist.Artist._update_set_signature_and_docstring = update


def _mark_set_generated(cls) -> None:
    """What ``Artist.__init_subclass__`` looks for on a class's ``set`` (so subclasses of it get their own),
    without building its signature and docstring."""
    cls.set._autogenerated_signature = True


#: Pixels kept between the figure's left edge and the leftmost y tick label or y label, and between its top edge and
#: the highest title (:func:`_labels_inside`).
EDGE_PX = 4.0


def _labels_inside(fig, dpi: float) -> None:
    """Move the grid's left edge right by what the y tick labels and y labels of its flat axes reach past the
    figure's left edge (``_figure``'s margins are fixed inches: a bias of a few mrad/s ticks as ``0.0025`` and
    ``−0.0005``, and the label beside them was cut off), and its top edge down by what the titles of the grid's
    axes reach past the figure's top (``evaluate --metric rpe -p``'s three-line title lost its first line, the one
    that says what the error is); a figure whose labels and titles fit is left as it is."""
    fig.set_dpi(dpi)  # measured at the resolution the file is written at
    renderer = fig.canvas.get_renderer()
    reach = [ax.yaxis.get_tightbbox(renderer) for ax in fig.axes if ax.name == "rectilinear"]
    left = min((box.x0 for box in reach if box is not None), default=EDGE_PX)
    if left < EDGE_PX:
        fig.subplots_adjust(left=fig.subplotpars.left + (EDGE_PX - left) / (fig.get_figwidth() * dpi))
    height = fig.get_figheight() * dpi
    grid = [ax for ax in fig.axes if ax.get_subplotspec() is not None]
    titles = [ax.title.get_window_extent(renderer) for ax in grid if ax.get_title()]
    over = max((box.y1 for box in titles), default=0.0) - (height - EDGE_PX)
    if over > 0.0:  # the rows give up the height, the gaps between them are kept (a lower row's title sits in one)
        rows = grid[0].get_subplotspec().get_gridspec().nrows
        par = fig.subplotpars
        row = (par.top - par.bottom) / (rows + (rows - 1) * par.hspace)
        top = par.top - over / height
        fig.subplots_adjust(top=top, hspace=par.hspace * row / (row - over / height / rows))


def _save(fig, path, dpi: float = 110):
    """Save as PNG into ``path``, a file name or a binary file object (a figure helper process's buffer), the
    y labels inside the figure (:func:`_labels_inside`)."""
    if isinstance(path, (str, Path)):
        path = Path(path)
    _labels_inside(fig, dpi)
    fig.savefig(path, dpi=dpi, format="png")
    return path


def warm_up() -> None:
    """Import matplotlib and draw one small text figure (loads the font and the Agg renderer), so a figure
    helper process is ready before the run needs its figures."""
    import io

    fig, axes = _figure(1, 1, (2.0, 2.0))
    axes[0, 0].set_title("0")
    fig.savefig(io.BytesIO(), dpi=20, format="png")


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
    fig, axes = _figure(1, 1, (8.5, 8.0), bottom=1.3, right=0.2)  # the legend (up to three rows) below the axes
    ax = axes[0, 0]
    truth_xy = truth_xyz[thin(len(truth_xyz), PATH_POINTS)]
    ax.plot(truth_xy[:, 0], truth_xy[:, 1], "-", color="0.3", lw=1.5, label="truth trajectory")
    colored = pair_xyz is not None and pair_error_m is not None and len(pair_error_m) > 0
    est_xy = est_xyz[thin(len(est_xyz), PATH_POINTS)]
    ax.plot(
        est_xy[:, 0],
        est_xy[:, 1],
        "-",
        color="tab:blue",
        lw=0.8 if colored else 1.2,
        alpha=0.5 if colored else 1.0,
        label="estimate (aligned)",
    )
    norm = None
    if colored:
        from matplotlib.colors import Normalize

        finite = [np.nanmax(pair_error_m)]
        if lm_error_m is not None and np.isfinite(lm_error_m).any():
            finite.append(np.nanmax(lm_error_m))
        norm = Normalize(0.0, max(max(finite), 1e-12))
        sel = thin(len(pair_error_m), SCATTER_POINTS, keep=int(np.nanargmax(pair_error_m)))
        sc = ax.scatter(
            pair_xyz[sel, 0],
            pair_xyz[sel, 1],
            c=pair_error_m[sel],
            cmap="viridis",
            norm=norm,
            s=4,
            zorder=3,
            label="associated estimate, colour = APE",
        )
        fig.colorbar(sc, ax=ax, shrink=0.8, label="error [m]")
    if len(est_xyz):
        ax.plot(est_xyz[0, 0], est_xyz[0, 1], "o", color="tab:blue", ms=5, label="estimate start")
    if lm_truth_xyz is not None and len(lm_truth_xyz):
        ax.plot(lm_truth_xyz[:, 0], lm_truth_xyz[:, 1], "x", color="0.2", ms=8, mew=1.5, label="true landmarks")
    if len(lm_est_xyz):
        if norm is not None and lm_error_m is not None and np.isfinite(lm_error_m).any():
            ok = np.isfinite(lm_error_m)
            ax.scatter(
                lm_est_xyz[ok, 0],
                lm_est_xyz[ok, 1],
                c=lm_error_m[ok],
                cmap="viridis",
                norm=norm,
                s=70,
                marker="o",
                edgecolors="tab:orange",
                linewidths=1.5,
                zorder=4,
                label="estimated landmarks (aligned), colour = error",
            )
            if (~ok).any():
                ax.plot(
                    lm_est_xyz[~ok, 0],
                    lm_est_xyz[~ok, 1],
                    "o",
                    mfc="none",
                    color="tab:orange",
                    ms=8,
                    mew=1.5,
                    label="estimated landmarks without truth",
                )
        else:
            ax.plot(
                lm_est_xyz[:, 0],
                lm_est_xyz[:, 1],
                "o",
                mfc="none",
                color="tab:orange",
                ms=8,
                mew=1.5,
                label="estimated landmarks (aligned)",
            )
    ax.set_aspect("equal", adjustable="datalim")  # before the labels: they are placed on the final limits
    groups = []
    if len(lm_est_xyz) and len(lm_est_ids) <= MAX_ID_LABELS:
        groups.append((lm_est_ids, lm_est_xyz, "tab:orange"))
        ax.plot([], [], " ", label="ids: estimate's orange")  # which of two ids is which
    if lm_truth_ids is not None and lm_truth_xyz is not None and 0 < len(lm_truth_ids) <= MAX_ID_LABELS:
        groups.append((lm_truth_ids, lm_truth_xyz, "0.2"))
        ax.plot([], [], " ", label="ids: truth's grey")
    if groups:
        _placed_labels(
            ax,
            [str(int(i)) for ids, _, _ in groups for i in ids],
            np.concatenate([np.asarray(xyz, dtype=np.float64) for _, xyz, _ in groups]),
            TOP_MARKER_RADIUS_PT,
            [c for ids, _, c in groups for _ in ids],
        )
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    fig.legend(loc="lower center", ncols=3, fontsize=8)  # below the axes: never over the data
    return _save(fig, path)


def plot_errors(
    path: Path,
    t_s: np.ndarray,
    position_error_m: np.ndarray,
    attitude_error_deg: np.ndarray,
    band_m: float | None = None,
    convergence_t_s: float | None = None,
    title: str = "Absolute pose error after SE(3) alignment",
    level: tuple[np.ndarray, np.ndarray] | None = None,
    verdict: str | None = None,
    extent_m: float | None = None,
    band_label: str = "convergence band",
    extent_name: str = "path's extent",
    attitude_turned: tuple[np.ndarray, float, float] | None = None,
) -> Path:
    """Aligned position and attitude error over time; on the position panel only (the convergence figure is about
    the position error) the error level ``(t_s, m)`` it is measured on, the band and the convergence time, and in
    its legend ``verdict``: why there is no convergence time, or what qualifies the one drawn (a coarse level), so
    the band is never read as a convergence the report does not claim; ``extent_m`` (a lost estimate's) the path's
    extent its level is judged against (``extent_name``: the scene's for a truth that does not translate), drawn so
    the level is seen above it; ``band_label`` names the band line (the whole-run fit's band when the frame of the
    run's end decided the convergence). ``attitude_turned``: the attitude error per pair less the constant turn of
    the truth's body frame against the estimate's, that turn (deg) and that error's rmse (report.md's note on the
    rotation APE), drawn beside the error as aligned."""
    fig, axes = _figure(2, 1, (9.0, 6.5))
    ax_p, ax_r = axes[0, 0], axes[1, 0]
    sel = envelope(len(t_s), [position_error_m])
    ax_p.plot(t_s[sel], position_error_m[sel], color="tab:blue", lw=1.0, label="‖position error‖")
    if level is not None:
        ax_p.plot(level[0], level[1], color="tab:orange", lw=1.5, label="error level (running median)")
    if band_m is not None:
        ax_p.axhline(band_m, color="tab:red", ls=":", lw=1.0, label=f"{band_label} {band_m:.3g} m")
    if extent_m is not None:
        ax_p.axhline(extent_m, color="0.3", ls="--", lw=1.0, label=f"{extent_name} {extent_m:.3g} m RMS")
    sel = envelope(len(t_s), [attitude_error_deg])
    ax_r.plot(t_s[sel], attitude_error_deg[sel], color="tab:purple", lw=1.0, label="attitude error angle")
    if attitude_turned is not None:
        left, angle, rmse = attitude_turned
        sel = envelope(len(t_s), [left])
        ax_r.plot(
            t_s[sel],
            left[sel],
            color="tab:green",
            lw=1.0,
            label=f"less the truth frame's constant {angle:.1f} deg turn (report.md's note): {rmse:.3g} deg rmse",
        )
    if convergence_t_s is not None:
        label = f"converged at {convergence_t_s:.2f} s" + (f" ({verdict})" if verdict else "")
        ax_p.axvline(convergence_t_s, color="tab:green", ls="--", lw=1.0, label=label)
    elif verdict:
        ax_p.plot([], [], " ", label=verdict)  # a legend line without a mark: the report's verdict
    ax_p.set_title(title)
    ax_p.set_ylabel("position error [m]")
    ax_r.set_ylabel("attitude error [deg]")
    ax_r.set_xlabel("time since estimate start [s]")
    for ax, y in ((ax_p, position_error_m), (ax_r, attitude_error_deg)):
        # errors are >= 0; a near-constant error must not be drawn on the frame edge or read as "1e-12 + ..."
        top = float(np.max(y)) * 1.1 if len(y) and np.max(y) > 0 else 1.0
        if band_m is not None and ax is ax_p:
            top = max(top, 1.1 * band_m)
        ax.set_ylim(0.0, top)
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)  # where it hides least of the curves (the verdict makes it four lines)
    return _save(fig, path)


#: what biases.png's grey band is, in its top title (report.md's bias section: BiasSection's Method words);
#: ``{share}``: "the last 20 % of" where the fraction is known, else "the last stretch of"
STABILITY_WINDOW_SAID = (
    "shaded: the stability window, {share} the bias time span: report.md's mean, std, range and drift of each axis"
)


def plot_biases(
    path: Path,
    t_s: np.ndarray,
    gyro: np.ndarray,
    velocity: np.ndarray,
    gyro_truth: np.ndarray | None = None,
    velocity_truth: np.ndarray | None = None,
    window_start_s: float | None = None,
    window_fraction: float | None = None,
) -> Path:
    """Bias estimate histories per axis; true values dashed in the same colour when known; the stability
    window of the report (the last ``window_fraction`` of the bias time span, from ``window_start_s``) shaded, and
    said in the figure: the top title gives the share and what the report measures over it (round 26:
    a grey band named "stability window" and defined only in report.md's Method table)."""
    fig, axes = _figure(2, 1, (10.0, 6.5), right=1.45)  # the legends right of the axes
    shaded = window_start_s is not None and len(t_s) > 0
    share = f"the last {100.0 * window_fraction:.3g} % of" if window_fraction is not None else "the last stretch of"
    gyro_title = "Gyro bias estimate" + (f"\n{STABILITY_WINDOW_SAID.format(share=share)}" if shaded else "")
    panels = (
        (axes[0, 0], gyro, gyro_truth, "gyro bias b_Ω [rad/s]", gyro_title),
        (axes[1, 0], velocity, velocity_truth, "velocity bias b_V [m/s]", "Velocity bias estimate"),
    )
    for ax, est, truth, ylabel, title in panels:
        if len(t_s) == 0:
            ax.text(0.5, 0.5, "no bias estimates", ha="center", va="center", transform=ax.transAxes)
        for k in range(3):
            if len(t_s):
                sel = envelope(len(t_s), [est[:, k]])  # each line its own extremes
                ax.plot(t_s[sel], est[sel, k], color=COLORS[k], lw=1.0, label=f"{AXES[k]} estimate")
            if truth is not None:
                ax.axhline(float(truth[k]), color=COLORS[k], ls="--", lw=1.0, label=f"{AXES[k]} truth")
        if shaded:
            ax.axvspan(window_start_s, float(t_s[-1]), color="0.85", alpha=0.5, lw=0, label="stability window")
        ax.set_title(title, fontsize=10 if "\n" in title else None)
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
    fig, axes = _figure(
        1, 1, (max(6.0, min(0.3 * n + 3.0, 18.0)), 4.5), bottom=0.85 if 20 < n <= MAX_ID_LABELS else 0.6
    )
    ax = axes[0, 0]
    x = np.arange(n)
    width = 0.4 if error_map_m is not None else 0.8
    ax.bar(
        x - (width / 2 if error_map_m is not None else 0.0),
        error_traj_m,
        width,
        color="tab:blue",
        label="after trajectory alignment",
    )
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


def plot_sigma_bounds(
    path: Path, t_s: np.ndarray, error: np.ndarray, sigma: np.ndarray, title: str = "", unmeasured: tuple = ()
) -> Path:
    """Per axis the error and the ±3σ band of the estimator's covariance: attitude (δθ, degrees) on the left,
    position (δp, m) on the right. An axis in ``unmeasured`` (0-2 attitude, 3-5 position: a planar run's axes
    whose error is zero on every pair) is drawn empty with a word: its zero error inside a band of the
    covariance the filter keeps open there would read as a consistent estimate."""
    fig, axes = _figure(3, 2, (11.0, 7.5), top=0.6)
    parts = ((slice(0, 3), np.degrees(1.0), "deg", "δθ"), (slice(3, 6), 1.0, "m", "δp"))
    for col, (sl, scale, unit, name) in enumerate(parts):
        e, sd = error[:, sl] * scale, sigma[:, sl] * scale
        for k in range(3):
            ax = axes[k, col]
            if 3 * col + k in unmeasured:
                ax.text(0.5, 0.5, "not measured: the run holds this axis (planar)", ha="center", va="center",
                        transform=ax.transAxes, fontsize=8, color="0.4")  # fmt: skip
                ax.set_ylabel(f"{name} {AXES[k]} [{unit}]")
                ax.set_xticks([])  # no 0-1 scale of degrees, metres or seconds where nothing is drawn
                ax.set_yticks([])
                continue
            ax.fill_between(t_s, -3.0 * sd[:, k], 3.0 * sd[:, k], color="0.85", lw=0, label="±3σ")
            ax.plot(t_s, e[:, k], color=COLORS[k], lw=0.8, label=f"{name} {AXES[k]}")
            ax.set_ylabel(f"{name} {AXES[k]} [{unit}]")
            ax.grid(True, alpha=0.3)
            ax.legend(loc="upper right", fontsize=7)
        axes[2, col].set_xlabel("time since estimate start [s]")
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plain_log_axis(axis) -> None:
    """Label a log-scale ``axis`` (``ax.yaxis``) in plain numbers at 1, 2 and 5 per decade: over less than a decade
    matplotlib labels its minor ticks as 2×10⁰, 3×10⁰, 4×10⁰, ..."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    axis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def plot_nees(path: Path, position, attitude, mean: dict, window_s: float, dof: dict | None = None) -> Path:
    """Position and attitude NEES averaged over windows, with each window's two-sided 95 % χ² bounds; ``dof`` per
    part the degrees of freedom each NEES is over (3 unless a planar run's axes without error are left out)."""
    from slamobs.pipeline.evaluation.metrics import nees_bounds

    fig, axes = _figure(2, 1, (9.0, 6.5))
    for ax, (t, nees, counts), part in ((axes[0, 0], position, "position"), (axes[1, 0], attitude, "attitude")):
        k = (dof or {}).get(part, 3)
        if len(t):
            bounds = {int(c): nees_bounds(k, int(c)) for c in np.unique(counts)}
            ax.fill_between(
                t,
                [bounds[int(c)][0] for c in counts],
                [bounds[int(c)][1] for c in counts],
                color="0.85",
                lw=0,
                step="mid",
                label="95 % bounds of a window's mean",
            )
            ax.plot(t, nees, color="tab:blue", lw=1.0, label=f"NEES, {window_s:g} s windows")
            ax.axhline(float(k), color="k", ls=":", lw=1.0, label=f"expected ({k})")
            ax.set_yscale("log")
            plain_log_axis(ax.yaxis)
        if mean.get(part) is not None:
            ax.set_title(f"{part.capitalize()} NEES ({k} DoF): mean {mean[part]:.3g} over the run")
        ax.set_ylabel("NEES")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize=8)  # not over the curve (it covered a rise at the right end)
    axes[1, 0].set_xlabel("time since estimate start [s]")
    return _save(fig, path)


def plot_segment_errors(
    path: Path,
    lengths_m: np.ndarray,
    translation_pct: list[np.ndarray],
    rotation_deg_per_m: list[np.ndarray],
    caveat: str = "",
) -> Path:
    """Box plots of the relative error per sub-trajectory length (rpg_trajectory_evaluation's figure): translation
    in % of the length and rotation in deg/m, one box per length (whiskers 1.5 IQR, outliers not drawn);
    ``caveat``: more title lines (:func:`.figure_jobs.turn_title_line`)."""
    fig, axes = _figure(2, 1, (7.5, 6.5))
    labels = [f"{x:g}" for x in lengths_m]
    panels = (
        (axes[0, 0], translation_pct, "translation error [%]", "tab:blue"),
        (axes[1, 0], rotation_deg_per_m, "rotation error [deg/m]", "tab:purple"),
    )
    for ax, data, ylabel, color in panels:
        ax.boxplot(
            [np.asarray(d, dtype=np.float64) for d in data],
            tick_labels=labels,
            showfliers=False,
            patch_artist=True,
            boxprops=dict(facecolor=color, alpha=0.35),
            medianprops=dict(color="black"),
        )
        ax.set_ylabel(ylabel)
        ax.set_ylim(bottom=0.0)
        ax.grid(True, axis="y", alpha=0.3)
    axes[0, 0].set_title("Relative error per sub-trajectory length (segments of the truth path)" + caveat)
    axes[1, 0].set_xlabel("sub-trajectory length [m]")
    return _save(fig, path)


VIOLIN_POINTS = 100  # heights of a violin's outline (matplotlib's violinplot default)
WHISKER_IQR = 1.5  # a box's whiskers reach the farthest value within this many IQRs of the box (Tukey, matplotlib)


def box_stats(values: np.ndarray) -> tuple[float, float, float, float, float, np.ndarray]:
    """Quartiles, whisker ends and outliers of one box as matplotlib's ``boxplot`` has them: q1, median, q3,
    the lowest and highest value within ``WHISKER_IQR`` × IQR of the box, and the values beyond."""
    q1, med, q3 = np.percentile(values, [25.0, 50.0, 75.0])
    reach = WHISKER_IQR * (q3 - q1)
    inside = values[(values >= q1 - reach) & (values <= q3 + reach)]
    low, high = (inside.min(), inside.max()) if len(inside) else (q1, q3)
    return q1, med, q3, min(low, q1), max(high, q3), values[(values < low) | (values > high)]


def violin_outline(values: np.ndarray, position: float, width: float) -> np.ndarray:
    """The closed outline of one violin: a Gaussian kernel density with Scott's bandwidth (as matplotlib's
    ``violinplot``) from the lowest to the highest value, ``width`` wide at its widest."""
    heights = np.linspace(values.min(), values.max(), VIOLIN_POINTS)
    bandwidth = values.std(ddof=1) * len(values) ** -0.2
    density = np.zeros(VIOLIN_POINTS)
    for chunk in np.array_split(values, max(1, len(values) // 4096)):  # (points × values) kept small
        density += np.exp(-0.5 * ((heights[:, None] - chunk[None, :]) / bandwidth) ** 2).sum(axis=1)
    half = 0.5 * width * density / density.max()
    return np.concatenate([np.c_[position - half, heights], np.c_[position + half, heights][::-1]])


def _distribution(ax, groups: list[np.ndarray], positions: np.ndarray, kind: str, color, width: float) -> None:
    """One box or violin per group at ``positions``; a group of one distinct value is a marker (a violin needs
    a spread), an empty group nothing. Each kind is a few collections, however many groups (matplotlib's
    ``boxplot`` and ``violinplot`` make artists per group, which took most of a figure's time)."""
    from matplotlib.collections import LineCollection, PolyCollection

    spread = [k for k, g in enumerate(groups) if len(g) and np.ptp(g) > 0]
    flat = [k for k, g in enumerate(groups) if len(g) and k not in spread]
    shapes, lines, outliers = [], [], []
    for k in spread:
        x, g, half = positions[k], groups[k], width / 2
        if kind == "violin":
            shapes.append(violin_outline(g, x, width))
            lines += [[(x - half / 2, v), (x + half / 2, v)] for v in (g.min(), np.median(g), g.max())]
            lines.append([(x, g.min()), (x, g.max())])
            continue
        q1, med, q3, low, high, out = box_stats(g)
        shapes.append([(x - half, q1), (x + half, q1), (x + half, q3), (x - half, q3)])
        lines += [[(x, low), (x, q1)], [(x, q3), (x, high)], [(x - half, med), (x + half, med)]]
        lines += [[(x - half / 2, v), (x + half / 2, v)] for v in (low, high)]
        outliers += [np.c_[np.full(len(out), x), out]]
    if shapes:
        edge = color if kind == "violin" else "0.2"
        ax.add_collection(PolyCollection(shapes, facecolors=color, edgecolors=edge, alpha=0.5, linewidths=0.8))
        ax.add_collection(LineCollection(lines, colors=color if kind == "violin" else "0.1", linewidths=1.0))
        ax.autoscale_view()
    if outliers and (points := np.concatenate(outliers)).size:
        ax.plot(points[:, 0], points[:, 1], "o", mfc="none", mec="0.3", ms=3, lw=0)
    if flat:
        ax.plot(positions[flat], [groups[k][0] for k in flat], "o", color=color, ms=4)


def plot_distributions(
    path: Path,
    values: dict[str, dict[str, np.ndarray]],
    kind: str,
    ylabel: str,
    title: str,
) -> Path:
    """Box (``kind="box"``) or violin plots of a metric over runs: on top one per estimator over every log,
    below one per log (the first ``MAX_LOG_GROUPS``) with an estimator's colour each. ``values[estimator][log]``
    holds the runs' values."""
    estimators = list(values)
    every_log = list(dict.fromkeys(log for per in values.values() for log in per))
    logs = every_log[:MAX_LOG_GROUPS]
    width = min(16.0, max(6.0, 1.2 + 0.5 * len(logs) * max(1, len(estimators))))  # half an inch a group, capped
    fig, axes = _figure(2, 1, (width, 7.0), bottom=1.0, gap=0.8)
    ax_e, ax_l = axes[0, 0], axes[1, 0]
    colors = [f"C{k % 10}" for k in range(len(estimators))]
    width = 0.8 / max(1, len(estimators))
    for k, est in enumerate(estimators):
        pooled = np.concatenate([v for v in values[est].values()] or [np.empty(0)])
        _distribution(ax_e, [pooled], np.array([float(k)]), kind, colors[k], 0.6)
        groups = [values[est].get(log, np.empty(0)) for log in logs]
        at = np.arange(len(logs)) + (k - (len(estimators) - 1) / 2) * width
        _distribution(ax_l, groups, at, kind, colors[k], width * 0.9)
        ax_l.plot([], [], "s", color=colors[k], alpha=0.6, label=est)
    ax_e.set_xticks(np.arange(len(estimators)), estimators)
    ax_e.set_xlim(-0.6, len(estimators) - 0.4)
    ax_e.set_title(f"{title}: per estimator, all logs")
    ax_l.set_xticks(np.arange(len(logs)), logs, rotation=20, ha="right", fontsize=8)
    ax_l.set_xlim(-0.6, len(logs) - 0.4)
    shown = f"first {len(logs)} of {len(every_log)} logs" if len(logs) < len(every_log) else "per log"
    ax_l.set_title(shown)
    ax_l.legend(loc="best", fontsize=8)
    for ax in (ax_e, ax_l):
        ax.set_ylabel(ylabel)
        ax.grid(True, axis="y", alpha=0.3)
    return _save(fig, path)


#: a 3D view's height axis is drawn at least this share of its widest horizontal extent (a level path's
#: centimetres would otherwise be a flat line); more than its own extent is a stretch the title states
MIN_Z_SHARE = 0.25
#: a 3D view's longest horizontal side gets at most this many tick intervals, a shorter one in proportion (at
#: least 2): TagSLAM test 11's 5 m of y beside 18 m of x and 16 m of z drew six labels over one another
MAX_3D_BINS = 6


def one_scale_3d(ax, xyz: np.ndarray) -> str:
    """Draw the 3D axes ``ax`` of the points ``xyz`` to one scale in x, y and z (matplotlib stretches each axis
    to the box, so 1 m of height looked as long as 40 m of path), z at least ``MIN_Z_SHARE`` of the horizontal
    extent, and a short horizontal side with fewer ticks (``MAX_3D_BINS``); returns the title's note of that
    stretch (" (one scale)" when there is none, " (z constant)" for a path whose height varies by less than the
    step lengths are written at, ``schemas.LENGTH_STEP_EXP``: there is no height to stretch)."""
    span = np.ptp(xyz, axis=0) if len(xyz) else np.zeros(3)
    wide = max(float(span[0]), float(span[1]), 1e-9)
    height = max(float(span[2]), MIN_Z_SHARE * wide)
    sides = (max(float(span[0]), 1e-3 * wide), max(float(span[1]), 1e-3 * wide), height)
    ax.set_box_aspect(sides, zoom=0.85)
    from matplotlib.ticker import MaxNLocator

    ax.zaxis.set_major_locator(MaxNLocator(3))
    longest = max(sides)
    for axis, side in ((ax.xaxis, sides[0]), (ax.yaxis, sides[1])):  # a short side's ticks in proportion
        axis.set_major_locator(MaxNLocator(max(2, round(MAX_3D_BINS * side / longest))))
    if float(span[2]) < 2.0**LENGTH_STEP_EXP:  # level below the step lengths are written at: nothing to stretch
        return " (z constant)"  # a planar TF or odometry's path said "z stretched 7.11e+08x"
    stretch = height / float(span[2])
    return f" (z stretched {stretch:.3g}x)" if stretch > 1.01 else " (one scale)"


def plot_trajectory(path: Path, xyz: np.ndarray, title: str = "Estimated trajectory (output frame)") -> Path:
    """The estimate as written: a top view (x-y) coloured by the fraction of the run (start dark, end light)
    and a 3D view to one scale (:func:`one_scale_3d`)."""
    fig, axes = _figure(1, 2, (12.0, 5.8), gap=0.0, right=0.4)
    top = axes[0, 0]
    box = axes[0, 1].get_position()
    axes[0, 1].remove()
    ax3 = fig.add_axes(box, projection="3d")
    colour = np.linspace(0.0, 1.0, len(xyz))
    if len(xyz):
        top.plot(xyz[:, 0], xyz[:, 1], "-", color="0.6", lw=0.6)
        sel = thin(len(xyz), SCATTER_POINTS)
        sc = top.scatter(xyz[sel, 0], xyz[sel, 1], c=colour[sel], cmap="viridis", s=3, zorder=3)
        top.plot(xyz[0, 0], xyz[0, 1], "o", color="tab:green", ms=6, label="start")
        top.plot(xyz[-1, 0], xyz[-1, 1], "s", color="tab:red", ms=6, label="end")
        ax3.plot(xyz[:, 0], xyz[:, 1], xyz[:, 2], "-", color="tab:blue", lw=0.8)
        ax3.scatter(*xyz[0], color="tab:green", s=20)
        ax3.scatter(*xyz[-1], color="tab:red", s=20)
        fig.colorbar(sc, ax=top, shrink=0.8, label="fraction of the run")
        top.legend(loc="upper right", fontsize=8)
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel("x [m]")
    top.set_ylabel("y [m]")
    top.set_title(title + ", top view")
    top.grid(True, alpha=0.3)
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    ax3.set_title("3D view" + one_scale_3d(ax3, xyz))
    return _save(fig, path)


#: radius of plot_map's landmark markers (``s=60`` points², edge included), points
MAP_MARKER_RADIUS_PT = 4.5
#: radius of the top view's landmark markers (estimates ``s=70`` with a 1.5 pt edge, truth an 8 pt cross), points
TOP_MARKER_RADIUS_PT = 5.0
#: an id label's size at 7 pt: width per character and height, points (DejaVu Sans digits 0.64 em, 1.2 em line)
LABEL_CHAR_PT, LABEL_HEIGHT_PT = 4.5, 8.5
#: how far from its landmark a label may go (points along x and y), tried nearest first
LABEL_GAPS_PT = (4.0, 10.0, 18.0)


def label_offsets(anchors_pt: np.ndarray, sizes_pt: np.ndarray, marker_radius_pt: float) -> np.ndarray:
    """Each label's lower-left corner relative to its anchor (points), chosen in turn: the first of the four corners
    about the anchor at each gap of ``LABEL_GAPS_PT`` whose box clears the labels placed before and every marker
    (a disc of ``marker_radius_pt``), else the spot that overlaps least. (N, 2) anchors and sizes (width, height)
    in points, on one figure's scale; labels in the order given take the best spots (TagSLAM test_11: "6 (506)"
    over "36 (19)", "35 (24)" over "11 (22)" with one fixed spot)."""
    a, wh = np.asarray(anchors_pt, dtype=np.float64), np.asarray(sizes_pt, dtype=np.float64)
    out = np.zeros_like(a)
    boxes: list[np.ndarray] = []
    for k in range(a.shape[0]):
        w, h = wh[k]
        spots = [
            (g if sx > 0 else -g - w, g if sy > 0 else -g - h)
            for g in LABEL_GAPS_PT
            for sy in (1, -1)
            for sx in (1, -1)
        ]
        best, least = spots[0], np.inf
        for dx, dy in spots:
            lo = a[k] + (dx, dy)
            clash = box_overlap(lo, lo + (w, h), boxes) + disc_overlap(lo, lo + (w, h), a, marker_radius_pt)
            if clash < least:
                best, least = (dx, dy), clash
            if clash == 0:
                break
        out[k] = best
        boxes.append(np.array([*(a[k] + best), *(a[k] + best + (w, h))]))
    return out


def box_overlap(lo: np.ndarray, hi: np.ndarray, boxes: list[np.ndarray]) -> float:
    """Area (points²) the box ``lo``-``hi`` shares with ``boxes`` (rows x0, y0, x1, y1)."""
    if not boxes:
        return 0.0
    b = np.asarray(boxes)
    w = np.clip(np.minimum(hi[0], b[:, 2]) - np.maximum(lo[0], b[:, 0]), 0, None)
    h = np.clip(np.minimum(hi[1], b[:, 3]) - np.maximum(lo[1], b[:, 1]), 0, None)
    return float(np.sum(w * h))


def disc_overlap(lo: np.ndarray, hi: np.ndarray, centres: np.ndarray, radius: float) -> float:
    """How deep (points) the box ``lo``-``hi`` reaches into discs of ``radius`` about ``centres``, summed."""
    nearest = np.clip(centres, lo, hi)
    return float(np.sum(np.clip(radius - np.linalg.norm(centres - nearest, axis=1), 0, None)))


def _placed_labels(ax, texts: list[str], xyz: np.ndarray, marker_radius_pt: float, colours=None) -> None:
    """``texts`` at 7 pt beside their landmarks' x-y positions where they clear each other and the markers
    (:func:`label_offsets`, on the axes' final limits): plain texts, each on the data transform shifted by its
    offset (an ``annotate`` per label drew the same pixels at about twice the cost)."""
    from matplotlib.transforms import ScaledTranslation

    ax.apply_aspect()
    anchors = ax.transData.transform(xyz[:, :2]) * (72.0 / ax.figure.dpi)
    sizes = np.array([(LABEL_CHAR_PT * len(t), LABEL_HEIGHT_PT) for t in texts])
    colours = colours or ["k"] * len(texts)
    for t, p, off, c in zip(texts, xyz, label_offsets(anchors, sizes, marker_radius_pt), colours):
        shifted = ax.transData + ScaledTranslation(off[0] / 72.0, off[1] / 72.0, ax.figure.dpi_scale_trans)
        ax.text(p[0], p[1], t, transform=shifted, fontsize=7, color=c, va="bottom", in_layout=False)


def plot_map(
    path: Path,
    ids: np.ndarray,
    xyz: np.ndarray,
    seen: np.ndarray,
    path_xyz: np.ndarray,
    truth_xyz: np.ndarray | None = None,
    truth_label: str = "",
) -> Path:
    """The landmark map from above over the path, each landmark labelled ``id (times seen)`` and coloured by how
    often it was seen; ``truth_xyz``: the landmark truth in the estimate's frame (open squares; ``truth_label``
    says how it was placed there)."""
    n = len(ids)
    with_truth = truth_xyz is not None and len(truth_xyz)
    # with the truth the legend's long line goes below the axes (inside, it covered landmarks)
    fig, axes = _figure(1, 1, (8.5, 8.0), right=0.2, bottom=1.1) if with_truth else _figure(1, 1, (8.5, 7.5), right=0.2)
    ax = axes[0, 0]
    if len(path_xyz):
        ax.plot(path_xyz[:, 0], path_xyz[:, 1], "-", color="0.7", lw=0.8, label="estimated path")
    if with_truth:
        ax.scatter(
            truth_xyz[:, 0],
            truth_xyz[:, 1],
            marker="s",
            s=90,
            facecolors="none",
            edgecolors="tab:green",
            lw=1.2,
            zorder=4,
            label=truth_label,
        )
    ax.set_aspect("equal", adjustable="datalim")  # before the labels: they are placed on the final limits
    if n:
        sc = ax.scatter(xyz[:, 0], xyz[:, 1], c=seen, cmap="plasma", s=60, edgecolors="k", lw=0.5, zorder=3)
        fig.colorbar(sc, ax=ax, shrink=0.8, label="times seen")
        if n <= MAX_ID_LABELS:
            _placed_labels(ax, [f"{int(i)} ({int(k)})" for i, k in zip(ids, seen)], xyz, MAP_MARKER_RADIUS_PT)
    else:
        ax.text(0.5, 0.5, "no landmarks in the map", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    seen_text = f", seen {int(np.min(seen))} to {int(np.max(seen))} times" if n else ""
    # the frame as estimated (trajectory.png's): a run with truth draws trajectory_top.png aligned onto the truth
    ax.set_title(f"Landmark map, output frame: {n} landmarks{seen_text}; labels: id (times seen)")
    ax.grid(True, alpha=0.3)
    if with_truth:
        fig.legend(loc="lower left", bbox_to_anchor=(0.01, 0.005), fontsize=8, frameon=False)
    elif len(path_xyz):
        ax.legend(loc="upper right", fontsize=8)
    return _save(fig, path)


def break_at_gaps(t: np.ndarray, *series: np.ndarray) -> tuple[np.ndarray, ...]:
    """``t`` and ``series`` with a NaN after every gap longer than three typical steps, so a line is not drawn
    across a stretch without data (it would show values nobody measured)."""
    t = np.asarray(t, dtype=np.float64)
    if t.size < 3:
        return (t, *series)
    step = np.diff(t)
    cut = np.flatnonzero(step > 3.0 * np.median(step)) + 1
    return tuple(np.insert(np.asarray(a, dtype=np.float64), cut, np.nan) for a in (t, *series))


def plot_measurements(
    path: Path, frame_t_s: np.ndarray, per_frame: np.ndarray, innovation: dict[str, np.ndarray] | None
) -> Path:
    """Detections per frame over time, and the innovation (measurement residual) norm per time bin: median,
    95th percentile and maximum."""
    fig, axes = _figure(2, 1, (9.0, 6.5))
    ax_d, ax_i = axes[0, 0], axes[1, 0]
    sel = envelope(len(frame_t_s), [per_frame])
    ax_d.plot(frame_t_s[sel], per_frame[sel], ".", ms=2, color="tab:blue")
    ax_d.set_ylabel("detections per frame")
    ax_d.set_title(f"Landmark detections: {len(per_frame)} frames, {int(np.sum(per_frame))} detections")
    ax_d.set_ylim(0, max(1, int(np.max(per_frame)) if len(per_frame) else 1) + 0.5)
    if innovation is not None and len(innovation["t_s"]):
        t, median, p95, top = break_at_gaps(*(innovation[k] for k in ("t_s", "median", "p95", "max")))
        # dots: lone bins; the median over the others (a bin of one detection has one value: a 4 Hz camera's)
        ax_i.plot(t, median, ".-", color="tab:blue", lw=1.0, ms=2, label="median", zorder=2.2)
        ax_i.plot(t, p95, ".-", color="tab:orange", lw=1.0, ms=2, label="95th percentile", zorder=2.1)
        ax_i.plot(t, top, ".-", color="tab:red", lw=0.6, ms=1.5, alpha=0.6, label="maximum")
        ax_i.legend(loc="upper right", fontsize=8)
    else:
        ax_i.text(0.5, 0.5, "no innovations recorded", ha="center", va="center", transform=ax_i.transAxes)
    ax_i.set_ylabel("innovation norm [m]")
    ax_i.set_title("Innovation (measurement residual) norm per time bin")
    ax_i.set_xlabel("time since estimate start [s]")
    for ax in (ax_d, ax_i):
        ax.grid(True, alpha=0.3)
    return _save(fig, path)


def plot_error_result(
    path,
    t_s: np.ndarray,
    errors: np.ndarray,
    stats: dict,
    ref_xyz: np.ndarray,
    est_xyz: np.ndarray,
    error_xyz: np.ndarray,
    *,
    plot_mode: str = "xyz",
    title: str = "",
    label: str = "error",
    aligned: bool = True,
    x_label: str = "t [s]",
) -> Path:
    """What evo_ape / evo_rpe ``-p`` shows, in one PNG: the error over time with its mean, median and RMSE and the
    ±std band, and the reference (dashed grey) with the estimate (``aligned`` or not, as its legend says)
    coloured by the error at ``error_xyz`` (the estimate positions each error belongs to) in ``plot_mode`` (evo's:
    two axes such as ``xy``, or ``xyz`` for a 3D view). ``x_label`` names what ``t_s`` is (poses without stamps,
    paired by index, give their index)."""
    from matplotlib.colors import Normalize

    fig, axes = _figure(2, 1, (9.0, 11.0), gap=0.8)
    raw = axes[0, 0]
    sel = envelope(len(t_s), [errors])
    # no line across a stretch without pairs (a truth's or a tracker's loss): it would show errors nobody measured
    raw.plot(*break_at_gaps(t_s[sel], errors[sel]), color="0.35", lw=1.0, label=label)
    for key, colour in (("rmse", "tab:blue"), ("median", "tab:green"), ("mean", "tab:red")):
        raw.axhline(stats[key], color=colour, lw=1.2, label=key)
    raw.axhspan(stats["mean"] - stats["std"], stats["mean"] + stats["std"], color="tab:olive", alpha=0.3, label="std")
    raw.set_xlabel(x_label)
    raw.set_ylabel(label)
    raw.set_title(title)
    raw.grid(True, alpha=0.3)
    raw.legend(loc="upper right", fontsize=8)
    box = axes[1, 0].get_position()
    axes[1, 0].remove()
    dims = [AXES.index(c) for c in plot_mode]
    ax = fig.add_axes(box, projection="3d" if plot_mode == "xyz" else None)
    ref, est = ref_xyz[thin(len(ref_xyz), PATH_POINTS)], est_xyz[thin(len(est_xyz), PATH_POINTS)]
    if len(ref_xyz) == len(t_s):  # the truth at each pair (APE): broken where the pairs are
        pick = thin(len(ref_xyz), PATH_POINTS)
        ref = np.column_stack(break_at_gaps(t_s[pick], *ref_xyz[pick].T)[1:])
    ax.plot(*(ref[:, d] for d in dims), "--", color="0.5", lw=1.0, label="reference")
    norm = Normalize(float(np.min(errors)) if len(errors) else 0.0, float(np.max(errors)) if len(errors) else 1.0)
    pick = thin(len(error_xyz), SCATTER_POINTS)
    sc = ax.scatter(*(error_xyz[pick, d] for d in dims), c=errors[pick], cmap="jet", norm=norm, s=4)
    what = "estimate (aligned)" if aligned else "estimate (not aligned)"
    ax.plot(*(est[:, d] for d in dims), "-", color="0.2", lw=0.4, alpha=0.5, label=what)
    fig.colorbar(sc, ax=ax, shrink=0.8, label=label)
    for d, setter in zip(dims, ("set_xlabel", "set_ylabel", "set_zlabel")):
        getattr(ax, setter)(f"{AXES[d]} [m]")
    if plot_mode != "xyz":
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(True, alpha=0.3)
    scale = one_scale_3d(ax, np.concatenate([ref_xyz, est_xyz])) if plot_mode == "xyz" else ""
    ax.set_title(f"{label} mapped onto the trajectory ({plot_mode}){scale}")
    ax.legend(loc="upper right", fontsize=8)
    return _save(fig, path)
