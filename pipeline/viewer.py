"""``slamobs view``: finished runs as a Rerun recording (``.rrd``), to open in the Rerun viewer.

Per run, under its label (the estimator's name, made unique across the runs):

    world/<label>/truth                 the truth path (static), when the run's truth can be read
    world/<label>/trajectory            the estimate's path (static), aligned to the truth as the report aligns it
    world/<label>/pose                  the estimated position over time
    world/<label>/landmarks             the final landmark map (static), labelled by id
    world/<label>/landmarks/covariance  3σ ellipsoids of the landmarks, when the run has covariance columns
    world/<label>/detections            a ray from the body to the landmark at each detection (innovations table)
    errors/<label>/position_m, errors/<label>/attitude_deg   the APE per pose over time (with truth)
    biases/<label>/gyro/{x,y,z}, biases/<label>/velocity/{x,y,z}   the estimated biases over time

The timeline ``time`` holds the log's stamps, so runs of one log line up. Without truth (no truth topic, the
log moved) the estimate is shown in its own frame and the errors are left out. Rerun (``rerun-sdk``, the
``view`` extra) is imported here and nowhere else.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slamobs.pipeline.errors import InputError, one_line
from slamobs.pipeline.evaluation.plots import PATH_POINTS, thin
from slamobs.pipeline.results_mcap import read_run_table

TIMELINE = "time"
APPLICATION = "slamobs"
RRD = "view.rrd"
SIGMAS = 3.0  # ellipsoid half-axes in standard deviations
MAX_RAYS = 20_000  # detection rays drawn per run (evenly thinned beyond)
EXTRA_HINT = "install it with: pip install 'slamobs[view]'"


@dataclass
class ViewRun:
    """What a run shows, in the truth frame when there is truth (else the estimate's own)."""

    path: Path
    name: str
    t_ns: np.ndarray
    position: np.ndarray
    truth: np.ndarray | None = None
    error_t_ns: np.ndarray | None = None
    errors: dict[str, np.ndarray] = field(default_factory=dict)
    landmark_ids: np.ndarray | None = None
    landmarks: np.ndarray | None = None
    landmark_cov: tuple[np.ndarray, np.ndarray] | None = None  # (landmark rows with one, their (n, 3, 3))
    rays: tuple[np.ndarray, np.ndarray] | None = None  # (t_ns, (n, 2, 3) segments)
    biases: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # name -> (t_ns, values)
    notes: list[str] = field(default_factory=list)


def rerun_module(path: str | Path = ""):
    """The ``rerun`` module; a one-line error naming the extra when it is missing."""
    try:
        import rerun
    except ImportError:
        raise InputError(path, f"the viewer needs rerun-sdk, which is not installed; {EXTRA_HINT}") from None
    return rerun


def _truth_alignment(run_dir: Path, meta: dict, poses, notes: list[str]):
    """The run's evaluation against its truth (the report's pairing and alignment), or None without truth."""
    from slamobs.pipeline.evaluation.run_dir import options_for_run, resolve_truth
    from slamobs.pipeline.evaluation.trajectory_evaluation import evaluate_trajectory

    try:
        truth = resolve_truth(meta, None)
        return evaluate_trajectory(poses, truth.stream, options_for_run(meta), estimate_offset=False)
    except (InputError, ValueError) as err:
        log = (meta.get("input") or {}).get("path")
        notes.append(f"{run_dir}: no truth shown (log {log}: {one_line(err)})")
        return None


def landmark_covariances(frame, rot: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Rows with a full covariance and their (n, 3, 3) matrices turned into the shown frame, or None."""
    from slamobs.pipeline.evaluation.tables import landmark_covariances as table_covariances

    mats = table_covariances(frame)
    if mats is None:
        return None
    rows = np.flatnonzero(np.isfinite(mats).all(axis=(1, 2)))
    if rows.size == 0:
        return None
    return rows, scale**2 * (rot @ mats[rows] @ rot.T)


def detection_rays(innov, position: np.ndarray, t_ns: np.ndarray, ids: np.ndarray, xyz: np.ndarray):
    """Per detection (innovations row) the segment from the body's position then to its landmark's position."""
    if innov is None or len(innov) == 0 or ids is None or len(ids) == 0:
        return None
    t = innov["t_ns"].to_numpy(np.int64)
    rows = thin(len(t), MAX_RAYS)
    t, lm = t[rows], innov["id"].to_numpy(np.int64)[rows]
    at = np.clip(np.searchsorted(ids, lm), 0, len(ids) - 1)
    known = ids[at] == lm
    body = position[np.clip(np.searchsorted(t_ns, t[known]), 0, len(t_ns) - 1)]
    order = np.argsort(t[known], kind="stable")
    return t[known][order], np.stack([body, xyz[at[known]]], axis=1)[order]


def _biases(run_dir: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    frame = read_run_table(run_dir, "biases")
    if frame is None or len(frame) == 0:
        return {}
    t = frame["t_ns"].to_numpy(np.int64)
    out = {}
    for kind, prefix in (("gyro", "gyro_bias"), ("velocity", "vel_bias")):
        for axis in "xyz":
            out[f"{kind}/{axis}"] = (t, frame[f"{prefix}_{axis}"].to_numpy(np.float64))
    return out


def load_view_run(run_dir: Path) -> ViewRun:
    """Read a run directory (of run, compare or a batch) into what the recording shows."""
    from slamobs.pipeline.evaluation.run_dir import read_json

    run_dir = Path(run_dir)
    if not (run_dir / "run.json").is_file():
        from slamobs.pipeline.stored_runs import not_a_run

        raise not_a_run(run_dir)
    meta = read_json(run_dir / "run.json")
    poses = read_run_table(run_dir, "poses")
    if poses is None or len(poses) == 0:
        raise InputError(run_dir, "the run has no poses to show")
    poses = poses.sort_values("t_ns", kind="stable")
    name = str((meta.get("observer") or {}).get("name") or run_dir.name)
    run = ViewRun(run_dir, name, poses["t_ns"].to_numpy(np.int64), poses[["x", "y", "z"]].to_numpy(np.float64))
    ev = _truth_alignment(run_dir, meta, poses, run.notes)
    rot, scale = np.eye(3), 1.0
    if ev is not None:
        rot, scale = ev.alignment.rot, ev.alignment.scale
        run.position = ev.alignment.positions(run.position)
        run.truth = ev.truth.position
        run.error_t_ns = ev.paired.t_est_ns
        run.errors = {"position_m": ev.translation.errors, "attitude_deg": ev.rotation.errors}
    landmarks = read_run_table(run_dir, "landmarks")
    if landmarks is not None and len(landmarks):
        landmarks = landmarks.sort_values("id", kind="stable")
        run.landmark_ids = landmarks["id"].to_numpy(np.int64)
        xyz = landmarks[["x", "y", "z"]].to_numpy(np.float64)
        run.landmarks = ev.alignment.positions(xyz) if ev is not None else xyz
        run.landmark_cov = landmark_covariances(landmarks, rot, scale)
        run.rays = detection_rays(
            read_run_table(run_dir, "innovations"), run.position, run.t_ns, run.landmark_ids, run.landmarks
        )
    run.biases = _biases(run_dir)
    return run


def run_labels(runs: list[ViewRun]) -> list[str]:
    """The estimator's name per run, numbered where several runs share it (entity path parts, escaped)."""
    seen: dict[str, int] = {}
    labels = []
    for run in runs:
        k = seen[run.name] = seen.get(run.name, 0) + 1
        labels.append(run.name if k == 1 else f"{run.name}-{k}")
    return labels


def ellipsoids(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Half-axes (``SIGMAS`` standard deviations) and ``(x, y, z, w)`` orientations of covariance ellipsoids."""
    from slamobs.pipeline.lie import rots_to_quats

    eigval, eigvec = np.linalg.eigh(cov)
    eigvec[np.linalg.det(eigvec) < 0, :, 2] *= -1.0  # a rotation, not a reflection
    return SIGMAS * np.sqrt(np.clip(eigval, 0.0, None)), rots_to_quats(eigvec)


def _series(rr, rec, path: str, t_ns: np.ndarray, values: np.ndarray) -> None:
    """A time series as Scalars on the time line (thinned to its envelope on long logs)."""
    from slamobs.pipeline.evaluation.plots import envelope

    keep = envelope(len(t_ns), [values], buckets=20_000)
    index = rr.TimeColumn(TIMELINE, timestamp=t_ns[keep].astype("datetime64[ns]"))
    rec.send_columns(path, indexes=[index], columns=rr.Scalars.columns(scalars=values[keep]))


def _log_map(rr, rec, base: str, run: ViewRun) -> None:
    """Landmarks, their covariance ellipsoids and the detection rays."""
    if run.landmarks is None:
        return
    labels = [str(i) for i in run.landmark_ids]
    rec.log(f"{base}/landmarks", rr.Points3D(run.landmarks, labels=labels, radii=0.05), static=True)
    if run.landmark_cov is not None:
        rows, cov = run.landmark_cov
        half, quat = ellipsoids(cov)
        shape = rr.Ellipsoids3D(centers=run.landmarks[rows], half_sizes=half, quaternions=quat, fill_mode="solid")
        rec.log(f"{base}/landmarks/covariance", shape, static=True)
    if run.rays is not None:
        t, segments = run.rays
        stamps, counts = np.unique(t, return_counts=True)
        index = rr.TimeColumn(TIMELINE, timestamp=stamps.astype("datetime64[ns]"))
        strips = rr.LineStrips3D.columns(strips=list(segments)).partition(counts)
        rec.send_columns(f"{base}/detections", indexes=[index], columns=strips)


def log_run(rr, rec, label: str, run: ViewRun) -> None:
    """Everything of one run under its label (see the module doc for the entity paths)."""
    base = f"world/{label}"
    if run.truth is not None:
        path = run.truth[thin(len(run.truth), PATH_POINTS)]
        rec.log(f"{base}/truth", rr.LineStrips3D([path], colors=[[128, 128, 128]]), static=True)
    rec.log(f"{base}/trajectory", rr.LineStrips3D([run.position[thin(len(run.position), PATH_POINTS)]]), static=True)
    keep = thin(len(run.t_ns), 10 * PATH_POINTS)
    index = rr.TimeColumn(TIMELINE, timestamp=run.t_ns[keep].astype("datetime64[ns]"))
    points = rr.Points3D.columns(positions=run.position[keep], radii=np.full(len(keep), 0.08)).partition(
        np.ones(len(keep), np.int64)
    )
    rec.send_columns(f"{base}/pose", indexes=[index], columns=points)
    _log_map(rr, rec, base, run)
    for name, values in run.errors.items():
        _series(rr, rec, f"errors/{label}/{name}", run.error_t_ns, values)
    for name, (t, values) in run.biases.items():
        _series(rr, rec, f"biases/{label}/{name}", t, values)


def record(rr, rec, runs: list[ViewRun]) -> None:
    """Every run into the recording ``rec`` (world z up, as the runs' map frames)."""
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    for label, run in zip(run_labels(runs), runs):
        log_run(rr, rec, rr.escape_entity_path_part(label), run)


def view_runs(run_dirs: list[Path], out: Path | None = None, *, spawn: bool = False, force: bool = False):
    """Record ``run_dirs`` into ``out`` (default: ``view.rrd`` in the first run directory; none with ``spawn``
    and no ``out``) and/or a viewer spawned now. Every run is read before anything is written. Returns
    (the file written or None, the runs)."""
    from slamobs.pipeline.writers import atomic_file, kept_unless, update_manifest

    runs = [load_view_run(Path(p)) for p in run_dirs]
    rr = rerun_module(run_dirs[0])
    if out is None and not spawn:
        out = Path(run_dirs[0]) / RRD
    rec = rr.RecordingStream(APPLICATION)
    if out is None:
        rec.spawn()
        record(rr, rec, runs)
        rec.flush()
        return None, runs
    out = Path(out)
    why_kept = kept_unless(
        lambda head: head.startswith(b"RRF"),
        "exists and is not a Rerun recording: --force replaces only those",
        force=force,
    )
    with atomic_file(out, why_kept=why_kept) as tmp:
        if spawn:
            rec.spawn(connect=False)
            rec.set_sinks(rr.FileSink(str(tmp)), rr.GrpcSink())
        else:
            rec.save(str(tmp))
        record(rr, rec, runs)
        rec.flush()
        rec.disconnect()
    update_manifest(out.parent, written=[out])  # in a run directory: still slamobs's output
    return out, runs
