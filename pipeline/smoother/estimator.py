"""``batch``: the factor-graph smoother behind the observers' interface (registry entry, same tables).

The first stretch asked for runs everything: the seed (an observer, or dead reckoning), the preintegration of
the odometry between keyframes, the solve, and the trajectory at every velocity sample; stretches then
hand out their rows. The tables mean what they mean for the observers: ``poses``/``biases`` at the velocity
samples (the bias of each sample's segment), the final map, and per detection the landmark estimate and the
innovation ``p̂ − R̂y − P̂`` at the detection's keyframe, both from the smoothed solution.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from slamobs.pipeline.alignment import stream_topics
from slamobs.pipeline.blocks import row_blocks
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.noise import DETECTION_LAW_KEYS, DETECTION_RATIOS
from slamobs.pipeline.observers.base import KernelState, ObserverSpec, Outputs, Stepper
from slamobs.pipeline.observers.time_offset import camera_named as time_offset_named
from slamobs.pipeline.observers.time_offset import note as time_offset_note
from slamobs.pipeline.smoother import anisotropy as an
from slamobs.pipeline.smoother import extrinsic as ex
from slamobs.pipeline.smoother import inverse_depth as idp
from slamobs.pipeline.smoother.evidence import ACROSS as EVIDENCE_ACROSS
from slamobs.pipeline.smoother.evidence import KEYS as EVIDENCE_KEYS
from slamobs.pipeline.smoother.evidence import MAX_KEYFRAMES as EVIDENCE_MAX_KEYFRAMES
from slamobs.pipeline.smoother.evidence import SAMPLE_FLOOR as EVIDENCE_SAMPLE_FLOOR
from slamobs.pipeline.smoother.evidence import SOLVE_BUDGET as EVIDENCE_SOLVE_BUDGET
from slamobs.pipeline.smoother.evidence import SOLVE_FLOOR as EVIDENCE_SOLVE_FLOOR
from slamobs.pipeline.smoother.evidence import in_passes as evidence_passes
from slamobs.pipeline.smoother.evidence import search as evidence_search
from slamobs.pipeline.smoother.settings import DEAD_RECKONING, BatchSettings

#: What the detection law's method says when batch leaves the held streams' factor out of it.
HELD_SCALE_LEFT_OUT = "batch, whose correlation in time weighs the detections' slow error"

#: Standard deviations (rad, m) added to a relative-motion factor across a gap between segments
#: (``limits.max_gap``): the samples say nothing about the motion there, the landmarks decide.
GAP_SIGMA = (1.0, 100.0)
#: Seconds between the keyframes whose pose marginals are computed (rows between them are interpolated), at
#: least; on a longer log the spacing grows so that at most ``COVARIANCE_MARGINALS`` are computed (the cap dates
#: from GTSAM's marginals, 10 ms each on the one-hour benchmark log; the package's solver computes them in one
#: sweep whatever their number, docs/outputs.md).
COVARIANCE_DT = 1.0
COVARIANCE_MARGINALS = 600
#: Rows per block of :func:`interpolate_covariance` (8,192 rows of 6 x 6 are 2.4 MB a temporary).
COVARIANCE_ROW_BLOCK = 8_192
#: Solves with each detection's σ(r) at the range the last solution predicts (``_at_predicted_ranges``).
RANGE_PASSES = 1
#: Solves with the inverse-depth factors linearized at the last solution's points (``_at_predicted_ranges``).
INVERSE_DEPTH_PASSES = 3
#: Largest share of the detections the χ² gate may drop as outliers; more means the solution is wrong.
MAX_GATED = 0.1
_IV, _JF = 0, 1  # the shared kernel-state slots (base.KernelState)
#: The nested test that keeps the floor the evidence held (``BatchSmoother.solve``, :func:`graph.floor_test`): the
#: floor is dropped where imposing it raises the other factors' whitened cost (``Δχ²``) by more than its effective
#: degrees of freedom ``m`` plus ``FLOOR_Z`` times ``√(2m)`` (normal approximation; 3: about one true floor in 700)
#: AND the detections' part of that rise alone exceeds ``FLOOR_Z √(2m)``: a floor only the motion rows fight is a
#: slow velocity error (a slipping wheel) as much as a climb, the landmarks tell them apart. A 3σ bound, not fitted
#: to the logs: docs/benchmarks.md, "batch's floor kept only where the data agree with it, session 32 (h-floorlr)".
#: It replaced the floor rows' own χ² at the solution (above 1), which a floor that shaped the solution kept low on
#: such a climb (0.13 / 0.15 at seed=3221).
FLOOR_Z = 3.0
#: The floor's weight, a share of its own, in the solves from each start before the one in full
#: (:meth:`BatchSmoother._candidate`): none, then 1 % and 10 %. A start whose tilts wander far off the floor (a
#: blind stretch's gyro drift) solved with the floor at once stalls in another basin (unseen sweep seed=2139, 3 m
#: range: from fast-adaptation's start cost 20,711 against 469 this way); tried there only, with 0.1 % added too
#: (the same solution), docs/benchmarks.md "The floor in batch's graph, session 31 (h-batchfloor)".
FLOOR_RAMP = (0.0, 0.01, 0.1)
#: What :meth:`BatchSmoother._solve` changes on the estimator, put back before it runs again without the floor.
_SOLVE_STATE = ("stream", "noise", "det_at", "det_range", "det_shape", "det_factor", "law_notes", "start_jumps")


def check_config(config) -> int:
    """Settings valid, before any log is read; the directions the seed needs."""
    from slamobs.pipeline.observers import get_observer

    settings = config.batch
    if settings.seed == DEAD_RECKONING:
        return 0
    seed = get_observer(settings.seed)
    seed.resolve_gains(config.gains.get(seed.name))
    return seed.directions_needed(config)


class _Segments:
    """Bias segments: ``segment_s`` seconds each from ``t0`` (the last one runs to the end), or one for the log."""

    def __init__(self, t0: float, t1: float, segment_s: float | None) -> None:
        self.t0, self.segment_s = t0, segment_s
        self.n = 1 if segment_s is None else max(1, int(np.ceil((t1 - t0) / segment_s - 1e-9)))

    def of(self, t: np.ndarray) -> np.ndarray:
        if self.n == 1:
            return np.zeros(np.shape(t), np.int64)
        return np.clip((np.asarray(t) - self.t0) // self.segment_s, 0, self.n - 1).astype(np.int64)


def across_gaps(kf_t: np.ndarray, gaps: np.ndarray | None) -> np.ndarray:
    """Which keyframe intervals (``K − 1``) span a velocity gap (``gaps``: (start, end) rows, None: none): the
    motion factors leave them (almost) unconstrained, the held velocity's windows leave them out."""
    across = np.zeros(kf_t.shape[0] - 1, bool)
    for lo, hi in gaps if gaps is not None else ():
        across |= (kf_t[:-1] < hi) & (kf_t[1:] > lo)
    return across


def covariance_keyframes(kf_t: np.ndarray, every_s: float = COVARIANCE_DT) -> np.ndarray:
    """The keyframes whose marginal covariance the smoother computes: the first at or after each multiple of
    ``every_s`` (longer where the log would need more than ``COVARIANCE_MARGINALS``) from the start, and the
    last (every keyframe of an hour's log, 72,000 at 20 Hz, would cost far more than the solve)."""
    every_s = covariance_spacing(kf_t, every_s)
    marks = kf_t[0] + every_s * np.arange(int((kf_t[-1] - kf_t[0]) // every_s) + 1)
    return np.unique(np.r_[np.searchsorted(kf_t, marks), kf_t.shape[0] - 1])


def covariance_spacing(kf_t: np.ndarray, every_s: float = COVARIANCE_DT) -> float:
    """Seconds between the keyframes whose marginals are computed (:func:`covariance_keyframes`)."""
    return max(every_s, (kf_t[-1] - kf_t[0]) / COVARIANCE_MARGINALS)


def covariance_gauge(kf_t: np.ndarray, kf_of_det: np.ndarray) -> int:
    """The keyframe the written covariances are conditioned on: the last one with a detection where the log goes on
    unseen after it for longer than the marginals' spacing (:func:`covariance_spacing`, within which the rows'
    covariance is interpolated anyway), else the last keyframe, the solve's own gauge. The solution is the same
    whatever keyframe the gauge is put on afterwards (the gauge prior sits at the solution's own pose), but every
    row's covariance is relative to that pose: where the log ends without detections (MR.CLAM 6 robot 1: its last
    740 keyframes), the last keyframe is dead reckoning from the map, and its drift, stated or not, entered every
    row's σ."""
    last = kf_t.shape[0] - 1
    seen = int(np.max(kf_of_det)) if kf_of_det.shape[0] else last
    return seen if kf_t[last] - kf_t[seen] > covariance_spacing(kf_t) else last


def gauge_record(kf_t: np.ndarray, gauge: int) -> dict:
    """run.json ``observer.smoother.covariance_gauge``: the keyframe the covariances are relative to (its time from
    the first keyframe, s), whether it is another than the solve's (the last) and the seconds after it."""
    return {
        "keyframe": int(gauge),
        "moved": bool(gauge != kf_t.shape[0] - 1),
        "t_s": round(float(kf_t[gauge] - kf_t[0]), 3),
        "unseen_after_s": round(float(kf_t[-1] - kf_t[gauge]), 3),
    }


def gauge_note(record: dict) -> list[str]:
    """The note of covariances conditioned on a keyframe before the last (:func:`covariance_gauge`), else []."""
    if not record["moved"]:
        return []
    return [
        f"batch: the written pose and landmark covariances are relative to the keyframe at {record['t_s']:g} s, the "
        f"last with a detection (the log's last {record['unseen_after_s']:g} s have none; "
        "observer.smoother.covariance_gauge); the estimate is unchanged"
    ]


def interpolate_covariance(
    t_cov: np.ndarray, cov: np.ndarray, t: np.ndarray, out: np.ndarray | None = None
) -> np.ndarray:
    """Covariances at times ``t`` linear in time between those at ``t_cov`` (held beyond the ends): between two
    keyframes a pose is the odometry's continuation of both (a convex combination of positive definite
    matrices stays positive definite). Written into ``out`` a row block at a time (an hour's stretch of
    (N, 6, 6) temporaries was the batch run's peak memory)."""
    out = np.empty((t.shape[0], *cov.shape[1:])) if out is None else out
    if t_cov.shape[0] < 2:
        out[:] = cov[:1]
        return out
    for rows in row_blocks(t.shape[0], COVARIANCE_ROW_BLOCK):
        tb = t[rows]
        j = np.clip(np.searchsorted(t_cov, tb, side="right"), 1, t_cov.shape[0] - 1)
        w = np.clip((tb - t_cov[j - 1]) / np.maximum(t_cov[j] - t_cov[j - 1], 1e-12), 0.0, 1.0)[:, None, None]
        out[rows] = (1.0 - w) * cov[j - 1] + w * cov[j]
    return out


def _in_step(progress, step: str):
    """``progress`` whose solver lines say which of the smoother's steps after its first solution they come from
    ("batch (noise levels): iteration 3, ..."): each step solves again, and a bare "iteration 5" repeated for
    40 s (MR.CLAM 7 r3) did not say whether the run had gone back or on. None stays None."""
    if progress is None:
        return None
    return lambda line: progress(f"batch ({step}): {line.removeprefix('batch: ')}")


def _climbing(progress, what: str, problem_at, solved_from):
    """``problem_at`` and a solver (``solved_from(problem, start, progress)``) for :func:`.evidence.climb` whose
    solves report as ``batch: <what> x<scale>: iteration 3, ...``: a scan's solves said nothing, and the step's
    last line before it ("predicted ranges: iteration 6") was repeated for 40 s (MR.CLAM 6 robot 1)."""
    at = [1.0]

    def problem(scale: float):
        at[0] = scale
        return problem_at(scale)

    def solve(problem, start):
        if progress is None:
            return solved_from(problem, start)
        return solved_from(
            problem, start, lambda line: progress(f"batch: {what} x{at[0]:g}: {line.removeprefix('batch: ')}")
        )

    return problem, solve


def gate_note(failed: int, n_det: int, seed_name: str, topics: dict[str, str]) -> str:
    """The warning of a solution more than ``MAX_GATED`` of the detections fail the χ² gate at, with the detection
    topic (``topics``: the aligned stream's, :func:`.alignment.stream_topics`)."""
    return (
        f"warning: batch: {failed} of {n_det} detections{stream_topics(topics, 'detections')} fail the χ² gate at "
        f"the smoother's solution: it probably stopped in a local minimum far from the optimum (seed '{seed_name}'); "
        "every detection was kept; try another batch.seed"
    )


def emptied_note(n_emptied: int) -> list[str]:
    """The note of the landmarks the χ² gate dropped every detection of (none: no note): nothing in the solve
    constrains them (seed=3973, a clock set back mid-log: a landmark split in two, one half all gated)."""
    if not n_emptied:
        return []
    them, their = ("them", "their") if n_emptied > 1 else ("it", "its")
    return [
        f"batch: the χ² gate dropped every detection of {n_emptied} landmark{'s' * (n_emptied > 1)}: nothing in "
        f"the solve constrains {them} ({their} σ null in landmarks.parquet, left out of the covariances and of the "
        f"levels' evidence); {their} position is the one the solve before the gate left"
    ]


class BatchSmoother(Stepper):
    """The smoother on an aligned stream; ``seed`` (tests) replaces the configured one by a prepared guess."""

    keeps_covariance = True
    gates_detections = True  # robust loss and its own gate

    def __init__(
        self,
        stream,
        gains: dict[str, float],
        options,
        settings: BatchSettings | None = None,
        noise=None,
        seed=None,
        fixed_bias: np.ndarray | None = None,
    ) -> None:
        from slamobs.pipeline.alignment import unbridged
        from slamobs.pipeline.noise import resolve_noise
        from slamobs.pipeline.observers import time_offset
        from slamobs.pipeline.smoother import correlation as dc

        stream = unbridged(stream)  # a gap of the odometry alone split as any gap between segments
        self.time_offset = time_offset.estimate(stream)
        stream = time_offset.shifted(stream, self.time_offset)  # the seeds run on the stamps it corrects too
        super().__init__(stream, options)
        self.where = options.source
        self.settings = (
            settings if settings is not None else options.batch if options.batch is not None else BatchSettings()
        )
        self.noise = noise if noise is not None else options.noise if options.noise is not None else resolve_noise()
        self.law_notes = []
        self.start_jumps: list[dict] = []  # the first start whose landmarks jump (:func:`.seed.observer_seed`)
        held = self.noise.detection_held_scale
        if held != 1.0 and dc.skipped(self.settings.detection_correlation, fixed_bias is not None) is None:
            # the held fit's factor stands for the detections' slow error, which the correlation step models
            unscaled = self.noise.scaled(dict.fromkeys(DETECTION_LAW_KEYS, 1.0 / held), by=HELD_SCALE_LEFT_OUT)
            self.noise = replace(unscaled, detection_held_scale=1.0)
            self.law_notes.append(
                f"batch: the detection law without the held streams' fit's factor {held:.3g} (the triplets' law): "
                "the detections' slow error is weighed by their correlation in time instead"
            )
        self.seed_override = seed
        self.fixed_bias = fixed_bias
        self.result = None  # filled by the first stretch
        #: each detection's variance factor for its errors' time correlation (None: white, every factor 1)
        self.det_factor = None
        #: the range each detection's σ(r) is evaluated at (None: its measured range; then the one a solution
        #: predicts, :meth:`_at_predicted_ranges`)
        self.det_range = None
        #: each detection's information shape, range apart from bearing (None: isotropic); a ratio set in the
        #: configuration holds from the first solve on
        self.det_shape = None
        if self._ratio_configured() and self.noise.detection_ratio != 1.0:
            self.det_shape = an.shape(self.stream.det_y, self.noise.detection_ratio, self.noise.ratio_split())
        #: the detections' median depth and range when they are weighed in inverse depth (its levels follow the
        #: law's: pipeline.smoother.inverse_depth), the record for run.json, and the body-frame points its factors
        #: are linearized at (None: the measurements)
        self.inverse_depth, self.inverse_depth_record, self.det_at = self._inverse_depth()
        from slamobs.pipeline.observers.riekf import floor_decision

        #: the floor held or not, riekf's decision on the same samples and setting (run.json ``smoother.floor``)
        self.floor = floor_decision(
            self.vel_t, self.stream.omega, self.stream.velocity, self.noise, self.stream.velocity_period_ns * 1e-9
        )
        # the shared state the stretch driver reads: its clocks, and the last pose written
        self.state = KernelState(1, np.eye(3), np.zeros(3), np.zeros(3), np.zeros(3))

    # ------------------------------------------------------------------ the whole solve
    def solve(self, progress=None) -> dict:
        """:meth:`_solve`; where the floor was held by the evidence (``noise.floor: auto``) and the data reject it
        (its nested test, ``FLOOR_Z``: the other factors' cost, the detections' too, rises with it by more than its
        degrees of freedom allow, a floor that is no plane under a gyro too noisy to show it), the whole solve again
        without it from the same start; run.json ``smoother.floor.dropped`` and a note say so."""
        kept = {k: getattr(self, k) for k in _SOLVE_STATE}
        c0 = time.process_time()
        summary = self._solve(progress)
        fl = summary["floor"]
        if not (fl["held"] and fl["floor"] == "auto" and fl["test"]["rejected"]):
            return summary
        for k, v in kept.items():
            setattr(self, k, v)
        self.floor = dict(self.floor, held=False)
        first_cpu = time.process_time() - c0
        summary = self._solve(progress)
        summary["floor"]["dropped"] = {"test": fl["test"], "chi2": fl["chi2"], "cpu_s": round(first_cpu, 3)}
        t = fl["test"]
        self.stats["notes"].append(
            f"batch: the floor (planar motion by the evidence) not held: imposing it raised the other factors' "
            f"whitened cost by {t['delta_chi2']:.4g} ({t['detections_delta_chi2']:.4g} the detections') for its "
            f"{t['dof']:.4g} effective degrees of freedom (z {t['z']:.3g}, detections {t['detections_z']:.3g} > "
            f"{FLOOR_Z:g}): the landmarks hold the keyframes off it (a floor that is no plane?); solved "
            "again without it (run.json smoother.floor.dropped; noise.floor: true holds it anyway)"
        )
        return summary

    def _solve(self, progress=None) -> dict:
        """Seed, preintegrate, solve, gate the outliers and solve again; when that solution is doubtful, the
        other starts too, keeping the lowest-cost candidate (:mod:`pipeline.smoother.candidates`); the summary
        (also kept in ``stats``)."""
        from slamobs.pipeline.smoother import candidates as cands
        from slamobs.pipeline.smoother import graph as g

        if self.vel_t.shape[0] < 2:
            raise InputError(self.where, "the batch smoother needs at least two velocity samples")
        kf_t, kf_of_det, gaps = self._keyframes()
        if progress is not None:
            progress(f"batch: seed observer ({self.settings.seed}) over {self.vel_t.shape[0]} samples")
        seed = self._seed(kf_t, kf_of_det)
        t0, c0 = time.perf_counter(), time.process_time()
        segments = self._segments()
        full = self._problem(kf_t, kf_of_det, gaps, seed, segments)
        first = self._candidate(full, seed, segments.n, progress)
        chosen, robust, seed_s = first, None, seed.seconds
        if (reason := cands.why_other_starts(full, first, int(kf_t.shape[0]))) is not None:
            chosen, robust, seed_s = self._robust(reason, full, first, (kf_t, kf_of_det, gaps), segments, progress)
        keyframes = (kf_t, kf_of_det, gaps)
        chosen, levels, level_notes = self._noise_levels(chosen, keyframes, segments, progress)
        chosen, seed_check, seed_notes = self._against_seeds(chosen, first.seed, keyframes, segments)
        problem, sol, extrinsic = self._extrinsic(chosen.problem, chosen.sol, progress)
        stats = g.residual_statistics(problem, sol)
        stats["landmark"]["gated"] = int(full.det_idx.shape[0] - problem.det_idx.shape[0])
        t_solve, c_solve = time.perf_counter() - t0, time.process_time() - c0
        gauge, cov_kf, pose_cov, landmark_cov, (t_cov, c_cov) = _marginals(kf_t, problem, sol)
        # every detection's χ² under the final model (the gated ones too): what the jump check judges
        every = g.whitened_residuals(replace(problem, **self._detections(kf_of_det)), sol)
        self.result = {
            "kf_t": kf_t,
            "kf_of_det": kf_of_det,
            "segments": segments,
            "solution": sol,
            "seed": seed,
            "cov_t": kf_t[cov_kf],
            "pose_cov": pose_cov,
            "landmark_cov": landmark_cov,
            "det_d2": np.einsum("mi,mi->m", every, every),
        }
        summary, seconds = self._summary(sol, chosen.seed.name, stats)
        if robust is not None:
            summary["robust"] = robust[0]
        summary.update(levels)
        summary["detection_inverse_depth"] = self.inverse_depth_record
        if self.inverse_depth is not None:  # the levels the final solution used
            summary["detection_inverse_depth"] |= idp.record(
                *idp.levels(self.noise, *self.inverse_depth), INVERSE_DEPTH_PASSES
            )
        summary["seed_check"] = seed_check
        summary["covariance_gauge"] = gauge_record(kf_t, gauge)
        summary["floor"] = self._floor_record(problem, sol)
        summary["extrinsic"] = extrinsic
        self.stats["substeps"] = int(kf_t.shape[0])
        self.stats["metadata"] = {
            "seed": chosen.seed.name,
            "smoother": summary,
            "noise": self.noise.as_dict(),
            "time_offset": self.time_offset,
            # a start's (riekf's) innovations jumping: the run splits those landmarks as it does its own
            "start_landmark_jumps": self.start_jumps,
        }
        self.stats["notes"] = [robust[1]] if robust is not None else []
        self.stats["notes"] += self.law_notes + level_notes
        self.stats["notes"] += seed_notes + self._floor_note() + gauge_note(summary["covariance_gauge"])
        self.stats["notes"] += list(chosen.notes or []) + ex.note(extrinsic)
        self.stats["notes"] += time_offset_note("batch", self.time_offset)
        self.timings.update(
            {
                "seed_s": seed_s,
                # the other starts' observer runs happen inside the solve's timer: counted once, in seed_s (the
                # CPU figure still holds them)
                "smoother_s": t_solve - (seed_s - seed.seconds),
                "smoother_cpu_s": c_solve,
                # the poses' and landmarks' marginals written to the tables (not the bias's, inside the solve)
                "pose_landmark_covariance_s": t_cov,
                "pose_landmark_covariance_cpu_s": c_cov,
                **{f"smoother_{k}_s": v for k, v in seconds.items()},
            }
        )
        return summary

    def _extrinsic(self, problem, sol, progress) -> tuple:
        """The detections' sensor position fitted jointly with the solution (:mod:`pipeline.smoother.extrinsic`):
        applied along its observable directions (the problem solved again with the detections moved, and the stream's
        detections and sensor moved with them, which the tables' innovations read), the problem, solution and record.
        Skipped where the detections come from no one fixed sensor (several cameras, a moving frame)."""
        from slamobs.pipeline.smoother import graph as g

        sensor = getattr(self.stream, "det_sensor", None)
        if sensor is None:
            return problem, sol, {"skipped": "the detections are in no one fixed sensor frame (several or moving)"}

        def again(shifted, start):
            if progress is not None:
                progress("batch: solved again with the detections' sensor at its fitted position")
            out = self._solved_from(shifted, start)
            merged = g.merge_summaries(start.summary, out.summary)
            merged.pop("error_before_gating", None)
            if "error_before_gating" in start.summary:
                merged["error_before_gating"] = start.summary["error_before_gating"]
            out.summary = merged
            return out

        named = time_offset_named(self.time_offset)
        problem, sol, rec, applied, cpu_s = ex.timed(problem, sol, np.asarray(sensor[1], float), again, named)
        self.timings["extrinsic_cpu_s"] = cpu_s
        if np.any(applied):
            self.stream = replace(
                self.stream, det_y=self.stream.det_y + applied, det_sensor=(sensor[0], np.asarray(sensor[1]) + applied)
            )
            if self.det_at is not None:
                self.det_at = self.det_at + applied
        return problem, sol, rec

    def _noise_levels(self, chosen, keyframes: tuple, segments: _Segments, progress) -> tuple:
        """The noise model refined on the solution ``chosen``, a pass at a time, each solving again: detection
        noise at the predicted ranges, the noise levels (evidence or cross-validation), range against bearing (the
        motion levels scanned again when it applies), time-correlated detections, the held velocity's level (the
        detections' model again at it), the detection law's level. The last solution, each pass's record (the
        summary's ``noise_scale``, ``held_velocity``, ``detection_correlation``, ``detection_anisotropy``,
        ``detection_level``) and their notes, in that order."""
        chosen, range_notes = self._at_predicted_ranges(
            chosen, keyframes, segments, _in_step(progress, "detection noise at the predicted ranges")
        )
        select = self._cross_validation if self.settings.noise_selection == "cross_validation" else self._evidence
        chosen, evidence, evidence_notes = select(chosen, keyframes, segments, _in_step(progress, "noise levels"))
        chosen, anisotropy, anisotropy_notes = self._weigh_range(
            chosen, keyframes, segments, _in_step(progress, "range against bearing")
        )
        if anisotropy.get("applied") and select == self._evidence:
            # the motion levels were scanned against isotropic detections, whose range error they soaked up: again
            scales = {k: r["scale"] for k, r in evidence.items() if "scale" in r}
            again_progress = _in_step(progress, "noise levels again")
            chosen, evidence, again = self._evidence(chosen, keyframes, segments, again_progress, scales)
            anisotropy_notes += again
            anisotropy["motion_scanned_again"] = True
        chosen, correlation, correlation_notes = self._decorrelate(
            chosen, keyframes, segments, _in_step(progress, "time-correlated detections")
        )
        chosen, held_velocity, held_notes = self._held_velocity(
            chosen, keyframes, segments, _in_step(progress, "the held velocity's level")
        )
        if held_velocity.get("scale", 1.0) != 1.0 and correlation.get("applied"):
            again_progress = _in_step(progress, "the detections' model at the held level")
            chosen, again, held_velocity["detections_again"], again_notes = self._detections_again(
                chosen, keyframes, segments, again_progress, correlation
            )
            if again is not None:
                anisotropy, anisotropy_notes, correlation, correlation_notes = again
            held_notes += again_notes
        correlation_notes += held_notes
        chosen, detection_level, level_notes = self._detection_level(
            chosen, keyframes, segments, _in_step(progress, "the detection law's level"), correlation
        )
        correlation_notes += level_notes
        levels = {
            "noise_scale": evidence,
            "held_velocity": held_velocity,
            "detection_correlation": correlation,
            "detection_anisotropy": anisotropy,
            "detection_level": detection_level,
        }
        return chosen, levels, range_notes + evidence_notes + anisotropy_notes + correlation_notes

    def _segments(self) -> _Segments:
        st = self.settings
        return _Segments(self.vel_t[0], self.vel_t[-1], st.segment_s if st.bias == "random-walk" else None)

    def first_problem(self):
        """The graph data the configured seed's solve starts from, and the seed as its guess (what
        ``benchmarks/batch_gtsam.py`` hands to GTSAM too)."""
        from slamobs.pipeline.smoother import graph as g

        kf_t, kf_of_det, gaps = self._keyframes()
        seed = self._seed(kf_t, kf_of_det)
        segments = self._segments()
        problem = self._problem(kf_t, kf_of_det, gaps, seed, segments)
        return problem, g.Guess(seed.rot, seed.pos, seed.landmarks, np.tile(problem.b_bar, (segments.n, 1)))

    def _candidate(self, problem, seed, n_segments: int, progress):
        """The smoother's solution from ``seed`` (gated and solved again as :meth:`_solve_gated` does)."""
        from slamobs.pipeline.smoother import graph as g
        from slamobs.pipeline.smoother.candidates import Candidate

        guess = g.Guess(seed.rot, seed.pos, seed.landmarks, np.tile(problem.b_bar, (n_segments, 1)))
        if problem.floor is not None:  # the floor's weight raised over solves (FLOOR_RAMP), then in full
            for w in FLOOR_RAMP:
                guess = self._solved_from(replace(problem, floor=problem.floor * w if w else None), guess, progress)
        solved, sol, notes = self._solve_gated(problem, guess, seed.name, progress)
        return Candidate(seed, solved, sol, notes)

    def _robust(self, reason: str, full, first, keyframes: tuple, segments: _Segments, progress):
        """The other starts (aligned to the first seed's gauge) solved too; every candidate, the starts as
        they are included, scored on ``full``; the best, its record and note, and the seeds' seconds."""
        from slamobs.pipeline.smoother import candidates as cands
        from slamobs.pipeline.smoother import graph as g

        kf_t, kf_of_det, gaps = keyframes
        found = [first, cands.Candidate(first.seed)]
        seconds = first.seed.seconds
        for name in cands.extra_seeds(first.seed.name, int(self.stream.landmark_ids.shape[0])):
            if progress is not None:
                progress(f"batch: first solution doubtful, solving from another start ({name})")
            try:
                seed = self._seed(kf_t, kf_of_det, name)
            except InputError:
                continue  # a start that diverged is no candidate
            seconds += seed.seconds
            seed = cands.align_to(seed, first.seed, full.anchor)
            problem = self._problem(kf_t, kf_of_det, gaps, seed, segments)
            found += [self._candidate(problem, seed, segments.n, progress), cands.Candidate(seed)]
        for c in found:  # the odometry preintegrated about each candidate's own bias: exact for a constant one
            guess = c.guess(segments.n)
            about = replace(c.seed, bias=guess.bias.mean(axis=0))
            c.cost = g.cost(replace(self._problem(kf_t, kf_of_det, gaps, about, segments), anchor=full.anchor), guess)
        best = cands.choose(found)
        if best.sol is None:  # a start as it is: its biases' covariance at it, no iteration
            best.sol = g.solve(full, best.guess(segments.n), max_iterations=0)
            best.problem, best.notes = full, []
        return best, cands.record(reason, found, best, first.seed), seconds

    def _against_seeds(self, chosen, first_seed, keyframes: tuple, segments: _Segments):
        """ "Never worse than its seed", checked once every step has re-solved: the final solution and its starts as
        they are (the configured seed's, and the kept candidate's when another) scored by the smoother's objective
        over every detection under the final noise model (levels, range/bearing shape, time correlation, σ at the
        solution's ranges): the final problem (its odometry preintegrated about the kept candidate's seed's bias,
        as every re-solve builds it) with every detection; another seed's odometry about its own bias. A start
        lower by more than ``candidates.TIE_COST`` is kept as it is. The candidate kept, the record, the notes."""
        from slamobs.pipeline.smoother import candidates as cands
        from slamobs.pipeline.smoother import graph as g

        kf_t, kf_of_det, gaps = keyframes
        if self.fixed_bias is not None:  # a reference run: its biases are given, no start to fall back on
            return chosen, {"skipped": "the biases are fixed (a reference run)"}, []
        final = replace(chosen.problem, **self._detections(kf_of_det))
        found = [chosen] + [cands.Candidate(s) for s in {id(s): s for s in (chosen.seed, first_seed)}.values()]
        problems = [
            final if c.seed is chosen.seed else self._problem(kf_t, kf_of_det, gaps, c.seed, segments) for c in found
        ]
        for c, p in zip(found, problems, strict=True):
            c.cost = g.cost(p, c.guess(segments.n))
        best = cands.choose(found)
        record, notes = cands.seed_check(found, best), []
        if best is not chosen:  # a start as it is: its biases' covariance at it, no iteration
            best.problem = problems[found.index(best)]
            best.sol = g.solve(best.problem, best.guess(segments.n), max_iterations=0)
            best.notes = []
            notes.append(cands.seed_check_note(record))
        return best, record, notes

    def _keyframes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Keyframe times, each detection's keyframe, and the velocity gaps between segments (None: no gap)."""
        from slamobs.pipeline.smoother.preintegration import keyframe_times

        s, vel_t = self.stream, self.vel_t
        starts = s.segment_starts
        gaps = np.stack([vel_t[starts - 1], vel_t[starts]], axis=-1) if starts.size else None
        kf_t = keyframe_times(vel_t, self.det_t, self.settings.keyframe_dt, gaps)
        kf_of_det = np.repeat(np.searchsorted(kf_t, self.det_t), np.diff(s.det_offsets))
        return kf_t, kf_of_det, gaps

    def _seed(self, kf_t: np.ndarray, kf_of_det: np.ndarray, name: str | None = None):
        """The initial guess: the tests' prepared one, dead reckoning, or the configured observer's trajectory
        (``name``: that start instead of the configured one)."""
        from slamobs.pipeline.smoother.seed import dead_reckoning_seed, observer_seed

        if name is None:
            if self.seed_override is not None:
                return self.seed_override
            name = self.settings.seed
        if name == DEAD_RECKONING:
            return dead_reckoning_seed(self.stream, kf_t, kf_of_det)
        from slamobs.pipeline.observers import get_observer

        spec = get_observer(name)
        gains = spec.resolve_gains(self.options.seed_gains if name == self.settings.seed else None)
        try:
            seed = observer_seed(name, self.stream, gains, self.options, kf_t)
        except InputError as err:
            raise InputError(self.where, err.problem) from None
        self.start_jumps = self.start_jumps or seed.landmark_jumps
        return seed

    def _problem(self, kf_t: np.ndarray, kf_of_det: np.ndarray, gaps: np.ndarray | None, seed, segments: _Segments):
        """The factor graph's data: the odometry preintegrated between keyframes about the seed's (or the fixed)
        bias, intervals across a gap left (almost) unconstrained, the detections, the bias priors and walk."""
        from slamobs.pipeline.smoother import graph as g

        st, nz = self.settings, self.noise
        k = kf_t.shape[0]
        walk = None
        if segments.n > 1:
            walk = np.sqrt(st.segment_s) * np.r_[np.full(3, nz.gyro_bias_walk), np.full(3, nz.velocity_bias_walk)]
            walk = np.maximum(walk, 1e-12)
        b_bar = seed.bias.copy() if self.fixed_bias is None else np.asarray(self.fixed_bias, float)
        data = self._motion_data(kf_t, gaps, b_bar, nz)
        if self.fixed_bias is None:
            prior_mean, prior = np.zeros(6), np.r_[np.full(3, nz.gyro_bias), np.full(3, nz.velocity_bias)]
        else:  # the reference of the tests: biases known
            prior_mean, prior = b_bar, np.full(6, 1e-9)
        return g.Problem(
            data=data,
            b_bar=b_bar,
            seg_of=segments.of(kf_t[:-1]),
            bias_prior_sigma=prior,
            bias_prior_mean=prior_mean,
            walk_sigma=walk,
            huber=st.huber,
            anchor=k - 1,
            floor=floor_information(kf_t) if self.floor["held"] else None,
            **self._detections(kf_of_det),
        )

    def _floor_record(self, problem, sol) -> dict:
        """The floor for run.json: riekf's decision (:func:`pipeline.observers.riekf.floor_decision`) and, when
        held, its levels per riekf pseudo-measurement (:func:`floor_information`), the mean squared whitened
        residual of its tilt and height rows at the solution (``chi2``: about 1 or less when the floor holds) and its
        nested test (``test``, :func:`graph.floor_test`: the solve without it from this solution, ``Δχ²``, its
        detections' part, its degrees of freedom ``dof``, ``z = (Δχ² − dof)/√(2 dof)`` and the detections' part over
        ``√(2 dof)``: ``rejected`` where both exceed ``FLOOR_Z``, what :meth:`solve` decides by)."""
        from slamobs.pipeline.observers import riekf as rk
        from slamobs.pipeline.smoother.graph import floor_at, floor_terms, floor_test

        rec = dict(self.floor)
        if rec["held"]:
            rec.update(tilt_sigma_rad=rk.PLANAR_TILT, height_sigma_m=rk.PLANAR_HEIGHT, per_s=rk.PLANAR_EVERY_S)
            a = problem.anchor
            r, _ = floor_terms(floor_at(sol.rot, sol.pos, a), sol.rot, sol.pos)
            if problem.floor is not None:
                w = r * r * problem.floor[:, [0, 0, 1]]
                rec["chi2"] = {"tilt": round(float(np.mean(w[:, :2])), 4), "height": round(float(np.mean(w[:, 2])), 4)}
                c0 = time.process_time()
                delta, detections, dof = floor_test(problem, sol, self._solved_from(replace(problem, floor=None), sol))
                ok = bool(np.isfinite(dof) and dof > 0.0)  # no marginals (a singular system): kept, z 0
                z = (delta - dof) / np.sqrt(2.0 * dof) if ok else 0.0
                z_det = detections / np.sqrt(2.0 * dof) if ok else 0.0
                dof = dof if ok else 0.0
                rec["test"] = {
                    "delta_chi2": round(delta, 3),
                    "detections_delta_chi2": round(detections, 3),
                    "dof": round(dof, 3),
                    "z": round(float(z), 3),
                    "detections_z": round(float(z_det), 3),
                    "bound_z": FLOOR_Z,
                    "rejected": bool(z > FLOOR_Z and z_det > FLOOR_Z),
                    "cpu_s": round(time.process_time() - c0, 3),
                }
        return rec

    def _floor_note(self) -> list[str]:
        """The note of a floor held (none otherwise: riekf's note says why not where it runs)."""
        from slamobs.pipeline.observers import riekf as rk

        if not self.floor["held"]:
            return []
        why = "planar motion" if self.floor["floor"] == "auto" else "noise.floor: true"
        return [
            f"batch: the floor held at every keyframe ({why}, as riekf decides): the body's up axis normal to the "
            f"plane of the keyframes' mean up axis and its height on it, tilt {rk.PLANAR_TILT:g} rad and height "
            f"{rk.PLANAR_HEIGHT:g} m per {rk.PLANAR_EVERY_S:g} s of keyframes, brought in by steps from each start "
            "(run.json smoother.floor)"
        ]

    def _inverse_depth(self) -> tuple[tuple[float, float] | None, dict, None]:
        """The detections' typical depth and range when inverse depth applies (else None), the record, no
        linearization point yet."""
        s = self.stream
        sensor = getattr(s, "det_sensor", None)
        why = idp.why_not(self.noise, sensor, s.det_y, self.settings.detection_inverse_depth)
        if why is None and self._ratio_configured():
            why = "noise.detection_ratio is set"
        if why is not None:
            return None, {"skipped": why}, None
        typical = idp.typical(sensor, s.det_y)
        return typical, idp.record(*idp.levels(self.noise, *typical), INVERSE_DEPTH_PASSES), None

    def _detections(self, kf_of_det: np.ndarray) -> dict:
        """The problem's detection fields: every detection of the stream, its σ at the current ranges, factors
        and shape (in inverse depth: the pseudo-measurements at the current linearization points)."""
        s = self.stream
        factor = 1.0 if self.det_factor is None else np.sqrt(self.det_factor)
        if self.inverse_depth is not None:
            levels = idp.levels(self.noise, *self.inverse_depth)  # the law's, as scaled by cross-validation
            y, sigma, shape = idp.factors(s.det_sensor, s.det_y, self.det_at, *levels)
            return {
                "kf_of_det": kf_of_det,
                "det_idx": s.det_idx,
                "det_y": y,
                "det_sigma": sigma * factor,
                "det_shape": shape,
            }
        ranges = np.linalg.norm(s.det_y, axis=1) if self.det_range is None else self.det_range
        return {
            "kf_of_det": kf_of_det,
            "det_idx": s.det_idx,
            "det_y": s.det_y,
            "det_sigma": self.noise.detection_sigma(ranges) * factor,
            "det_shape": self.det_shape,
        }

    def _motion_data(self, kf_t: np.ndarray, gaps: np.ndarray | None, b_bar: np.ndarray, nz) -> np.ndarray:
        """The relative-motion factors' data: the odometry preintegrated between keyframes about ``b_bar`` with
        the levels of ``nz``, intervals across a gap left (almost) unconstrained, the densities widened across a
        gap in the samples as riekf's (``shared_steps.gap_levels``)."""
        from slamobs.pipeline.observers.shared_steps import gap_levels
        from slamobs.pipeline.smoother.preintegration import D_END, D_W, preintegrate, whitening

        s, k = self.stream, kf_t.shape[0]
        data = np.zeros((k - 1, D_END))
        cov = np.zeros((k - 1, 6, 6))
        g_om, g_v, vel_gap, om_gap = gap_levels(s, self.vel_t, nz.held, gyro_density=nz.gyro)
        q_om, q_v = nz.gyro**2, nz.velocity**2
        levels = np.array([g_om, g_v])
        preintegrate(self.vel_t, s.omega, s.velocity, kf_t, b_bar, q_om, q_v, levels, vel_gap, om_gap, data, cov)
        # intervals across a gap: (almost) no constraint
        cov[across_gaps(kf_t, gaps)] += np.diag(np.r_[np.full(3, GAP_SIGMA[0] ** 2), np.full(3, GAP_SIGMA[1] ** 2)])
        data[:, D_W:D_END] = whitening(cov).reshape(-1, 36)
        return data

    def _at_predicted_ranges(self, chosen, keyframes: tuple, segments: _Segments, progress):
        """Each detection's ``σ(r)`` at the range the solution predicts for it instead of the measured one, solved
        (and gated) again, ``RANGE_PASSES`` times; nothing when the law does not grow with range. A measured range
        carries the detection's own error: a reading that came out short got a smaller σ and more weight than
        one that came out long, and the map and trajectory shrank (a stereo-like figure-8, σ ∝ r²: by 8 %)."""
        from slamobs.pipeline.smoother import graph as g

        if self.inverse_depth is not None:  # the factors linearized at the solution's points until they settle
            for _ in range(INVERSE_DEPTH_PASSES):
                self.det_at = g.predicted_detections(keyframes[1], self.stream.det_idx, chosen.sol)
                chosen = self._solved_again(chosen, chosen.sol, keyframes, segments, progress, same_motion=True)
            levels = idp.levels(self.noise, *self.inverse_depth)
            return chosen, [idp.note(*levels)]
        if self.noise.detection_per_m == 0.0 and self.noise.detection_per_m2 == 0.0:
            return chosen, []
        for _ in range(RANGE_PASSES):  # the motion factors as they are: only the detections' σ change
            predicted = g.predicted_detections(keyframes[1], self.stream.det_idx, chosen.sol)
            self.det_range = np.linalg.norm(predicted, axis=1)
            chosen = self._solved_again(chosen, chosen.sol, keyframes, segments, progress, same_motion=True)
        return chosen, [
            "batch: each detection's σ(r) at the range the solution predicts, not the measured one (whose own "
            "error would weigh the short readings up)"
        ]

    def _weigh_range(self, chosen, keyframes: tuple, segments: _Segments, progress):
        """The ratio of the detections' range error to their bearing error (:mod:`pipeline.smoother.anisotropy`)
        with the highest evidence, searched upwards from isotropic detections on the chosen solution's
        detections (each ratio warm-started from the one before); when a ratio other than 1 wins, the smoother
        solved (and gated) again from its solution. The candidate kept, the record, the notes."""
        from slamobs.pipeline.smoother import evidence as ev
        from slamobs.pipeline.smoother import graph as g

        if self._ratio_configured():  # applied since the first solve (__init__)
            record, note = an.configured(self.noise.detection_ratio)
            return chosen, record, [note]
        if self.inverse_depth is not None:  # the inverse-depth factors shape every detection (__init__)
            return chosen, {"skipped": "the detections are weighed in inverse depth"}, []
        kf_t = keyframes[0]
        st = self.settings
        why = an.skipped(st.detection_anisotropy, self.fixed_bias is not None, kf_t.shape[0], EVIDENCE_MAX_KEYFRAMES)
        if why is not None:  # said in the notes where the mode asked for it
            said = st.detection_anisotropy != "off" and self.fixed_bias is None
            return chosen, {"skipped": why}, [f"batch: range and bearing not weighed apart: {why}"] if said else []

        base, sols = chosen.problem, {1.0: chosen.sol}
        thinning = self._independent_detections(base, chosen.sol, kf_t)
        if thinning is not None:  # the scan on detections about one correlation time apart, solved on them first
            base = g.with_detections(base, thinning[0])
            sols[1.0] = self._solved_from(base, chosen.sol, progress)
        scores = {1.0: ev.log_evidence(base, sols[1.0])}

        def shaped(ratio: float):
            return replace(base, det_shape=an.shape(base.det_y, ratio))

        ev.climb(DETECTION_RATIOS, *_climbing(progress, "range/bearing", shaped, self._solved_from), sols, scores)
        winner = an.winner(scores, ev.best_scale(scores))
        record, note = an.record(scores, winner, ev.CRITERION), an.note(scores, winner)
        if thinning is not None:
            record["thinned"] = thinning[1]
            note += an.thinning_note(thinning[1])
        if winner == 1.0:
            return chosen, record, [note]
        self.det_shape = an.shape(self.stream.det_y, winner)
        return self._solved_again(chosen, sols[winner], keyframes, segments, progress), record, [note]

    def _ratio_configured(self) -> bool:
        return self.noise.sources.get("detection_ratio") == "config"

    def _independent_detections(self, problem, sol, kf_t: np.ndarray) -> tuple[np.ndarray, dict] | None:
        """The detections of ``problem`` the range/bearing ratio's evidence is computed on when their errors are
        correlated in time (:func:`pipeline.smoother.correlation.thinned`, at the correlation time fitted to
        ``sol``'s residuals) and the record of it; None when they are white or the correlation is not modelled
        (``batch.detection_correlation: off``)."""
        from slamobs.pipeline.smoother import correlation as dc
        from slamobs.pipeline.smoother import graph as g

        if dc.skipped(self.settings.detection_correlation, self.fixed_bias is not None) is not None:
            return None
        t = kf_t[problem.kf_of_det]
        corr = dc.fit(t, problem.det_idx, g.whitened_residuals(problem, sol))
        if not corr.significant:
            return None
        kept = dc.thinned(t, problem.det_idx, corr.tau)
        return kept, {"spacing_s": round(corr.tau, 3), "detections": int(kept.size), "of": int(t.shape[0])}

    def _decorrelate(self, chosen, keyframes: tuple, segments: _Segments, progress):
        """The detections' time correlation fitted to the chosen solution's residuals
        (:mod:`pipeline.smoother.correlation`); when significant, every detection's variance is scaled by its
        track's factor and the smoother solved (and gated) again from that solution. The candidate kept, the
        record and the notes."""
        from slamobs.pipeline.smoother import correlation as dc
        from slamobs.pipeline.smoother import graph as g

        why = dc.skipped(self.settings.detection_correlation, self.fixed_bias is not None)
        if why is not None:
            return chosen, {"skipped": why}, []
        kf_t, kf_of_det, gaps = keyframes
        p, sol = chosen.problem, chosen.sol
        corr = dc.fit(kf_t[p.kf_of_det], p.det_idx, g.whitened_residuals(p, sol))
        if not corr.significant:
            return chosen, dc.record(corr, None), []
        self.det_factor = f = dc.inflation(kf_t[kf_of_det], self.stream.det_idx, corr)
        return self._solved_again(chosen, sol, keyframes, segments, progress), dc.record(corr, f), [dc.note(corr, f)]

    def _held_velocity(self, chosen, keyframes: tuple, segments: _Segments, progress):
        """A held velocity's level scaled to its solution's short-window residuals (:mod:`pipeline.smoother.
        held_velocity`), solved (and gated) again when it moved: the candidate kept, the record, the notes."""
        from slamobs.pipeline.smoother import held_velocity as hv

        nz = self.noise
        if (why := self._held_velocity_skipped()) is not None:
            return chosen, {"skipped": why}, []
        kf_t, _, gaps = keyframes
        p, sol = chosen.problem, chosen.sol
        residual = hv.interval_residuals(p.data, p.b_bar, sol.rot, sol.pos, sol.bias, p.seg_of)
        density = hv.window_density(kf_t, sol.rot, residual, across_gaps(kf_t, gaps))
        level = np.asarray(nz.velocity, float)
        s = hv.scale(density, level, self.stream.velocity)
        record = hv.record(density, level, s)
        if s == 1.0:
            return chosen, record, []
        self.noise = nz.scaled({"velocity": s}, "the smoother's solution's residuals over short windows")
        return self._solved_again(chosen, sol, keyframes, segments, progress), record, [hv.note(level, s)]

    def _detections_again(self, chosen, keyframes: tuple, segments: _Segments, progress, before: dict):
        """The detections' range/bearing ratio and time correlation chosen again once the held velocity's level
        moved, as a run with that level stated chooses them: from a solution at it with white (and, unless a ratio
        is configured, isotropic) detections. Kept only when the correlated share held
        (:func:`pipeline.smoother.correlation.share_held`, against ``before``, the correlation record at the pairs'
        level): where it fell, the new ratio took over the slow error the correlation modelled and the
        evidence, computed on detections thinned as independent, counted it as range noise (MR.CLAM 6-r1, 6-r2,
        7-r2: ratio 16 -> 32, APE 4.5-7 % and maps 8-37 % worse); where it held (7-r4: 0.118 -> 0.092 m, its grid
        best) the new model is the one the level asks for (docs/benchmarks.md, "batch's detection model again at
        the held level, session 29"). The candidate, the new (ratio record, notes, correlation record, notes) or
        None when not kept, the record, the notes."""
        from slamobs.pipeline.smoother import correlation as dc

        held = (chosen, self.det_factor, self.det_shape)
        self.det_factor = None
        if not self._ratio_configured():
            self.det_shape = None
        again = self._solved_again(chosen, chosen.sol, keyframes, segments, progress)
        again, anisotropy, anisotropy_notes = self._weigh_range(again, keyframes, segments, progress)
        again, correlation, correlation_notes = self._decorrelate(again, keyframes, segments, progress)
        kept = dc.share_held(before, correlation)
        record = {
            "ratio": anisotropy.get("ratio"),
            "share": correlation.get("share"),
            "tau_s": correlation.get("tau_s"),
            "share_before": before.get("share"),
            "stderr_before": before.get("stderr"),
            "kept": kept,
        }
        note = dc.again_note(record)
        if not kept:
            chosen, self.det_factor, self.det_shape = held
            return chosen, None, record, [note]
        return again, (anisotropy, anisotropy_notes, correlation, correlation_notes), record, [note]

    def _detection_level(self, chosen, keyframes: tuple, segments: _Segments, progress, correlation: dict):
        """The detection law scaled to the median of the chosen solution's detection residuals whitened by the law
        and shape (:mod:`pipeline.smoother.detection_level`), solved (and gated) again when it moved: the
        candidate kept, the record, the notes."""
        from slamobs.pipeline.smoother import detection_level as dl
        from slamobs.pipeline.smoother import graph as g

        nz = self.noise
        configured = any(nz.sources.get(k) == "config" for k in DETECTION_LAW_KEYS)
        why = dl.skipped(
            self.settings.detection_level,
            configured,
            self.fixed_bias is not None,
            correlation,
            self.inverse_depth is not None,
        )
        if why is not None:
            return chosen, {"skipped": why}, []
        full = replace(chosen.problem, **self._detections(keyframes[1]))
        whitened = g.whitened_residuals(full, chosen.sol)
        if self.det_factor is not None:  # the marginal model's: the effective-sample factor is no error variance
            whitened = whitened * np.sqrt(self.det_factor)[:, None]
        s = dl.scale(whitened)
        record = dl.record(whitened, s)
        if not dl.moved(s):
            return chosen, record, []
        self.noise = nz.scaled(
            dict.fromkeys(DETECTION_LAW_KEYS, s), "the median of batch's whitened detection residuals"
        )
        again = self._solved_again(chosen, chosen.sol, keyframes, segments, progress, same_motion=True)
        return again, record, [dl.note(s)]

    def _held_velocity_skipped(self) -> str | None:
        """Why the velocity level is not taken from the solution's short-window residuals, or None."""
        from slamobs.pipeline.smoother import held_velocity as hv

        return hv.skipped(self.settings.held_velocity, self.noise, self.fixed_bias is not None)

    def _evidence_keys(self) -> tuple[str, ...]:
        """The levels the evidence scans: :data:`pipeline.smoother.evidence.KEYS`, and the velocity's axes across
        the heading apart (``evidence.ACROSS``) when the velocity stream holds its values."""
        return EVIDENCE_KEYS + (EVIDENCE_ACROSS,) * ("velocity" in self.noise.held)

    def _evidence_skipped(self, key: str) -> str | None:
        """Why the scale of the level ``key`` is not chosen by the evidence here, or None."""
        mode, nz = self.settings.noise_evidence, self.noise
        key = "velocity" if key == EVIDENCE_ACROSS else key
        if mode == "off":
            return "batch.noise_evidence is off"
        if nz.sources.get(key) == "config":
            return f"noise: {key} is set in the configuration"
        if key == "velocity" and self._held_velocity_skipped() is None:
            return "the held velocity's level is its solution's short-window residual (batch.held_velocity)"
        if self.fixed_bias is not None:
            return "the biases are fixed (a reference run)"
        if mode == "held" and key not in nz.held:
            return f"the {key} level is measured from its samples (batch.noise_evidence: held)"
        return None

    def _evidence(self, chosen, keyframes: tuple, segments: _Segments, progress, scales: dict | None = None):
        """The scales of the motion levels (:data:`pipeline.smoother.evidence.KEYS`, one after the other, again
        while one moves: they trade off; until the scans' linear solves exceed ``EVIDENCE_SOLVE_BUDGET`` times the
        first solution's, or ``EVIDENCE_SOLVE_FLOOR``) chosen by the evidence: the candidate kept, the record per
        key (its last scan; ``scale`` of the level the run started from, ``scales`` the ones an earlier scan
        kept), the notes. A pass that moved nothing but had a near step (``evidence.NEAR_GAIN``) takes it for one
        more pass, kept when that pass moves a level, else undone."""
        n_kf = keyframes[0].shape[0]
        if self.settings.noise_evidence != "off" and n_kf > EVIDENCE_MAX_KEYFRAMES:
            why = f"the log has {n_kf} keyframes (more than {EVIDENCE_MAX_KEYFRAMES}): each scale would cost a solve"
            return (
                chosen,
                {k: {"skipped": why} for k in EVIDENCE_KEYS},
                [f"batch: noise levels not chosen by the evidence: {why}"],
            )
        keys, context = self._evidence_keys(), (keyframes, segments, progress)
        state = {"chosen": chosen, "records": {}, "total": dict.fromkeys(keys, 1.0) | (scales or {}), "near": []}
        budget = max(EVIDENCE_SOLVE_BUDGET * chosen.sol.summary["linear_solves"], EVIDENCE_SOLVE_FLOOR)

        def run_pass(notes: list):
            state["chosen"], moved, near, solves = self._evidence_pass(
                keys, state["chosen"], state["records"], state["total"], context, notes
            )
            return moved, near, solves

        def take(near: tuple):
            held = (state["chosen"], {k: dict(r) for k, r in state["records"].items()}, dict(state["total"]))
            held += (self.noise,)
            state["chosen"], solves = self._take_near(near, state["chosen"], state["records"], state["total"], context)
            state["near"].append({"key": near[0], "scale": near[1], "gain": round(float(near[2]), 3), "kept": True})
            return held, solves

        def undo(held: tuple):
            state["chosen"], state["records"], state["total"], self.noise = held
            state["near"][-1]["kept"] = False

        passes, spent, moved = evidence_search(run_pass, take, undo, budget)
        for step in state["near"]:  # run.json beside the level's record: the near steps the notes tell of
            state["records"][step["key"]].setdefault("near_steps", []).append(
                {k: v for k, v in step.items() if k != "key"}
            )
        notes = evidence_passes(passes, again=scales is not None)
        if moved:
            notes.append(
                f"batch: the evidence scan stopped at its budget ({spent} linear solves, {EVIDENCE_SOLVE_BUDGET:g}x "
                f"the first solution's or {EVIDENCE_SOLVE_FLOOR}) while a level still moved"
            )
        return state["chosen"], state["records"], notes

    def _evidence_pass(self, keys, chosen, records: dict, total: dict, context: tuple, notes: list):
        """One pass of the evidence over the levels ``keys`` (records, totals and the pass's notes updated in
        place): the candidate kept, whether a level moved, the near step (:func:`.evidence.near_step`: key, scale,
        gain and that scale's solution) of highest gain when none moved, and the linear solves it took."""
        moved, near, spent = False, None, 0
        for key in keys:
            if (why := self._evidence_skipped(key)) is not None:
                records[key] = {"skipped": why}
                continue
            lowest = EVIDENCE_SAMPLE_FLOOR / total[key] if self._sampled(key) else 0.0
            chosen, records[key], note, solves, step = self._scan(key, chosen, *context, lowest)
            notes.append(note)
            total[key] *= records[key]["winner"]
            records[key]["scale"] = round(total[key], 9)  # of the level the run started from, over every pass
            spent += solves
            moved |= records[key]["winner"] != 1.0
            if step is not None and (near is None or step[2] > near[2]):
                near = step
        return chosen, moved, None if moved else near, spent

    def _take_near(self, near: tuple, chosen, records: dict, total: dict, context: tuple):
        """The near step ``near`` (key, scale, gain, solution) taken for one more pass: the noise scaled, the
        smoother solved (and gated) again from that scale's solution; the candidate and the linear solves."""
        key, scale, _, sol = near
        self.noise = _scaled(self.noise, key, scale, say=True)
        again = self._solved_again(chosen, sol, *context)
        total[key] *= scale
        records[key]["scale"] = round(total[key], 9)
        return again, again.sol.summary["linear_solves"]

    def _sampled(self, key: str) -> bool:
        """The level ``key`` is measured from its own stream's samples (not held, not stated, not a default): the
        evidence does not take it below ``evidence.SAMPLE_FLOOR`` of that."""
        return self.noise.sources.get(key) == "estimated" and key not in self.noise.held

    def _scan(self, key: str, chosen, keyframes: tuple, segments: _Segments, progress, lowest: float = 0.0):
        """The scale of the level ``key`` with the highest evidence (:mod:`pipeline.smoother.evidence`), searched
        from the chosen solution on its detections (no scale below ``lowest``); when a scale other than 1 wins, the
        noise is scaled and the smoother solved (and gated) again from that scale's solution. The candidate kept,
        the record, the note, the linear solves the scan took, and its near step (key, scale, gain, solution:
        :func:`.evidence.near_step`) or None."""
        from slamobs.pipeline.smoother import evidence as ev

        kf_t, kf_of_det, gaps = keyframes
        base = chosen.problem
        sols, scores = {1.0: chosen.sol}, {1.0: ev.log_evidence(base, chosen.sol)}

        def problem_at(scale: float):
            return replace(base, data=self._motion_data(kf_t, gaps, base.b_bar, _scaled(self.noise, key, scale)))

        for direction in ev.search_order():
            direction = [scale for scale in direction if scale >= lowest * (1.0 - 1e-9)]
            if ev.climb(direction, *_climbing(progress, key, problem_at, self._solved_from), sols, scores) != 1.0:
                break  # the evidence rose downwards: no need to look upwards
        winner = ev.best_scale(scores)
        level = self.noise.velocity[1:] if key == EVIDENCE_ACROSS else getattr(self.noise, key)
        record, note = ev.record(key, level, scores, winner)
        solves = sum(sols[s].summary["linear_solves"] for s in sols if s != 1.0)
        if winner == 1.0:
            near = ev.near_step(scores, winner)
            return chosen, record, note, solves, None if near is None else (key, near[0], near[1], sols[near[0]])
        self.noise = _scaled(self.noise, key, winner, say=True)
        again = self._solved_again(chosen, sols[winner], keyframes, segments, progress)
        solves += again.sol.summary["linear_solves"] - chosen.sol.summary["linear_solves"]
        return again, record, note, solves, None

    def _cross_validation(self, chosen, keyframes: tuple, segments: _Segments, progress):
        """The noise scales chosen by blocked cross-validation (:mod:`pipeline.smoother.cross_validation`) instead
        of the evidence; when a pair other than x1, x1 wins, the smoother solved (and gated) again at it from the
        chosen solution. The candidate kept, the record, the notes."""
        from slamobs.pipeline.smoother import cross_validation as cv
        from slamobs.pipeline.smoother import graph as g

        kf_t, kf_of_det, gaps = keyframes
        nz, st, base, s = self.noise, self.settings, chosen.problem, chosen.sol
        motion_keys = tuple(k for k in cv.MOTION_KEYS if nz.sources.get(k) != "config")
        detection_free = all(nz.sources.get(k) != "config" for k in DETECTION_LAW_KEYS)
        why = (
            f"the log has more than {EVIDENCE_MAX_KEYFRAMES} keyframes"
            if kf_t.shape[0] > EVIDENCE_MAX_KEYFRAMES
            else "the biases are fixed (a reference run)"
            if self.fixed_bias is not None
            else "the noise levels are set in the configuration"
            if not motion_keys and not detection_free
            else None
        )
        if why is not None:
            return chosen, {"cross_validation": {"skipped": why}}, [f"batch: noise not cross-validated: {why}"]

        def motion_data(scale: float) -> np.ndarray:
            return self._motion_data(kf_t, gaps, base.b_bar, cv.scaled_noise(nz, scale, 1.0, motion_keys))

        def solve(problem, guess):
            return g.solve(problem, guess, max_iterations=cv.MAX_ITERATIONS, relative_tolerance=st.relative_tolerance)

        start = g.Guess(s.rot, s.pos, s.landmarks, s.bias)
        pairs = cv.candidates(bool(motion_keys), detection_free)
        scores = cv.cross_validate(base, start, cv.fold_of(kf_t[base.kf_of_det]), motion_data, solve, pairs)
        won = cv.winner(scores)
        record, note = cv.record(scores, won, int(base.det_idx.shape[0]))
        if won == (1.0, 1.0):
            return chosen, {"cross_validation": record}, [note]
        self.noise = cv.scaled_noise(nz, *won, motion_keys)
        return self._solved_again(chosen, s, keyframes, segments, progress), {"cross_validation": record}, [note]

    def _solved_from(self, problem, start, progress=None):
        """``problem`` solved from the solution ``start`` with the settings' iterations and tolerance."""
        from slamobs.pipeline.smoother import graph as g

        st = self.settings
        guess = g.Guess(start.rot, start.pos, start.landmarks, start.bias)
        return g.solve(
            problem,
            guess,
            max_iterations=st.max_iterations,
            relative_tolerance=st.relative_tolerance,
            progress=progress,
        )

    def _solved_again(self, chosen, start, keyframes: tuple, segments: _Segments, progress, same_motion=False):
        """The smoother on ``chosen``'s seed solved (and gated) again at the current noise levels and detection
        factors, from the solution ``start``: the new candidate, its summary continuing ``chosen``'s.
        ``same_motion``: only the detections changed, ``chosen``'s motion factors are kept (not preintegrated
        again)."""
        from slamobs.pipeline.smoother import graph as g
        from slamobs.pipeline.smoother.candidates import Candidate

        kf_t, kf_of_det, gaps = keyframes
        if same_motion:
            full = replace(chosen.problem, **self._detections(kf_of_det))
        else:
            full = self._problem(kf_t, kf_of_det, gaps, chosen.seed, segments)
        guess = g.Guess(start.rot, start.pos, start.landmarks, start.bias)
        solved, sol, notes = self._solve_gated(full, guess, chosen.seed.name, progress)
        sol.summary = g.merge_summaries(chosen.sol.summary, sol.summary)
        return Candidate(chosen.seed, solved, sol, notes)

    def _solve_gated(self, problem, guess, seed_name: str, progress):
        """Solve; then, unless the χ² gate drops so many detections that the minimum must be wrong, solve again
        without the outliers the Huber kernel still listens to. The problem solved last, its solution, notes."""
        from slamobs.pipeline.smoother import graph as g

        st = self.settings
        sol = self._solved_from(problem, guess, progress)
        kept = self._gate(problem, sol, st.gate_chi2)
        n_det = int(problem.det_idx.shape[0])
        notes = []
        if kept is not None and n_det - kept.size > MAX_GATED * n_det:  # not outliers: a wrong minimum
            notes.append(gate_note(n_det - kept.size, n_det, seed_name, self.stream.topics))
            kept = None
        if kept is not None:  # outliers the Huber kernel still listens to: solved again without them
            notes += emptied_note(np.setdiff1d(problem.det_idx, problem.det_idx[kept]).size)
            first = sol.summary
            problem = g.with_detections(problem, kept)
            sol = self._solved_from(problem, sol, progress)
            sol.summary = g.merge_summaries(first, sol.summary)
        return problem, sol, notes

    def _summary(self, sol, seed_name: str, residuals: dict) -> tuple[dict, dict]:
        """The smoother's summary for the run's metadata, and the solver's seconds per stage (taken out of it)."""
        st = self.settings
        sd = np.sqrt(np.clip(np.einsum("sii->si", sol.bias_cov), 0.0, None))
        seconds = sol.summary.pop("seconds")
        summary = {
            "seed": seed_name,
            "bias_model": st.bias,
            **sol.summary,
            "residuals": residuals,
            "bias": {"estimate": sol.bias.tolist(), "sigma": sd.tolist()},
            "settings": {
                "huber": st.huber,
                "gate_chi2": st.gate_chi2,
                "keyframe_dt": st.keyframe_dt,
                "segment_s": st.segment_s,
                "max_iterations": st.max_iterations,
                "relative_tolerance": st.relative_tolerance,
            },
        }
        return summary, seconds

    @staticmethod
    def _gate(problem, sol, gate_chi2: float | None) -> np.ndarray | None:
        """Detections whose whitened residual at the solution passes the χ² gate (riekf's test, 3 degrees of
        freedom), or None when all do (or there is no gate)."""
        if gate_chi2 is None:
            return None
        from slamobs.pipeline.smoother.graph import whitened_residuals

        d2 = np.sum(whitened_residuals(problem, sol) ** 2, axis=1)
        kept = d2 <= gate_chi2
        return None if kept.all() else np.flatnonzero(kept)

    def detection_distances(self, det_first: int, det_stop: int) -> np.ndarray | None:
        """The detections' χ² under the solution's detection model (``ObserverResult.innovation_d2``)."""
        return None if self.result is None else self.result["det_d2"][det_first:det_stop]

    def landmark_covariance(self) -> np.ndarray | None:
        """The landmarks' marginal covariances at the solution (None before the solve)."""
        return None if self.result is None else self.result["landmark_cov"]

    # ------------------------------------------------------------------ stretches
    def _relocalise(self, iv: int) -> bool:
        """A new segment: nothing to do here, the keyframes after the gap are fit to the map by the solve (the
        relative motion across the gap is left almost unconstrained, ``GAP_SIGMA``)."""
        return True

    def _kernel(self, iv_stop: int, out: Outputs, budget: int) -> int:
        """Everything from the state's next sample to ``iv_stop`` at once (the solve, on the first call, is
        Python and compiled calls of about a second each at most: signals are handled between them)."""
        from slamobs.pipeline import native
        from slamobs.pipeline.smoother.preintegration import sample_poses

        if self.result is None:
            self.solve(self.options.progress)
            # the solve's freed temporaries back to the system before the stretches allocate their rows: glibc
            # keeps them in its heap else, and the rows and the writer's buffers land beside them
            native.return_freed_memory()
        res, s, ns = self.result, self.stream, self.state.ns
        sol = res["solution"]
        n_vel = self.n_vel
        every = self.options.out_every
        rows = np.arange(int(ns[_IV]), iv_stop)
        rows = rows[(rows % every == 0) | (rows == n_vel - 1)]
        n = rows.shape[0]
        if n:
            # the samples the poses integrate over: from the keyframe before the first row to the one after the last
            kf_t, vel_t = res["kf_t"], self.vel_t
            j0 = max(int(np.searchsorted(kf_t, vel_t[rows[0]], side="right")) - 1, 0)
            j1 = min(int(np.searchsorted(kf_t, vel_t[rows[-1]], side="left")), kf_t.shape[0] - 1)
            lo = max(int(np.searchsorted(vel_t, kf_t[j0], side="right")) - 1, 0)
            hi = min(int(np.searchsorted(vel_t, kf_t[j1], side="right")) + 1, n_vel)
            span = slice(lo, hi)
            bias_span = sol.bias[res["segments"].of(vel_t[span])]
            sample_poses(
                vel_t[span],
                s.omega[span],
                s.velocity[span],
                kf_t,
                sol.rot,
                sol.pos,
                bias_span,
                rows - lo,
                out.r[:n],
                out.p[:n],
            )
            out.b[:n] = bias_span[rows - lo]
        out.k[:n] = rows
        interpolate_covariance(res["cov_t"], res["pose_cov"], self.vel_t[rows], out.cov[:n])
        # detections of the frames up to iv_stop: estimates from the solution at their keyframes
        jf_stop = self._frames_before(iv_stop)
        a, b = int(s.det_offsets[int(ns[_JF])]), int(s.det_offsets[jf_stop])
        if b > a:
            kf = res["kf_of_det"][a:b]
            lm = sol.landmarks[s.det_idx[a:b]]
            out.trk[a - out.det_base : b - out.det_base] = lm
            out.innov[a - out.det_base : b - out.det_base] = (
                lm - np.einsum("mij,mj->mi", sol.rot[kf], s.det_y[a:b]) - sol.pos[kf]
            )
        self.lm[:] = sol.landmarks
        if n:
            self.state.r_hat[:], self.state.p_hat[:] = out.r[n - 1], out.p[n - 1]
        ns[_IV], ns[_JF] = iv_stop, jf_stop
        return n


def floor_information(kf_t: np.ndarray) -> np.ndarray:
    """Each keyframe's floor information (K, 2: the tilt rows' and the height row's ``1/σ²``): riekf's levels per
    pseudo-measurement (``PLANAR_TILT``, ``PLANAR_HEIGHT``) spread over the keyframes by the time each stands for
    (half its intervals, at most ``PLANAR_EVERY_S``): the same information per second as riekf's floor, whatever
    the keyframes' spacing."""
    from slamobs.pipeline.observers import riekf as rk

    share = np.zeros(kf_t.shape[0])
    if kf_t.shape[0] > 1:
        half = 0.5 * np.diff(kf_t)
        share[:-1] += half
        share[1:] += half
    w = np.minimum(share, rk.PLANAR_EVERY_S) / rk.PLANAR_EVERY_S
    return np.stack([w / rk.PLANAR_TILT**2, w / rk.PLANAR_HEIGHT**2], axis=1)


def _scaled(noise, key: str, scale: float, say: bool = False):
    """``noise`` with its level ``key`` scaled by ``scale`` (``say``: its method saying so); ``evidence.ACROSS``
    scales the velocity's body y and z axes."""
    if key == EVIDENCE_ACROSS:
        return noise.scaled({"velocity": np.array([1.0, scale, scale])}, "the smoother's evidence" if say else None)
    return noise.scaled({key: scale}, "the smoother's evidence" if say else None)


def _marginals(kf_t: np.ndarray, problem, sol) -> tuple:
    """The marginal covariances the tables carry (not the bias's, inside the solve): the gauge keyframe they are
    defined against, the keyframes they are computed at, the poses' and the landmarks' covariances, and the
    (wall, CPU) seconds they took."""
    from slamobs.pipeline.smoother import graph as g

    t1, c1 = time.perf_counter(), time.process_time()
    gauge = covariance_gauge(kf_t, problem.kf_of_det)
    cov_kf = np.union1d(covariance_keyframes(kf_t), [gauge])
    pose_cov, landmark_cov = g.covariances(replace(problem, anchor=gauge), sol, cov_kf)
    return gauge, cov_kf, pose_cov, landmark_cov, (time.perf_counter() - t1, time.process_time() - c1)


SPEC = ObserverSpec(
    name="batch",
    algorithm="smoother",
    paper="factor-graph smoother (Levenberg-Marquardt) over preintegrated odometry and landmark factors",
    summary="reference solution: keyframe poses, landmarks and biases by least squares, seeded by an observer "
    "(batch.seed)",
    gains=(),
    start=BatchSmoother,
    check_config=check_config,
    uses_noise=True,
    own_time_offset=True,
    interpolates=True,
    takes_known_map=False,
)
