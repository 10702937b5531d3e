"""Put the multi-rate streams on one time base and in the body frame: one ordered stream for an observer.

Angular velocity sets the time base (usually the fastest stream); body linear velocity is interpolated
linearly onto it. Landmark detections are moved from the camera frame into the body frame and their ids
mapped to dense indices. Everything an observer needs is here, as arrays.

Frames: the body frame is ``body_frame`` if given, else the frame of the linear velocity (the odometry child
frame). Each sensor frame is brought into it through ``/tf_static`` when a static chain exists (one constant
transform). Otherwise, as logs often publish fixed extrinsics on ``/tf`` (ROS1 static_transform_publisher,
robot_state_publisher) and moving ones (gimbals, TF tag frames under a world frame) only there, the chain
through ``/tf`` is interpolated at every sample: velocity and direction samples outside the ``/tf`` span hold
the nearest transform (an extrinsic that drifts little), detection frames outside it are dropped (a moving
camera must not be guessed). Which edges were used is reported in the notes.

Plausibility gates (``limits``, see ``DEFAULT_LIMITS``) drop what no sensor produces: angular rates and
speeds beyond a limit, detections nearer or farther from the body origin than a limit; each is counted in the
notes. Gaps in the velocity streams longer than ``max_gap`` split the run into segments
(``AlignedStream.segment_starts``): the observer holds its state across a gap rather than integrating the last
twist over it, time-base samples inside a linear-velocity gap and detection frames inside a gap are dropped.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from functools import partial

import numpy as np

from slamobs.pipeline.directions import (
    body_acceleration,
    gravity_up,
    ACCEL_GATE,
    ACCEL_TOL,
    DEFAULT_GRAVITY,
    DEFAULT_MAGNETIC_FIELD,
    DirectionSet,
    build_directions,
)
from slamobs.pipeline.blocks import (
    equal_rows,
    far_repeats,
    first_of_pairs,
    interp_sorted,
    row_blocks,
    row_norms3,
    unique_inverse,
)
from slamobs.pipeline.errors import InputError, plural
from slamobs.pipeline.frames import TfBuffer
from slamobs.pipeline.lie import rot_to_quat
from slamobs.pipeline.readers.decode import CLOCK_STEP_NS, off_pace, shared_id_text, stamp_pace
from slamobs.pipeline.readers.inspect import GAP_FACTOR
from slamobs.pipeline.readers.roles import (
    DIRECTION_ROLES,
    REQUIRED_ROLES,
    ROLE_PURPOSE,
    how_to_satisfy,
    trajectory_use,
)
from slamobs.pipeline.readers.tf_tree import BODY_FROM_CONFIG, BODY_FROM_DEFAULT
from slamobs.pipeline.streams import DetectionStream, LogStreams, PoseStream, Vec3Stream


@dataclass(frozen=True)
class Limits:
    """Plausibility gates (``limits:`` in run.yaml; None switches one off). Far outside anything a real vehicle or
    sensor produces, so they drop only corrupt samples: a detection nearer than 5 cm (no camera focuses there) or
    farther than 500 m, an angular rate above 100 rad/s (past every MEMS gyro's full scale, ~35-70 rad/s), a
    speed above 300 m/s; a velocity gap longer than 5 s splits the run into segments, except a gap of the linear
    velocity alone (the time base recording through it), which splits it past 10 s: up to that the gyro keeps the
    attitude and the velocity is interpolated across with its noise widened (``_bridged_gaps``)."""

    min_range: float | None = 0.05
    max_range: float | None = 500.0
    max_angular_rate: float | None = 100.0
    max_speed: float | None = 300.0
    max_gap: float | None = 5.0
    max_odometry_gap: float | None = 10.0

    def as_dict(self) -> dict[str, float | None]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


DEFAULT_LIMITS = Limits().as_dict()

#: Start of the note on the accelerometer's down-weighted samples (only runs that use the accelerometer keep it).
ACCEL_NOTE = "accelerometer: "

#: Velocity gaps longer than this (seconds) are reported: the observer holds the last sample across them.
GAP_WARN_S = 0.5
#: A measuring velocity stream's gaps (over ``GAP_FACTOR`` median intervals) covering this share of its span are a
#: warning (a 400 Hz IMU dropping 0.1 s every 4 s covers 2.5 %); under it a note (docs/benchmarks.md, "Silent
#: wrong results, round 9": the values on the real logs).
GAP_SHARE_WARN = 0.01
#: A velocity stream with at least this share of its samples equal to the one before is a held command, not a
#: measurement: its gaps are the command held, not samples lost.
HELD_STEP_SHARE = 0.5
#: A velocity stream with at least this share of its samples repeating the stamp before with another value is a
#: warning (MR.CLAM's robots: 0-3 such samples in 52,000-65,000, under 0.01 %).
REPEAT_SHARE_WARN = 0.01

#: The gyro against its own accelerometer (:func:`_gyro_by_gravity`): samples of the time base looked at (its start:
#: it runs on the run's path before the observer, so bounded; 2^15 is 163 s of 200 Hz, over 150 block pairs where 20
#: say something, and holds every real log's IMU whole), the blocks whose mean gravity direction is differenced (s),
#: the fewest block pairs that say anything, and how many times better a misread must fit.
TILT_SAMPLES = 1 << 15
TILT_BLOCK_S = 1.0
TILT_MIN_PAIRS = 20
TILT_MISREAD_GAIN = 4.0


#: The gyro's stamps against the odometry's own angular velocity (:func:`_gyro_lag`): an IMU stamped on another
#: clock seconds off the odometry's, in a log whose record times follow the stamps (a converted MCAP), passes every
#: header-against-record rule (a generated figure 8's IMU 0.3 s late: riekf 0.53 m against 0.011 m, exit 0, no
#: word; 2 s late: lost). Per lag, the rotation and offset that fit the gyro onto the odometry's angular velocity
#: (Kabsch, centred: any mounting, any bias) leave a misfit; the lags up to ``GYRO_LAG_MAX_S`` on a
#: ``GYRO_LAG_STEP_S`` grid (by FFT), then, unless the best of them is 0, refined to ``GYRO_LAG_FINE_S``, over the
#: first ``GYRO_LAG_SPAN_S`` of the odometry; a warning when the best lag is ``GYRO_LAG_WARN_S`` or more, its misfit
#: under ``GYRO_LAG_MAX_MISFIT`` of the odometry's variance and ``GYRO_LAG_GAIN`` times under that as stamped.
#: That lag is then taken off the IMU topic's stamps before anything reads them (:func:`_gyro_lag_taken_off`; on
#: slow turns too, ``GYRO_LAG_PROBE_S``): read as stamped, the detection pairs took it for the detections' offset.
GYRO_LAG_MAX_S = 20.0
GYRO_LAG_STEP_S = 0.05
GYRO_LAG_FINE_S = 0.005
GYRO_LAG_SPAN_S = 600.0
GYRO_LAG_WARN_S = 0.05
GYRO_LAG_MAX_MISFIT = 0.3
GYRO_LAG_GAIN = 4.0
#: both magnitudes are averaged over this window (s), or over the odometry's interval if longer
GYRO_LAG_SMOOTH_S = 0.1
#: odometry samples the fine grid and the lag as stamped are computed on (evenly spread)
GYRO_LAG_FINE_SAMPLES = 2000
#: The check's power: where a lag this long would fit under ``GYRO_LAG_GAIN`` times worse than the best lag (slow
#: turns, a ground robot's: a generated ground log's IMU 0.3 s late fit 1.93x better so shifted, a figure 8's 43x),
#: a note says the lag could not be checked, with the best fit found, rather than nothing.
GYRO_LAG_PROBE_S = 0.3
#: ... and warns then only where the lag fits this well (a generated ground robot: 0.0035 of the odometry's variance;
#: robot_localization's test1, a Husky whose wheels slip: 0.297, its best lag 0.4 s early a note, not a warning)
GYRO_LAG_SLOW_MAX_MISFIT = 0.05
#: ... and, on slow turns (where the gain asked is near 1), where that gain on the other half is ``GYRO_LAG_SIGMAS``
#: standard errors of the misfits' difference or more (:func:`_lag_gain_sigmas`; the standard error from
#: ``GYRO_LAG_BLOCKS`` consecutive blocks of the half; two, the round rule: a t of 9 degrees of freedom is over it
#: 4 % of the time, and both halves must be). The ratio alone asks the same of 360 samples as of 36,000: 2 Hz
#: odometry on a ground robot's slow turns (seed=4632, 180 s) moved a right IMU by +0.060 s on a 1.045x held-out
#: gain 1.3 standard errors from none (generated ground logs so moved: 0.75-1.32; their IMU 0.3 s late: 1.6-5.4).
#: Fast turns ask ``GYRO_LAG_GAIN`` (4x), which no such noise gives; a 20 s figure 8's IMU 0.3 s late fits its other
#: half 29x better, but with 100 samples a half only 2.5 standard errors (its few sharp turns carry the gain).
GYRO_LAG_SIGMAS = 2.0
GYRO_LAG_BLOCKS = 10
#: ... and moves a stream only where the lag each half of the span finds fits the other half that much better than
#: as stamped too (:func:`_held_out_gain`): the gain of the best of many lags on the same samples is biased up by
#: the choice (a clean two-hour ground log, seed=3979, and a 10-minute one, seed=3983: 0.100 s, 1.05x better, on
#: slow turns that ask 1.03-1.04x; on all the span's samples the clean log's best lag gains 1.01x). No constant:
#: the gain asked is the same (``GYRO_LAG_GAIN``, or the slow turns' share of the probe's), only measured on samples
#: the lag was not chosen on.


#: The gyro's axes in the body frame against the odometry's own angular velocity (:func:`_gyro_axes`): a gyro whose
#: frame reaches the body turned (an IMU frame listed in frames.assume_identity that is mounted otherwise, a wrong
#: extrinsic: robot_localization's test1 IMU reads its yaw rate on y, gravity on y) turns the estimate about another
#: axis than the odometry does; riekf and batch see it through the detections, fast-adaptation absorbs it into its
#: gyro bias (a generated figure 8, its IMU rolled 90 deg and taken as the body: APE 0.103 m against 0.046 m, a gyro
#: bias error of 0.45 rad/s, exit 0, no word). Over the first ``GYRO_LAG_SPAN_S`` of the odometry, its turn's main
#: axis against the gyro's response to it (least squares, centred: a bias does not count); a warning when the two are
#: ``GYRO_AXIS_WARN_DEG`` or more apart, the odometry turning at ``GYRO_AXIS_MIN_RATE`` rad/s RMS or more, and the
#: gyro's response explaining all but ``GYRO_AXIS_MAX_MISFIT`` of its variance (a gyro that follows the turn at all).
GYRO_AXIS_WARN_DEG = 30.0
GYRO_AXIS_MIN_RATE = 0.05
GYRO_AXIS_MAX_MISFIT = 0.5

#: The linear velocity's rate against the motion the IMU sees (:func:`_velocity_unresolved`): a velocity stream
#: samples the body's motion at its own rate; motion above half that rate (its Nyquist frequency) folds onto slower
#: motion in its samples, which no noise level or estimator undoes (a hand-held rig's 1.8 Hz step bob in 2 Hz
#: odometry, round 11's seed=4631: the velocity level estimated 1.3-3.4x the white truth, riekf 0.258 m "yes", no
#: word). The IMU's accelerometer, at its own rate, sees that motion: its spectrum (``UNRESOLVED_SEGMENTS_NYQUIST``
#: Nyquist periods a segment, Hann-windowed, averaged) over ``(2 pi f)^2`` above the velocity's Nyquist frequency,
#: the accelerometer's white floor (its median density over the top half of its band) taken off, is the velocity
#: the stream cannot carry; a warning where its variance is ``UNRESOLVED_VELOCITY_SHARE`` or more of the velocity
#: samples' own (centred, summed over the axes: frames do not matter).
UNRESOLVED_SEGMENTS_NYQUIST = 8
#: A tenth of the samples' variance: the folded motion then is a third of their spread (sqrt 0.1), beside which a
#: white-noise level read from them is that motion's, not the sensor's (seed=4631: 56 %; a generated hand-held rig
#: at 10 or 20 Hz and a flight at 2 Hz: none; robot_localization's test1 Husky, 10 Hz odometry beside a 30 Hz IMU:
#: 0.0098 m/s, under 0.5 %). Not told apart: a stream that averages over its interval holds none of that motion
#: (its samples' variance lacks it: 140 % on seed=4631's kind so sampled), and is named too.
UNRESOLVED_VELOCITY_SHARE = 0.1
#: gyro samples of that span the check takes, evenly spread (an hour at 400 Hz: 0.065 s of CPU with all 240,000
#: of its first 600 s, 0.02 s so; the angle is the same on the logs tried)
GYRO_AXIS_SAMPLES = 20000
#: What the turned gyro's warning asks for; the detection pairs' misread check names it when it sees the same turn
#: (``time_offset.GYRO_TURN_SEEN``).
GYRO_TURN_ADVICE = "record the transform of '{frame}' on /tf_static"
#: An accelerometer taken as the body as read (:func:`accel_up_unaligned`): its mean specific force over the log,
#: when its size is within ``ACCEL_UP_MIN_G`` of |g| (a frame that stays put or moves about a steady attitude; a
#: handheld IMU waved about, imu_tools' SparkFun sample at 0.65 g, tells no up axis), is gravity's reaction: the
#: frame's up axis. A warning when it is ``ACCEL_UP_WARN_DEG`` or more from +z, the body's up axis (REP 103): imu_tools'
#: Phidgets sample (upside down, 1.00 g) 179 deg off, robot_localization's test1 90 deg (its yaw rate on y too), the
#: ETH MSF MAV's 4 deg and a generated figure 8's IMU as mounted nothing.
ACCEL_UP_MIN_G = 0.9
ACCEL_UP_WARN_DEG = 30.0
#: Added to that warning when the gyro turns the other way about the odometry's axis (within ``GYRO_AXIS_WARN_DEG`` of
#: 180 deg): an IMU mounted upside down, as imu_tools' Phidgets sample is, taken as the body (a generated figure 8 so:
#: fast-adaptation's APE 0.148 m against 0.046 m with the IMU's extrinsic, its z gyro bias off by 0.64 rad/s, exit 0
#: and no word before session 30, when the angle was taken unsigned: 2 deg).
GYRO_TURN_REVERSED = "; it turns the other way: an IMU mounted upside down, or a gyro of the wrong sign"


#: An odometry stuck (a frozen driver, wheels off the ground): its whole twist, linear and angular, exactly zero for
#: ``STUCK_MIN_S`` or longer while the gyro (another topic) turns at a median ``STUCK_GYRO_RATE`` rad/s or more there
#: (a robot standing still: its gyro's noise and bias, ~0.01 rad/s; one turning on the spot: the odometry's own
#: angular velocity is not zero). A generated figure 8 whose /odom twist is zero over 14 of its 40 s: riekf APE 0.81 m
#: against 0.011 m, warned only as "moved along x -0.157x as far as its velocity says (in another unit or scale?)";
#: fast-adaptation 0.51 m against 0.12 m, "likely lost" (session 27).
STUCK_MIN_S = 1.0
STUCK_GYRO_RATE = 0.1
STUCK_SHOWN = 3  # stretches named in the warning


def _odometry_stuck(lv: Vec3Stream, twist: Vec3Stream, time_source: str, t_om, omega, gyro_topic: str) -> list[str]:
    """The warning of an odometry whose twist (``lv`` and its own angular velocity ``twist``, one message each)
    reads exactly zero for a while as the gyro (``omega`` on the time base ``t_om``) turns: see ``STUCK_MIN_S``."""
    if twist.t_ns.shape[0] != lv.t_ns.shape[0] or lv.t_ns.shape[0] < 2:
        return []
    t, v, w = _sorted(_times(lv, time_source), lv.xyz, twist.xyz)
    zero = np.all(v == 0.0, axis=1) & np.all(w == 0.0, axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], zero.view(np.int8), [0]])))
    runs = [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    stuck = []
    for a, b in runs:
        b = min(b + 1, t.shape[0] - 1)  # the zero holds until the next message
        if (t[b] - t[a]) * 1e-9 < STUCK_MIN_S:
            continue
        inside = row_norms3(omega[np.searchsorted(t_om, t[a]) : np.searchsorted(t_om, t[b])])
        inside = inside[np.isfinite(inside)]
        if inside.shape[0] and (median := float(np.median(inside))) >= STUCK_GYRO_RATE:
            stuck.append(((t[a] - t_om[0]) * 1e-9, (t[b] - t_om[0]) * 1e-9, median))
    if not stuck:
        return []
    total = sum(b - a for a, b, _ in stuck)
    spans = ", ".join(f"{a:.1f}-{b:.1f} s" for a, b, _ in stuck[:STUCK_SHOWN]) + (
        ", ..." if len(stuck) > STUCK_SHOWN else ""
    )
    rates = f"{min(m for *_, m in stuck):.2f}-{max(m for *_, m in stuck):.2f}"
    return [
        f"warning: {lv.topic}: its twist reads exactly zero for {total:.1f} s in "
        f"{plural(len(stuck), 'stretch', 'stretches')} "
        f"({spans} into the log) while {gyro_topic}'s gyro turns at a median {rates} rad/s there: the odometry "
        "stuck (a frozen driver, wheels off the ground), read as the body standing still; the estimate over those "
        "stretches follows the detections alone and is off: cut them (time.start, time.end) or fix the odometry"
    ]


#: A gyro saturating (its range exceeded on fast turns) holds its largest reading: the samples at the largest absolute
#: value of one axis, in stretches of ``SATURATED_MIN_RUN`` or more in a row, ``SATURATED_MIN_SHARE`` of the samples
#: or more, are named (a noisy gyro reads its largest value once). A generated hand-held rig whose gyro clips at
#: 1 rad/s (its yaw rate to 2.5 rad/s): riekf lost (APE 7.9 m), fast-adaptation 0.50 m with a verdict "yes", batch
#: 0.040 m with its gyro level x9, no word (docs/benchmarks.md, "Logs nobody has run yet, round 7").
SATURATED_MIN_RUN = 3
SATURATED_MIN_SHARE = 0.001


def _held_at_top(omega: np.ndarray) -> tuple[list, list]:
    """The axes of ``omega`` (N, 3) that hold their largest absolute reading in stretches (``SATURATED_MIN_RUN``,
    ``SATURATED_MIN_SHARE``): ``(axis, top, held samples, stretches, N)`` each, and each such stretch's first and
    last row, axis and reading held ``(a, b, k, top)``."""
    found, rows = [], []
    for k, axis in enumerate("xyz"):
        col = omega[:, k]
        top = max(float(col.max(initial=-np.inf)), -float(col.min(initial=np.inf)))
        if not np.isfinite(top):  # a NaN read (the run drops it): the finite samples'
            col = col[np.isfinite(col)]
            top = max(float(col.max(initial=0.0)), -float(col.min(initial=0.0)))
        # a noisy gyro's largest reading comes once: the stretches are looked for only where it comes often (the
        # hour's 720,000 samples: 4.5 CPU ms, the counts' strided passes)
        n, floor = col.shape[0], max(SATURATED_MIN_RUN, SATURATED_MIN_SHARE * col.shape[0])
        if top <= 0.0 or np.count_nonzero(col == top) + np.count_nonzero(col == -top) < floor:
            continue
        at = np.abs(omega[:, k]) == top  # on the rows as read (a NaN row is not at the top)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], at.view(np.int8), [0]])))
        runs = edges[1::2] - edges[::2]
        long = runs >= SATURATED_MIN_RUN
        held = int(runs[long].sum())
        if held >= SATURATED_MIN_SHARE * n:
            found.append((axis, top, held, int(np.count_nonzero(long)), n))
            rows += [(a, b, k, top) for a, b in zip(edges[::2][long].tolist(), (edges[1::2][long] - 1).tolist())]
    return found, rows


def _clipped_spans(rows: list, t_ns: np.ndarray, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stretches :func:`_held_at_top` found (``rows``) as ``(S, 2)`` int64 ns, their first and last sample
    (``t_ns`` the stamps of the rows of ``omega`` as read), in time order, and how far each one's true rate may lie
    beyond the reading held (rad/s): the rate's rise over half the stretch's span before it, or its fall over as
    long after it, the larger (a rate that rose at that pace and turned back at the middle; 3x the excess of a
    parabolic peak, the excess of a tent): ``AlignedStream.gyro_clipped``, ``gyro_excess``."""
    found = np.asarray([(a, b) for a, b, *_ in rows], np.int64)
    ends = t_ns[found]
    excess = np.zeros(found.shape[0])
    by_time = np.argsort(t_ns, kind="stable")
    ts = t_ns[by_time]
    for i, (a, b, k, top) in enumerate(rows):
        half = (int(t_ns[b]) - int(t_ns[a])) // 2
        # the sample half the span before the first (at or after that time) and half after the last (at or before)
        j0, j1 = np.searchsorted(ts, t_ns[a] - half), np.searchsorted(ts, t_ns[b] + half, side="right") - 1
        near = [by_time[j] for j, ok in ((j0, ts[min(j0, ts.shape[0] - 1)] < t_ns[a]), (j1, ts[j1] > t_ns[b])) if ok]
        held = top if omega[a, k] > 0 else -top  # signed: the rate may come from the other side's range
        excess[i] = max([abs(held - float(omega[j, k])) for j in near if np.isfinite(omega[j, k])], default=0.0)
    order = np.argsort(ends[:, 0], kind="stable")
    return np.sort(ends[order], axis=1), excess[order]


def _saturated_words(found: list, topic: str) -> list[str]:
    """The warning of a gyro on ``topic`` whose axes hold their largest absolute reading in stretches: the axes
    :func:`_held_at_top` found (``SATURATED_MIN_RUN``, ``SATURATED_MIN_SHARE``)."""
    if not found:
        return []
    said = "; ".join(
        f"about {axis} ±{top:.4g} rad/s on {held} samples ({100.0 * held / n:.2g} %) in "
        f"{plural(k, 'stretch', 'stretches')}"
        for axis, top, held, k, n in found
    )
    return [
        f"warning: {topic}: its angular velocity holds its largest reading in stretches ({said}): a gyro "
        "saturating, its range exceeded on fast turns? the turns there read too slow and every estimate turns too "
        "little: set the gyro's range higher at its driver"
    ]


#: One landmark id at several places (a misdecoded tag id, tags of one id in view in turn): two detections of one id
#: at most ``GHOST_PAIR_S`` apart, the first moved by the velocities between them, should land on the second. An id
#: with ``GHOST_MIN_PAIRS`` such pairs whose median misfit is ``GHOST_RATIO`` times the run's median and over
#: ``GHOST_MIN_M`` is named (a generated figure 8 with 10 % of its detections given id 9999: fast-adaptation 1.09 m
#: against 0.12 m, exit 0, no word; session 24).
GHOST_PAIR_S = 0.5
GHOST_MIN_PAIRS = 5
GHOST_RATIO = 20.0
GHOST_MIN_M = 0.2
GHOST_SHOWN = 5  # ids named in the warning
GHOST_SPAN_S = 600.0  # the detections of the first 10 min (the hour's 577,200: 0.16 CPU s; these: 0.03)
#: The same id misread rarely (no two of its detections within ``GHOST_PAIR_S``: about one detection in 70 of a
#: generated figure 8 given id 9999, fast-adaptation 0.31 m against 0.12 m, its map 0.58 m; session 25) is seen by
#: its distance to the other ids in the same frame, which for two static landmarks is one length whatever the pose:
#: an id whose distances to ids it was seen with at least twice change by a median (about each pair's median) of
#: ``GHOST_RATIO`` times the run's and over ``GHOST_MIN_M``, over ``GHOST_MIN_PAIRS`` such distances, is named.
GHOST_NEIGHBOURS = 2


def _axes(*order: int, sign=(1.0, 1.0, 1.0)) -> np.ndarray:
    return np.eye(3)[list(order)] * np.asarray(sign)[:, None]


#: Gyro misreads the detection pairs hardly see (they see yaw; ``time_offset.GYRO_MISREADS`` has the ones they
#: do), as the matrix that undoes them (``omega @ m.T`` in the IMU's frame, turned into the body's by its
#: extrinsic): x and y swapped (a generated figure 8 so read: riekf 0.87 m against 0.011 m, exit 0, no word), or
#: one of them of the wrong sign.
TILT_MISREADS = {
    "x and y were swapped": _axes(1, 0, 2),
    "x were of the wrong sign": _axes(0, 1, 2, sign=(-1.0, 1.0, 1.0)),
    "y were of the wrong sign": _axes(0, 1, 2, sign=(1.0, -1.0, 1.0)),
}


class WarnOnly:
    """The alignment's checks whose result is a note only (a warning; nothing the observers read depends on them):
    the gyro against its accelerometer (:func:`_gyro_by_gravity`), the landmark ids read at several places
    (:func:`_misread_ids`), an odometry stuck at zero while the gyro turns (:func:`_odometry_stuck`).
    :func:`align` adds each where its notes go (:meth:`add` gives a marker in their place); :meth:`run`, the one
    place they run, computes them: at once in :func:`align`, or with ``align(warn_only_later=True)`` on a thread
    beside the observer (``pipeline.run``: ~0.17 of the one-hour log's ~0.30 CPU s of align, docs/benchmarks.md
    session 26; the gyro's lag, 0.023 of them, left since its stamps are moved by it, session 27), and
    :meth:`joined` puts their notes where :func:`align` would have, so the notes are the same."""

    MARKER = "\0warn-only "

    def __init__(self) -> None:
        self.checks: list | None = []  # the checks' calls, in the order of their markers
        self.unique: list[bool] = []  # a note already said before it is left out (the directions' notes)
        #: where their notes go, in the markers' order: (before which of the notes without the markers, which check)
        self.at: list[tuple[int, int]] = []

    def add(self, check, *args, unique: bool = False) -> str:
        """``check(*args)`` (its notes, a list) to run later; the marker that stands for its notes meanwhile."""
        self.checks.append(partial(check, *args))
        self.unique.append(unique)
        return f"{self.MARKER}{len(self.checks) - 1}"

    def placed(self, notes: list[str]) -> list[str]:
        """``notes`` without the markers, whose places are kept (:attr:`at`)."""
        out, self.at = [], []
        for n in notes:
            if n.startswith(self.MARKER):
                self.at.append((len(out), int(n[len(self.MARKER) :])))
            else:
                out.append(n)
        return out

    def run(self) -> list[list[str]]:
        """Each check's notes, in the order added; the checks (and the samples they hold) are let go."""
        checks, self.checks = self.checks, None
        return [check() for check in checks]

    def joined(self, notes: list[str], found: list[list[str]]) -> list[str]:
        """``notes`` (:meth:`placed`'s, or those of them a caller keeps: the ones after the last place may go) with
        the notes ``found`` (:meth:`run`'s) in their places."""
        out, places = [], iter(self.at)
        place = next(places, None)
        for i in range(len(notes) + 1):
            while place is not None and place[0] <= i:
                k = place[1]
                out += [n for n in found[k] if not (self.unique[k] and n in out)]
                place = next(places, None)
            out += notes[i : i + 1]
        return out


@dataclass(frozen=True)
class AlignedStream:
    """Observer input. Times in int64 ns; ``t0_ns`` is the origin of the seconds the kernels use."""

    t0_ns: int
    vel_t_ns: np.ndarray  # (N,)
    omega: np.ndarray  # (N, 3) body angular velocity, measured (biased)
    velocity: np.ndarray  # (N, 3) body linear velocity, measured (biased)
    det_t_ns: np.ndarray  # (F,)
    det_offsets: np.ndarray  # (F + 1,)
    det_idx: np.ndarray  # (M,) index into landmark_ids
    det_y: np.ndarray  # (M, 3) landmark positions in the body frame
    landmark_ids: np.ndarray  # (L,) sorted unique ids
    body_frame: str
    notes: list[str] = field(default_factory=list)
    body_from: str = ""  # why body_frame is the body (:func:`body_frame_origin`), for run.json and the report
    #: The robot's base frame (``BASE_FRAMES``) TF places against a body taken from an odometry's child frame, and
    #: how (:func:`_base_frame`), or None (run.json ``input.base_frame``; the report names it where the truth looks
    #: turned).
    base_frame: dict | None = None
    #: The frame the truth's poses are of, where it is not the body and static TF places it on the body
    #: (:func:`truth_frame_in_body`; run.json ``input.truth_body``), or None: the report carries the truth to the body.
    truth_body: dict | None = None
    directions: DirectionSet | None = None  # inertial direction measurements on the velocity time base
    #: First velocity sample of each segment after the first (gaps longer than ``limits.max_gap``).
    segment_starts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    #: The detections' sensor-to-body transform ``(R, t)`` (``y_body = R y_sensor + t``) when it is one constant
    #: transform (one camera fixed on the body, or the body frame itself); None for several cameras or a moving
    #: frame. The batch smoother reads the detections in the sensor's own frame through it (inverse depth).
    det_sensor: tuple[np.ndarray, np.ndarray] | None = None
    #: Whether the angular and the linear velocity come from two topics (an IMU's gyro and an odometry): their
    #: stamps can then lag one another, which the time offset's ``velocity_lag`` looks for.
    two_twist_topics: bool = False
    #: The topic of each stream (``angular_velocity``, ``linear_velocity``, ``detections``) and the detections'
    #: frame (``camera``): what a check's warning about them names (:func:`stream_topics`).
    topics: dict[str, str] = field(default_factory=dict)
    #: The warn-only checks not yet run (``align(warn_only_later=True)``): ``notes`` lacks their notes until
    #: :meth:`WarnOnly.joined` puts them in; None (the usual) when ``notes`` is complete.
    warn_only: WarnOnly | None = None
    #: The gyro turned against the odometry's own angular velocity (:func:`_gyro_turn`: its topic and frame, the
    #: two unit axes in the body frame, the angle between them), the fact behind the alignment's warning; None when
    #: not seen. The detection pairs' gyro-misread check defers to it (``time_offset.GYRO_TURN_SEEN``).
    gyro_turn: dict | None = None
    #: The seconds the alignment added to the IMU topic's stamps to put its gyro on the odometry's clock
    #: (:func:`_gyro_lag_taken_off`; 0.0 when none): the detection pairs' offset search reads it, since detections
    #: that need the same move say the odometry, not the IMU, is the stream stamped off (``time_offset``).
    gyro_moved_s: float = 0.0
    #: What each sample of the velocities is, where the log tells (``LogStreams.twist_sampling``), else None: interval
    #: means were restamped to their midpoints by the reader; ``time_offset.sampling_record`` says so.
    twist_sampling: dict | None = None
    #: Where those means were restamped to their midpoints (``LogStreams.twist_to_start_ns``): each sample's
    #: interval's start (int64 ns, as ``vel_t_ns``), the stamp an estimator that holds each sample until the next
    #: takes it at (:func:`held_stamps`); None otherwise.
    vel_start_ns: np.ndarray | None = None
    #: The linear velocity's gaps when it has a topic of its own (:func:`_measured_gaps`; none when it shares the
    #: time base's topic, whose gaps are the time base's own intervals): ``(G, 2)`` int64 ns, its samples before
    #: and after each gap, across which the time base's samples got it interpolated; ``velocity_period_ns`` its
    #: median interval. riekf and batch widen the velocity's noise there (``shared_steps.gap_levels``).
    velocity_gaps: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    velocity_period_ns: float = 0.0
    #: Those of ``velocity_gaps`` longer than ``limits.max_gap`` that the time base recorded through (up to
    #: ``limits.max_odometry_gap``): bridged, not split. The gyro keeps the attitude across and the observers and
    #: riekf carry the pose on the interpolated velocity (riekf's noise widened to the motion's spread,
    #: ``shared_steps.gap_levels``); batch splits them (:func:`unbridged`). ``(B, 2)`` int64 ns, as ``velocity_gaps``.
    bridged_gaps: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    #: The stretches a gyro of its own holds its largest reading in (:func:`_held_at_top`: its range exceeded), its
    #: first and last sample each, ``(S, 2)`` int64 ns (none: no gyro clipped), how far each one's rate may lie
    #: beyond it ``gyro_excess`` (S,) rad/s (:func:`_clipped_spans`), and the largest reading held ``gyro_range``
    #: (rad/s): those samples are not measurements of the rate, whose error there is ``|ω| − range``. riekf and batch
    #: widen the gyro's noise over them (``shared_steps.clip_factor``); an observer's verdict says it integrated them
    #: (``evaluation.report.own_status``).
    gyro_clipped: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    gyro_excess: np.ndarray = field(default_factory=lambda: np.zeros(0))
    gyro_range: float = 0.0
    #: The linear velocity's white-noise density as recorded, per axis of its own message (m/s/√Hz; zeros: not
    #: estimated): the run sets it where it estimates it (``run.prepare_log``, the estimators with noise levels),
    #: since the samples interpolated onto the time base show less of it (0.015 for 0.85 on a generated figure 8).
    #: The detection pairs' velocity-scale check takes the dilution it causes off (``time_offset.velocity_scale``).
    velocity_density: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: Its white level per axis where that differs from ``velocity_density``: the sample pairs' level of an axis whose
    #: samples carry motion the rate does not resolve (``noise_estimation.FOLDED_SHARE``; the run sets
    #: ``velocity_density`` to the samples' own level there, which the axis's own check needs); zeros: as
    #: ``velocity_density``. The velocity-scale check pools the axes' levels from it.
    velocity_white_density: np.ndarray = field(default_factory=lambda: np.zeros(3))
    #: The IMU's accelerometer (its specific force in the body frame) as means over ``ACCEL_BLOCK_S`` blocks of the
    #: time base: ``(t0_ns, (B, 3) means)``, block ``k`` the samples of :func:`accel_block_index` ``k`` (NaN where it
    #: has none), for the velocity's own scale (``observers.accel_scale``); None without an accelerometer on the
    #: gyro's topic.
    accel_blocks: tuple[int, np.ndarray] | None = None

    def segments(self) -> list[dict]:
        """Each segment's first and last sample time (ns) and sample count, for run.json and the report."""
        n = self.vel_t_ns.shape[0]
        bounds = [0, *self.segment_starts.tolist(), n]
        return [
            {"start_ns": int(self.vel_t_ns[a]), "end_ns": int(self.vel_t_ns[b - 1]), "samples": b - a}
            for a, b in zip(bounds[:-1], bounds[1:])
            if b > a
        ]

    def seconds(self, t_ns: np.ndarray) -> np.ndarray:
        """Times relative to ``t0_ns`` in float64 seconds (exact to well below a microsecond)."""
        return (t_ns - self.t0_ns).astype(np.float64) * 1e-9

    @property
    def det_ids(self) -> np.ndarray:
        return self.landmark_ids[self.det_idx]


#: The stamps an estimator takes a twist of interval means at (run.json ``observer.time_offset.sampling.stamps``),
#: by how it integrates: one that takes the twist linear between samples (riekf, batch) each interval's midpoint, where
#: the mean is the motion to second order; one that holds each sample until the next (the observers) each interval's
#: start, so the hold covers exactly the interval the sample averages (:func:`held_stamps`).
MEAN_STAMPS = {"interpolates": "interval midpoints", "holds": "interval starts"}


def held_stamps(stream: AlignedStream) -> AlignedStream:
    """The stream as an estimator that holds each velocity sample until the next should integrate it: a twist of
    interval means (``vel_start_ns``) stamped at its intervals' starts, each then held over exactly the interval it
    averages (as an integrating odometry's own dead reckoning holds it); held from the midpoints instead, each would
    run half an interval late. The stream itself where the samples are not interval means. The origin ``t0_ns``
    stays (the first sample's seconds are then below zero); ``vel_start_ns`` goes (the stamps are those starts now:
    a second call changes nothing, and a cut of the samples has nothing beside them to cut)."""
    if stream.vel_start_ns is None:
        return stream
    return replace(stream, vel_t_ns=stream.vel_start_ns, vel_start_ns=None)


def _interval_starts(to_start: np.ndarray, t: np.ndarray, t_om: np.ndarray) -> np.ndarray:
    """Each time-base sample's interval start (``AlignedStream.vel_start_ns``): its stamp less ``to_start`` of the
    sample it is among the angular velocity's (stamps ``t``, as read; the time base keeps some of them, in time order,
    the last of equal stamps)."""
    order = np.argsort(t, kind="stable")
    k = order[np.searchsorted(t[order], t_om, side="right") - 1]
    return t_om - to_start[k]


#: What the checks' warnings call each stream, and the key of its topic in ``AlignedStream.topics``.
STREAM_ROLES = {"gyro": "angular_velocity", "odometry": "linear_velocity", "detections": "detections"}


def stream_topics(topics: Mapping[str, str], *names: str) -> str:
    """Which topics (and frame) a warning about the streams ``names`` (keys of :data:`STREAM_ROLES`, or
    ``camera``: the detections' frame) means, as its bracketed tail, e.g. ``" [gyro /imu/data, detections
    /tags in frame cam0]"``: the one place the checks' warnings name them (a log may hold a dozen topics);
    empty when none is known."""
    said = []
    for name in names:
        if name == "camera":
            if topics.get("camera"):
                said.append(f"camera frame {topics['camera']}")
        elif topics.get(STREAM_ROLES[name]):
            said.append(f"{name} {topics[STREAM_ROLES[name]]}")
    return f" [{', '.join(said)}]" if said else ""


def _times(stream, time_source: str) -> np.ndarray:
    return stream.rec_ns if time_source == "record" else stream.t_ns


@dataclass(frozen=True)
class _Extrinsic:
    """``x_body = rot x_frame + trans``: one constant transform, or one per sample (``(N, 3, 3)``, ``(N, 3)``)."""

    rot: np.ndarray
    trans: np.ndarray
    valid: np.ndarray | None = None  # per-sample lookups: inside the /tf span

    def rotate(self, x: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        if self.rot.ndim == 2:
            return x @ self.rot.T
        return np.einsum("nij,nj->ni", self.rot[rows], x)

    def apply(self, x: np.ndarray, rows: np.ndarray | slice = slice(None)) -> np.ndarray:
        out = self.rotate(x, rows)
        out += self.trans if self.trans.ndim == 1 else self.trans[rows]
        return out


_IDENTITY = _Extrinsic(np.eye(3), np.zeros(3))
_VARYING_RAD = 1e-3  # a /tf extrinsic turning more than this over the log is reported as time-varying


def _to_body(
    tf: TfBuffer,
    body: str,
    frame: str,
    topic: str,
    ident: set[str],
    t_ns: np.ndarray,
    notes: list[str],
    override: frozenset[str] = frozenset(),
    dropped: dict[tuple[str, str], str] | None = None,
) -> _Extrinsic:
    """Transform ``frame`` -> body: the /tf_static chain, else the /tf chain at ``t_ns``, else a one-line error.

    ``ident`` (``frames.assume_identity``) stands in only for frames TF does not know: a transform the log
    has is used, with a warning when the frame is listed. ``override`` (``frames.override_identity``) replaces
    even a known transform by the identity, with a warning naming what was replaced.
    """
    frame = frame.lstrip("/")
    if not frame:  # nothing to look up: say what is assumed (a camera's detections would be in its own frame)
        _note_once(notes, f"{topic}: no frame id: taken as the body frame '{body}' (no transform applied)")
        return _IDENTITY
    if frame == body:
        return _IDENTITY
    known = tf.chain(body, frame) is not None
    if frame in override:
        if known:
            _note_once(
                notes,
                f"warning: frames.override_identity: frame '{frame}' taken as body '{body}', replacing "
                f"its TF transform ({_describe(tf, body, frame)})",
            )
        return _IDENTITY
    if not known:
        if frame in ident:  # an assumption the report must show: which extrinsic was not measured
            _note_once(
                notes, f"{topic}: frame '{frame}' taken as body '{body}' (frames.assume_identity: TF has no transform)"
            )
            return _IDENTITY
        lost = "".join(f"; {w}" for w in dict.fromkeys(w for edge, w in (dropped or {}).items() if frame in edge))
        raise InputError(
            tf.path,
            f"no transform from frame '{frame}' to body frame '{body}' in /tf_static or /tf "
            f"({tf.explain(body, frame)}{lost}; set frames.body, list '{frame}' in frames.assume_identity, or give "
            "the transform: the camera of tag corners or images takes it from files in cameras: a Kalibr chain, "
            "or TagSLAM's camera_poses.yaml (camera in rig) and tagslam.yaml (odometry frame in rig))",
            topic,
        )
    if frame in ident:
        _note_once(
            notes,
            f"warning: frames.assume_identity lists '{frame}', but TF transforms it to body '{body}' "
            f"({_describe(tf, body, frame)}): TF's transform is used (frames.override_identity "
            "replaces it)",
        )
    found = tf.static_lookup(body, frame)
    if found is not None:
        return _Extrinsic(*found)
    res = tf.lookup(body, frame, t_ns, topic)
    note = f"{topic}: frame '{frame}' -> body '{body}' through /tf ({', '.join(res.dynamic)}), at each sample"
    if res.rot.shape[0] > 1:
        cos = (np.einsum("ij,nij->n", res.rot[0], res.rot) - 1.0) / 2.0
        turn = float(np.arccos(np.clip(cos, -1.0, 1.0)).max())
        if turn > _VARYING_RAD:
            note += f"; time-varying (turns up to {np.degrees(turn):.2f} deg)"
    notes.append(note)
    return _Extrinsic(res.rot, res.trans, res.valid)


def _describe(tf: TfBuffer, body: str, frame: str, static: str = "/tf_static: ") -> str:
    """A transform TF has, in a few words: its rotation angle and offset (after ``static``, where it comes from), or
    that it is time-stamped."""
    found = tf.static_lookup(body, frame)
    if found is None:
        return "time-stamped, on /tf"
    rot, trans = found
    angle = np.degrees(np.arccos(np.clip((np.trace(rot) - 1.0) / 2.0, -1.0, 1.0)))
    return f"{static}turned {angle:.1f} deg, offset {np.linalg.norm(trans):.3f} m"


def _note_once(notes: list[str], note: str) -> None:
    if note not in notes:
        notes.append(note)


def _held(ext: _Extrinsic, topic: str, notes: list[str]) -> None:
    """Velocity and direction samples outside the /tf span keep the nearest transform: say how many."""
    if ext.valid is not None and (n := int(np.count_nonzero(~ext.valid))):
        _note_once(notes, f"{topic}: {plural(n, 'sample')} outside the /tf span use the nearest transform")


def check_required(streams: LogStreams, directions: int = 0, needed_by: str | None = None) -> None:
    """Every role an estimator needs has samples (tag corners count as detections), and ``directions`` of the
    direction roles (accelerometer, magnetic field) for an estimator that needs them; else one error naming every
    missing role, each with what would give it, and who needs them (``needed_by``: the estimator's name; None:
    every estimator).

    Raises:
        InputError: One or more required roles missing; ``details`` holds one line per role.

    """
    missing = [
        role
        for role in REQUIRED_ROLES
        if not _has_samples(getattr(streams, role)) and not (role == "detections" and streams.tag_corners)
    ]
    absent = [role for role in DIRECTION_ROLES if not _has_samples(getattr(streams, role))]
    lacking = absent[: max(0, directions - (len(DIRECTION_ROLES) - len(absent)))]
    if missing or lacking:
        needed = len(REQUIRED_ROLES) + (directions if lacking else 0)
        roles = missing + lacking
        poses = (
            trajectory_use(streams.path, streams.truth.topic, missing=missing) if _has_samples(streams.truth) else ""
        )
        poses = f"; {poses}" if poses else ""  # a log of trajectories (evo's bags, ETH's Vicon beside an IMU)
        untyped = ""
        if streams.untyped:  # a damaged metadata.yaml: the topic that would have given the role may be one
            verb = "has its" if len(streams.untyped) == 1 else "have their"
            untyped = f", and {', '.join(streams.untyped)} {verb} message type empty in the log's metadata (not read)"
        raise InputError(
            streams.path,
            f"the log cannot run: {len(roles)} of the {needed} inputs needed by {needed_by or 'every estimator'} "
            f"{'is' if len(roles) == 1 else 'are'} missing ({', '.join(roles)}){untyped}; `slamobs info` shows what "
            "it has" + poses,
            details=tuple(
                f"{role} ({ROLE_PURPOSE[role]}): {_no_samples(getattr(streams, role), streams.empty.get(role, ()))}"
                f"{_how_to_give(role)}"
                for role in roles
            ),
        )


#: characters of a missing role's line in the error of a log that cannot run; longer, its first way is given and
#: ``slamobs info`` lists the rest (its readiness section gives them a line each)
HOW_TO_GIVE_CHARS = 300


def _how_to_give(role: str) -> str:
    """What would give ``role``, in one line of the error: every way when they are short, else the first and a
    count (detections have 6 ways over 15 message types: 900 characters in one line)."""
    ways = how_to_satisfy(role)
    text = "; ".join(ways)
    if len(text) <= HOW_TO_GIVE_CHARS:
        return text
    return (
        f"{ways[0]}; or one of {len(ways) - 1} other kinds of topic (`slamobs info` lists them, with what each needs)"
    )


def _has_samples(stream) -> bool:
    return stream is not None and len(stream) > 0


def _no_samples(stream, empty=()) -> str:
    """For a role whose topic was read but gave nothing: that topic, so it is not read as "no topic found"; for
    one no topic was chosen for, the log's topics of a type it accepts that were recorded empty (``empty``)."""
    if stream is None:
        return f"{', '.join(empty)} {'has' if len(empty) == 1 else 'have'} no messages in this log; " if empty else ""
    return f"{stream.topic} has no samples in this log or the --start/--end window; "


def _sorted(t: np.ndarray, *arrays: np.ndarray):
    if t.shape[0] > 1 and np.any(np.diff(t) < 0):
        order = np.argsort(t, kind="stable")
        return (t[order], *(a[order] for a in arrays))
    return (t, *arrays)


def _measured_gaps(t_ns: np.ndarray, x: np.ndarray) -> tuple[float, np.ndarray]:
    """A velocity stream's median interval (ns) and the index ``i`` of each interval ``t_ns[i] .. t_ns[i + 1]``
    over ``GAP_FACTOR`` of them: samples lost; none for a held stream (``HELD_STEP_SHARE``: its intervals are
    the command held) or one of fewer than three samples."""
    if t_ns.shape[0] < 3:
        return 0.0, np.zeros(0, np.int64)
    d = np.diff(t_ns)
    positive = d[d > 0]
    period = float(np.median(positive)) if positive.size else 0.0
    held = np.count_nonzero(equal_rows(x[1:], x[:-1])) >= HELD_STEP_SHARE * (x.shape[0] - 1)
    gaps = np.flatnonzero(d > GAP_FACTOR * period) if period > 0 and not held else np.zeros(0, np.int64)
    return period, gaps


def _gaps(t_ns: np.ndarray, x: np.ndarray, topic: str, across: str) -> list[str]:
    """What the run says of one velocity stream's gaps. A measuring stream (an IMU, wheel odometry: fewer than
    ``HELD_STEP_SHARE`` of its samples repeat the one before) gets its intervals over ``GAP_FACTOR`` median
    intervals (what ``slamobs info`` counts) named, how many, the longest, how long in all (a warning from
    ``GAP_SHARE_WARN`` of its span: dropped samples that ``across`` says what the run did over); a stream that
    repeats its values (a command logged as it is held: MR.CLAM's velocity, whose 400-900 gaps are the command
    held) gets its gaps over ``GAP_WARN_S`` noted."""
    if t_ns.shape[0] < 3:
        return []
    d = np.diff(t_ns)
    period, gaps = _measured_gaps(t_ns, x)
    if gaps.size:
        span = d[gaps] * 1e-9
        share = float((d[gaps] - period).sum() / (t_ns[-1] - t_ns[0]))
        longest = int(gaps[np.argmax(span)])
        text = (
            f"{topic}: {plural(gaps.size, 'gap')} over {GAP_FACTOR:g}x its median interval {period * 1e-6:.3g} ms "
            f"(longest {span.max():.3f} s at +{(t_ns[longest] - t_ns[0]) * 1e-9:.2f} s; {span.sum():.2f} s in all, "
            f"{share:.1%} of its span): samples dropped? {across}"
        )
        return [f"warning: {text}" if share >= GAP_SHARE_WARN else text]
    big = d * 1e-9 > GAP_WARN_S
    if not np.any(big):
        return []
    return [f"{topic}: {int(big.sum())} gap(s) longer than {GAP_WARN_S} s (largest {d.max() * 1e-9:.2f} s)"]


def _repeats(t_ns: np.ndarray, x: np.ndarray, topic: str) -> list[str]:
    """A warning when at least ``REPEAT_SHARE_WARN`` of a velocity stream's samples (``t_ns`` sorted) share their
    stamp with the one before and say otherwise (two publishers on one topic, a driver re-sending a message with
    another value), with how far apart they are beside the step between stamps: the run cannot tell which is right
    (a generated figure 8 whose odometry repeats every 5th message's stamp with zero velocity: riekf 0.053 m against
    0.011 m, and only the readers' note; MR.CLAM's robots have 0-3 in 52,000-65,000)."""
    same = t_ns[1:] == t_ns[:-1]
    if not same.any():  # the usual stream: no stamp twice, nothing to compare
        return []
    same &= ~equal_rows(x[1:], x[:-1])
    n = int(np.count_nonzero(same))
    if n < REPEAT_SHARE_WARN * t_ns.shape[0] or n == 0:
        return []
    apart = float(np.median(row_norms3(x[1:][same] - x[:-1][same])))
    step = float(np.median(row_norms3(np.diff(x[np.r_[True, ~(t_ns[1:] == t_ns[:-1])]], axis=0))))
    return [
        f"warning: {topic}: {n} of its {t_ns.shape[0]} samples share their stamp with the one before and say otherwise "
        f"({apart:.3g} apart, median, where samples a stamp apart differ by {step:.3g}): two publishers on one topic, "
        "or a driver re-sending with another value? The run cannot tell which is right"
    ]


def _windowed_mean(t_ns: np.ndarray, w: np.ndarray, q_ns: np.ndarray, half_ns: int) -> np.ndarray:
    """The mean of the samples ``w`` (N, 3) within ``half_ns`` of each query time (NaN rows where none is)."""
    cum = np.vstack((np.zeros((1, 3)), np.cumsum(w, axis=0)))
    lo, hi = np.searchsorted(t_ns, q_ns - half_ns, "left"), np.searchsorted(t_ns, q_ns + half_ns, "right")
    n = (hi - lo).astype(np.float64)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (cum[hi] - cum[lo]) / n, np.nan)


def lag_misfits(t_g, w_g, t_o, b, lags_s: np.ndarray, half_ns: int) -> np.ndarray:
    """Per lag, how far the gyro's angular velocity read ``lag`` later than the odometry's stamps ``t_o`` is from
    the odometry's ``b`` (both averaged over ``half_ns`` either side) once turned by the rotation that fits them best
    (Kabsch, each centred: the IMU's mounting and its bias fitted): the residual's share of ``b``'s variance (NaN with
    under half the odometry's samples covered). The lags a block at a time, each block's arrays whole. Public:
    tests/test_alignment.py checks :func:`coarse_lag_misfits` against it."""
    out = np.full(lags_s.shape[0], np.nan)
    n = t_o.shape[0]
    shifts = np.round(lags_s * 1e9).astype(np.int64)
    for rows in row_blocks(lags_s.shape[0], max(1, (1 << 20) // max(n, 1))):
        a = _windowed_mean(t_g, w_g, (t_o[None, :] + shifts[rows, None]).ravel(), half_ns).reshape(-1, n, 3)
        ok = np.isfinite(a[:, :, 0])
        cnt = ok.sum(axis=1)
        a = np.where(ok[:, :, None], a, 0.0)
        y = np.where(ok[:, :, None], b[None, :, :], 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            x = np.where(ok[:, :, None], a - (a.sum(axis=1) / cnt[:, None])[:, None, :], 0.0)
            y = np.where(ok[:, :, None], y - (y.sum(axis=1) / cnt[:, None])[:, None, :], 0.0)
        m = _kabsch_misfit(np.einsum("lni,lnj->lij", x, y), (x * x).sum(axis=(1, 2)), (y * y).sum(axis=(1, 2)))
        out[rows] = np.where(cnt >= max(0.5 * n, 20), m, np.nan)
    return out


def _kabsch_misfit(cross: np.ndarray, xx: np.ndarray, yy: np.ndarray) -> np.ndarray:
    """Per lag, the share of ``yy`` (the centred odometry's sum of squares) left once the centred gyro (sum of
    squares ``xx``) is turned by the rotation that fits it best onto the odometry (``cross``: (L, 3, 3), the sum of
    x y^T); NaN where ``yy`` is 0."""
    u, sv, vt = np.linalg.svd(cross)
    sv[:, -1] *= np.sign(np.linalg.det(u @ vt))  # a rotation, not a reflection
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(yy > 0, (xx + yy - 2.0 * sv.sum(axis=1)) / yy, np.nan)


def coarse_lag_misfits(t_g, w_g, t_o, w_o, half_ns: int) -> np.ndarray:
    """:func:`lag_misfits` on the coarse grid (lags ``k * GYRO_LAG_STEP_S``, ``|k| <= GYRO_LAG_MAX_S / step``), both
    streams averaged on a uniform grid of that step from the odometry's first stamp (not at its stamps), every sum
    over the pairs a lag makes one cross-correlation by FFT: the whole ±``GYRO_LAG_MAX_S`` for a few FFTs over
    the span, where the same fit per lag at 200 of the stamps cost 0.035 CPU s on a 90 s log (session 22). Public:
    tests/test_alignment.py checks it against :func:`lag_misfits`."""
    step = int(round(GYRO_LAG_STEP_S * 1e9))
    k = int(round(GYRO_LAG_MAX_S / GYRO_LAG_STEP_S))
    q_o = t_o[0] + step * np.arange((t_o[-1] - t_o[0]) // step + 1)
    b = _windowed_mean(t_o, w_o, q_o, half_ns)
    a = _windowed_mean(t_g, w_g, t_o[0] + step * np.arange(-k, q_o.shape[0] + k), half_ns)
    cols = []
    for x in (a, b):  # per stream: valid, its (centred once: smaller sums) values, their squares; 0 where invalid
        ok = np.isfinite(x[:, 0])
        x = np.where(ok[:, None], x - (x[ok].mean(axis=0) if ok.any() else 0.0), 0.0)
        cols.append(np.column_stack((ok, x, (x * x).sum(axis=1))))
    n = 1 << int(a.shape[0] - 1).bit_length()  # a is b and 2k more: no lag wraps round
    fa, fb = np.fft.rfft(cols[0], n, axis=0), np.conj(np.fft.rfft(cols[1], n, axis=0))
    r = np.fft.irfft(fa[:, :, None] * fb[:, None, :], n, axis=0)[: 2 * k + 1]  # r[j, p, q] = sum a_p[i + j] b_q[i]
    cnt = np.rint(r[:, 0, 0])
    with np.errstate(invalid="ignore", divide="ignore"):
        sa, sb = r[:, 1:4, 0], r[:, 0, 1:4]
        cross = r[:, 1:4, 1:4] - sa[:, :, None] * sb[:, None, :] / cnt[:, None, None]
        xx, yy = r[:, 4, 0] - (sa * sa).sum(axis=1) / cnt, r[:, 0, 4] - (sb * sb).sum(axis=1) / cnt
    ok = cnt >= max(0.5 * np.count_nonzero(cols[1][:, 0]), 20)
    cross[~ok] = 0.0
    return np.where(ok, _kabsch_misfit(cross, xx, yy), np.nan)


def _gyro_lag(
    t_g: np.ndarray, w_g: np.ndarray, twist: Vec3Stream, t_o: np.ndarray, gyro_topic: str
) -> tuple[list[str], float]:
    """A warning when the gyro's stamps (``t_g``, sorted; ``w_g``) look late or early against the linear-velocity
    topic's own angular velocity (``twist`` on the times ``t_o``): see ``GYRO_LAG_WARN_S``; and the lag (s) the
    run takes off the gyro's stamps (:func:`_gyro_lag_taken_off`): 0.0 but where it warns."""
    order = np.argsort(t_o, kind="stable")
    t_o, w_o = t_o[order], twist.xyz[order]
    keep = t_o <= t_o[0] + int(GYRO_LAG_SPAN_S * 1e9)
    t_o, w_o = t_o[keep], w_o[keep]
    if t_o.shape[0] < 20 or t_g.shape[0] < 20:
        return [], 0.0
    half = max(int(np.median(np.diff(t_o))) // 2, int(GYRO_LAG_SMOOTH_S * 0.5e9))
    reach = int(GYRO_LAG_MAX_S * 1e9) + half  # the gyro's samples any lag can reach, no more (an hour-long IMU)
    near = slice(np.searchsorted(t_g, t_o[0] - reach), np.searchsorted(t_g, t_o[-1] + reach, "right"))
    t_g, w_g = t_g[near], w_g[near]
    coarse = np.arange(-GYRO_LAG_MAX_S, GYRO_LAG_MAX_S + 0.5 * GYRO_LAG_STEP_S, GYRO_LAG_STEP_S)
    m = coarse_lag_misfits(t_g, w_g, t_o, w_o, half)
    if not np.isfinite(m).any():
        return [], 0.0
    k, probe = int(np.nanargmin(m)), int(round(GYRO_LAG_PROBE_S / GYRO_LAG_STEP_S))
    around = m[[max(k - probe, 0), min(k + probe, m.shape[0] - 1)]]  # NaN: too little overlap to say
    power = float(np.min(around) / max(float(m[k]), 1e-12)) if np.isfinite(around).all() else np.inf
    unseen = "" if power >= GYRO_LAG_GAIN else _lag_unseen(gyro_topic, twist.topic, power)
    if k == coarse.shape[0] // 2:
        # the best coarse lag 0 (the clocks agree): the fine grid would look within a coarse step (the warning's
        # least lag) of it, where the coarse grid found no lag better than 0, let alone GYRO_LAG_GAIN times
        return [unseen] if unseen else [], 0.0
    best = float(coarse[k])
    t_all, b_all = t_o, _windowed_mean(t_o, w_o, t_o, half)  # both averaged alike
    every = max(1, t_o.shape[0] // GYRO_LAG_FINE_SAMPLES)  # evenly spread stamps of the span: enough to time it
    t_o, b = t_all[::every], b_all[::every]
    fine = np.arange(best - GYRO_LAG_STEP_S, best + GYRO_LAG_STEP_S + 0.5 * GYRO_LAG_FINE_S, GYRO_LAG_FINE_S)
    m_fine = lag_misfits(t_g, w_g, t_o, b, fine, half)
    lag, m_best = float(fine[np.nanargmin(m_fine)]), float(np.nanmin(m_fine))
    m0 = float(lag_misfits(t_g, w_g, t_o, b, np.zeros(1), half)[0])
    gain = m0 / max(m_best, 1e-12) if np.isfinite(m0) else np.inf
    late = "late" if lag > 0 else "early"
    # where the turns are too slow for GYRO_LAG_GAIN, a lag that fits better than as stamped by half of what a
    # GYRO_LAG_PROBE_S lag would lose is the data telling (a clean log's best lag is 0, its gain 1)
    needed, most = (
        (GYRO_LAG_GAIN, GYRO_LAG_MAX_MISFIT) if not unseen else (1.0 + 0.5 * (power - 1.0), GYRO_LAG_SLOW_MAX_MISFIT)
    )
    moves = abs(lag) >= GYRO_LAG_WARN_S and m_best <= most and gain >= needed  # then the halves are asked
    held, sigmas = _held_out_gain(t_g, w_g, t_all, b_all, every, fine, half) if moves else (gain, np.inf)
    if not moves or held < needed or (unseen and sigmas < GYRO_LAG_SIGMAS):
        found = f"; the best fit, {abs(lag):.3f} s {late}, is {gain:.3g}x better than as stamped"
        found += (
            f" ({held:.3g}x on the span's other half, {sigmas:.2g} standard errors of its misfit's, not enough)"
            * bool(moves)
        )
        if not unseen and moves:  # fast turns: a lag that fit the whole span, not its halves, is not moved unsaid
            return [f"{gyro_topic}: its stamps were not moved against {twist.topic}'s own angular velocity{found}"], 0.0
        return [unseen + found * (abs(lag) >= GYRO_LAG_WARN_S and power >= 1.5)] if unseen else [], 0.0
    as_read = f"{m0:.3g}" if np.isfinite(m0) else "none (too little overlap)"
    slow = f"; slow turns: a {GYRO_LAG_PROBE_S:g} s lag fits only {power:.3g}x worse than the best" if unseen else ""
    return [
        f"warning: {gyro_topic}: its angular velocity's stamps look {abs(lag):.3f} s {late} against "
        f"{twist.topic}'s own angular velocity (misfit {m_best:.3g} of its variance so shifted, {as_read} as "
        f"stamped, over {np.ptp(t_o) * 1e-9:.0f} s{slow}): is the IMU stamped on another clock (or {twist.topic}: the "
        f"detections' time offset tells which)? The run moved its "
        f"stamps by {-lag:+.3f} s onto {twist.topic}'s clock (the IMU topic's every stream) before anything read "
        f"them; correct them at the driver (or time.topics: {{{gyro_topic}: record}} if its record times are right)"
    ], lag


def _held_out_gain(t_g, w_g, t_o, b, every: int, lags_s: np.ndarray, half_ns: int) -> tuple[float, float]:
    """How much better than as stamped the lag the gyro's fit finds on one half of the odometry's span (stamps
    ``t_o``, averaged ``b``; every ``every``-th stamp, on the grid ``lags_s``) fits the other half (all its stamps):
    the smaller of the two ways round (``GYRO_LAG_SLOW_MAX_MISFIT``; inf where neither half can be told); and that
    gain's weight, the smaller of the two halves' misfit differences in their standard errors
    (:func:`_lag_gain_sigmas`; inf likewise)."""
    n = t_o.shape[0]
    gains, sigmas = [], []
    for fit, test in ((slice(0, n // 2), slice(n // 2, n)), (slice(n // 2, n), slice(0, n // 2))):
        m = lag_misfits(t_g, w_g, t_o[fit][::every], b[fit][::every], lags_s, half_ns)
        if not np.isfinite(m).any():
            continue
        m0, m_lag = lag_misfits(t_g, w_g, t_o[test], b[test], np.array([0.0, lags_s[np.nanargmin(m)]]), half_ns)
        if np.isfinite(m0) and np.isfinite(m_lag):
            gains.append(m0 / max(m_lag, 1e-12))
            sigmas.append(_lag_gain_sigmas(t_g, w_g, t_o[test], b[test], float(lags_s[np.nanargmin(m)]), half_ns))
    return min(gains, default=np.inf), min(sigmas, default=np.inf)


def _lag_residuals(t_g, w_g, t_o, b, lag_s: float, half_ns: int) -> np.ndarray:
    """Per odometry stamp, the squared residual :func:`lag_misfits` sums at the lag ``lag_s`` (the gyro averaged
    ``lag_s`` later, turned by the rotation that fits it best onto ``b``, both centred), over ``b``'s centred sum of
    squares: their sum is the misfit; NaN where the gyro has no sample."""
    a = _windowed_mean(t_g, w_g, t_o + int(round(lag_s * 1e9)), half_ns)
    ok = np.isfinite(a[:, 0])
    out = np.full(t_o.shape[0], np.nan)
    if np.count_nonzero(ok) < 2:
        return out
    x, y = a[ok] - a[ok].mean(axis=0), b[ok] - b[ok].mean(axis=0)
    u, _, vt = np.linalg.svd(x.T @ y)
    u[:, -1] *= np.sign(np.linalg.det(u @ vt))  # a rotation, not a reflection
    yy = float(np.sum(y * y))
    out[ok] = np.sum((y - x @ (u @ vt)) ** 2, axis=1) / yy if yy > 0 else np.nan
    return out


def _lag_gain_sigmas(t_g, w_g, t_o, b, lag_s: float, half_ns: int) -> float:
    """How many standard errors the misfit at the lag ``lag_s`` is below the misfit as stamped on the stamps ``t_o``
    (``b`` averaged there): the per-stamp differences of :func:`_lag_residuals`' squares summed over
    ``GYRO_LAG_BLOCKS`` consecutive blocks, the standard error from the blocks' spread (neighbouring stamps' residuals
    share the motion's slow errors; blocks of seconds do not); inf where there are too few stamps to tell."""
    d = _lag_residuals(t_g, w_g, t_o, b, 0.0, half_ns) - _lag_residuals(t_g, w_g, t_o, b, lag_s, half_ns)
    d = d[np.isfinite(d)]
    if d.shape[0] < 2 * GYRO_LAG_BLOCKS:
        return np.inf
    sums = np.array([x.sum() for x in np.array_split(d, GYRO_LAG_BLOCKS)])
    se = float(np.std(sums, ddof=1)) * np.sqrt(GYRO_LAG_BLOCKS)
    return float(d.sum()) / se if se > 0 else np.inf


def _gyro_turn(t_g: np.ndarray, w_g: np.ndarray, twist: Vec3Stream, t_o: np.ndarray, gyro: Vec3Stream) -> dict | None:
    """The gyro's turn against the odometry's (``AlignedStream.gyro_turn``) when the gyro (``w_g``: body frame, on
    the time base ``t_g``) turns about another axis than the odometry's own angular velocity (``twist`` on the times
    ``t_o``, in the body frame) says: see ``GYRO_AXIS_WARN_DEG``; else None."""
    order = np.argsort(t_o, kind="stable")
    t_o, w_o = t_o[order], twist.xyz[order]
    keep = (t_o <= t_o[0] + int(GYRO_LAG_SPAN_S * 1e9)) & np.all(np.isfinite(w_o), axis=1)
    t_o, w_o = t_o[keep], w_o[keep]
    if t_o.shape[0] < 20:
        return None
    span = slice(np.searchsorted(t_g, t_o[0]), np.searchsorted(t_g, t_o[-1], "right"))  # t_g sorted: the time base
    every = max(1, (span.stop - span.start) // GYRO_AXIS_SAMPLES)  # evenly spread samples: enough for an axis
    t_g, w_g = t_g[span][::every], w_g[span][::every]
    inside = np.all(np.isfinite(w_g), axis=1)
    if np.count_nonzero(inside) < 20:
        return None
    t, g = (t_g[inside] - t_o[0]).astype(np.float64), w_g[inside]
    o = np.column_stack([np.interp(t, (t_o - t_o[0]).astype(np.float64), w_o[:, a]) for a in range(3)])
    o, g = o - o.mean(axis=0), g - g.mean(axis=0)
    lam, vec = np.linalg.eigh(o.T @ o / o.shape[0])
    if lam[-1] < GYRO_AXIS_MIN_RATE**2:
        return None  # the odometry hardly turns: nothing to tell an axis by
    d = vec[:, -1] * np.sign(vec[np.argmax(np.abs(vec[:, -1])), -1])  # its largest component positive
    s = o @ d
    a = g.T @ s / float(s @ s)  # the gyro's response to the odometry's turn about d (its sign: the turn's sense)
    misfit = float(np.sum((g - np.outer(s, a)) ** 2) / max(float(np.sum(g**2)), 1e-300))
    norm = float(np.linalg.norm(a))
    if misfit > GYRO_AXIS_MAX_MISFIT or norm == 0.0:
        return None
    # signed: a gyro turning the other way about the same axis (an IMU upside down) is 180 deg off, not 0
    angle = float(np.degrees(np.arccos(np.clip(float(a @ d) / norm, -1.0, 1.0))))
    if angle < GYRO_AXIS_WARN_DEG:
        return None
    return {
        "topic": gyro.topic,
        "frame": gyro.frame_id.lstrip("/"),
        "gyro_axis": [float(x) for x in a / norm],
        "odometry_axis": [float(x) for x in d],
        "angle_deg": angle,
        "misfit": misfit,
        "span_s": float(np.ptp(t_o)) * 1e-9,
    }


def _gyro_axes(turn: dict | None, odometry_topic: str, unaligned: str = "") -> list[str]:
    """The warning of a gyro turned against the odometry (:func:`_gyro_turn`'s ``turn``; none when None).
    ``unaligned``: the body frame, where no run took the gyro (``info --noise``) and its frame had no /tf_static
    transform (else "")."""
    if turn is None:
        return []
    frame = turn["frame"]
    gyro_axis, odometry_axis = np.asarray(turn["gyro_axis"]), np.asarray(turn["odometry_axis"])
    sign = float(np.sign(odometry_axis[np.argmax(np.abs(odometry_axis))]))  # the odometry's axis, largest positive
    lead, verdict = (
        (
            f"taken as the body '{unaligned}' as read (TF has no transform of '{frame}', as frames.assume_identity "
            "would take it), ",
            f"'{frame}' is not mounted as the body frame, and frames.assume_identity would read its axes wrong",
        )
        if unaligned
        else (
            "in the body frame ",
            f"its frame '{frame}' reaches the body turned (a frame listed in frames.assume_identity that is mounted "
            "otherwise, or a wrong extrinsic; slamobs info LOG shows the frames); a run takes it as read",
        )
    )
    return [
        f"warning: {turn['topic']}: {lead}its gyro turns about {_axis_words(gyro_axis, sign)} where "
        f"{odometry_topic}'s own angular velocity turns about {_axis_words(odometry_axis, sign)}, "
        f"{turn['angle_deg']:.0f} deg apart (over {turn['span_s']:.0f} s, misfit {turn['misfit']:.2g} of the gyro's "
        f"variance{GYRO_TURN_REVERSED * (turn['angle_deg'] >= 180.0 - GYRO_AXIS_WARN_DEG)}): {verdict}: "
        f"{GYRO_TURN_ADVICE.format(frame=frame)}"
    ]


def accel_up_unaligned(streams: LogStreams, body_frame: str | None = None) -> list[str]:
    """The warning of an accelerometer whose frame TF does not bring into the body, taken as read (as
    ``frames.assume_identity`` would take it), when its gravity says the frame is not mounted with the body's up axis
    (``ACCEL_UP_WARN_DEG``; public for ``slamobs info --noise``, beside :func:`gyro_axes_unaligned`, which needs an
    odometry's own angular velocity: imu_tools' Phidgets sample has none)."""
    acc = streams.accel
    if acc is None or len(acc) < 20:
        return []
    body = body_frame_name(streams.linear_velocity, body_frame)
    frame = acc.frame_id.lstrip("/")
    if not frame or frame == body:
        return []
    if TfBuffer(streams.static_tf, streams.tf, path=streams.path).static_lookup(body, frame) is not None:
        return []
    f = acc.xyz[np.all(np.isfinite(acc.xyz), axis=1)]
    g = float(np.linalg.norm(DEFAULT_GRAVITY))
    mean = f.mean(axis=0) if f.shape[0] else np.zeros(3)
    size = float(np.linalg.norm(mean))
    if size < ACCEL_UP_MIN_G * g or size > (2.0 - ACCEL_UP_MIN_G) * g:  # not steady, or not m/s^2: no up axis
        return []
    up = mean / size
    angle = float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))
    if angle < ACCEL_UP_WARN_DEG:
        return []
    upside = "; upside down" if angle >= 180.0 - ACCEL_UP_WARN_DEG else ""
    return [
        f"warning: {acc.topic}: taken as the body '{body}' as read (TF has no transform of '{frame}', as "
        f"frames.assume_identity would take it), its accelerometer's mean (gravity's reaction, {size / g:.2f} g over "
        f"{np.ptp(acc.t_ns) * 1e-9:.0f} s) points along [{', '.join(f'{x:.2f}' for x in up)}], {angle:.0f} deg from "
        f"the body's up axis (+z{upside}): '{frame}' is not mounted as the body frame (unless the body itself "
        "stood so tilted all along), and frames.assume_identity would read its axes wrong: "
        f"{GYRO_TURN_ADVICE.format(frame=frame)}"
    ]


def gyro_axes_unaligned(streams: LogStreams, body_frame: str | None = None) -> list[str]:
    """:func:`_gyro_axes` on a log the alignment cannot take (public for ``slamobs info --noise`` of a log without
    detections, such as robot_localization's test1, whose IMU frame TF does not know): the gyro brought into the body
    by its /tf_static transform, else as read, as ``frames.assume_identity`` would take it."""
    om, lv, twist = streams.angular_velocity, streams.linear_velocity, streams.twist_angular
    if om is None or lv is None or twist is None or twist.topic == om.topic or len(om) < 20:
        return []
    body = body_frame_name(lv, body_frame)
    if twist.frame_id.lstrip("/") not in ("", body):
        return []
    t, w = _sorted(om.t_ns, om.xyz)
    frame = om.frame_id.lstrip("/")
    found = None
    if frame and frame != body:
        found = TfBuffer(streams.static_tf, streams.tf, path=streams.path).static_lookup(body, frame)
        w = w if found is None else w @ found[0].T
    turn = _gyro_turn(t, w, twist, twist.t_ns, om)
    return _gyro_axes(turn, twist.topic, body if frame and frame != body and found is None else "")


def _axis_words(v: np.ndarray, sign: float | None = None) -> str:
    """An axis as a unit vector to two places, times ``sign`` (default: the sign that makes its largest component
    positive; two axes compared, one sign for both, keeps their senses apart)."""
    u = v / np.linalg.norm(v)
    return "[" + ", ".join(f"{x:.2f}" for x in u * (np.sign(u[np.argmax(np.abs(u))]) if sign is None else sign)) + "]"


def _lag_unseen(gyro_topic: str, twist_topic: str, power: float) -> str:
    """The note that the gyro's lag could not be checked (``GYRO_LAG_PROBE_S``): ``power``, how many times worse a
    lag that long fits than the best one."""
    return (
        f"{gyro_topic}: its stamps' lag against {twist_topic}'s own angular velocity could not be checked: too "
        f"little rotation (a lag of {GYRO_LAG_PROBE_S:g} s would fit only {power:.3g}x worse than the best one: "
        f"shorter lags go unseen)"
    )


class _Resampled:
    """A vector stream interpolated onto ``t_base`` (NaN outside its span) and rotated into the body frame,
    for the rows asked for (its frame is checked, and noted, on creation)."""

    def __init__(self, fr: _Frame, stream: Vec3Stream, t_base: np.ndarray) -> None:
        t, self.xyz = _sorted(_times(stream, fr.time_source), stream.xyz)
        self.t0 = t[0]
        self.rel = (t - t[0]).astype(np.float64)
        self.t_base = t_base
        self.ext = fr.to_body(stream.frame_id, stream.topic, t_base)
        _held(self.ext, stream.topic, fr.notes)

    def rows(self, rows: slice = slice(None)) -> np.ndarray:
        q = (self.t_base[rows] - self.t0).astype(np.float64)
        interp = np.interp if rows == slice(None) else interp_sorted
        out = np.column_stack([interp(q, self.rel, self.xyz[:, a], left=np.nan, right=np.nan) for a in range(3)])
        return self.ext.rotate(out, rows)


def _resampled(fr: _Frame, stream: Vec3Stream | None, t_base: np.ndarray) -> _Resampled | None:
    return None if stream is None or len(stream) < 2 else _Resampled(fr, stream, t_base)


def _resample(fr: _Frame, stream: Vec3Stream | None, t_base: np.ndarray) -> np.ndarray | None:
    """A vector stream interpolated onto ``t_base`` (NaN outside its span) and rotated into the body frame."""
    res = _resampled(fr, stream, t_base)
    return None if res is None else res.rows()


def body_frame_name(linear_velocity: Vec3Stream | None, body_frame: str | None = None) -> str:
    """The body frame: ``body_frame`` if given, else the frame of the linear velocity (odometry child frame)."""
    frame = body_frame or (linear_velocity.frame_id if linear_velocity is not None else "") or "base_link"
    return frame.lstrip("/")


def body_frame_origin(linear_velocity: Vec3Stream | None, body_frame: str | None, topic: str | None) -> str:
    """Why :func:`body_frame_name` took its frame, for run.json and the report: ``frames.body``, the linear
    velocity's frame (an Odometry's child_frame_id, a TwistStamped's header frame) on ``topic``, or the default."""
    if body_frame:
        return BODY_FROM_CONFIG
    if linear_velocity is not None and linear_velocity.frame_id:
        twist = f"the frame of {topic or 'the linear velocity'}'s twist"
        return f"{twist}: an Odometry's child_frame_id or a TwistStamped's header frame"
    return BODY_FROM_DEFAULT


#: The frames a robot's base goes by (REP 105; ``rig``: TagSLAM's, the body its camera_poses.yaml places the cameras
#: on and its reference trajectory tracks): a body frame taken from an odometry's child_frame_id under another name
#: may be a sensor's, so the run says which frame it took (:func:`body_frame_note`) and where the base is
#: (:func:`base_placed_note`: TagSLAM test 22's VIO frame is turned 120 deg against the rig; fast-adaptation's rotation
#: APE against the rig's trajectory 124.5 deg, 12.3 deg with frames.body: rig).
BASE_FRAMES = ("base_link", "base_footprint", "rig")


def body_frame_note(body: str, origin: str, truth_body: dict | None = None) -> str:
    """The note naming the frame a run took as the body, where it came from (:func:`body_frame_origin`) and the key
    that sets another. Public: the run gives it when an odometry's child frame other than a base frame became the
    body, the report (:func:`.evaluation.sections.body_frame_notes`) when the truth looks turned, in one wording
    (the summary prints it once). Where the truth is carried to the body from its own frame (``truth_body``:
    :func:`truth_frame_in_body`) the note says so in place of the turned truth a base's would be: TagSLAM test 22
    with ``frames.truth: rig`` was told its rig truth "looks turned" though the report compared it carried."""
    if truth_body:
        truth = f"the truth, of '{truth_body['frame']}', is carried to it before the report compares (its note)"
    else:
        truth = (
            "if the robot's base is another frame (the odometry's child frame a sensor's), a truth of the base looks "
            "turned against them"
        )
    return (
        f"the run took '{body}' as the body frame ({origin}): the poses, the map and the biases are that frame's; "
        f"{truth}; `slamobs info LOG` lists the frames into the body, and frames.body: FRAME in the run's config "
        "makes FRAME the body"
    )


#: where a static transform :func:`_describe` words comes from (the log's /tf_static and the cameras: files' rig
#: transforms, run.prepare_log)
STATIC_FROM = "static, from /tf_static or the cameras: files: "


def _base_frame(tf: TfBuffer, body: str) -> dict | None:
    """The first base frame (``BASE_FRAMES``) TF connects to ``body`` and how TF places it (``frame``, ``placed``:
    :func:`_describe`'s words), or None (run.json ``input.base_frame``)."""
    for base in BASE_FRAMES:
        if base in tf.frames and tf.chain(base, body) is not None:
            how = _describe(tf, base, body, static=STATIC_FROM)
            return {"frame": base, "placed": how}
    return None


def base_placed_note(body: str, base: dict | None, truth_body: dict | None = None) -> list[str]:
    """Where TF places a base frame against ``body``, an odometry's child frame taken as the body (``base``:
    :func:`_base_frame`, run.json ``input.base_frame``): a truth of the base is off the poses by that lever arm,
    turning with the robot (a figure 8 whose odometry's twist is in a frame 0.5 m beside base_link, TF giving it:
    riekf APE 0.49 m against the base's truth, 0.011 m with frames.body: base_link, with only the body-frame note,
    which speaks of a turned truth; session 27). Public: the run notes it, and the report again where the truth looks
    turned (:func:`.evaluation.sections.body_frame_notes`), in one wording (the summary prints it once). None where
    the truth is carried to the body from its own frame (``truth_body``, :func:`truth_frame_in_body`): no truth is
    then compared as the body's, and ``frames.body: BASE`` would advise what is already done (TagSLAM test 22 with
    ``frames.truth: rig``, as benchmarks/real_logs.py runs it, was offered ``frames.body: rig``)."""
    if not base or truth_body:
        return []
    name = base["frame"]
    return [
        f"TF places the body frame '{body}' against '{name}' ({base['placed']}): a truth of '{name}' is that far off "
        f"these poses, the offset turning with the robot, and is turned by that angle; frames.body: {name} "
        "makes the base the body"
    ]


#: why :func:`truth_frame_in_body` took a frame as the truth's: the config's key, or the truth message's own
TRUTH_FRAME_FROM_CONFIG = "frames.truth"
TRUTH_FRAME_FROM_MESSAGE = "the truth's child_frame_id"


def truth_frame_in_body(tf: TfBuffer, body: str, truth: PoseStream | None, stated: str | None) -> dict | None:
    """The frame the truth's poses are of and its pose in the body frame, where that frame is not the body: ``stated``
    (``frames.truth``), else the truth message's child_frame_id (an Odometry's, a TF pair's; a PoseStamped names
    none). A truth of another frame compared with the body's poses is a silent wrong comparison: its rotation APE is
    the frames' turn and its translation APE holds the lever arm swung by the rotation (TagSLAM test 22, whose
    truth is of the rig and whose body is the T265's frame: rotation APE 110 deg). Static transforms only (a frame
    that moves on the body has no one transform to carry the truth by): a child frame TF does not place so keeps
    today's comparison (the report's ``truth_frame_turn`` note, ``frames.truth_rotation``, are its fallback); a
    stated frame it does not place is an error. Returns ``{"frame", "from", "translation", "quat_xyzw"}`` (the
    frame's origin in the body and its rotation, ``x_body = R x_frame + t``; run.json ``input.truth_body``) or None.

    Raises:
        InputError: ``stated`` is a frame static TF does not connect to the body.
    """
    frame = (stated or (truth.child_frame_id if truth is not None else "") or "").lstrip("/")
    if not frame or frame == body:
        return None
    found = tf.static_lookup(body, frame)
    if found is None:
        if stated:
            raise InputError(
                truth.topic if truth is not None else "frames.truth",
                f"frames.truth: '{frame}' is not placed on the body frame '{body}' by static transforms (/tf_static, "
                f"the cameras: files): the truth cannot be carried to the body ({tf.explain(body, frame)})",
            )
        return None
    rot, trans = found
    return {
        "frame": frame,
        "from": TRUTH_FRAME_FROM_CONFIG if stated else TRUTH_FRAME_FROM_MESSAGE,
        "placed": _describe(tf, body, frame, static=STATIC_FROM),
        "translation": [float(v) for v in trans],
        "quat_xyzw": [float(v) for v in rot_to_quat(np.ascontiguousarray(rot))],
    }


def truth_body_note(body: str, truth_body: dict | None, still_turned: bool = False) -> list[str]:
    """The run's note that the report compares the truth carried from its own frame to the body
    (:func:`truth_frame_in_body`'s ``truth_body``), with how TF places that frame; empty without one. The report
    adds, where the carried truth still looks turned (``still_turned``: its ``ape.truth_frame_turn``) and the frame
    was the message's, that the child_frame_id may name another frame than its poses' (TagSLAM's
    ``/tagslam/odom/body_rig`` names the odometry's frame and holds the rig's poses: with ``frames.body: rig`` it was
    carried 120 deg the wrong way, batch rotation APE 116 deg) and the key that states the right one."""
    if not truth_body:
        return []
    note = (
        f"the truth is of the frame '{truth_body['frame']}' ({truth_body['from']}), which TF places on the body frame "
        f"'{body}' ({truth_body['placed']}): the report carries the truth by that transform to the body before "
        "comparing (truth_tum.txt holds it so carried)"
    )
    if still_turned and truth_body["from"] == TRUTH_FRAME_FROM_MESSAGE:
        note += (
            "; carried so, it still looks turned (the rotation APE's note): the child_frame_id may not name the frame "
            "its poses are of (TagSLAM's reference names the odometry's frame and holds the rig's poses); "
            "frames.truth: FRAME states it (frames.truth: BODY compares it as it is)"
        )
    return [note]


def align(
    streams: LogStreams,
    *,
    body_frame: str | None = None,
    truth_frame: str | None = None,
    time_source: str = "header",
    identity_frames: tuple[str, ...] = (),
    override_identity: tuple[str, ...] = (),
    gravity=DEFAULT_GRAVITY,
    magnetic_field=DEFAULT_MAGNETIC_FIELD,
    keep_directions: bool = True,
    keep_accel: bool = True,
    release: bool = False,
    limits: dict[str, float | None] | None = None,
    warn_only_later: bool = False,
) -> AlignedStream:
    """Build the observer's ordered input from the decoded streams of one log.

    ``keep_directions=False`` leaves the direction samples out of the result (observers without IMU
    directions, which get no accelerometer note). ``keep_accel=False`` leaves ``AlignedStream.accel_blocks`` out
    (only the detection time offset's velocity-scale check reads them: riekf and batch; 0.04 CPU s on an hour at
    200 Hz, on the run's serial path). ``release=True`` removes each sensor stream from
    ``streams`` once it has been used (for a caller that reads nothing else of them), so the samples of a long
    log are not held twice. Each part runs in its own function so its temporaries are gone before the next
    part starts; the notes come in the order velocities, detections, directions. ``limits`` are the
    plausibility gates and ``max_gap`` (default ``DEFAULT_LIMITS``; a None entry switches one off).
    ``warn_only_later=True`` leaves the :class:`WarnOnly` checks to the caller (``AlignedStream.warn_only``).
    ``truth_frame`` (``frames.truth``) names the frame the truth is of (:func:`truth_frame_in_body`).
    """
    lim = {**DEFAULT_LIMITS, **(limits or {})}
    check_required(streams)
    om: Vec3Stream = streams.angular_velocity
    lv: Vec3Stream = streams.linear_velocity
    det: DetectionStream = streams.detections
    body_from = body_frame_origin(lv, body_frame, lv.topic if lv is not None else None)
    frame, dir_frame = _checked_frames(streams, body_frame, time_source, identity_frames, override_identity)
    tf, body = frame.tf, frame.body
    truth_body = truth_frame_in_body(tf, body, streams.truth, truth_frame)

    warn = WarnOnly()
    accel, magnetic, gyro_moved_s = streams.accel, streams.magnetic, 0.0
    if (twist := streams.twist_angular) is not None and twist.topic != om.topic:
        (om, accel, magnetic), gyro_moved_s = _gyro_lag_taken_off(frame, twist, om, accel, magnetic)
    t_om, omega, velocity, (lo, hi), starts, lv_gaps = _velocities(
        streams.path, om, lv, frame, lim, streams.missing_spans
    )
    vel_start = None
    if streams.twist_to_start_ns is not None and om.topic == lv.topic:
        vel_start = _interval_starts(streams.twist_to_start_ns, _times(om, frame.time_source), t_om)
    gyro_turn = None
    if twist is not None and twist.topic != om.topic:
        gyro_turn = _odometry_twist_checks(frame, warn, twist, om, lv, t_om, omega)
    two_topics, gyro_topic = om.topic != lv.topic, om.topic
    clipped = (np.zeros((0, 2), np.int64), np.zeros(0), 0.0)
    if two_topics:  # a gyro of its own (an odometry's angular velocity is a computed one, often held at set values)
        found, rows = _held_at_top(om.xyz)
        frame.notes.extend(_saturated_words(found, om.topic))
        if rows:  # the samples beyond the gyro's range: not measurements of the rate (riekf and batch widen them)
            clipped = (*_clipped_spans(rows, _times(om, frame.time_source), om.xyz), max(r[3] for r in rows))
    topics = _role_topics(om, lv, det)
    lv_own = (lv.topic, _times(lv, frame.time_source), lv.xyz) if lv.topic != gyro_topic else None
    del om, lv
    # The directions before the detections: the IMU samples can go before the detections are moved.
    if release:
        streams.angular_velocity = streams.linear_velocity = streams.accel = streams.magnetic = None
        streams.twist_angular = None
    directions, w = _directions(
        dir_frame, t_om, omega, velocity, accel, magnetic, gravity, magnetic_field, keep_directions
    )
    accel_blocks = None
    if accel is not None and accel.topic == gyro_topic:  # the IMU's own accelerometer
        accel_blocks = _imu_accel_checks(dir_frame, warn, accel, t_om, omega, velocity, keep_accel, lv_own)
    del accel, magnetic
    if release:
        streams.detections = None
    det_t_ns, offsets, det_idx, det_y, landmark_ids, det_sensor = _detections(
        streams.path, det, lo, hi, frame, lim, _gap_spans(t_om, starts)
    )
    detected = (det_t_ns, offsets, det_idx, det_y, landmark_ids)
    frame.notes.append(warn.add(_misread_ids, det.topic, t_om, omega, velocity, *detected))
    del det
    notes = frame.notes + [n for n in dir_frame.notes if n not in frame.notes]
    base = None
    if body_from not in (BODY_FROM_CONFIG, BODY_FROM_DEFAULT) and body not in BASE_FRAMES:
        base = _base_frame(tf, body)
        # an odometry's child frame
        notes[:0] = [body_frame_note(body, body_from, truth_body), *base_placed_note(body, base, truth_body)]
    notes += truth_body_note(body, truth_body)
    if w is not None:
        notes.append(_accel_weights_note(w))
    notes = warn.placed(notes)
    if not warn_only_later:
        notes, warn = warn.joined(notes, warn.run()), None
    return AlignedStream(
        t0_ns=int(t_om[0]),
        vel_t_ns=t_om,
        omega=omega,
        velocity=velocity,
        det_t_ns=det_t_ns,
        det_offsets=offsets,
        det_idx=det_idx,
        det_y=det_y,
        landmark_ids=landmark_ids,
        body_frame=body,
        notes=notes,
        body_from=body_from,
        base_frame=base,
        truth_body=truth_body,
        directions=directions if keep_directions else None,
        segment_starts=starts,
        det_sensor=det_sensor,
        two_twist_topics=two_topics,
        topics=topics,
        warn_only=warn,
        gyro_turn=gyro_turn,
        gyro_moved_s=gyro_moved_s,
        twist_sampling=streams.twist_sampling,
        vel_start_ns=vel_start,
        velocity_gaps=lv_gaps[0],
        velocity_period_ns=lv_gaps[1],
        bridged_gaps=lv_gaps[2],
        gyro_clipped=clipped[0],
        gyro_excess=clipped[1],
        gyro_range=clipped[2],
        accel_blocks=accel_blocks,
    )


def _checked_frames(
    streams: LogStreams,
    body_frame: str | None,
    time_source: str,
    identity_frames: tuple[str, ...],
    override_identity: tuple[str, ...],
) -> tuple[_Frame, _Frame]:
    """The frames the velocities and detections (first) and the directions (second, their notes kept apart) are
    moved into, once the log's frames, clock resets and stamp pace are checked (each raising an InputError)."""
    om, lv = streams.angular_velocity, streams.linear_velocity
    body = body_frame_name(lv, body_frame)
    ident = {f.lstrip("/") for f in identity_frames}
    override = frozenset(f.lstrip("/") for f in override_identity)
    tf = TfBuffer(streams.static_tf, streams.tf, path=streams.path, time_source=time_source)
    _check_frames(streams, tf, body_frame, ident, override)
    _no_clock_reset(streams.path, time_source, (om, "angular velocity"), (lv, "linear velocity"))
    _stamps_at_record_pace(streams.path, time_source, streams, (om, "angular velocity"), (lv, "linear velocity"))
    dropped = streams.static_tf_dropped
    frame = _Frame(tf, body, ident, time_source, [], override, dropped)
    return frame, _Frame(tf, body, ident, time_source, [], override, dropped)


def _odometry_twist_checks(fr: _Frame, warn: WarnOnly, twist: Vec3Stream, om: Vec3Stream, lv, t_om, omega):
    """The odometry's twist ``twist`` (on another topic than the gyro ``om``) against the gyro: a stuck odometry
    (warn-only, when it also gives the velocity ``lv``), and the turn of a body-frame twist against the gyro's with
    its notes on ``fr`` (not warn-only: the detection pairs' gyro-misread check reads it, ``AlignedStream.gyro_turn``;
    None for a twist in another frame)."""
    if twist.topic == lv.topic:
        fr.notes.append(warn.add(_odometry_stuck, lv, twist, fr.time_source, t_om, omega, om.topic))
    if twist.frame_id.lstrip("/") not in ("", fr.body):
        return None
    gyro_turn = _gyro_turn(t_om, omega, twist, _times(twist, fr.time_source), om)
    fr.notes.extend(_gyro_axes(gyro_turn, twist.topic))
    return gyro_turn


def _role_topics(om: Vec3Stream, lv: Vec3Stream, det: DetectionStream | None) -> dict[str, str]:
    """The topic of each role the run reads (``AlignedStream.topics``), the detections' cameras or frame too."""
    topics = {"angular_velocity": om.topic, "linear_velocity": lv.topic}
    if det is not None:
        topics.update(detections=det.topic, camera=", ".join(det.cameras) if det.cameras else det.frame_id)
    return topics


def _imu_accel_checks(fr: _Frame, warn: WarnOnly, accel: Vec3Stream, t_om, omega, velocity, keep: bool, lv_own):
    """The IMU's own accelerometer ``accel`` (on the gyro's topic): the gyro's scale against gravity (warn-only,
    its note on ``fr``), the velocity stream's rate against the motion (warn-only, :func:`_velocity_unresolved`;
    ``lv_own``: its topic, stamps and samples, None where it is the IMU's topic) and, when ``keep``, the
    accelerometer's blocks for the time offset's velocity-scale check (``AlignedStream.accel_blocks``, else None)."""
    head = _accel_head(accel, t_om)
    blocks = _accel_blocks(replace(fr, notes=[]), accel, t_om) if keep else None
    fr.notes.append(warn.add(_gyro_by_gravity, replace(fr, notes=[]), head, t_om, omega, velocity, unique=True))
    if lv_own is not None:
        fr.notes.append(warn.add(_velocity_unresolved, head, _times(head, fr.time_source), *lv_own))
    return blocks


def _accel_weights_note(w: np.ndarray) -> str:
    """How many direction samples the accelerometer's weights ``w`` down-weighted or skipped as accelerating."""
    return (
        f"{ACCEL_NOTE}{100.0 * float(np.mean(w < 1.0)):.1f} % of samples down-weighted and "
        f"{100.0 * float(np.mean(w == 0.0)):.1f} % skipped as accelerating "
        f"(| |f - a_body| - |g| | above {ACCEL_TOL} / {ACCEL_GATE} m/s^2)"
    )


def _gyro_lag_taken_off(fr: _Frame, twist: Vec3Stream, om: Vec3Stream, *others: Vec3Stream | None) -> tuple:
    """:func:`_gyro_lag` of the gyro's stream ``om`` as read (its samples sorted by the run's clock), its notes
    added to ``fr``'s; ``om`` and those of ``others`` (the accelerometer, the magnetometer) on the IMU's topic with
    that lag taken off the stamps the run reads (the rest as given). Not a :class:`WarnOnly` check: the velocities'
    time base and the detection pairs' offset search read its result (the gyro's lag read as stamped was taken for
    the detections' offset and applied to them: issue 23, docs/benchmarks.md session 27); and the seconds added to
    those stamps (``AlignedStream.gyro_moved_s``)."""
    notes, lag = _gyro_lag(*_sorted(_times(om, fr.time_source), om.xyz), twist, _times(twist, fr.time_source), om.topic)
    fr.notes.extend(notes)
    if lag == 0.0:
        return (om, *others), 0.0
    field, shift = ("rec_ns" if fr.time_source == "record" else "t_ns"), -int(round(lag * 1e9))
    moved = tuple(
        s if s is None or s.topic != om.topic else replace(s, **{field: _times(s, fr.time_source) + shift})
        for s in (om, *others)
    )
    return moved, -lag


def _misread_ids(topic: str, t_om, omega, velocity, det_t_ns, offsets, det_idx, det_y, landmark_ids) -> list[str]:
    """The warnings of the two id checks (:func:`_ids_at_many_places`, else :func:`_ids_far_from_their_neighbours`)
    on the detections of ``topic``."""
    said = _ids_at_many_places(t_om, omega, velocity, det_t_ns, offsets, det_idx, det_y, landmark_ids)
    said = said or _ids_far_from_their_neighbours(det_t_ns, offsets, det_idx, det_y, landmark_ids)
    return [f"warning: {topic}: {n}" for n in said]


def _ids_at_many_places(t_om, omega, velocity, det_t_ns, offsets, det_idx, det_y, landmark_ids) -> list[str]:
    """The ids whose detections do not follow the body's motion (``GHOST_*``): each detection of an id, moved by
    the angular and linear velocity at the middle of the interval to the next detection of that id, against that
    next detection, over the first ``GHOST_SPAN_S``; one sentence per run, without the topic."""
    t = np.repeat(det_t_ns, np.diff(offsets))
    n = int(np.searchsorted(t, t[0] + int(GHOST_SPAN_S * 1e9), side="right")) if t.shape[0] else 0
    t, det_idx, det_y = t[:n], det_idx[:n], det_y[:n]
    order = np.argsort(det_idx, kind="stable")  # by landmark, then time (the rows are in time order)
    same = det_idx[order][1:] == det_idx[order][:-1]
    a, b = order[:-1][same], order[1:][same]
    dt = (t[b] - t[a]) * 1e-9
    near = (dt > 0.0) & (dt <= GHOST_PAIR_S)
    a, b, dt = a[near], b[near], dt[near]
    if a.shape[0] < 2 * GHOST_MIN_PAIRS or t_om.shape[0] < 2:
        return []
    k = np.clip(np.searchsorted(t_om, (t[a] + t[b]) // 2), 0, t_om.shape[0] - 1)
    # a static landmark: y_b = R^T (y_a - v dt), R = exp(omega dt) (Rodrigues, numpy: no kernel to compile)
    phi = omega[k] * dt[:, None]
    u = det_y[a] - velocity[k] * dt[:, None]
    th = row_norms3(phi)
    ax = phi / np.maximum(th, 1e-12)[:, None]
    c, s = np.cos(th), np.sin(th)
    dot = (1.0 - c) * np.einsum("ij,ij->i", ax, u)
    # y_b - R^T u, with R^T u = u c - s (ax x u) + (1 - c)(ax . u) ax
    e = row_norms3(det_y[b] - u * c[:, None] + s[:, None] * np.cross(ax, u) - ax * dot[:, None])
    ok = np.isfinite(e)
    if np.count_nonzero(ok) < 2 * GHOST_MIN_PAIRS:
        return []
    e, lm = e[ok], det_idx[a][ok]
    median = float(np.median(e))
    if not (said := ghost_ids(lm, e, landmark_ids, median, "pairs")):  # pairs grouped by landmark (sorted above)
        return []
    return [
        f"{said}: its detections under {GHOST_PAIR_S:g} s apart disagree "
        f"with the body's motion between them by a median of that many metres, where the run's pairs disagree by "
        f"{median:.3g} m: one id seen at several places (a misdecoded tag id, or two tags with one id), used as "
        "read; the observers without a gate place it between them: drop or fix that id in the detections"
    ]


def ghost_ids(lm: np.ndarray, e: np.ndarray, landmark_ids: np.ndarray, median: float, what: str) -> str:
    """The warning's head for both id checks: the landmarks (``lm``, indices grouped in runs) whose median ``e``
    over at least ``GHOST_MIN_PAIRS`` values exceeds ``GHOST_MIN_M`` and ``GHOST_RATIO`` times the run's ``median``,
    worst first (``GHOST_SHOWN`` of them), as "landmark id 9999 (12 pairs, 3.1 m)"; "" when there is none."""
    bounds = np.flatnonzero(np.r_[True, lm[1:] != lm[:-1], True])
    found = []
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        m = float(np.median(e[lo:hi]))
        if hi - lo >= GHOST_MIN_PAIRS and m > GHOST_MIN_M and m > GHOST_RATIO * median:
            found.append((int(landmark_ids[lm[lo]]), hi - lo, m))
    if not found:
        return ""
    found.sort(key=lambda f: -f[2])
    listed = ", ".join(f"{i} ({n} {what}, {m:.3g} m)" for i, n, m in found[:GHOST_SHOWN])
    return f"landmark id{'s' if len(found) > 1 else ''} {listed}" + (" ..." if len(found) > GHOST_SHOWN else "")


def _ids_far_from_their_neighbours(det_t_ns, offsets, det_idx, det_y, landmark_ids) -> list[str]:
    """The ids whose distance to the other ids of the same frame changes from frame to frame (``GHOST_NEIGHBOURS``):
    each pair of detections in one frame gives the two ids' distance; each id pair seen together at least twice its
    median; each id the median change about those medians, over the first ``GHOST_SPAN_S``. One sentence per run,
    without the topic."""
    n_frames = (
        int(np.searchsorted(det_t_ns, det_t_ns[0] + int(GHOST_SPAN_S * 1e9), side="right")) if det_t_ns.size else 0
    )
    sizes = np.diff(offsets[: n_frames + 1])
    a_parts, b_parts = [], []
    for k in np.unique(sizes[sizes >= 2]):  # frames of k detections: their k (k - 1) / 2 pairs at once
        ii, jj = np.triu_indices(int(k), 1)
        first = offsets[:n_frames][sizes == k][:, None]
        a_parts.append((first + ii).ravel())
        b_parts.append((first + jj).ravel())
    if not a_parts:
        return []
    a, b = np.concatenate(a_parts), np.concatenate(b_parts)
    lo, hi = np.minimum(det_idx[a], det_idx[b]), np.maximum(det_idx[a], det_idx[b])
    d = row_norms3(det_y[a] - det_y[b])
    ok = np.isfinite(d) & (lo != hi)
    key = lo[ok].astype(np.int64) * landmark_ids.shape[0] + hi[ok]
    d, lo, hi = d[ok], lo[ok], hi[ok]
    keys, inv, counts = np.unique(key, return_inverse=True, return_counts=True)
    order = np.argsort(inv, kind="stable")
    bounds = np.r_[0, np.cumsum(counts)]
    centre = np.empty(keys.shape[0])
    for j in np.flatnonzero(counts >= GHOST_NEIGHBOURS):  # each id pair's median distance
        centre[j] = np.median(d[order[bounds[j] : bounds[j + 1]]])
    seen = counts[inv] >= GHOST_NEIGHBOURS
    change = np.abs(d - centre[inv])[seen]
    if change.shape[0] < 2 * GHOST_MIN_PAIRS:
        return []
    median = float(np.median(change))
    ids = np.concatenate([lo[seen], hi[seen]])
    both = np.concatenate([change, change])
    order = np.argsort(ids, kind="stable")
    if not (said := ghost_ids(ids[order], both[order], landmark_ids, median, "distances")):
        return []
    return [
        f"{said}: its distance to the other ids seen in the same frame "
        f"changes between frames by a median of that many metres, where the run's id pairs change by {median:.3g} m "
        "(two static landmarks keep one distance): one id read at several places (a tag id misread now and then, or "
        "two tags with one id), used as read; the observers without a gate place it between them: drop or fix that "
        "id in the detections"
    ]


def _tilt_blocks(t_s: np.ndarray, omega: np.ndarray, velocity: np.ndarray, f: np.ndarray, g: float):
    """The accelerometer's "up" (body acceleration ``dv/dt + omega x v`` from the velocity taken off:
    ``directions.gravity_up``, samples it trusts fully) as ``TILT_BLOCK_S`` block means, the block of each sample,
    the samples per block, and which consecutive block pairs are mostly trusted samples. ``omega`` here only gates
    and places "up": a misread gyro's ``omega x v`` moves it (and on a tilted mount leaves too few samples)."""
    up, weight = gravity_up(f, body_acceleration(t_s, omega, velocity), g)
    ok = (weight >= 1.0) & np.all(np.isfinite(up), axis=1)
    k = ((t_s - t_s[0]) / TILT_BLOCK_S).astype(np.int64)
    nb = int(k[-1]) + 1
    full = np.bincount(k, minlength=nb).astype(np.float64)
    used = np.bincount(k[ok], minlength=nb).astype(np.float64)
    # float even when no sample is trusted (a gyro in deg/s: every omega x v far off): bincount of nothing is int
    u = np.column_stack([np.bincount(k[ok], up[ok, a], minlength=nb) for a in range(3)]).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        u /= row_norms3(u)[:, None]
    good = (used >= 0.8 * full) & (full > 0)
    return u, k, full, good[1:] & good[:-1]


def _tilt_cost(blocks, omega: np.ndarray):
    """How far the blocks' "up" (:func:`_tilt_blocks`) turns otherwise than ``omega`` turns it: the trimmed mean
    squared residual of ``du/dt + (omega - b) x u`` between consecutive block means, a gyro bias ``b`` fitted; and
    the block pairs it had (NaN cost under ``TILT_MIN_PAIRS``)."""
    u, k, full, pair = blocks
    n = int(np.count_nonzero(pair))
    if n < TILT_MIN_PAIRS:
        return float("nan"), n
    nb = full.shape[0]
    w = np.column_stack([np.bincount(k, omega[:, a], minlength=nb) for a in range(3)]) / np.maximum(full, 1)[:, None]
    um, wm = 0.5 * (u[1:] + u[:-1])[pair], 0.5 * (w[1:] + w[:-1])[pair]
    c = (u[1:] - u[:-1])[pair] / TILT_BLOCK_S + np.cross(wm, um)
    # c - b x um = c + um x b, linear in b: [um]x stacked
    z = np.zeros(n)
    s = np.stack([np.column_stack([z, -um[:, 2], um[:, 1]]), np.column_stack([um[:, 2], z, -um[:, 0]])], axis=1)
    s = np.concatenate([s, np.column_stack([-um[:, 1], um[:, 0], z])[:, None]], axis=1)
    b = np.linalg.lstsq(s.reshape(-1, 3), -c.reshape(-1), rcond=None)[0]
    d2 = np.sort(np.sum((c + s @ b) ** 2, axis=1))
    return float(np.mean(d2[: max(1, int(0.9 * n))])), n


#: The accelerometer's block length (s) on the time base (``AlignedStream.accel_blocks``): its vibration and noise
#: averaged, the body's acceleration kept (a figure 8's changes over seconds).
ACCEL_BLOCK_S = 0.1


def accel_block_index(t_ns: np.ndarray, t0_ns: int) -> np.ndarray:
    """The ``ACCEL_BLOCK_S`` block from ``t0_ns`` of each time-base sample (``AlignedStream.accel_blocks``). Public:
    the velocity scale's check (``observers.accel_scale``) takes the gyro's and the velocity's means over the same
    blocks."""
    return ((t_ns - t0_ns) // int(ACCEL_BLOCK_S * 1e9)).astype(np.int64)


def block_means(k: np.ndarray, x: np.ndarray, nb: int) -> tuple[np.ndarray, np.ndarray]:
    """Means of the rows of ``x`` (N, 3) over blocks ``k`` (N,) in ``[0, nb)`` (NaN where a block has none) and
    each block's count. Public: the accelerometer's blocks here and the gyro's and the velocity's over the same
    blocks (``observers.accel_scale``) are one computation."""
    count = np.bincount(k, minlength=nb).astype(np.float64)
    sums = np.column_stack([np.bincount(k, x[:, a], minlength=nb) for a in range(x.shape[1])])
    with np.errstate(invalid="ignore", divide="ignore"):
        return sums / np.where(count > 0, count, np.nan)[:, None], count


def _accel_blocks(fr: _Frame, accel: Vec3Stream, t_om: np.ndarray) -> tuple[int, np.ndarray] | None:
    """The accelerometer rotated into the body frame as ``ACCEL_BLOCK_S`` block means of the time base's blocks
    (NaN in a block without a sample): ``AlignedStream.accel_blocks``. Its own samples are binned by their times
    and the means rotated (an IMU fixed on the body); interpolated onto the time base first only where its
    extrinsic moves (0.10 against 0.04 CPU s on an hour at 200 Hz)."""
    res = _resampled(fr, accel, t_om)
    if res is None:
        return None
    t0 = int(t_om[0])
    nb = int(accel_block_index(t_om[-1:], t0)[0]) + 1
    moving = res.ext.rot.ndim != 2
    k = accel_block_index(t_om if moving else res.rel.astype(np.int64) + res.t0, t0)
    f = res.rows() if moving else res.xyz
    ok = np.isfinite(f).all(axis=1) & (k >= 0) & (k < nb)
    means, _ = block_means(k[ok], f[ok], nb)
    return t0, means if moving else res.ext.rotate(means)


def _accel_head(accel: Vec3Stream, t_om: np.ndarray) -> Vec3Stream:
    """The accelerometer's samples over the time base's head that :func:`_gyro_by_gravity` looks at (same
    messages as the gyro's: twice its ``TILT_SAMPLES``), copied: a check run later holds no more of the stream."""
    head = slice(0, min(len(accel), 2 * min(t_om.shape[0], TILT_SAMPLES)))
    return replace(accel, t_ns=accel.t_ns[head].copy(), rec_ns=accel.rec_ns[head].copy(), xyz=accel.xyz[head].copy())


def _velocity_unresolved(accel: Vec3Stream, t_acc: np.ndarray, lv_topic: str, t_v: np.ndarray, v: np.ndarray) -> list:
    """A warning when the IMU's accelerometer (``accel``'s head, on the times ``t_acc``) shows linear motion above
    the velocity stream's Nyquist frequency (``lv_topic``: its stamps ``t_v``, samples ``v``) that the stream
    cannot carry: see ``UNRESOLVED_VELOCITY_SHARE``."""
    if t_acc.shape[0] < 3 or t_v.shape[0] < 3:
        return []
    fs, f_n = 1e9 / float(np.median(np.diff(t_acc))), 0.5e9 / float(np.median(np.diff(np.sort(t_v))))
    if not (np.isfinite(fs) and np.isfinite(f_n)) or fs <= 4.0 * f_n:  # too little of the IMU's band above f_n
        return []
    seg = 1 << int(np.ceil(np.log2(UNRESOLVED_SEGMENTS_NYQUIST * fs / f_n)))
    x = accel.xyz[np.all(np.isfinite(accel.xyz), axis=1)]
    k = x.shape[0] // seg
    if k < 2:
        return []
    x = x[: k * seg].reshape(k, seg, 3)
    w = np.hanning(seg)
    spec = np.abs(np.fft.rfft((x - x.mean(axis=1, keepdims=True)) * w[None, :, None], axis=1)) ** 2
    psd = 2.0 * spec.sum(axis=2).mean(axis=0) / (fs * float(w @ w))  # one-sided, summed over the axes
    f = np.fft.rfftfreq(seg, 1.0 / fs)
    floor = float(np.median(psd[f > 0.25 * fs]))
    above = f > f_n
    var_hi = float(np.sum(np.maximum(psd[above] - floor, 0.0) / (2.0 * np.pi * f[above]) ** 2) * (f[1] - f[0]))
    span = (t_v >= t_acc[0]) & (t_v <= t_acc[-1])
    vv = v[span & np.all(np.isfinite(v), axis=1)]
    var_v = float(np.sum(vv.var(axis=0))) if vv.shape[0] >= 3 else 0.0
    share = var_hi / var_v if var_v > 0 else np.inf
    if not share >= UNRESOLVED_VELOCITY_SHARE:
        return []
    peak = float(f[above][np.argmax(np.maximum(psd[above] - floor, 0.0) / f[above] ** 2)])
    return [
        f"warning: {lv_topic}: its linear velocity at {2.0 * f_n:.3g} Hz is too slow for the motion: {accel.topic}'s "
        f"accelerometer shows {np.sqrt(var_hi):.3g} m/s RMS of velocity above its {f_n:.3g} Hz Nyquist frequency "
        f"(most near {peak:.2g} Hz), {100.0 * share:.0f} % of the velocity samples' variance, over the first "
        f"{(t_acc[-1] - t_acc[0]) * 1e-9:.0f} s; the samples fold it onto slower motion that no noise level undoes "
        f"(the velocity level estimated from them is too high, the estimate off by it): record a faster odometry "
        f"topic (over {2.0 * peak:.2g} Hz, twice that motion's) or one that averages over its interval"
    ]


def _gyro_by_gravity(fr: _Frame, accel: Vec3Stream, t_om, omega, velocity) -> list[str]:
    """A warning when the IMU's accelerometer says its gyro is misread: over the first ``TILT_SAMPLES`` samples of
    the time base, its gravity direction turns ``TILT_MISREAD_GAIN`` times more as read than as the angular
    velocity undone by one of ``TILT_MISREADS`` says (:func:`_tilt_cost`; the best one named). Both costs of a
    candidate are taken on the "up" its own angular velocity gives (:func:`_tilt_blocks`), if that leaves at least
    as many block pairs as read: on a tilted mount a misread's ``omega x v`` leaves too few samples near |g| as read
    (the IMU pitched 45 deg, x and y swapped: 4 block pairs of 39, no word, riekf 10.1 m). The detections cannot
    see these (their pairs see the yaw); the gravity direction sees roll and pitch rates wherever the body tilts."""
    n = min(t_om.shape[0], TILT_SAMPLES)
    if n < 3:
        return []
    res = _resampled(fr, accel, t_om[:n])  # accel: its head (:func:`_accel_head`)
    if res is None:
        return []
    f = res.rows()
    norm = row_norms3(f)
    if not np.any(np.isfinite(norm)):
        return []
    t_s = (t_om[:n] - t_om[0]).astype(np.float64) * 1e-9
    g = float(np.nanmedian(norm))
    r = res.ext.rot if res.ext.rot.ndim == 2 else np.eye(3)  # misread in the IMU's frame (the gyro's, one message)
    read_pairs = int(np.count_nonzero(_tilt_blocks(t_s, omega[:n], velocity[:n], f, g)[3]))
    gains, pairs = {}, {}
    for what, m in TILT_MISREADS.items():
        undone = omega[:n] @ (r @ m @ r.T).T
        blocks = _tilt_blocks(t_s, undone, velocity[:n], f, g)
        cost, pairs[what] = _tilt_cost(blocks, undone)
        base = _tilt_cost(blocks, omega[:n])[0]
        if pairs[what] >= read_pairs and base > 0 and cost == cost:  # so undone, at least as many samples near |g|
            gains[what] = base / max(cost, 1e-300)
    what, gain = max(gains.items(), key=lambda kv: kv[1], default=("", 0.0))
    if not gain >= TILT_MISREAD_GAIN:
        return []
    return [
        f"warning: {accel.topic}: the gyro reads as if its {what}: "
        f"its accelerometer's gravity direction follows the angular velocity {gain:.3g}x better so undone than as "
        f"read (tilt rates over {pairs[what]} pairs of {TILT_BLOCK_S:g} s blocks in the first {t_s[-1]:.0f} s): a "
        "run takes it as read; check the gyro's axes (a driver's axis map, another IMU's extrinsic), which the "
        "detections cannot see"
    ]


def _check_frames(
    streams: LogStreams, tf: TfBuffer, body_frame: str | None, ident: set[str], override: frozenset[str] = frozenset()
) -> None:
    """The frames the config names exist in the log: ``frames.body`` as a stream frame or in TF,
    ``frames.assume_identity`` and ``frames.override_identity`` as the frame of a sensor stream (the only
    frames they apply to)."""
    sensors = {
        s.frame_id.lstrip("/")
        for s in (
            streams.angular_velocity,
            streams.linear_velocity,
            streams.detections,
            streams.accel,
            streams.magnetic,
        )
        if s is not None and s.frame_id
    }
    if body_frame:
        body = body_frame.lstrip("/")
        if body not in sensors | tf.frames:
            known = ", ".join(sorted(sensors | tf.frames)[:12]) or "none"
            raise InputError(
                streams.path, f"frames.body names '{body}', which is not a frame of the log (its frames: {known})"
            )
    for option, names in (("assume_identity", ident), ("override_identity", override)):
        if unused := sorted(set(names) - sensors):
            raise InputError(
                streams.path,
                f"frames.{option} names {', '.join(repr(f) for f in unused)}, which no "
                f"sensor stream of the log uses (their frames: {', '.join(sorted(sensors))})",
            )


def _directions(
    fr: _Frame,
    t_om: np.ndarray,
    omega: np.ndarray,
    velocity: np.ndarray,
    accel: Vec3Stream | None,
    magnetic: Vec3Stream | None,
    gravity,
    magnetic_field,
    keep: bool,
):
    """The direction set (``keep``) and the accelerometer weights (None without an accelerometer)."""
    if keep:
        t_s = (t_om - t_om[0]).astype(np.float64) * 1e-9
        directions = build_directions(
            t_s, omega, velocity, _resample(fr, accel, t_om), _resample(fr, magnetic, t_om), gravity, magnetic_field
        )
        if directions is not None and "gravity" in directions.names:
            return directions, directions.weight[:, directions.names.index("gravity")]
        return directions, None
    # an observer without directions gets no accelerometer note (both frames are still checked)
    _resampled(fr, accel, t_om)
    _resampled(fr, magnetic, t_om)
    return None, None


@dataclass(frozen=True)
class _Frame:
    """Where the streams go: the body frame through ``tf``; notes collect what was done."""

    tf: TfBuffer
    body: str
    ident: set[str]
    time_source: str
    notes: list[str]
    override: frozenset[str] = frozenset()
    dropped: dict[tuple[str, str], str] | None = None  # LogStreams.static_tf_dropped, for the error naming a frame

    def to_body(self, frame_id: str, topic: str, t_ns: np.ndarray) -> _Extrinsic:
        return _to_body(self.tf, self.body, frame_id, topic, self.ident, t_ns, self.notes, self.override, self.dropped)


def _clock(stream, time_source: str) -> str:
    """Which clock a stream's times are on, for messages: the alignment's ``time_source`` (``record``: every stream's
    record times), or the stream's own (all-zero header stamps, or the topic's ``time.topics``, replace its stamps by
    its record times)."""
    if time_source == "record" or stream.t_ns is stream.rec_ns or np.array_equal(stream.t_ns, stream.rec_ns):
        return "record time"
    return "header stamps"


def _no_overlap_hint(om: Vec3Stream, lv: Vec3Stream, clock_om: str, clock_lv: str) -> str:
    """What can join two velocity streams that do not overlap: another ``time.source`` only when their record times
    overlap; when those do not either (a topic stamped and recorded on another clock, a log merged or rewritten), no
    time setting can, and the hint says so and what can."""
    rec_om, rec_lv = (np.array([s.rec_ns.min(), s.rec_ns.max()]) for s in (om, lv))
    if om.topic != lv.topic and (rec_om[1] < rec_lv[0] or rec_lv[1] < rec_om[0]):
        epochs = {bool(r[0] * 1e-9 > ABSOLUTE_AFTER_S) for r in (rec_om, rec_lv)}
        which = " (one on a clock since boot, the other on UNIX time)" if len(epochs) > 1 else ""
        return (
            f"; their record times do not overlap either ({om.topic}: {_span(rec_om)}, {lv.topic}: "
            f"{_span(rec_lv)}){which}: the two topics were not recorded on one clock, and no time.source joins "
            "them: fix one topic's stamps and record times in the log, or name two velocity topics on one clock "
            "(topics.angular_velocity, topics.linear_velocity)"
        )
    clocks = {clock_om, clock_lv}
    if len(clocks) > 1:
        return "; the two clocks differ: try time.source: auto or record"
    if clocks == {"header stamps"}:  # e.g. one driver stamping simulated time in a wall-clock recording
        return "; is one of them on another clock (simulated time)? try time.source: auto"
    return ""


def _span(t: np.ndarray) -> str:
    return f"{t[0] * 1e-9:.3f} .. {t[-1] * 1e-9:.3f} s"


def _gate_norm(
    t: np.ndarray, x: np.ndarray, limit: float | None, what: str, key: str, unit: str, topic: str, notes: list[str]
):
    """Samples whose magnitude exceeds ``limit`` dropped (and counted)."""
    if limit is None or not t.shape[0]:
        return t, x
    norm = row_norms3(x)
    bad = norm > limit
    if n := int(np.count_nonzero(bad)):
        notes.append(
            f"{topic}: {plural(n, what + ' sample')} above limits.{key} {limit:g} {unit} dropped "
            f"(largest {norm.max():.3g} {unit})"
        )
        t, x = t[~bad], x[~bad]
    return t, x


def _usable(path, t: np.ndarray, n_read: int, what: str, stream, key: str, time_source: str) -> None:
    """A time base needs two distinct stamps: say why a stream has none (no samples, one, all equal)."""
    name = f"{what} ({stream.topic})"
    if t.shape[0] == 0:
        raise InputError(
            path,
            f"{name}: all {n_read} samples are above limits.{key}: not a plausible sensor "
            f"stream (raise or switch off limits.{key} if it is)",
        )
    if t.shape[0] == 1:
        raise InputError(path, f"{name} has a single sample: the observer needs a stream of them")
    _not_one_time(path, t, name, "samples", stream, time_source)


def _not_one_time(path, t: np.ndarray, name: str, what: str, stream, time_source: str) -> None:
    """Several samples (``what``) of ``stream`` all at one time (``t``, any order): one line saying what would give
    it a usable time."""
    if t.shape[0] < 2 or t.min() != t.max():
        return
    when = "zero" if t[0] == 0 else f"{t[0] * 1e-9:.3f} s"
    clock = _clock(stream, time_source)
    if clock == "header stamps" and np.ptp(stream.rec_ns) > 0:
        hint = f"its record times advance: set time.source: record (or time.topics: {{{stream.topic}: record}})"
    else:
        hint = "its record times do not advance either: the log carries no usable time for it"
    raise InputError(path, f"{name}: all {t.shape[0]} {what} have the same time ({when}) on its {clock}; {hint}")


def _no_clock_reset(path, time_source: str, *streams: tuple[Vec3Stream, str]) -> None:
    """A velocity stream whose header clock was reset during the recording (stamps that go back, by at least
    ``CLOCK_STEP_NS``, to before the stream's first one: a clock set back to ~0) is one line pointing to record
    time: ordered by header stamps, the recording's later part would run first, its earlier part after a gap of
    the whole reset (two segments in reversed order). A step back that stays within the stream's span (a clock set
    back 1 s) is the readers' out-of-order note. Record times (``time.source: record``, or the topic's
    ``time.topics``) are not looked at. O(n), no sort: by stamp, the first sample is then not the first recorded,
    and at least two samples lie before the stamps of the clock's first run."""
    if time_source == "record":
        return
    for stream, what in streams:
        t, rec = stream.t_ns, stream.rec_ns
        if t.shape[0] < 2 or t is rec or int(rec[0]) - int(rec.min()) < CLOCK_STEP_NS:
            continue
        before = rec < rec[0]  # recorded before the earliest stamp was: the clock's first run
        if np.count_nonzero(t < t[before].min()) < 2:  # one stray stamp (a lone 0) is no reset
            continue
        t0 = int(rec.min())
        raise InputError(
            path,
            f"{what} ({stream.topic}): its header clock was reset {(int(rec[0]) - t0) * 1e-9:.3f} s into the "
            f"recording (the stamps go back from {int(t[before].max()) * 1e-9:.3f} s to {int(t[0]) * 1e-9:.3f} s): "
            "ordered by header stamps the recording's later part would run first; set time.source: record "
            f"(or time.topics: {{{stream.topic}: record}})",
        )


def _stamps_at_record_pace(path, time_source: str, streams: LogStreams, *checked: tuple[Vec3Stream, str]) -> None:
    """A velocity stream whose header stamps advance ``decode.STAMP_PACE_FACTOR`` times faster or slower than the
    log's other streams' (each against its record times: :func:`decode.off_pace`) is one line naming the pace and
    record time: stamps in another unit (0.9 s of stamps over 900 s of recording) make every sample a thousandth
    of its true interval and put the other topics' frames outside the stream's span (the error used to blame the
    detections). A log whose record times all run at another pace (written by a converter in seconds) is not."""
    if time_source == "record":
        return
    sensors = (streams.angular_velocity, streams.linear_velocity, streams.detections, streams.accel, streams.magnetic)
    paces: dict[str, float | None] = {}
    for s in sensors:  # a topic of two roles (an IMU's gyro and accelerometer) by its first
        if s is not None and s.t_ns is not s.rec_ns and len(s.t_ns) and s.t_ns.min() < s.t_ns.max():
            paces.setdefault(s.topic, stamp_pace(s.t_ns, s.rec_ns))
    off = off_pace(paces)
    for stream, what in checked:
        if stream.topic in off:
            t, rec = stream.t_ns, stream.rec_ns
            raise InputError(
                path,
                f"{what} ({stream.topic}): its header stamps advance {off[stream.topic]:.3g}x as fast as the "
                f"other topics' ({np.ptp(t) * 1e-9:.3f} s of stamps over {np.ptp(rec) * 1e-9:.3f} s of recording): "
                f"stamps in another unit (ms or us written as s)? set time.topics: {{{stream.topic}: record}} "
                "(or time.source: record)",
            )


def _velocities(path, om: Vec3Stream, lv: Vec3Stream, fr: _Frame, lim: dict, holes=()):
    """Time base (int64 ns), body angular and linear velocity on it, the span both streams cover, the first
    sample of each segment after the first (velocity gaps longer than ``lim["max_gap"]``, and the ``holes``: record
    time spans a split recording's missing files leave) and the linear velocity's own gaps with its median interval
    (``AlignedStream.velocity_gaps``)."""
    notes = fr.notes
    t_om, w = _sorted(_times(om, fr.time_source), om.xyz)
    t_lv, v = _sorted(_times(lv, fr.time_source), lv.xyz)
    n_om, n_lv = t_om.shape[0], t_lv.shape[0]
    t_om, w = _gate_norm(
        t_om, w, lim["max_angular_rate"], "angular-velocity", "max_angular_rate", "rad/s", om.topic, notes
    )
    t_lv, v = _gate_norm(t_lv, v, lim["max_speed"], "linear-velocity", "max_speed", "m/s", lv.topic, notes)
    _usable(path, t_om, n_om, "angular velocity", om, "max_angular_rate", fr.time_source)
    _usable(path, t_lv, n_lv, "linear velocity", lv, "max_speed", fr.time_source)
    notes += _repeats(t_om, w, om.topic) + (_repeats(t_lv, v, lv.topic) if lv.topic != om.topic else [])
    t_om, w = _last_of_each_stamp(t_om, w, om.topic, notes)
    lo, hi = max(t_om[0], t_lv[0]), min(t_om[-1], t_lv[-1])
    if hi <= lo:
        clock_om, clock_lv = _clock(om, fr.time_source), _clock(lv, fr.time_source)
        hint = _no_overlap_hint(om, lv, clock_om, clock_lv)
        raise InputError(
            path,
            f"angular velocity ({om.topic}: {_span(t_om)}, {clock_om}) and linear velocity "
            f"({lv.topic}: {_span(t_lv)}, {clock_lv}) do not overlap in time{hint}",
        )
    first, stop = np.searchsorted(t_om, lo, side="left"), np.searchsorted(t_om, hi, side="right")  # sorted
    if n_out := t_om.shape[0] - int(stop - first):
        notes.append(f"{plural(n_out, 'angular-velocity sample')} outside the linear-velocity span dropped")
        t_om, w = t_om[first:stop], w[first:stop]
    held = "the run holds the sample before each gap across it"
    om_gaps = _gaps(t_om, w, om.topic, held)  # before the drop below: the holes it leaves are the velocity's
    max_gap = lim["max_gap"]
    split_lv = _odometry_split(max_gap, lim["max_odometry_gap"])
    if split_lv is not None and t_lv.shape[0] > 1:
        # time-base samples inside a linear-velocity gap would get a velocity interpolated over it: dropped
        gap = np.flatnonzero(np.diff(t_lv) > split_lv * 1e9)
        if gap.size:
            k = np.searchsorted(t_lv, t_om, side="right") - 1
            inside = np.isin(k, gap) & (t_om > t_lv[np.clip(k, 0, None)])
            if n_in := int(np.count_nonzero(inside)):
                notes.append(
                    f"{plural(n_in, 'angular-velocity sample')} inside {lv.topic} gaps longer than "
                    f"{_split_name(max_gap, split_lv)} {split_lv:g} s dropped"
                )
                t_om, w = t_om[~inside], w[~inside]
    bridged = _bridged_gaps(t_lv, t_om, max_gap, split_lv) if lv.topic != om.topic else np.zeros(0, np.int64)
    if bridged.size:
        where = ", ".join(
            f"+{(t_lv[k] - t_om[0]) * 1e-9:.2f} s ({(t_lv[k + 1] - t_lv[k]) * 1e-9:.1f} s)" for k in bridged[:5]
        )
        notes.append(
            f"{lv.topic}: {plural(bridged.size, 'gap')} longer than limits.max_gap {max_gap:g} s at {where}"
            f"{', ...' if bridged.size > 5 else ''} while {om.topic} recorded through: bridged, not split (up to "
            f"limits.max_odometry_gap {split_lv:g} s): the gyro keeps the attitude and the pose is carried across on "
            "the interpolated velocity (batch splits the run there)"
        )
    t_om = t_om.astype(np.int64)  # its own array: the stream's may be shared with other roles
    if t_om.shape[0] < 2:
        raise InputError(
            path, f"angular velocity ({om.topic}) and linear velocity ({lv.topic}) share fewer than two samples in time"
        )

    gyro_ext = fr.to_body(om.frame_id, om.topic, t_om)
    _held(gyro_ext, om.topic, notes)
    vel_ext = fr.to_body(lv.frame_id, lv.topic, t_om)
    _held(vel_ext, lv.topic, notes)
    # Linear velocity of the body origin from the velocity of the odometry frame (lever arm t_bc), a block
    # of samples at a time into the result arrays (the same per-row arithmetic as whole arrays).
    rel = (t_lv - lo).astype(np.float64)
    omega = np.empty((t_om.shape[0], 3))
    velocity = np.empty((t_om.shape[0], 3))
    for rows in row_blocks(t_om.shape[0]):
        omega[rows] = gyro_ext.rotate(w[rows], rows)
        rel_q = (t_om[rows] - lo).astype(np.float64)
        v_interp = np.column_stack([interp_sorted(rel_q, rel, v[:, a]) for a in range(3)])
        block = vel_ext.rotate(v_interp, rows)
        block -= np.cross(omega[rows], vel_ext.trans)
        velocity[rows] = block
    lerp = "the run interpolates the velocity across each gap (riekf widens its velocity noise there)"
    notes += om_gaps + (_gaps(t_lv, v, lv.topic, lerp) if lv.topic != om.topic else [])
    starts = _segment_starts(t_om, max_gap, _hole_starts(t_om, om, fr.time_source, holes), notes)
    period, gaps = _measured_gaps(t_lv, v) if lv.topic != om.topic else (0.0, np.zeros(0, np.int64))
    lv_gaps = (
        np.column_stack([t_lv[gaps], t_lv[gaps + 1]]).astype(np.int64),
        period,
        np.column_stack([t_lv[bridged], t_lv[bridged + 1]]).astype(np.int64),
    )
    # Detections are kept up to the last time-base sample, not to the end of the linear velocity: after it the
    # estimators have no motion (an IMU clock that jumps ahead leaves half the odometry span without one).
    return t_om, omega, velocity, (lo, min(hi, int(t_om[-1]))), starts, lv_gaps


def _odometry_split(max_gap: float | None, max_odometry_gap: float | None) -> float | None:
    """The longest gap of the linear velocity alone that the run bridges (a longer one splits it): ``max_gap``, or
    ``max_odometry_gap`` where that is the longer (None: no split)."""
    if max_gap is None or max_odometry_gap is None:
        return max_gap
    return max(max_gap, max_odometry_gap)


def _split_name(max_gap: float | None, split_lv: float) -> str:
    """Which limit a linear-velocity gap longer than ``split_lv`` s split the run by."""
    return "limits.max_gap" if split_lv == max_gap else "limits.max_odometry_gap"


def _bridged_gaps(t_lv: np.ndarray, t_om: np.ndarray, max_gap: float | None, split_lv: float | None) -> np.ndarray:
    """The index ``k`` of each linear-velocity gap ``t_lv[k] .. t_lv[k + 1]`` longer than ``max_gap`` (up to
    ``split_lv``) that the time base ``t_om`` recorded through (no interval of its own over ``max_gap`` there, which
    splits the run, :func:`_segment_starts`): bridged, not split (``AlignedStream.bridged_gaps``)."""
    if max_gap is None or split_lv is None or split_lv <= max_gap or t_lv.shape[0] < 2:
        return np.zeros(0, np.int64)
    d = np.diff(t_lv)
    gap = np.flatnonzero((d > max_gap * 1e9) & (d <= split_lv * 1e9))
    om_gap = np.flatnonzero(np.diff(t_om) > max_gap * 1e9)
    if om_gap.size and gap.size:
        a, b = t_om[om_gap], t_om[om_gap + 1]
        gap = gap[~((a[None, :] < t_lv[gap + 1, None]) & (b[None, :] > t_lv[gap, None])).any(axis=1)]
    return gap.astype(np.int64)


def _hole_starts(t_om: np.ndarray, om: Vec3Stream, time_source: str, holes) -> np.ndarray:
    """The first time-base sample after each of ``holes`` (record-time spans a missing file of a split recording
    leaves): the first sample recorded after the hole, on the time base's clock."""
    out = []
    times = _times(om, time_source)
    for _, end in holes:
        after = om.rec_ns >= end
        if after.any() and not after.all():
            k = int(np.searchsorted(t_om, times[after].min(), side="left"))
            if 0 < k < t_om.shape[0]:
                out.append(k)
    return np.array(out, np.int64)


def _segment_starts(t_om: np.ndarray, max_gap: float | None, holes: np.ndarray, notes: list[str]) -> np.ndarray:
    """The first sample of each segment after the first: after a velocity gap longer than ``max_gap`` and after a
    missing file's hole (``holes``: their first samples), with a note of where."""
    starts = np.zeros(0, np.int64)
    if max_gap is not None:
        starts = (np.flatnonzero(np.diff(t_om) > max_gap * 1e9) + 1).astype(np.int64)
        if starts.size:
            notes.append(
                f"{starts.size} velocity gap(s) longer than limits.max_gap {max_gap:g} s at {_where(t_om, starts)}: "
                f"the run has {starts.size + 1} segments; nothing is integrated across a gap"
            )
    extra = np.setdiff1d(holes, starts)
    if extra.size:
        starts = np.union1d(starts, extra).astype(np.int64)
        notes.append(
            f"{extra.size} gap(s) where a split recording's file is missing at {_where(t_om, extra)}: the run has "
            f"{starts.size + 1} segments; nothing is integrated across a gap"
        )
    return starts


def _where(t_om: np.ndarray, starts: np.ndarray) -> str:
    """Where segments start: time of the last sample before each gap from the first, and the gap's length."""
    return ", ".join(
        f"+{(t_om[k - 1] - t_om[0]) * 1e-9:.2f} s ({(t_om[k] - t_om[k - 1]) * 1e-9:.1f} s)" for k in starts[:5]
    ) + (", ..." if starts.size > 5 else "")


def _last_of_each_stamp(t: np.ndarray, w: np.ndarray, topic: str, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The time base's samples without those a later sample shares its stamp with: a sample is integrated up to the
    next stamp, so such a sample covered no time (the estimators used only the last of each stamp) and a time base
    of repeated stamps has no sample period (a driver stamping IMU samples in pairs)."""
    later = np.zeros(t.shape[0], bool)
    later[:-1] = t[1:] == t[:-1]
    if n := int(np.count_nonzero(later)):
        notes.append(
            f"{topic}: {plural(n, 'angular-velocity sample')} dropped, each sharing its stamp with a later one "
            "(which is kept: a sample holds until the next stamp, so these covered no time)"
        )
        return t[~later], w[~later]
    return t, w


def _gap_spans(t_om: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(G, 2) open time intervals between segments: from the last sample before a gap to the first after it."""
    return np.column_stack([t_om[starts - 1], t_om[starts]]) if starts.size else np.zeros((0, 2), np.int64)


def _camera_rows(
    fr: _Frame, det: DetectionStream, t_det: np.ndarray, frame_of: np.ndarray
) -> tuple[_Extrinsic, np.ndarray | None]:
    """Camera -> body transform of every detection row of a several-camera stream, and which rows have one (a
    camera on /tf outside its span: None when every row does)."""
    m = det.ids.shape[0]
    rot, trans, ok = np.empty((m, 3, 3)), np.empty((m, 3)), np.ones(m, bool)
    camera_of = np.asarray(det.camera_of)
    dynamic = False
    for c, frame in enumerate(det.cameras):
        rows = np.flatnonzero(camera_of == c)
        ext = fr.to_body(frame, det.topic, t_det)
        if ext.rot.ndim == 2:
            rot[rows], trans[rows] = ext.rot, ext.trans
            continue
        f = frame_of[rows]
        rot[rows], trans[rows] = ext.rot[f], ext.trans[f]
        if ext.valid is not None:
            ok[rows] = ext.valid[f]
            dynamic = True
    if dynamic and (n_tf := int(np.count_nonzero(~ok))):
        fr.notes.append(f"{det.topic}: {n_tf} detections outside the /tf span of their camera dropped")
    return _Extrinsic(rot, trans), (ok if dynamic else None)


def _detections(
    path, det: DetectionStream, lo: int, hi: int, fr: _Frame, lim: dict | None = None, gaps: np.ndarray | None = None
):
    """Detection frames inside ``[lo, hi]`` and outside the velocity ``gaps`` in time order, in the body frame,
    without detections outside the range gates of ``lim``: stamps, CSR offsets, dense landmark indices,
    positions, the sorted landmark ids and the sensor-to-body transform when it is one constant transform (else
    None). Rows are gathered only when some are dropped or moved (a clean log
    keeps its order: an hour of detections is tens of MB per copy)."""
    notes = fr.notes
    lim = {**DEFAULT_LIMITS, **(lim or {})}
    if det.ids.shape[0] == 0:
        raise InputError(path, f"the {len(det)} detection messages hold no detections", det.topic)
    t_det = _times(det, fr.time_source)
    # else all seen at one instant
    _not_one_time(path, t_det, f"detections ({det.topic})", "frames", det, fr.time_source)
    counts = np.diff(det.offsets)
    frame_of = np.repeat(np.arange(len(det)), counts)
    in_span = _frames_in_span(path, det, t_det, lo, hi, gaps, notes, fr.time_source)
    cam_ext, in_span, keep_rows, row_of = _camera_to_body(fr, det, t_det, frame_of, in_span, notes)
    frames = np.argsort(t_det, kind="stable")
    frames = frames[in_span[frames]]
    sel = _unique_rows(det, frame_of, _kept_rows(in_span, frame_of, keep_rows), notes)
    det_y = cam_ext.apply(det.xyz if sel is None else det.xyz[sel], row_of if sel is None else row_of[sel])
    del row_of
    # range for the gates: from the sensor when it is fixed on the body (one static camera, or the cameras of a
    # rig), else (frames moving relative to the body, e.g. TF tag frames under a world frame) from the body origin
    fixed_sensor = bool(det.cameras) or cam_ext.rot.ndim == 2
    rng = row_norms3(det.xyz if sel is None else det.xyz[sel]) if fixed_sensor else None
    if sel is None and frames.size == len(det) and bool(np.all(np.diff(frames) == 1)):
        del frame_of  # every detection, frames already in time order
        ids, per_frame = det.ids, counts
    else:
        frame_rank = _rank_in(frames, len(det))[frame_of if sel is None else frame_of[sel]]
        del frame_of
        det_y, rng, ids, per_frame = _in_frame_order(
            frame_rank, frames.size, det_y, rng, det.ids if sel is None else det.ids[sel]
        )
        del frame_rank
    t_frames = t_det[frames]
    n_gated = ids.shape[0]
    det_y, ids, per_frame, t_frames = _range_gate(
        det.topic, det_y, row_norms3(det_y) if rng is None else rng, ids, per_frame, t_frames, lim, notes
    )
    offsets = np.concatenate([[0], np.cumsum(per_frame)]).astype(np.int64)
    landmark_ids, det_idx = _landmark_index(path, det, ids, n_gated, counts, notes)
    return (
        t_frames.astype(np.int64),
        offsets,
        det_idx.astype(np.int64),
        np.ascontiguousarray(det_y, dtype=np.float64),
        landmark_ids.astype(np.int64),
        None if det.cameras or cam_ext.rot.ndim != 2 else (cam_ext.rot.copy(), np.array(cam_ext.trans, float)),
    )


def _frames_in_span(
    path,
    det: DetectionStream,
    t_det: np.ndarray,
    lo: int,
    hi: int,
    gaps: np.ndarray | None,
    notes: list[str],
    time_source: str,
) -> np.ndarray:
    """Per detection frame: inside ``[lo, hi]`` and outside the velocity ``gaps`` (the drops noted); an error
    saying where the frames are when none is inside."""
    in_span = (t_det >= lo) & (t_det <= hi)
    if len(det) and not in_span.any():  # say where they are: most often a topic on another clock
        clock = _clock(det, time_source)
        hint = (
            f"; on another clock? set time.source: auto (or time.topics: {{{det.topic}: record}})"
            if clock == "header stamps"
            else ""
        )
        raise InputError(
            path,
            f"no detection frame inside the velocity time span ({lo * 1e-9:.3f} .. {hi * 1e-9:.3f} s): its "
            f"{len(det)} frames span {t_det.min() * 1e-9:.3f} .. {t_det.max() * 1e-9:.3f} s on its {clock}{hint}",
            det.topic,
        )
    if n_out := len(det) - int(np.count_nonzero(in_span)):
        notes.append(f"{plural(n_out, 'detection frame')} outside the velocity span dropped")
    if gaps is not None and gaps.shape[0]:
        k = np.searchsorted(gaps[:, 0], t_det, side="left") - 1  # the gap starting before each frame
        in_gap = (k >= 0) & (t_det < gaps[np.clip(k, 0, None), 1])
        in_gap &= t_det > gaps[np.clip(k, 0, None), 0]
        if n_gap := int(np.count_nonzero(in_span & in_gap)):
            notes.append(f"{det.topic}: {n_gap} detection frames inside velocity gaps (between segments) dropped")
            in_span &= ~in_gap
    return in_span


def _camera_to_body(
    fr: _Frame, det: DetectionStream, t_det: np.ndarray, frame_of: np.ndarray, in_span: np.ndarray, notes: list[str]
):
    """The camera-to-body transform, the frames still kept, the rows kept (None: by frame) and each row's
    transform index: frames or rows without a transform are dropped (and noted)."""
    if det.cameras:  # several cameras: one transform per detection row
        cam_ext, row_ok = _camera_rows(fr, det, t_det, frame_of)
        keep_rows = in_span[frame_of] if row_ok is None else in_span[frame_of] & row_ok
        return cam_ext, in_span, keep_rows, np.arange(det.ids.shape[0])  # rows of the per-row transforms
    cam_ext = fr.to_body(det.frame_id, det.topic, t_det)
    if cam_ext.valid is not None and in_span.any() and not (in_span & cam_ext.valid).any():
        raise InputError(
            fr.tf.path,
            f"none of its {plural(int(np.count_nonzero(in_span)), 'detection frame')} inside the velocity time span "
            f"is inside the time span of /tf's transform from frame '{det.frame_id}' to body '{fr.body}' (a fixed "
            "camera's extrinsic published on /tf once, or on another clock?): publish a fixed extrinsic on "
            "/tf_static",
            det.topic,
        )
    if cam_ext.valid is not None and (n_tf := int(np.count_nonzero(in_span & ~cam_ext.valid))):
        notes.append(f"{det.topic}: {plural(n_tf, 'detection frame')} outside the /tf span dropped")
        in_span &= cam_ext.valid
    return cam_ext, in_span, None, frame_of


def _kept_rows(in_span: np.ndarray, frame_of: np.ndarray, keep_rows: np.ndarray | None) -> np.ndarray | None:
    """Indices of the detection rows kept, None when every row is (no copy for a clean log)."""
    if keep_rows is None:
        return None if bool(in_span.all()) else np.flatnonzero(in_span[frame_of]).astype(np.int64)
    return None if bool(keep_rows.all()) else np.flatnonzero(keep_rows).astype(np.int64)


def _unique_rows(
    det: DetectionStream, frame_of: np.ndarray, sel: np.ndarray | None, notes: list[str]
) -> np.ndarray | None:
    """``sel`` without repeated ids within a frame: they are ambiguous, the first one is kept (and noted)."""
    n_sel = det.ids.shape[0] if sel is None else sel.size
    if not n_sel:
        return sel
    # (frame, id) pairs compared whole: a key of the id's low 32 bits took ids 5 and 5 + 2^32 for one
    first = first_of_pairs(frame_of if sel is None else frame_of[sel], det.ids if sel is None else det.ids[sel])
    if first.size < n_sel:
        notes.append(f"{det.topic}: {n_sel - first.size} repeated ids within a frame dropped")
        mask = np.zeros(n_sel, bool)
        mask[first] = True
        _two_tags_one_id(det, frame_of, np.arange(det.ids.shape[0]) if sel is None else sel, notes)
        sel = np.flatnonzero(mask) if sel is None else sel[mask]
    return sel


def _two_tags_one_id(det: DetectionStream, frame_of: np.ndarray, rows: np.ndarray, notes: list[str]) -> None:
    """A warning when the repeated ids within a frame (among ``rows``) lie apart (:func:`blocks.far_repeats`)
    (a generated figure 8 with one tag's id given to another: that landmark gone from the map, 39 of its detections
    taken as the other's, and only the note of the repeats dropped)."""
    camera = None if det.camera_of is None else det.camera_of[rows]
    ids, apart, seen = far_repeats(frame_of[rows], det.ids[rows], det.xyz[rows], camera)
    if ids.size:
        notes.append(f"warning: {det.topic}: {shared_id_text(ids, apart, seen)}")


def _rank_in(frames: np.ndarray, n: int) -> np.ndarray:
    """Position of each of ``n`` frames in the time-ordered ``frames`` (garbage for frames not in it)."""
    rank = np.empty(n, np.int64)
    rank[frames] = np.arange(frames.size)
    return rank


def _in_frame_order(frame_rank: np.ndarray, n_frames: int, det_y: np.ndarray, rng: np.ndarray | None, ids: np.ndarray):
    """Rows sorted by their frame's rank (stable) and the rows per frame: the CSR layout in time order."""
    order_det = np.argsort(frame_rank, kind="stable")
    return (
        det_y[order_det],
        rng[order_det] if rng is not None else None,
        ids[order_det],
        np.bincount(frame_rank, minlength=n_frames),
    )


def _landmark_index(
    path, det: DetectionStream, ids: np.ndarray, n_gated: int, counts: np.ndarray, notes: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    """The sorted landmark ids and each detection's index into them; an error naming the cause if none is left."""
    landmark_ids, det_idx = unique_inverse(ids)
    if landmark_ids.size == 0 and n_gated:  # the gate, not the time span, took them all: say so and what to do
        gate = notes[-1].partition(": detections dropped by the range gate: ")[2].partition(";")[0]
        raise InputError(
            path,
            f"all {n_gated} detections inside the velocity time span were dropped by the range "
            f"gate ({gate}): if those ranges are real, change limits.min_range / "
            "limits.max_range (null switches a gate off); a range of 0 is a detection without "
            "a position",
            det.topic,
        )
    if landmark_ids.size == 0:
        raise InputError(
            path,
            "no landmark detections inside the velocity time span (of "
            f"{int(counts.sum())} detections in {len(det)} frames)",
            det.topic,
        )
    return landmark_ids, det_idx


def _range_gate(
    topic: str,
    det_y: np.ndarray,
    dist: np.ndarray,
    ids: np.ndarray,
    per_frame: np.ndarray,
    t_frames: np.ndarray,
    lim: dict,
    notes: list[str],
):
    """Detections whose range ``dist`` is below or above the range limits dropped (and counted); a frame left
    empty by it is dropped too (the previous frame stays valid, as if this one had not come)."""
    lo, hi = lim["min_range"], lim["max_range"]
    if (lo is None and hi is None) or not det_y.shape[0]:
        return det_y, ids, per_frame, t_frames
    near = dist < lo if lo is not None else np.zeros(dist.shape, bool)
    far = dist > hi if hi is not None else np.zeros(dist.shape, bool)
    bad = near | far
    if not bad.any():
        return det_y, ids, per_frame, t_frames
    parts = []
    if n := int(np.count_nonzero(near)):
        parts.append(f"{n} closer than limits.min_range {lo:g} m (nearest {dist[near].min():.3g} m)")
    if n := int(np.count_nonzero(far)):
        parts.append(f"{n} farther than limits.max_range {hi:g} m (farthest {dist[far].max():.3g} m)")
    owner = np.repeat(np.arange(per_frame.shape[0]), per_frame)
    kept = np.bincount(owner[~bad], minlength=per_frame.shape[0])
    emptied = (kept == 0) & (per_frame > 0)
    extra = f"; {int(emptied.sum())} frames left empty dropped" if emptied.any() else ""
    notes.append(f"{topic}: detections dropped by the range gate: {', '.join(parts)}{extra}")
    keep_frame = ~emptied
    return det_y[~bad], ids[~bad], kept[keep_frame], t_frames[keep_frame]


#: A time-window bound larger than this is an absolute stamp in seconds (Unix time: 1e9 s is 2001-09-09); one
#: at or below it counts in seconds from the start of the run's time base (its first angular-velocity sample).
ABSOLUTE_AFTER_S = 1e9


@dataclass(frozen=True)
class TimeWindow:
    """The part of a log a run uses (``time.start`` / ``time.end``, ``--start`` / ``--end``), resolved on the
    run's time base: ``start_ns``/``end_ns`` the window as asked (None: open), ``t0_ns`` the log's start."""

    start_ns: int | None
    end_ns: int | None
    t0_ns: int
    given: tuple[float | None, float | None]

    def describe(self) -> dict:
        """The window as run.json and the report state it: as given, as stamps, and in seconds from the start."""
        rel = [None if t is None else (t - self.t0_ns) / 1e9 for t in (self.start_ns, self.end_ns)]
        return {
            "given": list(self.given),
            "start_ns": self.start_ns,
            "end_ns": self.end_ns,
            "start_s": rel[0],
            "end_s": rel[1],
            "log_start_ns": self.t0_ns,
            "rule": f"bounds above {ABSOLUTE_AFTER_S:g} are absolute stamps [s], others seconds from the log's start",
        }

    @classmethod
    def described(cls, d: dict) -> TimeWindow:
        """The window of a :meth:`describe` dict (run.json's ``time_window``)."""
        return cls(d["start_ns"], d["end_ns"], d["log_start_ns"], tuple(d["given"]))

    def poses(self, stream: PoseStream, stamps: np.ndarray | None = None) -> PoseStream:
        """The poses of ``stream`` whose ``stamps`` (default its ``t_ns``) lie in the window."""
        keep = self.keeps(stream.t_ns if stamps is None else stamps)
        cols = ("t_ns", "rec_ns", "position", "quat_xyzw")
        return replace(stream, **{k: np.asarray(getattr(stream, k))[keep] for k in cols})

    def keeps(self, t_ns: np.ndarray) -> np.ndarray:
        """Which stamps lie in the window (bounds included)."""
        t = np.asarray(t_ns)
        ok = np.ones(t.shape[0], dtype=bool)
        if self.start_ns is not None:
            ok &= t >= self.start_ns
        if self.end_ns is not None:
            ok &= t <= self.end_ns
        return ok


def relabelled(aligned: AlignedStream, det_ids: np.ndarray, **changes) -> AlignedStream:
    """``aligned`` with its detections' landmark ids ``det_ids`` (one per detection row, of the rows ``changes``
    gives or of its own): ``landmark_ids`` and ``det_idx`` rebuilt from them (the one place they are), every other
    field kept as it is but those in ``changes``. :func:`subset` cuts with it; ``observers.base.split_jumps``
    gives a jumping landmark's later detections an id of their own with it."""
    ids, det_idx = unique_inverse(np.asarray(det_ids))
    return replace(
        aligned,
        landmark_ids=ids.astype(aligned.landmark_ids.dtype),
        det_idx=det_idx.reshape(-1).astype(aligned.det_idx.dtype),
        **changes,
    )


def subset(aligned: AlignedStream, rows: slice | np.ndarray, frames: slice | np.ndarray, **changes) -> AlignedStream:
    """``aligned`` cut to the velocity samples ``rows`` and the detection frames ``frames``, each a slice (step 1;
    its arrays views) or sorted indices: the samples' arrays and directions cut, the segment starts moved onto the
    samples kept (a start whose sample went: the next sample kept; none at the first or past the last), the
    detections of the frames kept with their landmark ids rebuilt (:func:`relabelled`), every field the cut does not
    touch kept as it is (``replace``: a new ``AlignedStream`` listed them and lost those added later; session 32),
    and the fields ``changes`` gives on top. :func:`windowed` and :func:`unbridged` cut with it."""
    starts = aligned.segment_starts
    if isinstance(rows, slice):
        a, b, _ = rows.indices(aligned.vel_t_ns.shape[0])
        starts = starts[(starts > a) & (starts < b)] - a
    else:
        at = np.searchsorted(rows, starts, side="left")
        starts = at[(at > 0) & (at < rows.shape[0])].astype(np.int64)
    d = aligned.directions
    if d is not None:
        d = DirectionSet(d.names, d.inertial, d.body[rows], d.weight[rows], d.gravity_norm)
    off = aligned.det_offsets
    if isinstance(frames, slice):
        fa, fb, _ = frames.indices(aligned.det_t_ns.shape[0])
        da = int(off[fa])
        det_rows = slice(da, int(off[fb]))
        det_offsets = off[fa : fb + 1] - da
    else:
        counts = np.diff(off)[frames]
        det_offsets = np.r_[0, np.cumsum(counts)].astype(off.dtype)
        det_rows = np.arange(det_offsets[-1], dtype=np.int64) - np.repeat(det_offsets[:-1] - off[frames], counts)
    cut = dict(
        vel_t_ns=aligned.vel_t_ns[rows],
        vel_start_ns=None if aligned.vel_start_ns is None else aligned.vel_start_ns[rows],
        omega=aligned.omega[rows],
        velocity=aligned.velocity[rows],
        directions=d,
        segment_starts=starts,
        det_t_ns=aligned.det_t_ns[frames],
        det_offsets=det_offsets,
        det_y=aligned.det_y[det_rows],
    )
    return relabelled(aligned, aligned.landmark_ids[aligned.det_idx[det_rows]], **(cut | changes))


def unbridged(aligned: AlignedStream) -> AlignedStream:
    """``aligned`` with its bridged gaps (``AlignedStream.bridged_gaps``) split as any gap longer than
    ``limits.max_gap``: the time-base samples inside each dropped, a segment starting after it, the detection
    frames inside it dropped. For batch, whose keyframes after a gap are fit to the map by the solve: carried across
    on the interpolated velocity (and seeded by an observer carried so), its solution was the worse (a generated
    figure 8 with the odometry silent 7 s: 0.22 m against 0.009 m split; docs/benchmarks.md, session 33)."""
    b = aligned.bridged_gaps
    if b.shape[0] == 0:
        return aligned
    t = aligned.vel_t_ns
    k = np.clip(np.searchsorted(b[:, 0], t, side="right") - 1, 0, None)
    rows = np.flatnonzero(~((t > b[k, 0]) & (t < b[k, 1])))
    t_new = t[rows]
    after = np.searchsorted(t_new, b[:, 1], side="left")
    after = after[(after > 0) & (after < t_new.shape[0])]
    frames = slice(None)
    if after.size:
        lo, hi = t_new[after - 1], t_new[after]
        j = np.clip(np.searchsorted(lo, aligned.det_t_ns, side="right") - 1, 0, None)
        frames = np.flatnonzero(~((aligned.det_t_ns > lo[j]) & (aligned.det_t_ns < hi[j])))
    cut = subset(aligned, rows, frames, bridged_gaps=np.zeros((0, 2), np.int64))
    return replace(cut, segment_starts=np.union1d(cut.segment_starts, after).astype(np.int64))


def time_window(start: float | None, end: float | None, t0_ns: int) -> TimeWindow | None:
    """``start``/``end`` (seconds, :data:`ABSOLUTE_AFTER_S` decides absolute or relative) on a time base starting
    at ``t0_ns``; None when neither is given."""
    if start is None and end is None:
        return None

    def stamp(v: float | None) -> int | None:
        if v is None:
            return None
        if v > ABSOLUTE_AFTER_S:  # to the microsecond: a double holds Unix seconds to about 0.2 µs
            return int(round(v * 1e6)) * 1000
        return t0_ns + int(round(v * 1e9))

    return TimeWindow(stamp(start), stamp(end), int(t0_ns), (start, end))


def windowed(aligned: AlignedStream, window: TimeWindow | None, path) -> AlignedStream:
    """``aligned`` restricted to ``window`` (its time origin moves to the first sample kept).

    Raises:
        InputError: The window is empty, or keeps fewer than two velocity samples of the log.
    """
    if window is None:
        return aligned
    if window.start_ns is not None and window.end_ns is not None and window.end_ns <= window.start_ns:
        d = window.describe()
        raise InputError(path, f"time window: its end ({d['end_s']:g} s) is not after its start ({d['start_s']:g} s)")
    t = aligned.vel_t_ns
    keep = window.keeps(t)
    if np.count_nonzero(keep) < 2:
        span = f"0 to {(t[-1] - t[0]) / 1e9:.3f} s (stamps {t[0] / 1e9:.3f} to {t[-1] / 1e9:.3f})"
        d = window.describe()
        asked = f"{_bound(d['start_s'])} to {_bound(d['end_s'])} s"
        raise InputError(path, f"time window {asked} from the log's start is outside the log, which spans {span}")
    rows = np.flatnonzero(keep)
    a, b = int(rows[0]), int(rows[-1]) + 1
    # detection frames are in time order: those within the velocity samples kept
    fa, fb = np.searchsorted(aligned.det_t_ns, t[a], "left"), np.searchsorted(aligned.det_t_ns, t[b - 1], "right")
    return subset(aligned, slice(a, b), slice(int(fa), int(fb)), t0_ns=int(t[a]), notes=list(aligned.notes))


def _bound(v: float | None) -> str:
    return "…" if v is None else f"{v:g}"
