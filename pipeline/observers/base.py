"""What every observer shares: gain specifications and validation, options, the result arrays, and the
stretch-by-stretch driver of the kernels.

A kernel keeps its whole state in arrays (:class:`Stepper`), so a run can stop before any event and go
on later exactly as if it had not stopped: ``ObserverSpec.chunks`` yields the outputs a stretch of
samples at a time (a multi-hour log is written without holding its histories), ``ObserverSpec.run`` is
the same run in one stretch.

Every kernel call does a bounded amount of work (``WORK_PER_CALL``; each interval at most
``shared_steps.MAX_SUBSTEPS`` sub-steps) and returns to Python, which then handles Ctrl-C and SIGTERM
(compiled code never runs Python's signal handlers) and stops a diverged run early.

Segments (``AlignedStream.segment_starts``, velocity gaps longer than ``limits.max_gap``): nothing is
integrated across a gap (the twist held from before it says nothing about the motion during it); the clock
jumps to the first sample after the gap and the landmarks count as unseen until the next frame. The map and
the biases are kept. The pose is re-anchored to the map (:meth:`Stepper._relocalise`) by the first frame
within ``max_meas_age`` after the gap that sees at least three mapped landmarks; without one it is held.
Across a bridged gap (``AlignedStream.bridged_gaps``: the odometry alone silent, the gyro recording) the pose is
carried and its position re-anchored to the landmarks mapped before the gap (:meth:`Stepper._bridge_edge`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from slamobs.pipeline.alignment import MEAN_STAMPS, AlignedStream, held_stamps, relabelled, stream_topics
from slamobs.pipeline.blocks import id_time_order, row_norms3, row_squares3
from slamobs.pipeline.errors import BadInput, GainError
from slamobs.pipeline.noise import chi2_quantile
from slamobs.pipeline.observers.shared_steps import CAP_IV, CAPPED, motion_spread

#: Work units (sub-steps times the landmarks each one touches, plus one per event) a kernel does per call
#: before it returns to Python: a few tens of milliseconds, so a signal is handled well within a second.
WORK_PER_CALL = 250_000
#: A detection whose innovation (its distance from the map when it arrives) is over this many times the median
#: of the run's is a gross outlier (another landmark's ID, an absurd range); an observer without a gate says so
#: when there are at least ``GROSS_NOTE_COUNT`` of them and ``GROSS_NOTE_SHARE`` of the detections.
GROSS_INNOVATION, GROSS_NOTE_COUNT, GROSS_NOTE_SHARE = 20.0, 5, 0.005
#: A landmark seen again after at least ``RESIGHT_GAP_S`` s out of view tests the map against the trajectory: an
#: observer without a gate says its estimate is likely lost when at least ``RESIGHT_COUNT`` such detections
#: arrived a median over ``RESIGHT_RATIO`` times the median innovation of all detections (consistent runs with
#: 20 or more: 1.3-2.5; fast-adaptation lost on a generated loop, APE 16.9 m: 7.3; on MR.CLAM, APE 2-11 m:
#: 4.0-8.6; docs/benchmarks.md "Lost fast-adaptation notes").
RESIGHT_GAP_S, RESIGHT_COUNT, RESIGHT_RATIO = 10.0, 20, 3.0
#: An observer without a gate whose velocity bias estimate wanders (rms about its median after the first fifth of
#: the run) by over this share of the velocity input's rms took up the motion itself, and is likely lost even where
#: no landmark is seen again. The wander, not the size: a slow vehicle's constant odometry bias, learned right,
#: is a large share of its speed too (docs/benchmarks.md "Silent wrong results, round 6", and the lead's rows).
BIAS_SHARE = 0.3
#: A velocity input whose slow part (its running mean over ``MOTION_MEAN_WINDOW_S`` s: the motion) has no larger an
#: rms than its fast part (the rest: the noise) is a body that does not translate (a rig turning in place, a robot at
#: rest): its rms is then its noise, no scale of a motion the bias could have taken up, so the bias check says nothing
#: (:func:`bias_share`; white noise at 4-200 Hz: slow over fast 0.02-0.4; a round rule, not fitted to a log). Not the
#: report's ``evaluation.sections.STILL_SPAN_S``: that judges a truth pose at rest by its displacement, this splits a
#: velocity input's spectrum.
MOTION_MEAN_WINDOW_S = 2.0
#: The bias check keeps the rows of every how many-th velocity sample (a long run's rows are not held twice).
BIAS_STRIDE = 4
#: A landmark "jumps" (its id reused for another landmark, or the landmark moved) when its detections on one side of
#: a time split, at least ``JUMP_MIN_DETECTIONS`` on each side, arrive a median over ``JUMP_RATIO`` times the run's
#: median innovation from the map and those on the other side under ``JUMP_CALM`` times, while the other landmarks'
#: detections over the first side's span (at least ``JUMP_MIN_DETECTIONS``) stay under ``JUMP_CALM`` times (else the
#: pose, not the landmark, was off: riekf on MR.CLAM 7 r4 as recorded, landmarks 12 and 13 at 28x and 56x over
#: its last seconds, seen alone); and three quarters of the first side over ``JUMP_CALM`` times (riekf's 10 last
#: detections of landmark 12 on 7 r4: 5 calm, then 5 at 57x while every landmark was at 50-80x for 30 s).
#: MR.CLAM 6 r1 with landmark 6's id given to landmark 16 from mid-log (8.7 m away): riekf 159x after the jump,
#: batch 118x before it; as recorded, riekf and batch have no side over 13x with 8 detections or more. Only the
#: estimators with a gate and noise levels (riekf, batch) check it: an observer's innovations, once it is lost,
#: jump too (fast-adaptation on MR.CLAM 6 r1 with its velocity in km/h: landmark 6 22x, then 1.6x).
JUMP_MIN_DETECTIONS, JUMP_RATIO, JUMP_CALM = 10, 20.0, 3.0
#: Candidate splits tried per landmark (evenly over its detections), the best one then refined over the indices
#: between its neighbours (``_best_split``): the check stays linear on long logs and the split exact.
JUMP_SPLITS = 256
#: A jumping landmark seen at its two places in turn (two tags sharing one id, seen alternately: one change point
#: leaves both places on each side). Its detections in time order, each one's log ‖e‖ taken as the median over the
#: ``JUMP_RUN`` around it, are far when over the geometric mean of ``JUMP_RATIO`` and ``JUMP_CALM`` times the run's
#: median; runs of at least half ``JUMP_MIN_DETECTIONS`` far ones other than one stretch at an end of its
#: detections are the other place's visits (:func:`far_spans`), each given the new id.
JUMP_RUN = 9
#: Such a stretch is a jump also where no one change point is (:func:`_best_split` needs three quarters of a side
#: far): a second tag with the id seen once mid-log for 6 s, 86 detections 156x the run's median between 38 and 100
#: near ones (a generated hand-held rig, seed=3653: riekf said it lost the log while 0.06 m off, batch 1.89 m
#: against 0.055 with the true levels, no landmark named; docs/benchmarks.md, "Logs nobody has run yet, round 6"),
#: when the stretches' median is over ``JUMP_RATIO`` times the run's, as a change point's far side must be (TagSLAM
#: test_11's landmark 96, 49 detections at 19x while the pose was off, is not one).
#: A split jump's two landmarks, once the run is made again (:func:`split_places`), are one place when their
#: difference's Mahalanobis distance² under their stated covariances is under this χ² quantile: the split found no
#: second place, and the warning says the jump was more likely the estimate's than an id reused.
SPLIT_SAME_PLACE = 0.95
#: Integer state slots every kernel shares (``KernelState.ns``).
_IV, _JF, _NVIS = 0, 1, 2
_T, _MEAS_T = 0, 1


class ObserverDiverged(BadInput, ValueError):
    """The estimate became non-finite; ``t_ns`` is the time of the velocity sample reached, ``stats`` the
    run's statistics so far."""

    def __init__(self, t_ns: int, stats: dict) -> None:
        super().__init__(f"non-finite state at t_ns={t_ns}")
        self.t_ns = t_ns
        self.stats = stats


@dataclass(frozen=True)
class GainSpec:
    """One gain: any finite value > 0 is valid, ``limit`` (a stability condition coupling it to other gains) may
    bound it from above; ``search`` is where ``slamobs tune`` looks (log-uniform), as a fraction of ``limit`` for
    gains that have one. The range spans the papers', the reference runs' and the default values with room on
    both sides, but stops where the sub-stepped kernels get expensive without a gain in accuracy."""

    name: str
    default: float
    description: str
    search: tuple[float, float] = (0.01, 100.0)
    #: The gain must stay strictly below ``limit(gains)`` (None: only > 0); ``check_gains`` enforces it.
    limit: Callable[[dict[str, float]], float] | None = None


@dataclass(frozen=True)
class ObserverOptions:
    """Run options that are not gains (they never change the observer's law)."""

    max_meas_age: float = 0.5  # seconds a landmark frame stays valid before landmarks count as unseen
    min_landmarks_bias: int = 3  # bias adaptation frozen below this many visible landmarks (docs/observers.md §3.2)
    out_every: int = 1  # record pose/bias every n-th velocity sample
    #: The log the stream came from, named in errors.
    source: str = "<stream>"
    #: The reference estimators' typed settings (the observers ignore them): noise levels resolved for this log
    #: (pipeline.noise.NoiseSettings; None: the defaults), the smoother's section (smoother.settings.BatchSettings;
    #: None: its defaults) and the gains of its seed observer.
    noise: object | None = field(default=None, compare=False)
    batch: object | None = None
    seed_gains: dict | None = None
    #: A known map (:class:`pipeline.known_map.MapStart`): initial landmarks, which are fixed, start pose.
    known_map: object | None = None
    #: Where an estimator that solves the whole log at once (batch) says what it is doing while it works (the run's
    #: progress line); streaming observers report by their stretches instead.
    progress: Callable[[str], None] | None = field(default=None, compare=False, repr=False)
    #: The time offset's decision already made on this very stream (:func:`.time_offset.decide`'s record), which an
    #: observer then starts on instead of deciding again (tune's trials, many on one prepared log); None: decided
    #: at the start. The reference estimators decide their own (``ObserverSpec.own_time_offset``) and ignore it.
    time_offset: dict | None = field(default=None, compare=False, repr=False)


@dataclass
class ObserverResult:
    """Histories and final map of one run, as arrays (the writers turn them into tables)."""

    t_ns: np.ndarray  # (K,)
    rotation: np.ndarray  # (K, 3, 3) body -> map
    position: np.ndarray  # (K, 3)
    gyro_bias: np.ndarray  # (K, 3)
    vel_bias: np.ndarray  # (K, 3)
    landmark_ids: np.ndarray  # (L,)
    landmark_xyz: np.ndarray  # (L, 3) final map
    det_t_ns: np.ndarray  # (M,) per detection
    det_ids: np.ndarray  # (M,)
    track_xyz: np.ndarray  # (M, 3) landmark estimate at the detection time
    innovation: np.ndarray  # (M, 3) e_i at the detection time
    stats: dict = field(default_factory=dict)
    #: Wall and CPU seconds of an estimator's own stages so far (batch: seed_s, smoother_s, smoother_cpu_s);
    #: measurements, unlike ``stats``, which a run reproduces exactly.
    timings: dict = field(default_factory=dict)
    #: Observer-specific tables (e.g. "jumps"), columns named as in ``schemas/<name>.json``.
    extra_tables: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    #: Observers whose law turns the whole estimate (C, E) write everything in their map frame; this is its
    #: pose in their working (inertial) frame: ``rotation``/``translation`` now and ``mean_rotation`` (see
    #: :meth:`KernelState.frame_mean`), ``estimated_s`` seconds of estimation. None for the others.
    map_frame: dict | None = None
    #: The reference estimators' uncertainty (None for the observers): per row the 6×6 covariance of the pose
    #: error ``(δθ, δp)`` with ``R̂ = Exp(δθ) R``, ``p̂ = p + δp``, both in the map frame (docs/outputs.md), and
    #: per landmark (``landmark_ids`` order) the 3×3 covariance of its position in the map frame.
    pose_cov: np.ndarray | None = None
    landmark_cov: np.ndarray | None = None
    #: Per detection its squared distance from the map under the estimator's own noise model (batch: its residual
    #: whitened by the covariance its solve weighs the detection with, the χ² its gate reads), or None: the
    #: estimators without one, whose jump check judges ‖e‖ in metres (:class:`InnovationRecord`).
    innovation_d2: np.ndarray | None = None


def max_per_frame(det_offsets: np.ndarray) -> int:
    """Most detections in one frame (0 without frames)."""
    return int(np.diff(det_offsets).max()) if det_offsets.shape[0] > 1 else 0


def output_rows(n_vel: int, out_every: int, first: int, stop: int) -> int:
    """Recorded rows among velocity samples ``first .. stop - 1`` (every ``out_every``-th, and the last)."""
    if stop <= first:
        return 0
    n = (stop + out_every - 1) // out_every - (first + out_every - 1) // out_every
    last = n_vel - 1
    return n + int(first <= last < stop and last % out_every != 0)


@dataclass
class Outputs:
    """Preallocated output rows of one stretch; kernels fill them (detection rows from ``det_base`` on)."""

    k: np.ndarray  # (K,) int64 velocity-sample index of each row
    r: np.ndarray  # (K, 3, 3)
    p: np.ndarray  # (K, 3)
    b: np.ndarray  # (K, 6) [b_Ω, b_V]
    trk: np.ndarray  # (M, 3)
    innov: np.ndarray  # (M, 3)
    det_base: int
    #: (K, 6, 6) pose covariance per row (``ObserverResult.pose_cov``) for estimators that keep one, else None
    cov: np.ndarray | None = None

    @classmethod
    def empty(cls, rows: int, det_first: int, det_stop: int, with_cov: bool = False) -> Outputs:
        m = det_stop - det_first
        return cls(
            np.empty(rows, np.int64),
            np.empty((rows, 3, 3)),
            np.empty((rows, 3)),
            np.empty((rows, 6)),
            np.empty((m, 3)),
            np.empty((m, 3)),
            det_first,
            np.empty((rows, 6, 6)) if with_cov else None,
        )

    @classmethod
    def whole_log(cls, n_vel: int, out_every: int, n_det: int) -> Outputs:
        """The outputs of one pass over a whole log (``run_kernel``): every recorded row of ``n_vel`` velocity
        samples, ``n_det`` detection rows from 0 on."""
        return cls.empty(output_rows(n_vel, out_every, 0, n_vel), 0, n_det)

    def arrays(self) -> tuple:
        """``(k, r, p, b, trk, innov, det_base)``: the outputs as every observer's event loop takes them, after
        its state (``KernelState.arrays``)."""
        return self.k, self.r, self.p, self.b, self.trk, self.innov, self.det_base

    def recorded(self, o: int) -> tuple:
        """``(k, r, p, b, trk, innov)`` of the first ``o`` rows: what ``run_kernel`` returns before its counts."""
        return self.k[:o], self.r[:o], self.p[:o], self.b[:o], self.trk, self.innov

    def rows_from(self, o: int) -> Outputs:
        """The same outputs from row ``o`` on (views; detection rows keep their places)."""
        cov = None if self.cov is None else self.cov[o:]
        return Outputs(self.k[o:], self.r[o:], self.p[o:], self.b[o:], self.trk, self.innov, self.det_base, cov)


class KernelState:
    """The state every landmark observer's kernel keeps between stretches, as arrays it updates in place:
    estimate (R̂, P̂, b̂_Ω, b̂_V), the visible measurements, the held twist, a sub-step counter, float clocks
    ``fs`` (``[t, meas_t, ...]``), integer counters ``ns`` (``[iv, jf, nvis, started, substeps]``, then the
    sub-step cap count and the first capped sample, see ``shared_steps.count_capped``) and the map frame
    ``(f_r, f_p)``. Observers add their own arrays and order them for their kernel."""

    def __init__(
        self, n_max: int, r0: np.ndarray, p0: np.ndarray, b_om0: np.ndarray, b_v0: np.ndarray, n_clocks: int = 2
    ) -> None:
        self.r_hat = np.array(r0, dtype=np.float64)
        self.p_hat = np.array(p0, dtype=np.float64)
        self.b_om = np.array(b_om0, dtype=np.float64)
        self.b_v = np.array(b_v0, dtype=np.float64)
        self.y = np.zeros((max(n_max, 1), 3))
        self.vis_idx = np.zeros(max(n_max, 1), dtype=np.int64)
        self.om_m = np.zeros(3)
        self.v_m = np.zeros(3)
        self.counter = np.zeros(1, dtype=np.int64)
        self.fs = np.zeros(n_clocks)
        self.fs[1] = -np.inf  # time of the last frame: none yet
        self.ns = np.zeros(7, dtype=np.int64)
        self.ns[CAP_IV] = -1
        # map frame -> working frame (x_work = f_r x_map + f_p): moved only by laws that turn the whole
        # estimate (shared_steps.turn_frame); the identity for the others
        self.f_r = np.eye(3)
        self.f_p = np.zeros(3)
        # its orientation summed over the velocity samples once it has settled (``shared_steps.frame_sample``)
        self.f_sum = np.zeros((3, 3))
        self.f_stat = np.zeros(2)  # [seconds the frame has been estimated, samples summed]

    def restart(self, t: float) -> None:
        """Start a new segment at time ``t``: no integration up to it, no landmark visible until the next frame."""
        self.fs[_T] = t
        self.fs[_MEAS_T] = -np.inf
        self.ns[_NVIS] = 0

    def frame_mean(self) -> np.ndarray:
        """Mean orientation of the map frame in the working frame over the samples summed so far (chordal
        mean, projected onto SO(3)); the current one before any is summed."""
        from slamobs.pipeline.lie import nearest_rotation

        return nearest_rotation(self.f_sum) if self.f_stat[1] > 0 else self.f_r.copy()


def gross_note(norms: np.ndarray) -> list[str]:
    """A note when many detections arrived over ``GROSS_INNOVATION`` times the median innovation from the map
    (``norms``: every detection's ‖e‖) and went into an observer that has no gate for them (on a generated log
    with 1.5 % wrong IDs: 47 of 1786; on the clean one and the sample logs: none)."""
    norms = norms[np.isfinite(norms) & (norms > 0.0)]
    if norms.size == 0:
        return []
    median = float(np.median(norms))
    gross = int(np.count_nonzero(norms > GROSS_INNOVATION * median))
    if gross < max(GROSS_NOTE_COUNT, GROSS_NOTE_SHARE * norms.size):
        return []
    return [
        f"{gross} of {norms.size} detections ({100.0 * gross / norms.size:.1f} %) arrived over "
        f"{GROSS_INNOVATION:g}x the median distance from the map ({median:.3g} m): mis-identified landmarks, absurd "
        "ranges or a pose this observer had lost; it has no gate for them (they pull the pose and map), riekf and "
        "batch reject such detections"
    ]


def resightings(det_idx: np.ndarray, det_t: np.ndarray) -> np.ndarray:
    """Which detections see their landmark again after ``RESIGHT_GAP_S`` s or more out of view."""
    order = id_time_order(det_idx, det_t)
    t, idx = det_t[order], det_idx[order]
    back_sorted = np.zeros(t.shape[0], dtype=np.bool_)
    same = idx[1:] == idx[:-1]
    back_sorted[1:] = same & (np.diff(t) >= RESIGHT_GAP_S)
    back = np.empty_like(back_sorted)
    back[order] = back_sorted
    return back


def resighting_check(norms: np.ndarray, back: np.ndarray) -> dict:
    """run.json's record of the map-against-trajectory check: detections of landmarks seen again (``back``:
    :func:`resightings`) and the median of their innovation ‖e‖ (``norms``) over that of all detections, gross
    outliers (:func:`gross_note`'s) left out of both; ``ratio`` None when there are none."""
    ok = np.isfinite(norms) & (norms > 0.0)
    if not ok.any():
        return {"detections": 0, "median_m": None, "ratio": None}
    ok &= norms <= GROSS_INNOVATION * float(np.median(norms[ok]))
    back = back & ok
    n_back = int(np.count_nonzero(back))
    median = float(np.median(norms[ok]))
    back_median = float(np.median(norms[back])) if n_back else None
    return {
        "detections": n_back,
        "median_m": back_median,
        "ratio": back_median / median if n_back and median > 0.0 else None,
        "usual_m": median,
    }


def running_mean(t_ns: np.ndarray, x: np.ndarray, window_s: float) -> np.ndarray:
    """The mean of the rows of ``x`` (N, d) whose stamps ``t_ns`` (N, sorted) lie within ``window_s`` / 2 of each."""
    half = int(round(window_s * 5e8))
    lo = np.searchsorted(t_ns, t_ns - half, side="left")
    hi = np.searchsorted(t_ns, t_ns + half, side="right")
    csum = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x, axis=0)])
    return (csum[hi] - csum[lo]) / (hi - lo)[:, None]


#: A body stands still (:func:`still_mask`) through a stretch where neither stream's running mean over
#: ``MOTION_MEAN_WINDOW_S`` s changes, the windows just before and after each sample differing by no more than
#: ``STILL_CHI2`` (χ²(3) at 0.999) under their own noise (the densities over the window), when the velocity's running
#: mean is within ``STILL_CHI2`` of zero at one of its samples at least: no change of motion a stream's white noise
#: would not explain, and no translation (a round rule, not fitted to a log; docs/benchmarks.md "A robot at rest
#: with one landmark in view, session 36" and "riekf's bias readings at rest, without batch's, session 37").
STILL_CHI2 = 16.27


def still_mask(t_ns: np.ndarray, omega: np.ndarray, velocity: np.ndarray, q_om, q_v, held=()) -> np.ndarray:
    """Which of the velocity samples (stamps ``t_ns``, (N,) sorted; ``omega`` and ``velocity`` (N, 3) there) the
    body stands still at (``STILL_CHI2``), from the densities' variances ``q_om`` and ``q_v`` (3 each, per s).
    The whole steady stretch, not only its samples whose velocity mean is near zero: at rest the velocity reads its
    bias, and samples kept for their own mean near zero would read that bias pulled towards zero (a hand-held rig's
    0.05 m/s by a third, seed=3963). None when a stream is held (``noise.held``: commands, MR.CLAM's): a command of
    zero reads no bias, its error is the motion's (a scale, slip), which an additive bias stands in for only while
    the body moves."""
    n = t_ns.shape[0]
    if n < 3 or held:
        return np.zeros(n, dtype=bool)
    w = MOTION_MEAN_WINDOW_S
    q_v, q_om = np.asarray(q_v, dtype=np.float64), np.asarray(q_om, dtype=np.float64)
    slow = running_mean(t_ns, np.asarray(velocity, dtype=np.float64), w)
    om = running_mean(t_ns, np.asarray(omega, dtype=np.float64), w)
    half = int(round(w * 5e8))
    before = np.clip(np.searchsorted(t_ns, t_ns - half), 0, n - 1)
    after = np.clip(np.searchsorted(t_ns, t_ns + half, side="right") - 1, 0, n - 1)
    d2w = np.sum((om[after] - om[before]) ** 2 / (2.0 * q_om / w), axis=1)
    d2dv = np.sum((slow[after] - slow[before]) ** 2 / (2.0 * q_v / w), axis=1)
    steady = (d2w < STILL_CHI2) & (d2dv < STILL_CHI2)  # NaN compares false
    near_zero = np.sum(slow**2 / (q_v / w), axis=1) < STILL_CHI2
    stretch = np.cumsum(steady & ~np.concatenate([[False], steady[:-1]]))  # each steady stretch's number, from 1
    entered = np.bincount(stretch[steady & near_zero], minlength=int(stretch[-1]) + 1) > 0
    return steady & entered[stretch]


def bias_share(k: np.ndarray, bias: np.ndarray, velocity: np.ndarray, t_ns: np.ndarray | None = None) -> dict:
    """run.json's record of the velocity bias check: the velocity bias estimate's rms over the rows kept (``bias``
    (M, 3) at velocity samples ``k``), its ``wander_m_s`` (rms about its median over the rows after the first fifth
    of the velocity samples, when the estimate has settled) and that wander's share of the velocity input's rms
    (``velocity``: (N, 3) at stamps ``t_ns``). With the stamps, a share over ``BIAS_SHARE`` is None when the body
    does not translate: the rms of the velocity's running mean over ``MOTION_MEAN_WINDOW_S`` s (``motion_rms_m_s``) no
    larger than that of the rest (``velocity_noise_m_s``), which is then all the velocity's rms measures (the two
    are computed only there: the hour's velocity samples take ~0.1 s)."""

    def rms(rows: np.ndarray) -> float:
        return float(np.sqrt(np.mean(row_squares3(rows)))) if rows.size else 0.0

    settled = bias[k >= velocity.shape[0] // 5]
    settled = settled if settled.size else bias
    b, v = rms(bias), rms(velocity)
    wander = rms(settled - np.median(settled, axis=0)) if settled.size else 0.0
    out = {"rms_m_s": b, "wander_m_s": wander, "velocity_rms_m_s": v}
    moves = v > 0.0
    if moves and wander > BIAS_SHARE * v and t_ns is not None and velocity.shape[0] > 1:  # only a verdict's runs
        slow = running_mean(np.asarray(t_ns), np.asarray(velocity, dtype=np.float64), MOTION_MEAN_WINDOW_S)
        out |= {"motion_rms_m_s": rms(slow), "velocity_noise_m_s": rms(velocity - slow)}
        moves = moves and out["motion_rms_m_s"] > out["velocity_noise_m_s"]
    return out | {"share": wander / v if moves else None}


def bias_held(bias: np.ndarray, det_offsets: np.ndarray, min_landmarks: int) -> dict | None:
    """run.json's record of biases that never moved: None when the bias rows kept (``bias``: (M, 6), gyro then
    velocity) change anywhere, else their ``start`` value, the most landmarks any detection frame holds
    (``det_offsets``: the frames' offsets into the detections), ``max_landmarks_per_frame``, and the observer's
    ``min_landmarks_bias`` (it adapts its biases only while that many are in view: docs/observers.md §3.2)."""
    if bias.shape[0] == 0 or np.any(bias != bias[:1]):
        return None
    per_frame = np.diff(det_offsets)
    return {
        "start": [float(v) for v in bias[0]],
        "max_landmarks_per_frame": int(per_frame.max()) if per_frame.size else 0,
        "min_landmarks_bias": int(min_landmarks),
    }


def held_bias_note(name: str, held: dict | None) -> list[str]:
    """Estimator ``name``'s note when its bias estimates stayed at their start value (``held``: :func:`bias_held`):
    the bias rows of biases.parquet and of the report are then that value, not an estimate, which the report's
    bias table alone does not say (TagSLAM test 22: two tags, fast-adaptation's biases [0, 0, 0] throughout)."""
    if not held:
        return []
    gyro, vel = (", ".join(f"{v:.3g}" for v in held["start"][a : a + 3]) for a in (0, 3))
    most, need = held["max_landmarks_per_frame"], held["min_landmarks_bias"]
    why = (
        f"it adapts them only while {need} or more landmarks are in view (min_landmarks_bias), and no detection "
        f"frame of this log holds more than {most}"
        if most < need
        else "with the gains it ran on they never moved"
    )
    return [
        f"{name}: its gyro and velocity bias estimates stayed at their start value, gyro [{gyro}] rad/s and "
        f"velocity [{vel}] m/s, for the whole run: "
        f"{why}; the biases in biases.parquet and in the report are that start value, not an estimate of the "
        "log's biases (riekf and batch estimate them from every detection)"
    ]


def lost_evidence(check: dict | None, bias: dict | None = None) -> tuple[str, str] | None:
    """Which check of an observer without a gate says its estimate is likely lost, and what it says: at least
    ``RESIGHT_COUNT`` landmarks seen again arrived over ``RESIGHT_RATIO`` times the usual distance from the map
    (``check``: :func:`resighting_check`; ``resightings``): the map and the trajectory disagree, which the median
    innovation cannot show when the pose was lost all along (the map follows it). Else its velocity bias estimate
    wanders by over ``BIAS_SHARE`` of the velocity's rms (``bias``: :func:`bias_share`; ``velocity_bias``), which
    needs no landmark seen again. None when neither does. The run's warning (:func:`lost_note`) and the report's
    ``convergence.own_status`` (:func:`.evaluation.report.own_status`) and a tune's trial (its ``likely_lost``) all
    say these words."""
    if check and check["detections"] >= RESIGHT_COUNT and check["ratio"] is not None and check["ratio"] > RESIGHT_RATIO:
        return "resightings", (
            f"landmarks seen again after {RESIGHT_GAP_S:g} s or more out of view ({check['detections']} detections) "
            f"arrived a median {check['median_m']:.3g} m from its map, {check['ratio']:.1f}x its usual "
            f"{check['usual_m']:.3g} m, so its trajectory and map disagree"
        )
    if bias and bias["share"] is not None and bias["share"] > BIAS_SHARE:
        return "velocity_bias", (
            f"its velocity bias estimate wanders by {bias['share']:.2f}x the velocity's rms ({bias['wander_m_s']:.3g} "
            f"m/s rms about its median against {bias['velocity_rms_m_s']:.3g} m/s): it took up the motion itself (an "
            "odometry's bias drifts slowly), and its trajectory and map follow it"
        )
    return None


def lost_note(name: str, check: dict | None, bias: dict | None = None) -> list[str]:
    """Estimator ``name``'s warning when :func:`lost_evidence` says its estimate is likely lost, else none."""
    advice = "do not trust it without truth: run riekf or batch (`slamobs compare`), or tune its gains (`slamobs tune`)"
    found = lost_evidence(check, bias)
    return [] if found is None else [f"warning: {name}: its estimate is likely lost: {found[1]}; {advice}"]


class InnovationRecord:
    """Every detection's time, landmark id and distance from the map as the stretches of a run come (for
    :func:`landmark_jumps` once the run is done): ``√d²`` under the estimator's own noise model where it has one
    (``ObserverResult.innovation_d2``: batch; in metres its residuals named the shipped camera log's landmark 27,
    first seen 10-11 m away, a jump), else the innovation ‖e‖ in metres (riekf)."""

    def __init__(self) -> None:
        self._parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def add(self, result: ObserverResult) -> None:
        """The detections of one stretch (``result``'s ``det_t_ns``, ``det_ids``, ``innovation_d2`` or
        ``innovation``)."""
        if result.innovation_d2 is not None:
            norms = np.sqrt(np.asarray(result.innovation_d2, float))
        else:
            norms = np.linalg.norm(result.innovation, axis=1)
        self._parts.append((np.asarray(result.det_t_ns), np.asarray(result.det_ids), norms))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Times (ns), ids and innovation norms of all detections so far."""
        if not self._parts:
            return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0)
        return tuple(np.concatenate(c) for c in zip(*self._parts, strict=True))


def split_candidates(n: int) -> np.ndarray:
    """The indices :func:`landmark_jumps` tries as the change point of a landmark with ``n`` detections: at most
    ``JUMP_SPLITS``, ``JUMP_MIN_DETECTIONS`` from either end (past ``JUMP_SPLITS`` detections not every index: the
    best is refined between its neighbours)."""
    return np.unique(np.linspace(JUMP_MIN_DETECTIONS, n - JUMP_MIN_DETECTIONS, JUMP_SPLITS).astype(np.int64))


def _split_cost(e: np.ndarray, log_e: np.ndarray, k: int, median: float) -> tuple | None:
    """The cost of splitting a landmark's innovations ``e`` (time order, ``log_e`` their logs) before index ``k``
    and the median ratio of each side, (cost, ratio before, ratio after); None when the split is no jump (one side
    over ``JUMP_RATIO`` and the other under ``JUMP_CALM`` times ``median``, three quarters of the first over
    ``JUMP_CALM`` times)."""
    a, b = float(np.median(e[:k])) / median, float(np.median(e[k:])) / median
    if max(a, b) <= JUMP_RATIO or min(a, b) >= JUMP_CALM:
        return None
    if np.quantile(e[:k] if a > b else e[k:], 0.25) < JUMP_CALM * median:
        return None  # a quarter of the far side or more is calm: a burst (the pose lost a while), no jump
    lo, hi = log_e[:k], log_e[k:]
    return float(np.abs(lo - np.median(lo)).sum() + np.abs(hi - np.median(hi)).sum()), a, b


def _best_split(e: np.ndarray, median: float) -> tuple | None:
    """A landmark's change point (index, ratio before, ratio after), ``e`` its innovations in time order: the split
    of least absolute deviation of log ‖e‖ from each side's median among those :func:`_split_cost` takes; None
    when no split is. The best of :func:`split_candidates` is then refined over every index between its two
    neighbouring candidates, so the split is exact on a landmark seen more often than the candidates are many (the
    cost of a step falls towards its change point from either side: the true one lies between those neighbours)."""
    log_e, tried = np.log(e), split_candidates(e.shape[0])
    best, best_i = (np.inf,), -1
    for i, k in enumerate(tried):
        c = _split_cost(e, log_e, int(k), median)
        if c is not None and c[0] < best[0]:
            best, best_i, best_k = c, i, int(k)
    if best_i < 0:
        return None
    lo = int(tried[best_i - 1]) + 1 if best_i > 0 else best_k
    hi = int(tried[best_i + 1]) if best_i + 1 < tried.shape[0] else best_k + 1
    for k in range(lo, hi):
        c = _split_cost(e, log_e, k, median) if k != best_k else None
        if c is not None and c[0] < best[0]:
            best, best_k = c, k
    return best_k, best[1], best[2]


def far_spans(t_ns: np.ndarray, e: np.ndarray, median: float) -> list[list[int]]:
    """The first and last time (ns) of each stretch of a landmark's detections (``t_ns`` in time order, ``e`` their
    innovation norms) that sits far from its map place (``JUMP_RUN``); empty when they are one stretch at an end
    (one change point, as :func:`landmark_jumps` splits it)."""
    h = JUMP_RUN // 2
    if e.shape[0] < JUMP_RUN:
        return []
    windows = np.lib.stride_tricks.sliding_window_view(np.pad(np.log(e), h, mode="edge"), JUMP_RUN)
    far = np.median(windows, axis=1) > np.log(median) + 0.5 * np.log(JUMP_RATIO * JUMP_CALM)
    edges = np.flatnonzero(far[1:] != far[:-1]) + 1
    runs = [
        (int(a), int(b))
        for a, b in zip(np.r_[0, edges], np.r_[edges, far.shape[0]], strict=True)
        if far[a] and b - a >= JUMP_MIN_DETECTIONS // 2
    ]
    if len(runs) == 1 and (runs[0][0] == 0 or runs[0][1] == far.shape[0]):
        return []
    return [[int(t_ns[a]), int(t_ns[b - 1])] for a, b in runs]


def landmark_jumps(t_ns: np.ndarray, ids: np.ndarray, norms: np.ndarray) -> list[dict]:
    """The landmarks whose detections jump (``JUMP_RATIO``, ``JUMP_CALM``, ``JUMP_MIN_DETECTIONS``): their id,
    the time of the first detection after the split (ns), the detections and median innovation ratio of each side.
    Innovations of exactly zero (a landmark's first sighting) are left out."""
    ok = np.isfinite(norms) & (norms > 0.0)
    if np.count_nonzero(ok) < 2 * JUMP_MIN_DETECTIONS:
        return []
    t_ns, ids, norms = t_ns[ok], ids[ok], norms[ok]
    median = float(np.median(norms))
    # A far side's median over JUMP_RATIO times needs half its JUMP_MIN_DETECTIONS or more that far: only landmarks
    # with that many are searched (the split search on every landmark cost 2.3 CPU s on the one-hour log)
    lids, inverse = np.unique(ids, return_inverse=True)
    far = np.bincount(inverse, weights=norms > JUMP_RATIO * median, minlength=lids.shape[0])
    seen = np.bincount(inverse, minlength=lids.shape[0])
    out = []
    for lid in lids[(far >= JUMP_MIN_DETECTIONS // 2) & (seen >= 2 * JUMP_MIN_DETECTIONS)]:
        mine = np.flatnonzero(ids == lid)
        order = mine[np.argsort(t_ns[mine], kind="stable")]
        spans = far_spans(t_ns[order], norms[order], median)  # seen at its two places in turn
        at = np.zeros(order.shape[0], bool)
        for a, b in spans:
            at |= (t_ns[order] >= a) & (t_ns[order] <= b)
        split = _best_split(norms[order], median)
        if split is not None:
            k, before, after = split
            bad = order[:k] if before > after else order[k:]
        elif spans and float(np.median(norms[order[at]])) > JUMP_RATIO * median:  # no one change point: far
            k = int(np.argmax(at))  # stretches amid near ones, as far as a jump's far side (the comment on JUMP_RUN)
            before, after = (float(np.median(norms[part])) / median for part in (order[:k], order[k:]))
            bad = order[at]
        else:
            continue
        bad = bad[norms[bad] > JUMP_RATIO * median]  # its far detections: the span over which the others must be calm
        during = (t_ns >= t_ns[bad].min()) & (t_ns <= t_ns[bad].max()) & (ids != lid)
        if np.count_nonzero(during) < JUMP_MIN_DETECTIONS or float(np.median(norms[during])) / median >= JUMP_CALM:
            continue  # the others were off then too, or not seen enough to tell: the pose, not this landmark
        jump = {
            "id": int(lid),
            "t_ns": int(t_ns[order[k]]),
            "before": [k, before],
            "after": [order.shape[0] - k, after],
        }
        if spans:
            jump["far_spans"] = spans
            jump["far"] = [int(at.sum()), float(np.median(norms[order][at])) / median]
            jump["near"] = [int((~at).sum()), float(np.median(norms[order][~at])) / median]
        out.append(jump)
    return out


def split_jumps(aligned: AlignedStream, jumps: list[dict], taken: np.ndarray) -> AlignedStream:
    """``aligned`` with the detections of each jumping landmark (:func:`landmark_jumps`) from its jump on given an
    id of their own, the next free one above ``taken`` and the stream's ids (set as each jump's ``new_id``): a
    landmark after it, not the same place. ``aligned`` is left as it was (compare runs others on it)."""
    t_det = np.repeat(aligned.det_t_ns, np.diff(aligned.det_offsets))
    ids = aligned.det_ids.copy()
    next_id = int(max(aligned.landmark_ids.max(initial=0), np.max(taken, initial=0))) + 1
    for j in jumps:
        j["new_id"] = next_id
        later = t_det >= j["t_ns"]
        if "far_spans" in j:  # seen at its two places in turn: the far stretches, each whole
            later = np.zeros(t_det.shape[0], bool)
            for a, b in j["far_spans"]:
                later |= (t_det >= a) & (t_det <= b)
        ids[(aligned.det_ids == j["id"]) & later] = next_id
        next_id += 1
    return relabelled(aligned, ids)


def split_places(jumps: list[dict], ids: np.ndarray, xyz: np.ndarray, cov: np.ndarray | None) -> None:
    """Each split jump (a ``new_id``, :func:`split_jumps`) given where the run made again put its two landmarks,
    ``ids`` / ``xyz`` / ``cov`` its map (``cov`` per landmark 3×3, or None): ``apart_m``, their distance, and with a
    covariance ``apart_d2``, the Mahalanobis distance² of their difference under the sum of the two covariances (the
    correlation of the two estimates left out, so an upper bound of the difference's spread), its ``apart_dof``
    (the sum's rank: 2 on a planar map) and ``one_place``: ``apart_d2`` under the χ² quantile ``SPLIT_SAME_PLACE``.
    A reused id gives two places apart; two estimates within their stated σ say the jump was no second place (the
    pose, or the landmark's first place, off while those detections came: TagSLAM test_11's landmark 24, its 75
    far detections split off as landmark 521, whose estimate came out 0.06 m from 24's at σ 0.29 m)."""
    row = {int(i): k for k, i in enumerate(np.asarray(ids).tolist())}
    for j in jumps:
        if "new_id" not in j or j["id"] not in row or j["new_id"] not in row:
            continue
        a, b = row[j["id"]], row[j["new_id"]]
        d = np.asarray(xyz[b], float) - np.asarray(xyz[a], float)
        j["apart_m"] = float(np.linalg.norm(d))
        if cov is None:
            continue
        s = np.asarray(cov[a], float) + np.asarray(cov[b], float)
        if not np.all(np.isfinite(s)) or not np.all(np.isfinite(d)):
            continue
        dof = int(np.linalg.matrix_rank(s, hermitian=True))
        if dof == 0:
            continue
        j["apart_d2"] = float(d @ np.linalg.pinv(s, hermitian=True) @ d)
        j["apart_dof"] = dof
        j["one_place"] = bool(j["apart_d2"] <= chi2_quantile(SPLIT_SAME_PLACE, dof))


def _apart_words(j: dict) -> str:
    """Where the run made again put a split jump's two landmarks (:func:`split_places`), or nothing."""
    if "apart_m" not in j:
        return ""
    if "apart_d2" not in j:
        return f"; made again, the two {j['apart_m']:.3g} m apart"
    bound = chi2_quantile(SPLIT_SAME_PLACE, j["apart_dof"])
    return (
        f"; made again, the two {j['apart_m']:.3g} m apart, Mahalanobis distance² {j['apart_d2']:.3g} under their "
        f"stated covariances, {'within' if j['one_place'] else 'over'} {bound:.3g}, the χ² {SPLIT_SAME_PLACE:g} "
        f"quantile of {j['apart_dof']} DoF"
    )


def _jump_words(j: dict, t0_ns: int) -> str:
    """One jump of :func:`jump_note`: where it is, the detections on either side (or, seen at two places in turn,
    the far stretches), and the new id."""
    new = f"; {'those' if 'far_spans' in j else 'from then on'} landmark {j['new_id']}" if "new_id" in j else ""
    if "far_spans" in j:
        spans = ", ".join(f"{(a - t0_ns) / 1e9:.1f}-{(b - t0_ns) / 1e9:.1f} s" for a, b in j["far_spans"][:4])
        more = f" and {len(j['far_spans']) - 4} more" if len(j["far_spans"]) > 4 else ""
        return (
            f"{j['id']} seen at two places in turn ({j['far'][0]} detections in {len(j['far_spans'])} stretches, "
            f"{spans}{more}, a median {j['far'][1]:.3g}x the run's usual distance from the map, {j['near'][0]} "
            f"between them {j['near'][1]:.3g}x{new}{_apart_words(j)})"
        )
    return (
        f"{j['id']} at {(j['t_ns'] - t0_ns) / 1e9:.1f} s ({j['before'][0]} detections before it a median "
        f"{j['before'][1]:.3g}x the run's usual distance from the map, {j['after'][0]} after it {j['after'][1]:.3g}x"
        f"{new}{_apart_words(j)})"
    )


#: How every landmark-jump warning of estimator ``name`` begins (:func:`jump_note`), so a table of runs finds them in
#: a run's notes (:func:`jump_warnings`).
JUMP_WARNING = "warning: {name}: landmark "


def jump_warnings(name: str, notes: list[str]) -> list[str]:
    """Estimator ``name``'s landmark-jump warnings (:func:`jump_note`'s words) among a run's ``notes`` (run.json
    ``notes``), each from its ``landmark``: ``compare`` repeats them under its table after the estimator's name, as
    the run's report.md has them."""
    start = JUMP_WARNING.format(name=name)
    return [n.removeprefix(f"warning: {name}: ") for n in notes if n.startswith(start)]


def jump_note(
    name: str, jumps: list[dict], t0_ns: int, lost: bool = False, topics: Mapping[str, str] | None = None
) -> list[str]:
    """Estimator ``name``'s warning naming the landmarks that jump (:func:`landmark_jumps`) and the detection topic
    (``topics``: the aligned stream's, :func:`.alignment.stream_topics`); those split by :func:`split_jumps` (a
    ``new_id``) say which id their later detections got. ``lost``: the run's own checks named a misread input first
    (``time_offset.misread``), so the jumps are likely its pose's and were not split."""
    if not jumps:
        return []
    said = "; ".join(_jump_words(j, t0_ns) for j in jumps) + stream_topics(topics or {}, "detections")
    if lost:
        return [
            JUMP_WARNING.format(name=name) + f"{said}: jumps that follow a misread input the detections named (the "
            "warnings above: the gyro, the camera extrinsic or the velocity), so more likely the estimate's pose lost "
            "than a landmark id reused; the run was not made again with them split: fix that input first"
        ]
    if all("new_id" in j for j in jumps) and any(j.get("one_place") for j in jumps):
        apart = [j for j in jumps if not j.get("one_place")]
        same = [j for j in jumps if j.get("one_place")]
        return jump_note(name, apart, t0_ns, topics=topics) + [
            JUMP_WARNING.format(name=name) + f"{'; '.join(_jump_words(j, t0_ns) for j in same)}"
            f"{stream_topics(topics or {}, 'detections')}: the run made again with the detections after the jump as a "
            "landmark of their own put it where the first one is, within their stated σ: one place after all, so the "
            "jump was more likely the estimate's (its pose, or that landmark's first place, off while those "
            "detections came) than an id reused or a landmark moved; the results are those of the run made again "
            "(the new id in landmarks.parquet, no truth for it): give the detections an id of their own only if the "
            "log's landmarks say so"
        ]
    if all("new_id" in j for j in jumps):
        return [
            JUMP_WARNING.format(name=name)
            + f"{said}: a landmark id reused for another landmark (a tag printed again, a "
            "barcode reassigned) or a landmark moved; the run was made again with the detections after the jump "
            "as a landmark of their own (the new id in landmarks.parquet, no truth for it): give them an id of "
            "their own in the log"
        ]
    return [
        JUMP_WARNING.format(name=name) + f"{said}: a landmark id reused for another landmark (a tag printed again, a "
        "barcode reassigned) or a landmark moved; the estimate took them as one place, so its map and the poses "
        "near those detections are off: give the detections after the jump an id of their own"
    ]


def bridge_events(stream: AlignedStream) -> np.ndarray:
    """(E, 2) int64 rows (velocity sample, kind) in order: each bridged gap's first sample inside it (kind 0),
    the last sample before each detection frame inside it (1) and its first sample after it (2)."""
    t, d = stream.vel_t_ns, stream.det_t_ns
    rows = []
    for a, b in stream.bridged_gaps:
        i0, i1 = int(np.searchsorted(t, a, "right")), int(np.searchsorted(t, b, "left"))
        frames = d[(d > a) & (d < b)]
        inside = np.unique(np.clip(np.searchsorted(t, frames, "right") - 1, i0, i1))
        rows += [(i0, 0)] + [(int(k), 1) for k in inside if k < i1] + [(i1, 2)]
    return np.array(rows, dtype=np.int64).reshape(-1, 2)


class Stepper:
    """One run of an observer's kernel over an aligned stream, advanced a stretch of samples at a time.

    Subclasses hold the kernel's state arrays in ``state`` (a :class:`KernelState`) and implement
    :meth:`_kernel` (run until the next event is velocity sample ``iv_stop``, frames before it included, or
    until ``budget`` work units are spent) and optionally :meth:`_extra`.
    """

    state: KernelState
    #: Whether the kernel fills ``Outputs.cov`` (the reference estimators' pose covariance).
    keeps_covariance = False
    #: Whether the kernel rejects detections that do not fit (riekf's gate); one that does not gets a note when
    #: gross outliers went in (:func:`gross_note`).
    gates_detections = False
    #: Whether the caller makes the whole run's checks itself (:meth:`end_checks`; ``ObserverSpec.chunks``) instead
    #: of :meth:`advance` with the last stretch.
    end_checks_later = False
    #: The time offset's record and notes when it was decided before the start (``ObserverSpec._started``), which
    #: :meth:`end_checks` adds to the run's metadata and notes.
    time_offset_said: tuple[dict, list[str]] | None = None

    def __init__(self, stream: AlignedStream, options: ObserverOptions) -> None:
        self.stream, self.options = stream, options
        self.vel_t = stream.seconds(stream.vel_t_ns)
        self.det_t = stream.seconds(stream.det_t_ns)
        n = stream.landmark_ids.shape[0]
        self.lm = np.zeros((n, 3))  # the map, updated in place by the kernel
        self.lm_init = np.zeros(n, dtype=np.bool_)
        self.start_pose = None
        if (known := options.known_map) is not None:
            # x, y, z and each landmark's update weight (shared_steps.landmark_weight: 0 = fixed by the map)
            self.lm = np.array(known.lm, dtype=np.float64)
            self.lm_init = np.array(known.lm_init, dtype=np.bool_)
            self.start_pose = known.pose
        self.iv = 0  # next velocity sample
        self.jf = 0  # next detection frame
        self._segment = 0  # segment starts passed so far
        self._bridges = bridge_events(stream)
        self._bridge = 0  # bridged-gap events passed so far
        self._mapped_before = self.lm_init.copy()  # the landmarks mapped when the last bridged gap began
        self._bias_before = np.zeros(3)
        self._anchored = (0.0, 0.0)  # time (s) and variance (m²) of the carried position's last re-anchoring
        self._anchor_gain = 1.0
        self._spread = motion_spread(stream.velocity) if stream.bridged_gaps.shape[0] else np.zeros(3)
        self.stats: dict = {"substeps": 0}
        self.timings: dict[str, float] = {}
        self._innovation_norms: list[np.ndarray] = []  # per stretch, for gross_note (observers without a gate)
        self._biases: list[tuple[np.ndarray, np.ndarray]] = []  # per stretch, k and b (6) where k % BIAS_STRIDE == 0

    @property
    def n_vel(self) -> int:
        return int(self.vel_t.shape[0])

    @property
    def n_max(self) -> int:
        """Most detections in one frame: the size of the visible-landmark buffers."""
        return max_per_frame(self.stream.det_offsets)

    def _kernel(self, iv_stop: int, out: Outputs, budget: int) -> int:  # pragma: no cover - abstract
        """Run the kernel from its state; returns the rows written to ``out`` (from its first row)."""
        raise NotImplementedError

    def _extra(self) -> dict[str, dict[str, np.ndarray]]:
        """Observer-specific table rows of the stretch just run."""
        return {}

    def landmark_covariance(self) -> np.ndarray | None:
        """(L, 3, 3) covariance of each landmark's position in the map frame as it is now (NaN for landmarks not
        yet estimated), for estimators that keep one; None for the observers."""
        return None

    def detection_distances(self, det_first: int, det_stop: int) -> np.ndarray | None:
        """Detections ``det_first .. det_stop − 1``'s ``ObserverResult.innovation_d2``; None for the estimators
        without their own noise model of a detection's distance from the map."""
        return None

    def _frame(self) -> dict | None:
        state = getattr(self, "state", None)
        if state is None or not getattr(self, "keeps_map_frame", False):
            return None
        return {
            "rotation": state.f_r.copy(),
            "translation": state.f_p.copy(),
            "mean_rotation": state.frame_mean(),
            "estimated_s": float(state.f_stat[0]),
            "samples": int(state.f_stat[1]),
        }

    def map_xyz(self) -> np.ndarray:
        """The map as written, in the frame of the written poses: the kernel's map moved by ``F⁻¹`` for the
        observers that keep a map frame (:class:`KernelState`), the live map itself for the others."""
        state, xyz = getattr(self, "state", None), self.lm[:, :3]  # a known map adds a weight column
        if state is None or (np.array_equal(state.f_r, np.eye(3)) and not state.f_p.any()):
            return xyz
        return (xyz - state.f_p) @ state.f_r

    def _frames_before(self, iv: int) -> int:
        """Detection frames processed before velocity sample ``iv`` (all of them at the end)."""
        return int(np.searchsorted(self.det_t, self.vel_t[iv], side="left")) if iv < self.n_vel else self.det_t.shape[0]

    def advance(self, iv_stop: int) -> ObserverResult:
        """Run up to velocity sample ``iv_stop`` (exclusive; ``n_vel`` runs to the end, trailing frames too);
        returns that stretch's rows, the map (the live array) and the statistics as they are now. The last
        stretch's statistics hold the whole run's checks (:meth:`end_checks`) unless ``end_checks_later``.

        The kernel is called as often as its work budget needs, and restarted at every segment start.

        Raises:
            ObserverDiverged: The estimate became non-finite.

        """
        s = self.stream
        iv_stop = min(iv_stop, self.n_vel)
        jf_stop = self._frames_before(iv_stop)
        det_first, det_stop = int(s.det_offsets[self.jf]), int(s.det_offsets[jf_stop])
        rows_out = output_rows(self.n_vel, self.options.out_every, self.iv, iv_stop)
        out = Outputs.empty(rows_out, det_first, det_stop, self.keeps_covariance)
        if self.iv == 0 and self.start_pose is not None:  # a known map fixes the frame: start where it says
            self.state.r_hat[:], self.state.p_hat[:] = self.start_pose
            self.start_pose = None
        starts = s.segment_starts
        ns = self.state.ns
        rows = 0
        while True:
            nxt = int(starts[self._segment]) if self._segment < starts.shape[0] else self.n_vel
            if ns[_IV] == nxt < self.n_vel and ns[_JF] >= self._frames_before(nxt):
                self.state.restart(float(self.vel_t[nxt]))  # a segment starts: nothing integrated across the gap
                key = "relocalised" if self._relocalise(nxt) else "held"
                self.stats[key] = self.stats.get(key, 0) + 1
                self._segment += 1
                continue
            ev = self._bridges
            edge = int(ev[self._bridge, 0]) if self.reanchors_bridged and self._bridge < ev.shape[0] else self.n_vel
            if ns[_IV] == edge < self.n_vel and ns[_JF] >= self._frames_before(edge):
                self._bridge_edge(edge, int(ev[self._bridge, 1]))
                self._bridge += 1
                continue
            nxt = min(nxt, edge)
            stop = min(iv_stop, nxt)
            target = jf_stop if stop == iv_stop else self._frames_before(stop)
            while ns[_IV] < stop or ns[_JF] < target:
                rows += self._kernel(stop, out.rows_from(rows), WORK_PER_CALL)
                self._check_state()
            if stop == iv_stop:
                break
        assert rows == out.k.shape[0], (rows, out.k.shape[0])
        self.stats["capped_intervals"] = int(ns[CAPPED])
        if ns[CAP_IV] >= 0:
            self.stats["first_capped_ns"] = int(s.vel_t_ns[min(int(ns[CAP_IV]), self.n_vel - 1)])
        frames = slice(self.jf, jf_stop)
        self.iv, self.jf = iv_stop, jf_stop
        if not self.gates_detections:
            self._innovation_norms.append(row_norms3(out.innov))
            kept = out.k % BIAS_STRIDE == 0  # by sample, not by row of the stretch: a run in stretches keeps the same
            self._biases.append((out.k[kept], out.b[kept]))
        if iv_stop >= self.n_vel and not self.end_checks_later:
            self.end_checks()
        det_t = np.repeat(s.det_t_ns[frames], np.diff(s.det_offsets[frames.start : frames.stop + 1]))
        return ObserverResult(
            t_ns=s.vel_t_ns[out.k],
            rotation=out.r,
            position=out.p,
            gyro_bias=out.b[:, :3],
            vel_bias=out.b[:, 3:],
            landmark_ids=s.landmark_ids,
            landmark_xyz=self.map_xyz(),
            det_t_ns=det_t,
            det_ids=s.landmark_ids[s.det_idx[det_first:det_stop]],
            track_xyz=out.trk,
            innovation=out.innov,
            stats=dict(self.stats),
            timings=dict(self.timings),
            extra_tables=self._extra(),
            map_frame=self._frame(),
            pose_cov=out.cov,
            landmark_cov=self.landmark_covariance(),
            innovation_d2=self.detection_distances(det_first, det_stop),
        )

    def end_checks(self, stats: dict | None = None) -> None:
        """The whole run's checks of an observer without a gate, once it has run to the end, into its statistics
        (and into ``stats`` too: the last stretch's, when :meth:`advance` left them out): the gross outliers'
        note, the map-against-trajectory check (:func:`resighting_check`) and the velocity bias's share
        (:func:`bias_share`), which run.py's :func:`lost_note` reads, and whether the biases never moved
        (:func:`bias_held`), which its :func:`held_bias_note` reads."""
        if self.gates_detections:
            return
        s = self.stream
        norms = np.concatenate(self._innovation_norms)
        det_t = np.repeat(self.det_t, np.diff(s.det_offsets))[: norms.shape[0]]
        check = resighting_check(norms, resightings(s.det_idx[: norms.shape[0]], det_t))
        offset, said = self.time_offset_said or (None, [])  # decided before the start (ObserverSpec._started)
        self.stats["notes"] = said + gross_note(norms)  # and run.py's lost_note from the check
        self.stats.setdefault("metadata", {})
        if offset is not None:
            self.stats["metadata"]["time_offset"] = offset
        self.stats["metadata"]["resightings"] = check
        k, b = (np.concatenate(a) for a in zip(*self._biases))
        self.stats["metadata"]["velocity_bias"] = bias_share(k, b[:, 3:], s.velocity, s.vel_t_ns)
        self.stats["metadata"]["bias_held"] = bias_held(b, s.det_offsets, self.options.min_landmarks_bias)
        if stats is not None:
            stats.update(self.stats)

    #: Whether the position is re-anchored across a bridged gap (:meth:`_bridge_edge`): the observers; riekf carries
    #: it with its covariance widened over the gap instead (``shared_steps.gap_levels``).
    reanchors_bridged = True

    def _bridge_edge(self, iv: int, kind: int) -> None:
        """An event of a bridged gap (:func:`bridge_events`). At its first sample: note the landmarks mapped and
        the velocity bias. Before each frame inside it and at its end: the position re-anchored to the landmarks
        mapped before the gap when the frame (at the end: the first within ``max_meas_age``) sees three of them:
        their fit with the carried attitude (the gyro recorded through), weighed against the carried position's
        variance, which grows as ``(spread × time since the last re-anchoring)²`` (``shared_steps.motion_spread``,
        as riekf's over the gap); else the pose is carried on. At its end the velocity bias is put back to its
        value at the start: across the gap the bias law learns the interpolation's error, not the odometry's
        bias (docs/observers.md "Gaps")."""
        t = float(self.vel_t[iv])
        if kind == 0:
            self._mapped_before = self.lm_init.copy()
            self._bias_before = self.state.b_v.copy()
            self._anchored = (t, 0.0)
            return
        if kind == 2:
            self.state.b_v[:] = self._bias_before
        t_a, var_a = self._anchored
        carried = var_a + float(np.sum(self._spread**2)) * (t - t_a) ** 2
        moved = self._relocalise(iv, self._mapped_before, carried)
        if moved:
            self._anchored = (t, (1.0 - self._anchor_gain) * carried)
        if kind == 2:
            key = "bridged_relocalised" if moved else "bridged_carried"
            self.stats[key] = self.stats.get(key, 0) + 1

    def _relocalise(self, iv: int, mapped: np.ndarray | None = None, carried: float | None = None) -> bool:
        """Re-anchor the pose to the map at segment start ``iv``: the least-squares rigid fit of the first
        frame within ``max_meas_age`` that sees three or more mapped landmarks (not all on a line; only those
        of ``mapped`` when given), carried back to the segment start with the bias-corrected odometry. False
        when no frame qualifies."""
        from slamobs.pipeline.lie import se3_exp, umeyama

        s, st = self.stream, self.state
        t_b = self.vel_t[iv]
        jf = int(st.ns[_JF])
        mapped = self.lm_init if mapped is None else mapped
        while jf < self.det_t.shape[0] and self.det_t[jf] - t_b <= self.options.max_meas_age:
            a, b = int(s.det_offsets[jf]), int(s.det_offsets[jf + 1])
            idx = s.det_idx[a:b]
            known = mapped[idx]
            if np.count_nonzero(known) >= 3:
                try:
                    r_f, p_f, _ = umeyama(s.det_y[a:b][known], self.lm[idx[known]])
                except ValueError:  # collinear
                    jf += 1
                    continue
                # body motion from t_b to the frame, then the pose at t_b = T_f T_bf⁻¹
                r_bf, p_bf = np.eye(3), np.zeros(3)
                k = iv
                while k < self.n_vel and self.vel_t[k] < self.det_t[jf]:
                    dt = min(self.vel_t[k + 1] if k + 1 < self.n_vel else np.inf, self.det_t[jf]) - self.vel_t[k]
                    d_r, d_p = se3_exp(dt * (s.omega[k] - st.b_om), dt * (s.velocity[k] - st.b_v))
                    p_bf, r_bf = p_bf + r_bf @ d_p, r_bf @ d_r
                    k += 1
                if carried is not None:  # the attitude kept; the position fit weighed against the carried one's
                    r_f = st.r_hat @ r_bf
                    fits = self.lm[idx[known]] - s.det_y[a:b][known] @ r_f.T
                    p_c = st.p_hat + st.r_hat @ p_bf
                    fit_var = float(np.sum(np.var(fits, axis=0, ddof=1))) / fits.shape[0]
                    self._anchor_gain = carried / (carried + fit_var) if carried + fit_var > 0.0 else 0.0
                    p_f = p_c + self._anchor_gain * (fits.mean(axis=0) - p_c)
                st.r_hat[:, :] = r_f @ r_bf.T
                st.p_hat[:] = p_f - st.r_hat @ p_bf
                return True
            jf += 1
        return False

    def _check_state(self) -> None:
        st = self.state
        if not (np.isfinite(st.r_hat).all() and np.isfinite(st.p_hat).all()):
            iv = min(int(st.ns[_IV]), self.n_vel - 1)
            raise ObserverDiverged(
                int(self.stream.vel_t_ns[max(iv, 0)]), {**self.stats, "capped_intervals": int(st.ns[CAPPED])}
            )


@dataclass(frozen=True)
class ObserverSpec:
    name: str
    algorithm: str
    paper: str
    summary: str
    gains: tuple[GainSpec, ...]
    #: A :class:`Stepper` of this observer on a stream (checks that the stream has what it needs).
    start: Callable[[AlignedStream, dict[str, float], ObserverOptions], Stepper]
    #: Minimum number of inertial directions (gravity, magnetic field) the observer needs; 0 = none.
    min_directions: int = 0
    #: Conditions that couple several gains (raises GainError), checked with the per-gain rules before any
    #: log is read.
    check_gains: Callable[[dict[str, float]], None] | None = None
    #: Estimators configured beyond their gains (the reference estimators): checks the run's configuration
    #: before any log is read (raises GainError, or InputError for a missing optional dependency) and returns
    #: the number of inertial directions the run needs (e.g. batch seeded by an observer that uses them).
    check_config: Callable[[object], int] | None = None
    #: Whether the estimator starts from a known map (``options.known_map``); the reference estimators do not.
    takes_known_map: bool = True
    #: Whether it weighs measurements by noise levels (``options.noise``): the reference estimators do.
    uses_noise: bool = False
    #: Whether it estimates the detections' time offset itself (the reference estimators: riekf beside its filter,
    #: batch before its seeds); the others start on the stamps :func:`.time_offset.decide` moves (:meth:`_started`).
    own_time_offset: bool = False
    #: Whether it takes the twist linear between samples (riekf and batch: ``shared_steps.twist_at``) rather than
    #: holding each sample until the next (the observers' integrators): which stamps a twist of interval means
    #: takes (``alignment.MEAN_STAMPS``, :meth:`_started`).
    interpolates: bool = False

    def directions_needed(self, config) -> int:
        """Inertial directions a run of this estimator with ``config`` needs (checking the config first)."""
        if self.check_config is not None:
            return max(self.min_directions, self.check_config(config))
        return self.min_directions

    def run(self, stream: AlignedStream, gains: dict[str, float], options: ObserverOptions) -> ObserverResult:
        """The whole run in one stretch."""
        stepper = self._started(stream, gains, options)
        return stepper.advance(stepper.n_vel)

    def chunks(
        self, stream: AlignedStream, gains: dict[str, float], options: ObserverOptions, samples: int
    ) -> Iterator[ObserverResult]:
        """The run ``samples`` velocity samples at a time (the last stretch also runs the trailing frames);
        each item holds its stretch's rows, the map so far and the statistics so far. The whole run's checks
        (:meth:`Stepper.end_checks`) are added to the last item's ``stats`` (the same dict) when the generator
        is resumed after it: the caller writes the last stretch on its writer thread meanwhile (docs/benchmarks.md,
        session 21)."""
        stepper = self._started(stream, gains, options)
        stepper.end_checks_later = True
        for stop in range(samples, stepper.n_vel + samples, samples):
            part = stepper.advance(stop)
            yield part
        if stepper.n_vel == 0:
            part = stepper.advance(0)
            yield part
        stepper.end_checks(part.stats)

    def _started(self, stream: AlignedStream, gains: dict[str, float], options: ObserverOptions) -> Stepper:
        """:attr:`start` on ``stream``; an estimator without its own time offset (``own_time_offset``) on the
        detection stamps moved by it where :func:`.time_offset.decide` finds it reliable (the reference estimators'
        rule; its record is run.json ``observer.time_offset``, its note the run's). Decided before the observer
        starts, unless ``options.time_offset`` holds the decision on this stream already: bounded by the search's
        pairs (0.06 CPU s on the one-hour log; docs/benchmarks.md, session 33). The search decides on the stream's
        own stamps; an estimator that holds each velocity sample (not :attr:`interpolates`) then integrates a twist
        of interval means from its intervals' starts (:func:`.alignment.held_stamps`), which its record's
        ``sampling.stamps`` says."""
        if self.own_time_offset:
            return self.start(stream if self.interpolates else held_stamps(stream), gains, options)
        from slamobs.pipeline.observers import time_offset

        offset = time_offset.decide(stream) if options.time_offset is None else options.time_offset
        shifted = time_offset.shifted(stream, offset)
        if not self.interpolates and stream.vel_start_ns is not None:
            shifted = held_stamps(shifted)
            offset = {**offset, "sampling": {**offset["sampling"], "stamps": MEAN_STAMPS["holds"]}}
        stepper = self.start(shifted, gains, options)
        said = time_offset.note(self.name, offset)
        stepper.time_offset_said = (offset, said)
        return stepper

    def resolve_gains(self, user: dict | None) -> dict[str, float]:
        """Defaults overlaid with the user's gains, exactly as given; anything invalid is an error."""
        known = {g.name: g.default for g in self.gains}
        user = dict(user or {})
        unknown = sorted(set(user) - set(known))
        if unknown:
            raise GainError(
                f"unknown gain(s) {', '.join(unknown)} for observer '{self.name}' (known: {', '.join(known)})"
            )
        out = dict(known)
        for name, value in user.items():
            if value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
                raise GainError(f"gain {name} of observer '{self.name}' must be a number, got {value!r}")
            if not math.isfinite(value) or value <= 0:
                raise GainError(f"gain {name} of observer '{self.name}' must be finite and > 0, got {value!r}")
            out[name] = float(value)
        if self.check_gains is not None:
            self.check_gains(out)
        return out
