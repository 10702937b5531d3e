"""Estimate vs reference, the evo way: synchronise -> align -> APE or RPE, with evo's titles and result arrays.

This is the one path behind ``slamobs evaluate`` (evo drop-in), the run report and the evo-compatible result
zip. Steps and their order follow ``evo_ape`` / ``evo_rpe`` 1.38.1: association (or interpolation) first,
then the alignment fitted on the associated pairs (optionally only the first ``n`` or the first ``T``
seconds), then the metric on the aligned estimate.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from slamobs.pipeline.evaluation import metrics
from slamobs.pipeline.evaluation.align import ATTITUDE, DESCRIPTIONS, Alignment, canonical, fit_alignment
from slamobs.pipeline.evaluation.metrics import RotationRows
from slamobs.pipeline.evaluation.rpe import DELTA_UNITS, accumulated_distances, rpe_pairs
from slamobs.pipeline.evaluation.sync import (
    NS_PER_S,
    ReferenceMotion,
    TimeOffset,
    associate,
    halves_spread,
    interpolate_poses,
    time_offset_against,
)
from slamobs.pipeline.streams import PoseStream

SYNC_METHODS = ("nearest", "interpolation")


@dataclass(frozen=True)
class SyncOptions:
    """evo ``--t_max_diff``, ``--t_offset`` (added to the estimate stamps) and ``--sync_method``."""

    t_max_diff_s: float = 0.01
    t_offset_s: float = 0.0
    method: str = "nearest"


@dataclass(frozen=True)
class AlignOptions:
    """evo ``-a`` / ``-s`` / ``--align_origin`` as one ``kind`` (see ``align.KINDS``), ``--n_to_align``, and
    ``first_s``: fit on the pairs of the first ``first_s`` seconds only (beyond evo)."""

    kind: str = "none"
    n: int | None = None
    first_s: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "kind", canonical(self.kind))  # rpg's "posyaw" is "yaw"


@dataclass(frozen=True)
class RpeOptions:
    """evo ``--delta``, ``--delta_unit`` (f, m, d, r), ``--delta_tol``, ``--all_pairs``, ``--pairs_from_reference``."""

    delta: float = 1.0
    unit: str = "f"
    rel_tol: float = 0.1
    all_pairs: bool = False
    pairs_from_reference: bool = False


@dataclass(frozen=True)
class Paired:
    """Poses of both trajectories at associated stamps, in the order of the driving (shorter) series.

    Rotations are quaternions, or matrices when the file had them (KITTI), of the pairs (interpolated ones)
    or rows of the streams' (:class:`~.metrics.RotationRows` with an index: not copied); ``ref_rot``/``est_rot``
    give the matrices of the rows asked for: no (N, 3, 3) array is ever held.
    """

    t_ref_ns: np.ndarray | None  # None when paired by index
    t_est_ns: np.ndarray | None  # on the estimate's own clock (the offset is not added), as evo keeps it
    ref_pos: np.ndarray
    ref_rotation: np.ndarray | RotationRows  # (N, 4) quaternions (x, y, z, w), (N, 3, 3) matrices or stream rows
    est_pos: np.ndarray
    est_rotation: np.ndarray | RotationRows
    idx_ref: np.ndarray | None  # into the input streams; None for the interpolated side
    idx_est: np.ndarray | None
    method: str  # nearest | interpolation | index
    driving: str  # reference | estimate
    n_ref: int
    n_est: int

    def __len__(self) -> int:
        return int(self.ref_pos.shape[0])

    @property
    def unpaired(self) -> int:
        """How many poses of the driving (shorter) series found no stamp of the other within the association
        window (0 when paired by index): ROS_example.bag's ORB-SLAM estimate, 5812 of 8362 at 0.01 s."""
        return (self.n_ref if self.driving == "reference" else self.n_est) - len(self)

    @cached_property
    def ref_rot(self) -> RotationRows:
        r = self.ref_rotation
        return r if isinstance(r, RotationRows) else RotationRows(r)

    @cached_property
    def est_rot(self) -> RotationRows:
        r = self.est_rotation
        return r if isinstance(r, RotationRows) else RotationRows(r)


class Source:
    """What the metrics read of a trajectory: its PoseStream, and optionally the rotation matrices as written
    (KITTI files; else they come from the quaternions) and whether it has stamps (else: pairing by index).
    Anything with these attributes works, e.g. ``readers.trajectory_files.Trajectory``."""

    def __init__(self, stream: PoseStream, rotations: np.ndarray | None = None, timed: bool = True) -> None:
        self.stream, self.rotations, self.timed = stream, rotations, timed


def _source(x) -> Source:
    return Source(x) if isinstance(x, PoseStream) else x


def _rots(src: Source, idx: np.ndarray | None = None) -> RotationRows:
    """The rotations of ``src`` (rows ``idx``): matrices as written if it has them, else its quaternions."""
    r = np.asarray(src.rotations if src.rotations is not None else src.stream.quat_xyzw, dtype=np.float64)
    return RotationRows(r, index=idx)


def _span(t_ns: np.ndarray) -> str:
    return f"[{t_ns.min() / 1e9:.9f}, {t_ns.max() / 1e9:.9f}] s ({t_ns.shape[0]} stamps)"


def synchronize(reference, estimate, opts: SyncOptions = SyncOptions(), *, ref_label: str = "reference") -> Paired:
    """Pair the poses of ``estimate`` with those of ``reference`` (evo ``sync.associate_trajectories``).

    Both are PoseStreams or :class:`Source`-like objects. Without stamps (``timed`` False, KITTI files) the
    poses are paired by index and both must have the same length. ``interpolation`` first associates like
    ``nearest`` and then replaces the poses of the longer series by its interpolation (linear position, slerp
    rotation) at the stamps of the shorter one.
    """
    rs, es = _source(reference), _source(estimate)
    ref, est = rs.stream, es.stream
    n_ref, n_est = len(ref), len(est)
    if n_ref == 0 or n_est == 0:
        raise ValueError(f"empty trajectory: reference has {n_ref} poses, estimate {n_est}")
    ref_p = np.asarray(ref.position, dtype=np.float64)
    est_p = np.asarray(est.position, dtype=np.float64)
    if not (rs.timed and es.timed):
        if n_ref != n_est:
            raise ValueError(
                f"poses without stamps are paired by index, but the reference has {n_ref} poses "
                f"and the estimate {n_est}"
            )
        idx = np.arange(n_ref)
        return Paired(
            None, None, ref_p, _rots(rs), est_p, _rots(es), idx, idx.copy(), "index", "estimate", n_ref, n_est
        )
    if opts.method not in SYNC_METHODS:
        raise ValueError(f"sync method must be one of {SYNC_METHODS}, got {opts.method!r}")
    idx_ref, idx_est = associate(ref.t_ns, est.t_ns, opts.t_max_diff_s, opts.t_offset_s)
    if idx_ref.size == 0:
        raise ValueError(
            f"no estimate stamp lies within {opts.t_max_diff_s} s of a {ref_label} stamp (estimate offset "
            f"{opts.t_offset_s} s): estimate spans {_span(np.asarray(est.t_ns))}, {ref_label} spans "
            f"{_span(np.asarray(ref.t_ns))}. Are both on the same clock (header stamps vs. recording time, sim "
            f"time vs. wall time)?"
        )
    driving = "reference" if n_ref < n_est else "estimate"
    t_ref, t_est = np.asarray(ref.t_ns)[idx_ref], np.asarray(est.t_ns)[idx_est]
    if opts.method == "nearest":
        return Paired(
            t_ref,
            t_est,
            ref_p[idx_ref],
            _rots(rs, idx_ref),
            est_p[idx_est],
            _rots(es, idx_est),
            idx_ref,
            idx_est,
            "nearest",
            driving,
            n_ref,
            n_est,
        )
    offset_ns = int(round(opts.t_offset_s * NS_PER_S))
    if driving == "reference":  # the estimate is resampled at the reference stamps, on its own clock
        t_est = t_ref - offset_ns
        pos, quat = interpolate_poses(est.t_ns, est_p, est.quat_xyzw, t_est)
        return Paired(
            t_ref,
            t_est,
            ref_p[idx_ref],
            _rots(rs, idx_ref),
            pos,
            quat,
            idx_ref,
            None,
            "interpolation",
            driving,
            n_ref,
            n_est,
        )
    t_ref = t_est + offset_ns
    pos, quat = interpolate_poses(ref.t_ns, ref_p, ref.quat_xyzw, t_ref)
    return Paired(
        t_ref,
        t_est,
        pos,
        quat,
        est_p[idx_est],
        _rots(es, idx_est),
        None,
        idx_est,
        "interpolation",
        driving,
        n_ref,
        n_est,
    )


def n_to_align(paired: Paired, opts: AlignOptions) -> int | None:
    """Number of leading pairs the alignment is fitted on (None = all)."""
    n = opts.n if opts.n is not None and opts.n >= 0 else None
    if opts.first_s is not None:
        if paired.t_est_ns is None:
            raise ValueError("aligning on the first seconds needs stamped poses")
        t = paired.t_est_ns
        k = int(np.count_nonzero(t - t[0] <= int(round(opts.first_s * NS_PER_S))))
        n = k if n is None else min(n, k)
    return n


def align_paired(paired: Paired, opts: AlignOptions) -> tuple[Alignment, np.ndarray]:
    """Fit the alignment on the (first) pairs; return it with the aligned estimate positions."""
    rots = (paired.ref_rot, paired.est_rot)  # origin and yaw read the first; se3 and sim3 all where positions cannot
    al = fit_alignment(opts.kind, paired.ref_pos, paired.est_pos, *rots, n_to_align(paired, opts))
    return al, (paired.est_pos if al.kind == "none" else al.positions(paired.est_pos))


def aligned_rotations(al: Alignment, paired: Paired) -> RotationRows:
    """The estimate's rotation matrices after the alignment ``R_a R_est`` (built for the rows asked for)."""
    return paired.est_rot if al.kind == "none" else paired.est_rot.turned(al.rot)


def alignment_title(opts: AlignOptions, al: Alignment) -> str:
    """The alignment lines of evo's result title."""
    kind = opts.kind
    title = {
        "se3": "\n(with SE(3) Umeyama alignment)",
        "sim3": "\n(with Sim(3) Umeyama alignment)",
        "scale": "\n(scale corrected)",
        "none": "\n(not aligned)",
        "origin": "\n(with origin alignment)",
        "yaw": "\n(with 4-DoF translation + yaw alignment)",
    }[kind]
    if al.kind == ATTITUDE:
        title = "\n(with attitude alignment: the truth positions cannot fix a rotation)"
    elif kind in ("se3", "sim3", "scale", "yaw"):
        if opts.first_s is not None:
            title += f" (aligned poses: {al.n_points}, first {opts.first_s:g} s)"
        elif opts.n is not None and opts.n >= 0:
            title += f" (aligned poses: {opts.n})"  # as given, like evo
    return title


@dataclass(frozen=True)
class ErrorResult:
    """One metric on one trajectory pair: the errors, their statistics, and everything evo stores with them."""

    metric: str  # "ape" | "rpe"
    relation: str
    unit: str
    title: str
    errors: np.ndarray
    stats: dict
    alignment: Alignment
    paired: Paired
    est_pos_aligned: np.ndarray
    ref_name: str = "reference"
    est_name: str = "estimate"
    pair_i: np.ndarray | None = None  # RPE: index pairs into the paired poses
    pair_j: np.ndarray | None = None

    @cached_property
    def arrays(self) -> dict[str, np.ndarray]:
        """evo's result arrays besides ``error_array`` (:func:`_timing_arrays`, the alignment's matrix), built on
        first use: only the evo zip (``--export evo``) reads them (the hour's APE: two path lengths and the stamps
        of 360,000 pairs, ~15 ms each time a report computed them unused)."""
        arrays = _timing_arrays(self.paired, self.est_pos_aligned, keep=self.pair_j if self.metric == "rpe" else None)
        if self.alignment.evo_matrix is not None:
            arrays["alignment_transformation_sim3"] = self.alignment.evo_matrix
        return arrays

    @cached_property
    def est_rot_aligned(self) -> RotationRows:
        """The estimate rotations after the alignment (built on first use)."""
        return aligned_rotations(self.alignment, self.paired)

    @property
    def label(self) -> str:
        return f"{self.metric.upper()} ({self.unit})"

    @property
    def evo_stats(self) -> dict[str, float]:
        return {k: float(self.stats[k]) for k in metrics.EVO_STATS}

    def pretty(self) -> str:
        """evo's ``Result.pretty_str()``: title, blank line, sorted statistics with 6 decimals."""
        lines = [self.title, ""] + [f"{k:>10}\t{v:.6f}" for k, v in sorted(self.evo_stats.items())]
        return "\n".join(lines) + "\n"


def seconds(t_ns: np.ndarray) -> np.ndarray:
    """Float seconds of int nanosecond stamps, rounded once (as evo gets them parsing decimal text); plain
    ``t_ns / 1e9`` rounds twice above 2⁵³ ns and can be one ulp (0.24 µs) off."""
    t = np.asarray(t_ns, dtype=np.int64)
    whole, frac = np.divmod(t, NS_PER_S)
    return whole.astype(np.float64) + frac.astype(np.float64) / NS_PER_S


def _timing_arrays(paired: Paired, est_pos_aligned: np.ndarray, keep: np.ndarray | None = None) -> dict:
    """evo's per-value arrays: seconds_from_start, timestamps (estimate clock), distances_from_start
    (reference path), distances (aligned estimate path); for RPE on the poses ``[0] + j`` without the first."""
    ref_pos, est_pos = paired.ref_pos, est_pos_aligned
    t = paired.t_est_ns
    if keep is not None:
        ids = np.concatenate([[0], keep])
        ref_pos, est_pos = ref_pos[ids], est_pos[ids]
        t = None if t is None else t[ids]
    out = {}
    cut = slice(1, None) if keep is not None else slice(None)
    if t is not None:
        ts = seconds(t)
        out["seconds_from_start"] = (ts - ts[0])[cut]
        out["timestamps"] = ts[cut]
        out["distances_from_start"] = accumulated_distances(ref_pos)[cut]
        out["distances"] = accumulated_distances(est_pos)[cut]
    return out


def ape(
    ref,
    est,
    relation: str = "trans_part",
    sync: SyncOptions = SyncOptions(),
    align: AlignOptions = AlignOptions(),
    *,
    ref_name: str = "reference",
    est_name: str = "estimate",
    paired: Paired | None = None,
    like: ErrorResult | None = None,
) -> ErrorResult:
    """Absolute pose error of ``est`` against ``ref`` (evo_ape); PoseStreams or :class:`Source`-likes.

    ``like``: an APE of the same ``paired`` under the same ``align`` (another relation of one comparison);
    its alignment and aligned positions are shared instead of computed and held again.
    """
    paired = paired or synchronize(ref, est, sync)
    al, pos = (like.alignment, like.est_pos_aligned) if like is not None else align_paired(paired, align)
    name, unit = metrics.POSE_RELATIONS[relation]
    title = f"APE w.r.t. {name} ({unit})" + alignment_title(align, al)
    if relation in ("trans_part", "point_distance"):  # positions only: no rotation matrix is ever built
        errors = metrics.ape_translation(paired.ref_pos, pos)
    else:
        errors = metrics.ape_errors(relation, paired.ref_pos, paired.ref_rot, pos, aligned_rotations(al, paired))
    return ErrorResult(
        "ape",
        relation,
        unit,
        title,
        errors,
        metrics.statistics(errors),
        al,
        paired,
        pos,
        ref_name,
        est_name,
    )


def rpe(
    ref,
    est,
    relation: str = "trans_part",
    sync: SyncOptions = SyncOptions(),
    align: AlignOptions = AlignOptions(),
    opts: RpeOptions = RpeOptions(),
    *,
    ref_name: str = "reference",
    est_name: str = "estimate",
    paired: Paired | None = None,
    like: ErrorResult | None = None,
) -> ErrorResult:
    """Relative pose error of ``est`` against ``ref`` (evo_rpe); pairs from the aligned estimate unless
    ``pairs_from_reference``. ``like``: a result of the same ``paired`` under the same ``align`` whose
    alignment and aligned positions are shared."""
    paired = paired or synchronize(ref, est, sync)
    al, pos = (like.alignment, like.est_pos_aligned) if like is not None else align_paired(paired, align)
    name, unit = metrics.POSE_RELATIONS[relation]
    delta = int(opts.delta) if opts.unit == "f" else float(opts.delta)
    title = (
        f"RPE w.r.t. {name} ({unit})\nfor delta = {delta} ({DELTA_UNITS[opts.unit]}) using "
        f"{'all' if opts.all_pairs else 'consecutive'} pairs" + alignment_title(align, al)
    )
    angles = opts.unit in ("d", "r")
    rot = aligned_rotations(al, paired) if angles or relation != "point_distance" else None
    if opts.pairs_from_reference:
        i, j = rpe_pairs(
            paired.ref_pos, paired.ref_rot if angles else None, opts.delta, opts.unit, opts.rel_tol, opts.all_pairs
        )
    else:
        i, j = rpe_pairs(pos, rot, opts.delta, opts.unit, opts.rel_tol, opts.all_pairs)
    ref_rot = None if relation == "point_distance" else paired.ref_rot
    errors = metrics.rpe_errors(relation, paired.ref_pos, ref_rot, pos, rot, i, j)
    return ErrorResult(
        "rpe",
        relation,
        unit,
        title,
        errors,
        metrics.statistics(errors),
        al,
        paired,
        pos,
        ref_name,
        est_name,
        pair_i=i,
        pair_j=j,
    )


def describe(result: ErrorResult, sync: SyncOptions, align: AlignOptions, rpe_opts: RpeOptions | None = None) -> dict:
    """How the numbers of ``result`` were obtained, JSON-ready."""
    p = result.paired
    out = {
        "metric": result.metric,
        "pose_relation": result.relation,
        "definition": metrics.RELATION_DEFINITIONS[result.relation],
        "unit": result.unit,
        "association": {
            "method": p.method,
            "t_max_diff_s": float(sync.t_max_diff_s) if p.method != "index" else None,
            "t_offset_s": float(sync.t_offset_s) if p.method != "index" else None,
            "driving_series": p.driving,
            "n_pairs": len(p),
            "n_unpaired": p.unpaired,  # of the driving series: no stamp of the other within t_max_diff_s
            "n_reference": p.n_ref,
            "n_estimate": p.n_est,
        },
        "alignment": {
            "type": result.alignment.kind,
            "description": DESCRIPTIONS[result.alignment.kind],
            "n_points": result.alignment.n_points,
            "n_to_align": align.n,
            "first_s": align.first_s,
            "sim3_matrix": [[float(v) for v in row] for row in result.alignment.matrix],
            "scale": float(result.alignment.scale),
        },
    }
    if rpe_opts is not None:
        out["rpe"] = {
            "delta": float(rpe_opts.delta),
            "delta_unit": DELTA_UNITS[rpe_opts.unit],
            "rel_delta_tol": float(rpe_opts.rel_tol),
            "all_pairs": bool(rpe_opts.all_pairs),
            "pairs_from": "reference" if rpe_opts.pairs_from_reference else "aligned estimate",
            "n_pairs": int(result.errors.shape[0]),
        }
    return out


def checked_time_offset(
    ref: PoseStream,
    est: PoseStream,
    sync: SyncOptions,
    align: AlignOptions,
    max_offset_s: float = 1.0,
    *,
    without: bool = True,
    found: Callable[[], TimeOffset | None] | None = None,
) -> TimeOffset | None:
    """:func:`~.sync.estimate_time_offset` of two time-sorted pose streams, checked against the trajectories:
    the translation APE rmse (association rule ``sync``, alignment ``align``) with the offset applied and
    without it, so that a correlation peak which makes the error larger is not called reliable. ``without=False``
    leaves ``rmse_without_m`` None for a caller that computes that APE anyway and fills it in (the report).
    ``found()``: the offset searched another way (a run's: the truth against the log's own velocity samples,
    :func:`.trajectory_evaluation.log_time_offset`), checked here the same way instead of searching the estimate."""
    if found is None:
        reference = ReferenceMotion(ref.t_ns, ref.position, ref.quat_xyzw)  # the truth's side, once for three

        def search(part: slice = slice(None)) -> TimeOffset | None:
            t, pos, quat = (np.asarray(x)[part] for x in (est.t_ns, est.position, est.quat_xyzw))
            return time_offset_against(reference, t, pos, quat, max_offset_s=max_offset_s)

        off = search()
        # the halves of the estimate's poses must agree, as a log's velocity samples must (one `reliable`)
        off = None if off is None else replace(off, uncertainty_s=halves_spread(search, len(est)))
    else:
        off = found()
    if off is None:
        return None

    def rmse(offset_s: float) -> float | None:
        try:
            return float(ape(ref, est, "trans_part", replace(sync, t_offset_s=offset_s), align).stats["rmse"])
        except ValueError:  # too few pairs at that offset
            return None

    return replace(off, checked=True, rmse_with_m=rmse(off.offset_s), rmse_without_m=rmse(0.0) if without else None)
