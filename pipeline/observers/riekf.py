"""``riekf``: right-invariant EKF SLAM with velocity biases (Barrau & Bonnabel, "An EKF-SLAM algorithm with
consistency properties", 2015), the Kalman-filter baseline the observers are compared with.

State ``X = (R, P, p_1..p_n) ∈ SE_{1+n}(3)`` and biases ``b = (b_Ω, b_V)``. Error ``η = X̂ X⁻¹ = exp(ξ)`` (the
right-invariant error: in the notation of docs/observers.md §1 it is the papers' left error
``R̃ = R̂Rᵀ, P̃ = P̂ − R̃P, p̃_i = p̂_i − R̃p_i``) and ``b̃ = b − b̂``; the filter's covariance is that of
``(ξ_R, ξ_P, b̃_Ω, b̃_V, ξ_1..ξ_n)``.

* Propagation (velocity samples, linear between samples: :func:`pipeline.observers.shared_steps.twist_at`):
  ``X̂ ← X̂ exp(Δt [Ω_m − b̂_Ω; V_m − b̂_V])`` at the mid-point of each step. The error obeys
  ``ξ̇ = Ad_X̂ (b̃ + n)`` (``Ad_X̂`` maps a body twist ``(δω, δv)`` to ``(R̂δω, R̂δv + [P̂]×R̂δω, [p̂_i]×R̂δω)``): no
  state-dependent term in the group block, which is what makes the filter consistent. The transition over
  any interval is ``I + Σ F_k`` exactly (each ``F_k`` maps biases to the group, so their products vanish), and
  the process noise only enters the group rows: both are accumulated as a few 3×3 running sums per velocity
  sample and applied to the covariance once per detection frame, as six low-rank terms in the same pass over
  the covariance as the frame's Kalman downdate (``O((6 + 3m) D²/2)`` for ``D`` state dimensions and ``m``
  detections; :func:`propagation_terms`, :func:`apply`).
* A gyro slower than its motion (a VIO's twist at 4 Hz on a hand-held rig): the rotation the linear twist misses
  between samples (``noise.gyro_unresolved``, from the samples' own second differences) is not the white noise of
  ``noise.gyro``, and a filter weighing the twist at its white level believes its attitude and carries the map off
  with it. riekf's gyro level is raised per axis to ``UNRESOLVED_FACTOR`` times that density where this exceeds the
  white level (:func:`unresolved_gyro`, a note); where the rate resolves the motion it is 1e-4 of the white level
  and nothing changes. The floor's evidence reads the white level (the missed rotation is motion, not noise).
* Update (each detection frame): the innovation ``z_i = R̂y_i + P̂ − p̂_i = −e_i`` has the constant Jacobian
  ``H = [0, I, 0, 0, …, −I, …]`` and noise ``R̂ N R̂ᵀ``; a χ² gate (3 DoF, 99.99 %) drops outliers. The
  correction is ``X̂ ← exp(−ξ̂) X̂``, ``b̂ ← b̂ + b̃̂``.
* Gaps (new segments, ``limits.max_gap``): nothing is integrated across them (as for the observers); the pose
  is re-anchored to the map where a frame allows it and gets the covariance of a fresh start (``GAP_SIGMA``).
* Gaps in the velocity samples (shorter than ``limits.max_gap``, longer than ``shared_steps.GAP_INTERVALS`` median
  intervals):
  the twist is interpolated across them as between any two samples, but its error there is the two samples' noise
  alone, not a white noise averaged over the samples the interval would have held: the process noise over such an
  interval is that of its two samples (``shared_steps.gap_factor``, ``span / (2 interval)`` times the white
  density's). Held (commanded) streams (``noise.held``) keep the density: their intervals are commands held,
  not samples missing.
  An odometry on a topic of its own is interpolated onto the gyro's stamps, so its gaps do not show on the time
  base: the alignment keeps them (``AlignedStream.velocity_gaps``) and the velocity's noise over each time-base
  interval inside one takes that gap's factor (``shared_steps.gap_levels``, which batch's smoother shares).
  (Generated figure 8 with three 1 s velocity gaps: pose NEES 140 without it, 5.7 with it, 5.5 with no gaps;
  docs/benchmarks.md, "riekf across a gap in the velocity stream".)
  Such a gap longer than ``limits.max_gap`` that the gyro recorded through (``AlignedStream.bridged_gaps``, up to
  ``limits.max_odometry_gap``) is carried across, its factor at least the motion's spread over the whole gap
  (``shared_steps.motion_factor``): the landmarks after it re-anchor the position instead of being gated.
* New landmarks are augmented with their proper covariance: ``p̂ = R̂y + P̂`` has the error ``ξ_P + R̂n``
  (independent of the attitude error in these coordinates), so its rows copy ``P̂``'s and its own block is
  ``Σ_PP + N``. Landmarks out of view stay in the state with their estimate and covariance; as in every
  EKF, an update moves them only through their correlation with what was measured.

* Recovery (the filter never loses a log silently): the detections of known landmarks are counted in windows of
  ``WINDOW``; when more than ``RECOVER_SHARE`` of a window fail the gate, the noise model does not fit the log
  (or the estimate is lost). The filter re-estimates a variance factor from the window's innovations (median
  Mahalanobis distance² over the χ² median, at least ``MIN_STEP``) and applies it: at the first failing window
  to the detection variances (the detections are noisier than assumed); at a second one in a row to every
  noise variance and the covariance (for a linear filter a common factor keeps the gain and makes the gate
  consistent again: the estimate may be lost); from a third one on the landmarks that failed the gate are
  also re-initialised (at their next detection, like a new one). The filter gives up (status ``lost``, an
  ``error:`` line in the notes) after ``MAX_FAILING`` failing windows in a row, or when the detection noise
  would exceed ``MAX_SIGMA_SHARE`` of the median detection range (detections that say nothing at that level),
  unless landmarks that never passed the gate failed in that window: those are re-initialised instead and no
  noise changes. Such a landmark holds only the detection it was started from, which may have carried another
  landmark's id (one not yet seen): it sits metres from every true detection of it, and in view alone it filled a
  window no noise level explains; the filter gave up there, at its first failing window with 0 recoveries, on a
  run 0.19 m off (docs/benchmarks.md, "riekf's false lost, session 39 (h-falselost2)"). A landmark that passed
  before (an id reused, a tag moved) is not re-started by this. The filter keeps updating after it gave up (only
  the recoveries stop): where the windows pass again to the log's end, the run says from when, and only the
  stretch before is called no estimate.
  With one detection per frame the window cannot tell a pose error from the detections' noise
  (:func:`_common_share` unknown): a factor the detections cannot have goes to the motion alone, not a give-up
  (docs/benchmarks.md, "riekf's floor without heading, session 30 (h-floorweight)"). On a log where no window
  fails, none of this changes a number.
* Overconfidence (a consistency check that changes no number): a consistent filter's innovations are white, so
  the sum of a window's accepted innovations has the sum of their joint covariances (a frame's cross blocks
  included) and its Mahalanobis distance² follows χ² (3 DoF) whatever the window's size. A slowly varying error
  the noise model lacks (wheel slip; the gate still passes) makes them correlated: when the median of that d²
  over the last ``CONSISTENCY_WINDOWS`` passing windows exceeds ``OVERCONFIDENT_D2`` (χ² 90 %: about 3 in 1000
  windows of a consistent filter), the time and the median are recorded (run.json
  ``observer.filter.consistency``, a note: the covariance understates the error). Raising the velocity-bias walk
  on this test was tried and left out (docs/benchmarks.md, "riekf: overconfidence from the innovations").
* The map's covariance scaled by the innovations (:func:`innovation_consistency`): over the whole run, the mean of
  every passing window's d² (the test above) against the 97.5 % bound of a mean of that many χ² (3 DoF) values.
  Above it, the errors the detections see are larger or more correlated than the covariance says by that mean over
  3 (a variance component), and the written landmark covariance (landmarks.parquet ``cov_*``, ``sigma``) is
  multiplied by it; run.json ``observer.filter.innovation_consistency`` holds the statistics and the factor (1
  within the bound), with a note when it is above 1. The estimate and the pose covariance are unchanged. Errors the
  detections cannot see (a camera's calibration, a tag's size, the truth's own) are not in it (docs/benchmarks.md,
  "riekf's map σ on real logs").
* The pose's covariance widened by the detections' correlation in time (:func:`correlation_factor`): the filter
  treats each detection's error as independent of the last; on real logs a landmark's detection errors are
  correlated over seconds, so the same information is counted several times and the pose covariance is too small.
  Each accepted detection's innovation, whitened by its gate distance (``z / |z| · √d²``), joins its landmark's
  last ``CORRELATION_LAGS`` (:func:`_correlation_sums`); the lag products pooled over the landmarks give the
  integrated autocorrelation ``ν = 1 + 2 Σ ρ_k`` (Sokal's window, its standard error), the factor by which counting
  them as independent overstates their information. When ``ν`` minus ``CORRELATION_SES`` standard errors exceeds
  1, the written pose covariance is the filter's times ``ν`` (each stretch at its write, from the pass so far:
  a written stretch is never rescaled); run.json ``observer.filter.correlation`` holds ``ν``, its standard
  error and whether it was applied, with a note. Output only: the filter, the map and its covariance are unchanged
  (docs/benchmarks.md, "riekf's correlation factor").
* Velocity-bias walk (learned from the log unless ``noise.velocity_bias_walk`` is given): variance matching on the
  bias states (Myers & Tapley 1976, Mohamed & Schwarz 1999: a state's corrections ``δx̂ = Kz`` have the covariance
  ``K S Kᵀ``, the downdate ``U Uᵀ`` of its rows, when the model is right). Over the last ``CONSISTENCY_WINDOWS``
  windows that passed the gate, the summed ``|δb̂_V|²`` is compared with the summed trace of ``U Uᵀ`` on the
  velocity-bias rows; when it exceeds ``WALK_RATIO`` times that (``WALK_RATIO_AGAIN`` once raised), the bias moves
  more than its walk allows (a slowly varying velocity error, such as wheel slip, that the frozen bias pushes into the
  position), and the walk's standard deviation is multiplied by that ratio squared (the ratio understates the
  walk: the corrections and their expectation both shrink with the gain; up to ``MAX_WALK_FACTOR`` in all; run.json
  ``observer.filter.walk``, a note). The ratio measured on the generated ground robot with slip is 4-6, on MR.CLAM,
  TagSLAM and clean generated logs at most 3.7, where a larger walk hurts (docs/benchmarks.md, "riekf's
  velocity-bias walk from the log (session 16)"). On a log where it stays below, nothing changes. A raise comes late
  (the signal appears once the bias prior has collapsed) and the trajectory before it kept the slip's error in a
  covariance that did not allow for it (position, heading and map NEES 5-30 on the generated ground logs): so when
  the first stretch's largest ratio exceeds ``RESTART_RATIO`` the filter starts again from the log's start with the
  walk's standard deviation multiplied by that ratio squared (:meth:`RiEKF._walk_restart`, before anything of the
  stretch is returned; up to ``MAX_WALK_PASSES`` passes; run.json ``observer.filter.walk`` ``passes`` and
  ``start_walk``, a note). Only on a ground robot whose floor is held (below, "Planar motion": wheels on a floor,
  where slip is the slow velocity error); not where the velocity level was estimated from detection pairs over
  seconds (held commands, ``noise.held``: MR.CLAM), which already holds the slow error (a walk on top made MR.CLAM
  worse), nor on moving 3-D logs, whose large corrections came from elsewhere (stereo detections' skewed depth: the
  walk from the start made those worse; docs/benchmarks.md, "riekf under wheel slip, session 19 (h-slip)").
* Gyro-bias walk (learned from the log unless ``noise.gyro_bias_walk`` is given): the same test on the gyro-bias
  rows, over the same windows (:func:`_walk_check` checks both): the summed ``|δb̂_Ω|²`` against the summed trace of
  ``U Uᵀ`` on the gyro-bias rows, raised at the same ratios, and the first stretch run again from the start with the
  gyro's walk learned when its largest ratio exceeds ``RESTART_RATIO`` (:meth:`RiEKF._walk_restart`, one restart
  for both walks; run.json ``observer.filter.walk.gyro``, a note). Only where the angular velocity is an IMU's gyro
  (its own topic, ``AlignedStream.two_twist_topics``, not held): an odometry's or a VIO's angular velocity has no
  gyro bias that walks, and TagSLAM test_11's VIO twist reached the ratio with its coloured error (the walk at the
  100x cap made its map 0.138 -> 0.241 m); MR.CLAM's commanded ω is held. And, as the velocity's, only on a ground
  robot whose floor is held: a MEMS gyro's bias walks on any rig, but the generated flights and hand-held rigs with
  a walk never reached the ratio (nothing to gain there), while on the figure-8 other errors did (the detection
  noise told half its size; detections moved 3 m at the end), and the walk learned from them moved those runs. A gyro
  bias walking 0.002 rad/s/√s on a generated ground robot (seed=9967) cost riekf 0.462 m against 0.256 learned
  (0.234 given the true walk); docs/benchmarks.md, "riekf under a gyro bias that walks, session 35 (h-gyrowalk)".
* Blind stretches: after ``BLIND_S`` or more without a known landmark's detection (none in view, or a detection
  gap), the pose error has grown by dead reckoning alone and a re-observed landmark may fall outside the
  propagated covariance (wheel slip the noise model lacks). The first ``BLIND_WINDOW`` known-landmark detections
  that follow are checked: when nearly all (over ``BLIND_SHARE``) fail the gate, the pose is off (not a few
  outliers), and the position's covariance is re-opened to the error the landmarks see (their median squared
  innovation on each axis, uncorrelated with the rest of the state, as at a segment start): the re-observed
  landmarks re-anchor the pose (run.json ``observer.filter.blind``, a note). Elsewhere nothing changes. (Acting on
  half failing or on correlated innovations, re-opening the attitude too, or scaling the whole pose block, made
  real logs worse: docs/benchmarks.md, "riekf after a blind stretch".)
* Stated levels above the samples: a message's covariance more than ``1 / noise.STATED_LOW`` times above the
  samples' white-noise estimate is believed (a coloured noise, a VIO's, is louder than its samples show), yet where
  the sensor is white riekf weighs that stream too loosely (1.2-1.9x its APE with the true levels on session 33's
  flights and hand-held rigs). Where a key of ``noise.above_samples`` (gyro, velocity: stated above the samples) is
  that far above, the first stretch is run at the stated levels, then at the samples' on every stated key above
  them, then (two keys) on each alone (:func:`level_candidates`, :meth:`RiEKF._level_restart`), and the pass whose
  innovation deviance per tested detection (:func:`innovation_likelihood`) is lowest is kept; the stated stays
  unless another's deviance over the stated pass's tested detections is lower by more than the χ² quantile
  ``LEVEL_CHOICE_P`` for the keys it changes (:func:`chosen_level`). Each candidate's evidence is that of its last
  pass, after the walk's and the bias priors' restarts below have run at its levels (a pass that lost the track says
  nothing of the levels: TagSLAM test_22's first, 48 detections in a row gated at either velocity level); the chosen
  one's are run again. run.json ``observer.filter.stated_levels`` and a note say which level was used and why
  (docs/benchmarks.md, "riekf between a stated level above the samples' and theirs, session 34"). A key whose
  odometry's own poses support its stated level (``noise.drift_evidence``: the twist's long-horizon drift from them,
  a constant bias taken out) is not tried (``NoiseSettings.disputed``). Nowhere else does anything change.
* Range against bearing where the turn rate is held: the triplets within 1 s cannot see a range error that changes
  more slowly (MR.CLAM's is 92-97 % shared by two detections within 1 s), and a held (commanded) turn rate's error
  hides the rest. Where the gyro's level came from the held streams' fit and the triplets found no ratio
  (``noise.ratio_by_deviance``; no stated level above the samples'), the first stretch is run at ``detection_ratio``
  1 and at ``noise.DETECTION_RATIOS`` (batch's ladder) upwards while the deviance falls by more than the χ²
  quantile ``LEVEL_CHOICE_P`` of one degree of freedom (batch's climb, :func:`ratio_climbing`), as the candidates
  above, by the same rule (:func:`chosen_level`: the lowest deviance per tested detection, 1 kept unless it is
  within that quantile of it), the deviance tallied over the axes that carry error
  (:func:`ratio_deviance`: the vertical axis left out of a detection whose vertical innovation is exactly 0, a
  planar rig's, whose ``log det`` share would otherwise reward a large ρ). run.json's ``noise.levels.detection_ratio``
  says the ratio, each one's deviance and why (:func:`ratio_method`), and a note (docs/benchmarks.md, "riekf learns
  the range-against-bearing ratio from its own innovations, session 37 (h-ratio2)").
* Bias priors narrowed: the biases start at zero with the priors ``noise.gyro_bias`` and ``noise.velocity_bias`` (0.2
  by default: an unknown start). From a few landmarks over a short stretch the filter may learn a bias along a
  direction they barely resolve (TagSLAM's test_22: pitch rate against vertical velocity from one or two tags ahead
  for 10 s, a velocity bias of 0.22 m/s where the twist has none above 0.02) and carry it through a blind stretch; the
  landmarks that return then lie far outside the covariance and every one fails the gate, while the recovery's windows
  are never judged (the status was ``converged``; now ``gated_at_end``, :func:`filter_status`). When the first stretch
  holds ``LOST_IN_A_ROW`` or more known-landmark detections in a row failing the gate at its end, or, in a pass where
  neither a recovery nor a blind stretch's re-anchoring acted, as many failing before it in an open run (ended by a
  frame whose detections mostly pass, not by one where as many or more fail: with two tags back the state may fit one
  and not the other, while a wrong tag fails alone among passing ones; and a track lost for that long and then taken
  again was taken by a jump; docs/benchmarks.md, "riekf's gate cascade after a blind stretch, session 32") and the
  filter did not give up, it starts again from the log's start with both priors' standard deviations multiplied by
  ``PRIOR_NARROWING``, again each pass while the stretch holds such a run, up to ``MAX_PRIOR_PASSES``
  (:meth:`RiEKF._prior_restart`, before anything of the stretch is returned; run.json ``observer.filter.bias_priors``,
  a note); when the last of those holds one too, no bias explains it (a moved landmark, say) and a last pass puts the
  priors back (``kept`` false, a note). The first narrowed pass that keeps the track is not the best one (TagSLAM
  test_22 at a gyro level of 0.045: 0.56 m after one pass, 0.23 after three), so from it the priors are narrowed once
  more each pass while the innovations' deviance per tested detection (:func:`innovation_likelihood`, a gated
  detection's at the gate) falls and the track holds, up to ``MAX_PRIOR_PASSES``; the narrowing with the lowest
  deviance is kept, run once more when a narrower one came after it (run.json ``bias_priors.narrowed_tried``, the
  note; docs/benchmarks.md, "riekf's bias-prior narrowing: a pass chosen by its likelihood, session 33"). The end of
  the log sets how the start is weighed: fair for an offline tool, not an online filter's. Not when either prior is
  given in the configuration. Elsewhere nothing changes (docs/benchmarks.md, "riekf's bias priors after a lost track,
  session 22 (h-riekf22)").
* Bias priors from detection pairs: with both priors at their defaults, the biases start at the constant biases
  that keep each landmark's dead-reckoned position still between pairs of its detections
  (:func:`pipeline.noise_estimation.pair_bias_estimate`, each pair weighed by its detections' and its dead
  reckoning's covariance), each axis's prior standard deviation ``PAIR_PRIOR_SDS`` times the estimate's spread
  (over resampled landmarks and blocks of time; times √χ² above 1) and at least the bias walk over the span it is
  made from, within the log's first ``PAIR_PRIOR_WINDOW_S`` (:func:`pair_bias_prior`); only with
  ``PAIR_PRIOR_LANDMARKS`` or more landmarks (TagSLAM's test_22's two tags put 0.1 m/s on its vertical velocity) and
  the pairs' mean squared whitened residual χ² at most ``PAIR_PRIOR_CHI2``; a pass started from it that ends with
  the track lost (or gives up) is run again with the default start (:meth:`RiEKF._prior_restart`). The narrowing
  above scales these priors. run.json ``observer.filter.bias_priors.from_pairs``, a note (docs/benchmarks.md,
  "riekf's bias priors from the log, second attempt, session 29 (h-riekfprior2)").
* Planar motion (a ground robot on a flat floor): a 6-DoF filter has no way to know the floor is flat, and with a
  noisy gyro its roll and pitch walk while no landmark is in view; the height follows them (docs/benchmarks.md,
  "riekf on ground robots (session 18, h-riekfg)"). When the log's roll and pitch rates and vertical velocity
  spread no more than ``PLANAR_RATIO`` times their noise per sample (:func:`planar_evidence`: what they measure is
  noise, not motion), or the roll and pitch rates are motion but the angles they integrate to stay within
  ``PLANAR_TILT`` (:func:`tilt_spread`: a wheeled robot wobbling on an uneven floor, whose tilt the floor's σ
  covers; docs/benchmarks.md, "riekf behind fast-adaptation on a ground robot with little to see"), the floor
  through the start pose is held every ``PLANAR_EVERY_S`` as pseudo-measurements
  (:func:`_planar_update`): the body's up axis normal to it (``PLANAR_TILT``) and the position's height on it
  (``PLANAR_HEIGHT``). The floor's height error (the start's tilt a few metres on) is the same at every one, not
  new each time: the height row's noise brings the filter's height variance down to that level and no further
  (the information over the log is bounded; repeated as independent, the height's NEES was 4-15); the tilt rows
  (the body's wobble on the floor, new each time) keep ``PLANAR_TILT`` and carry nothing on the heading about the
  normal (turning about it tilts the up axis no less; linearized at the estimate's tilt they read a heading that is
  not there: heading NEES 20-100 beside one landmark at a time; session 30 (h-floorweight)). Held roll and pitch
  leave the heading's variance to grow by the gyro's noise alone over a blind stretch, less than a slipping wheel
  turns it: when the blind check re-opens the position, the heading relative to the map is re-opened too, about
  the robot (:func:`_reopen_heading`). run.json ``observer.filter.planar`` and a note say so; ``noise.floor``
  (``auto``, true, false) follows the evidence,
  forces the floor or turns it off. Samples with no roll, pitch or vertical part at all (a planar log by
  construction) stay in their plane without it, and nothing changes.
* At rest: a body that stands still neither turns nor moves, so its gyro reads its bias and its velocity input its
  bias. Beside a single landmark in view nothing else holds the gyro's bias about the vertical: a heading and a
  tangential velocity bias that turn the body about the landmark leave its detections unchanged, so a ground robot
  at rest with one landmark turned its heading 48 deg in 120 s at the gyro bias's error of 0.007 rad/s (seed=3962:
  APE 0.93 m, "lost"; docs/benchmarks.md, "A robot at rest with one landmark in view, session 36"). The velocity
  samples at rest (:func:`base.still_mask`: a stretch where neither stream's running mean over
  ``base.MOTION_MEAN_WINDOW_S`` changes more than their white noise explains, the velocity's near zero at one of
  its samples; the whole stretch, so that the velocity's mean over it reads its bias, not one pulled towards zero)
  are summed over windows of ``base.MOTION_MEAN_WINDOW_S`` s, and each window's means are a measurement of both
  biases (:func:`_still_update`), with the densities' variances over the window, gated like a detection. A rig
  turning in place at a steady rate reads to both streams like one at rest: the gate against the filter's own
  gyro bias keeps it out once a landmark has narrowed that bias (docs/benchmarks.md, "riekf's bias readings at
  rest, without batch's, session 37"). While the heading is unknown (a rotation variance above that of a heading
  uniform over the circle, ``HEADING_UNKNOWN_VAR``: a blind start on the wide gyro-bias prior) a window reads the
  biases only and leaves the pose and the map as they were: the correlations that would move them were propagated
  about a heading that may be turns off, and the pose they claimed was a linearisation's (docs/benchmarks.md,
  "riekf's still readings while the heading is unknown, session 37").

Noise levels come from :mod:`pipeline.noise` (``noise`` in ``run.yaml`` key by key, else the log's plausible
message covariances, else estimated from the log, else defaults). The start pose defines the map frame (the
problem's gauge, docs/observers.md §1.1): its covariance is zero; the biases start at zero with the prior
standard deviations ``noise.gyro_bias`` and ``noise.velocity_bias`` (an unknown start, not a guess; narrowed when the
track is lost, above) or at the detection pairs' estimate (above), and drift as slow random walks.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from numba import types
from slamobs.pipeline.cholesky import cholesky_lower
from slamobs.pipeline.errors import Unwind
from slamobs.pipeline.kernel_cache import njit, subroutine

from slamobs.pipeline.lie import floor_tilt_row, project_so3, se3_exp_into, skew, so3_left_jacobian_apply
from slamobs.pipeline.noise import (
    DETECTION_RATIOS,
    DEVIANCE_RATIO_METHOD,
    LEVEL_CHOICE_P,
    chi2_quantile,
    format_level,
    nees_bounds,
    ratio_by_deviance,
    stated_above,
)
from slamobs.pipeline.observers.base import (
    MOTION_MEAN_WINDOW_S,
    KernelState,
    ObserverDiverged,
    ObserverSpec,
    Outputs,
    Stepper,
    still_mask,
)
from slamobs.pipeline.observers.shared_steps import gap_factor, gap_levels, record_row, twist_at
from slamobs.pipeline.observers.time_offset import note as time_offset_note
from slamobs.pipeline.simd import add8, fma8, load8, mul8, splat8, store8, sub8

#: Mahalanobis gate of one landmark innovation (χ², 3 DoF, 99.99 %).
GATE_CHI2 = 21.1
#: A heading this uncertain is unknown: the variance of one drawn uniformly over the circle, π²/3 rad². Past it a
#: still reading's correction of the pose through the biases' correlations is a linearisation about an estimate
#: that may be turns off (:func:`_still_update`).
HEADING_UNKNOWN_VAR = math.pi**2 / 3.0
#: Longest propagation step of the covariance sums (s); longer gaps are cut (the mean step is exact anyway).
MAX_STEP_S = 0.01
#: Re-orthonormalise R̂ every this many propagation steps (as the observers, docs/observers.md §6.1).
REORTHO_EVERY = 1000
#: Fixed part of the error state: ξ_R, ξ_P, b̃_Ω, b̃_V; landmark slots follow in order of first sighting.
N_FIXED = 12
#: Indices into the accumulator stack ``acc`` (3×3 each) and the scalar ``fs`` clocks.
_SR, _SPR, _QRR, _QPR, _QPP = 0, 1, 2, 3, 4
_T, _MEAS_T, _ACC_DT, _SCALE, _LOST_T, _DSCALE, _KNOWN_T, _BLIND_T, _WALK, _PLANE_T, _WALK_MAX = range(11)
#: Velocity gaps (module docstring, "Gaps in the velocity samples"): the ``fs`` slots of the gyro's and the
#: velocity's sample interval (their median; 0 where the stream is held: no gap factor).
_GAP_OM, _GAP_V = 11, 12
#: The gyro-bias walk's variance factor and its first stretch's largest ratio (module docstring, "Gyro-bias walk"):
#: the velocity's are ``_WALK`` and ``_WALK_MAX``; :data:`_WALK_SLOTS` lists both walks' slots, gyro first.
_GWALK, _GWALK_MAX = 13, 14
#: A still stretch's running sums (:func:`_still_update`): its first sample's time, the samples, the gyro's and the
#: velocity's sums.
_STILL_T0, _STILL_N, _STILL_SUM = 15, 16, 17
#: After the filter gave up (``_LOST_T``): the time of the first window of the passing windows that run to the end
#: (0 where the last window failed; module docstring, "Recovery").
_AGAIN_T = 23
_N_CLOCKS = 24
#: Integer state ``ns``: the slots every kernel shares (base.KernelState: iv, jf, nvis (unused here), started,
#: steps, and the sub-step cap's two, never hit here), then the filter's own.
_IV, _JF, _STARTED, _STEPS = 0, 1, 3, 4
_NSEEN, _GATED, _UPDATES, _SKIPPED = 7, 8, 9, 10
#: The recovery's slots (module docstring, "Recovery"): detections tested and gated in the current window,
#: recoveries made, consecutive failing windows, landmarks re-initialised, and whether the filter gave up.
_WIN_N, _WIN_GATED, _RECOVERIES, _FAILING, _REINIT, _LOST = 11, 12, 13, 14, 15, 16
#: The consistency check's slots (module docstring, "Overconfidence"): windows in its ring, times it fired.
_CONSISTENCY_N, _OVERCONFIDENT = 17, 18
#: After a blind stretch (module docstring, "Blind stretches"): whether its check is pending, the known-landmark
#: detections tested and gated since it ended, and the pose covariances re-opened.
_ARMED, _PB_N, _PB_GATED, _RELOCS = 19, 20, 21, 22
#: The velocity-bias walk (module docstring, "Velocity-bias walk"): windows in its ring, times it was raised, and
#: whether it is fixed (given in the configuration).
_WALK_N, _WALK_RAISES, _WALK_FIXED = 23, 24, 25
#: The known-landmark detections in a row, up to the latest, that failed the gate; the longest open run that ended so
#: far, and the current one (an open run is ended by a frame whose detections mostly pass, not by one where as many or
#: more fail, and dropped when a recovery or a blind stretch's re-anchoring acts; module docstring, "Bias priors
#: narrowed").
_TAIL_GATED, _LONGEST_GATED, _OPEN_GATED = 26, 27, 28
#: The gyro-bias walk's raises and whether it is fixed (the velocity's are ``_WALK_RAISES`` and ``_WALK_FIXED``).
_GWALK_RAISES, _GWALK_FIXED = 29, 30
N_SLOTS = 31
#: The two bias walks (module docstring, "Gyro-bias walk"), gyro then velocity: each one's ``fs`` slots (variance
#: factor, the largest ratio), ``ns`` slots (raises, fixed), ``win_sum`` row
#: (its corrections' ring; the next row their expectation's).
_WALK_SLOTS = ((_GWALK, _GWALK_MAX, _GWALK_RAISES, _GWALK_FIXED, 9), (_WALK, _WALK_MAX, _WALK_RAISES, _WALK_FIXED, 6))
#: Recovery (module docstring): detections per window, the gated share that triggers it, the χ² (3 DoF) median
#: the window's median distance² is compared with, the smallest and largest variance factor of one recovery, the
#: failing windows in a row after which the filter gives up, and the detection noise (as a share of the median
#: detection range) beyond which the detections carry no information.
WINDOW = 50
RECOVER_SHARE = 0.5
CHI2_MEDIAN_3 = 2.366
MIN_STEP, MAX_STEP = 4.0, 1e4
MAX_FAILING = 4
#: Share of the window's innovations common to a frame above which a failing window is put down to the motion
#: (a pose error moves all of a frame's innovations alike), not to the detections (``_common_share``).
COMMON_SHARE = 4.0
MAX_SIGMA_SHARE = 0.25
#: Overconfidence (module docstring): the median over ``CONSISTENCY_WINDOWS`` windows of the summed innovations' d² (χ²,
#: 3 DoF, 90 %) above which the filter is overconfident.
OVERCONFIDENT_D2 = 6.25
CONSISTENCY_WINDOWS = 7
#: Rows of the window sums ``win_sum`` (columns: ``CONSISTENCY_WINDOWS``): the window's summed innovations and their
#: covariance (0-3), the consistency ring (4), the bias corrections (5: the window's, gyro in columns 2-3, velocity
#: in 0-1; 6-7 the velocity's ring, 9-10 the gyro's), the run's innovation tally (8,
#: :func:`innovation_consistency`, :func:`innovation_likelihood`, :func:`ratio_deviance`). Public: tests that call
#: :func:`update` allocate it.
WIN_SUM_ROWS = 11
#: The pose covariance's correlation factor (module docstring, :func:`correlation_factor`): the lags of a landmark's
#: consecutive accepted innovations summed (a ν up to about ``CORRELATION_LAGS / CORRELATION_WINDOW`` is measured
#: whole, a larger one truncated: under-, never overstated), Sokal's window constant ``c`` (the window is the first
#: ``M ≥ c ν``), and the standard errors by which ν must exceed 1 to be applied.
CORRELATION_LAGS = 48
CORRELATION_WINDOW = 5.0
CORRELATION_SES = 2.0
#: Velocity-bias walk (module docstring): over the last ``CONSISTENCY_WINDOWS`` passing windows, the ratio of the
#: squared velocity-bias corrections to what a consistent filter expects of them above which the walk is raised
#: (first time; ``WALK_RATIO_AGAIN`` once raised), and the largest factor on its standard deviation in all.
WALK_RATIO = 4.0
WALK_RATIO_AGAIN = 2.0
MAX_WALK_FACTOR = 100.0
#: Velocity-bias walk from the first stretch (module docstring): the ratio above which the filter starts again with the
#: walk the stretch learned, and the most passes over it in all.
RESTART_RATIO = 2.0
MAX_WALK_PASSES = 4
#: Bias priors narrowed (module docstring): the known-landmark detections in a row failing the gate in the first
#: stretch from which its track is lost, the factor on both bias priors' standard deviations per pass, and the
#: passes with narrowed priors at most.
LOST_IN_A_ROW = 20
PRIOR_NARROWING = 0.25
MAX_PRIOR_PASSES = 3
#: Known-landmark detections in a row failing the gate at the log's end from which the run says so (below
#: ``LOST_IN_A_ROW`` nothing else does): a consistent filter's detection fails the gate (``GATE_CHI2``, 3 DoF) with
#: probability about 1e-4, so five in a row are not chance, and a wrong tag fails alone, with others passing between;
#: the end of every real log of ``benchmarks/real_logs.py`` has none (TagSLAM test_22 cut within 20 detections of its
#: return after 17.9 s unseen: 6-17, riekf 2.7-4.7 m off, status converged; docs/benchmarks.md, session 31 (h-tag22)).
TAIL_NOTE_IN_A_ROW = 5
#: run.json ``observer.filter.status`` and, as ``status_checked``, what each one says was checked (one place: the
#: status is :func:`filter_status`'s, never more than the run's notes allow: a run whose last detections fail the gate
#: was ``converged`` before, 2.7-4.7 m off at TagSLAM test_22's cut ends; docs/benchmarks.md, session 32).
STATUSES = {
    "lost": "the filter gave up: most detections kept failing the gate after its recoveries (run.json lost_at_s)",
    "gated_at_end": (
        f"its last {TAIL_NOTE_IN_A_ROW} or more known-landmark detections in a row failed the gate: the pose at the "
        "log's end is most likely off by more than its σ says (bias_priors.gated_in_a_row_at_end)"
    ),
    "recovered": (
        "most detections of a window failed the gate and the noise was raised (recovery_log); not given up, and "
        f"fewer than {TAIL_NOTE_IN_A_ROW} known-landmark detections in a row failed it at the end"
    ),
    "converged": (
        "no window of detections needed a recovery, not given up, and fewer than "
        f"{TAIL_NOTE_IN_A_ROW} known-landmark detections in a row failed the gate at the end (not a check of the "
        "error, nor of the σ: observer.filter.consistency and the report's uncertainty are)"
    ),
}


def filter_status(gave_up: bool, recoveries: int, gated_at_end: int) -> str:
    """The filter's status (:data:`STATUSES`): ``lost`` when it gave up, ``gated_at_end`` when its last
    ``TAIL_NOTE_IN_A_ROW`` or more known-landmark detections in a row failed the gate (whatever came before),
    ``recovered`` after a recovery, else ``converged``."""
    if gave_up:
        return "lost"
    if gated_at_end >= TAIL_NOTE_IN_A_ROW:
        return "gated_at_end"
    return "recovered" if recoveries else "converged"


#: The statuses that say the run's estimate is off (the others only what was checked): a table's ``ok`` (the run
#: finished: ``compare``, a batch's summary) and the report's converged figure name them beside it
#: (:func:`.evaluation.report.own_status`).
OFF_STATUSES = ("lost", "gated_at_end")


#: Bias priors from detection pairs (module docstring): the fewest landmarks whose resampling gives the estimate's
#: spread, the spreads the prior's standard deviations are, and the log's first seconds it is made from (a prior is
#: of the start's bias, which the walk moves over the log; the one-hour benchmark log's 3 million pairs took 33 CPU s,
#: its first 300 s 0.2 s; TagSLAM's and the generated logs are shorter: the whole log).
PAIR_PRIOR_LANDMARKS = 5
PAIR_PRIOR_SDS = 3.0
PAIR_PRIOR_WINDOW_S = 300.0
#: The largest mean squared whitened residual of the pairs (about 1 when the fit explains them) at which the
#: estimate is used: above it slip or a gyro noisier than its level are in the pairs, which a constant bias fit
#: cannot tell from a bias (docs/benchmarks.md, session 29 (h-riekfprior2)).
PAIR_PRIOR_CHI2 = 1.5
#: Planar motion (module docstring): the RMS of the roll and pitch rates and of the vertical velocity over their noise
#: per sample at or below which the body moves in a plane, the tilt (rad) and height (m) standard deviations of the
#: floor's pseudo-measurements, and the seconds between them.
PLANAR_RATIO = 1.25
#: A gyro slower than its motion (module docstring): riekf's gyro level per axis at least this many times the
#: density of the rotation its rate does not resolve (``noise.gyro_unresolved``). Chosen on generated hand-held
#: rigs at 4 Hz (docs/benchmarks.md, "riekf's gyro level on a rig whose only angular velocity is slow", session 33).
UNRESOLVED_FACTOR = 2.0
PLANAR_TILT = 0.02
PLANAR_HEIGHT = 0.05
PLANAR_EVERY_S = 0.5
#: Blind stretches (module docstring): the seconds without a known landmark's detection after which the first
#: ``BLIND_WINDOW`` tested detections are checked, and the share of them failing the gate above which the pose, not
#: a few outliers, is off.
BLIND_S = 20.0
BLIND_WINDOW = 20
BLIND_SHARE = 0.9
#: What a recovery did, by failing windows in a row (1, 2, 3 and more).
RECOVERY_ACTIONS = {
    0: "the motion noise variances and the covariance (the frames' innovations moved together: a pose error)",
    1: "the detection variances",
    2: "every noise variance and the covariance",
    3: "every noise variance and the covariance, re-initialising the landmarks that failed,",
    4: "no noise: the landmarks that failed before ever passing re-initialised (the detections' factor beyond any)",
}
#: Recoveries recorded for the notes (time, variance factor, total factor, failing windows in a row).
MAX_LOG = 64
#: The covariance is allocated to a multiple of this many rows and columns, the one-pass scratch rows to a multiple
#: of this many columns: :func:`apply`'s tiles are this many rows by one or two vectors of :mod:`pipeline.simd`.
PAD = 8
#: The dense kernels' floating-point flags (``propagation_terms``, ``apply``, ``_gain``, ``update`` and the frame's
#: helpers ``_gate``, ``_mahalanobis3``, ``_reset_landmark``, ``_bias_corrections``, ``_correct``, declared here: a
#: kernel's flags are its own, never its caller's, kernel_cache.njit): ``a * b + c``
#: fused into one multiply-add instruction (one rounding instead of two; the order of the additions as written, no
#: other ``fastmath`` licence): half the floating-point instructions of the dense pass (docs/benchmarks.md, "riekf's
#: filter stage"). The same bits run after run, compiled or loaded from the cache; with the flag on ``_advance`` and
#: the per-sample kernels too, a run that compiled them gave other bits (2.9e-13) than one that loaded them.
CONTRACT = {"contract"}
#: Work units (base.WORK_PER_CALL) of a velocity step and, per 1000 multiply-adds, of a frame's update.
_FRAME_WORK_SCALE = 1000


@njit(cache=True)
def accumulate(h, r_hat, p_hat, q_om, q_v, acc, w=None):
    """Running sums of one propagation step of length ``h`` from the state at its start: ``Σ R̂h``,
    ``Σ [P̂]×R̂h`` (the bias columns of the transition) and ``Σ M h``, ``Σ [P̂]×M h``,
    ``Σ ([P̂]×M[P̂]×ᵀ + R̂ Q_V R̂ᵀ) h`` with ``M = R̂ Q_Ω R̂ᵀ`` (the process noise). ``w``: (3, 3, 3) scratch for ``M``,
    ``R̂ Q_V R̂ᵀ`` and ``[P̂]×M``, indexed whole (a view or an allocation per step cost more than the step's sums).
    Public: tests/test_riekf.py checks the kernel against dense algebra."""
    if w is None:
        w = np.empty((3, 3, 3))
    for a in range(3):
        for b in range(3):
            sw = 0.0
            sv = 0.0
            for c in range(3):
                sw += r_hat[a, c] * q_om[c] * r_hat[b, c]
                sv += r_hat[a, c] * q_v[c] * r_hat[b, c]
            w[0, a, b] = sw
            w[1, a, b] = sv
    px, py, pz = p_hat[0], p_hat[1], p_hat[2]
    # [P̂]× X for a 3x3 X, row by row: row0 = py X[2] − pz X[1], row1 = pz X[0] − px X[2], row2 = px X[1] − py X[0]
    for b in range(3):
        acc[_SR, 0, b] += h * r_hat[0, b]
        acc[_SR, 1, b] += h * r_hat[1, b]
        acc[_SR, 2, b] += h * r_hat[2, b]
        acc[_SPR, 0, b] += h * (py * r_hat[2, b] - pz * r_hat[1, b])
        acc[_SPR, 1, b] += h * (pz * r_hat[0, b] - px * r_hat[2, b])
        acc[_SPR, 2, b] += h * (px * r_hat[1, b] - py * r_hat[0, b])
        w[2, 0, b] = py * w[0, 2, b] - pz * w[0, 1, b]
        w[2, 1, b] = pz * w[0, 0, b] - px * w[0, 2, b]
        w[2, 2, b] = px * w[0, 1, b] - py * w[0, 0, b]
    for a in range(3):
        for b in range(3):
            acc[_QRR, a, b] += h * w[0, a, b]
            acc[_QPR, a, b] += h * w[2, a, b]
    # [P̂]× M [P̂]×ᵀ = (w[2] = [P̂]×M) [P̂]×ᵀ: its [a, b] = Σ_c w[2, a, c] [P̂]×[b, c]
    for a in range(3):
        c0 = w[2, a, 2] * py - w[2, a, 1] * pz
        c1 = w[2, a, 0] * pz - w[2, a, 2] * px
        c2 = w[2, a, 1] * px - w[2, a, 0] * py
        acc[_QPP, a, 0] += h * (c0 + w[1, a, 0])
        acc[_QPP, a, 1] += h * (c1 + w[1, a, 1])
        acc[_QPP, a, 2] += h * (c2 + w[1, a, 2])


@njit(cache=True, fastmath=CONTRACT)
def propagation_terms(cov, d, lm, slot_lm, acc, acc_dt, q_bw, q_bv, lt, rt, dp):
    """The accumulated transition ``Φ = I + F`` and noise ``Q`` as the terms of one symmetric update, applied
    later together with the frame's Kalman downdate (:func:`apply`): ``Σ⁻ = Σ + FΣ_b + (FΣ_b)ᵀ + FΣ_bbFᵀ + Q``.
    Off the position rows every row ``i`` of ``F`` and of ``Q``'s factor is ``j_i``-linear: ``F_i = (j_iᵀ ΣR̂h, 0)``
    and ``Q = J W Jᵀ`` with ``J_i = (j_iᵀ, 0)``, where ``j_i`` is ``e_a`` on the attitude rows, row ``a`` of
    ``[p̂_s]×`` on a landmark's, zero on the biases'. There the change is ``ΔΣ_ij = j_i·z_j + z_i·j_j`` with
    ``z_j = ΣR̂h Σ_(b_Ω, j) + ½ M j_j``, ``M = ΣR̂h Σ_(b_Ω b_Ω) ΣR̂hᵀ + ΣM h``: rows 0..2 of ``lt`` hold ``jᵀ``, 3..5
    ``zᵀ``, ``rt`` the two swapped. The position rows' change (3 × d, every column) goes to ``dp``. The bias
    random walk over the interval is added to ``Σ`` now (at its start: the transition carries it), and the sums
    are cleared. False when no time has passed (nothing to apply). An entry of ``Σ⁻`` is then ``Σ_ij + dp[i − 3, j]``
    on a position row ``i`` (``dp[j − 3, i]`` on a position column), else ``Σ_ij + Σ_(k<6) lt[k, i] rt[k, j]``.
    Public: tests/test_riekf_exactness.py checks it against dense algebra."""
    lt[:6, :d] = 0.0
    rt[:6, :d] = 0.0
    dp[:, :d] = 0.0
    if acc_dt <= 0.0:
        return False
    for c in range(3):
        cov[6 + c, 6 + c] += q_bw * q_bw * acc_dt
        cov[9 + c, 9 + c] += q_bv * q_bv * acc_dt
    n = (d - N_FIXED) // 3
    sr, spr, qrr, qpr, qpp = acc[_SR], acc[_SPR], acc[_QRR], acc[_QPR], acc[_QPP]
    for a in range(3):
        lt[a, a] = 1.0
    for s in range(n):  # [p]× = [[0, −p2, p1], [p2, 0, −p0], [−p1, p0, 0]], row a in column r0 + a
        p = lm[slot_lm[s]]
        r0 = N_FIXED + 3 * s
        lt[1, r0], lt[2, r0] = -p[2], p[1]
        lt[0, r0 + 1], lt[2, r0 + 1] = p[2], -p[0]
        lt[0, r0 + 2], lt[1, r0 + 2] = -p[1], p[0]
    w = np.empty((6, 6))  # the bias block (after the walk)
    for e in range(6):
        for k in range(6):
            w[e, k] = cov[6 + e, 6 + k]
    mh = np.empty((3, 3))  # ½ (ΣR̂h Σ_ΩΩ ΣR̂hᵀ + ΣM h), symmetric
    for a in range(3):
        for b in range(3):
            v = 0.0
            for e in range(3):
                for k in range(3):
                    v += sr[a, e] * w[e, k] * sr[b, k]
            mh[a, b] = v + qrr[a, b]
    for a in range(3):
        for b in range(a, 3):
            v = 0.25 * (mh[a, b] + mh[b, a])
            mh[a, b], mh[b, a] = v, v
    for a in range(3):
        za = lt[3 + a, :d]
        s0, s1, s2, m0, m1, m2 = sr[a, 0], sr[a, 1], sr[a, 2], mh[a, 0], mh[a, 1], mh[a, 2]
        b0, b1, b2, j0, j1, j2 = cov[6, :d], cov[7, :d], cov[8, :d], lt[0, :d], lt[1, :d], lt[2, :d]
        for j in range(d):
            za[j] = s0 * b0[j] + s1 * b1[j] + s2 * b2[j] + m0 * j0[j] + m1 * j1[j] + m2 * j2[j]
        za[3], za[4], za[5] = 0.0, 0.0, 0.0  # the position rows: in dp
    for a in range(3):
        rt[a, :d] = lt[3 + a, :d]
        rt[3 + a, :d] = lt[a, :d]
    # the position rows: F_(3+a) = (ΣR̂h-weighted [P̂]×: acc[_SPR][a], acc[_SR][a]) and ΔΣ_(3+a, j) for every j:
    # Σ_e F_(3+a, e) Σ_(6+e, j) + (Σ_(b, 3+a) + F_(3+a) Σ_bb)·F_j + Q_(3+a, j)
    fp = np.empty((3, 6))
    for a in range(3):
        for c in range(3):
            fp[a, c], fp[a, 3 + c] = spr[a, c], sr[a, c]
    gp = np.empty((3, 6))  # Σ_(b, 3+a) + F_(3+a) Σ_bb
    for a in range(3):
        for e in range(6):
            v = cov[6 + e, 3 + a]
            for k in range(6):
                v += fp[a, k] * w[k, e]
            gp[a, e] = v
    for a in range(3):
        # off the position columns F_j = (j_jᵀ ΣR̂h, 0) and Q_(3+a, j) = (ΣQ_PR j_j)_a: one 3-vector on j_j
        u0 = qpr[a, 0] + gp[a, 0] * sr[0, 0] + gp[a, 1] * sr[0, 1] + gp[a, 2] * sr[0, 2]
        u1 = qpr[a, 1] + gp[a, 0] * sr[1, 0] + gp[a, 1] * sr[1, 1] + gp[a, 2] * sr[1, 2]
        u2 = qpr[a, 2] + gp[a, 0] * sr[2, 0] + gp[a, 1] * sr[2, 1] + gp[a, 2] * sr[2, 2]
        da = dp[a, :d]
        f0, f1, f2, f3, f4, f5 = fp[a, 0], fp[a, 1], fp[a, 2], fp[a, 3], fp[a, 4], fp[a, 5]
        b0, b1, b2, b3, b4, b5 = cov[6, :d], cov[7, :d], cov[8, :d], cov[9, :d], cov[10, :d], cov[11, :d]
        j0, j1, j2 = lt[0, :d], lt[1, :d], lt[2, :d]
        for j in range(d):
            x = f0 * b0[j] + f1 * b1[j] + f2 * b2[j] + f3 * b3[j] + f4 * b4[j] + f5 * b5[j]
            da[j] = x + u0 * j0[j] + u1 * j1[j] + u2 * j2[j]
        for b in range(3):
            v = qpp[a, b]
            for e in range(6):
                v += gp[a, e] * fp[b, e]
            da[3 + b] += v
    acc[:, :, :] = 0.0
    return True


@subroutine(types.none)
def _rows8x16(cov, i, j, lt, rt, k):
    """Rows ``i .. i + 7``, columns ``j .. j + 15`` of :func:`apply`'s sum: the tile held in registers (16 vectors)
    across all ``k`` terms, each added as one fused multiply-add (``fma8``), in the order of the terms."""
    c00, c01 = load8(cov, i, j), load8(cov, i, j + 8)
    c10, c11 = load8(cov, i + 1, j), load8(cov, i + 1, j + 8)
    c20, c21 = load8(cov, i + 2, j), load8(cov, i + 2, j + 8)
    c30, c31 = load8(cov, i + 3, j), load8(cov, i + 3, j + 8)
    c40, c41 = load8(cov, i + 4, j), load8(cov, i + 4, j + 8)
    c50, c51 = load8(cov, i + 5, j), load8(cov, i + 5, j + 8)
    c60, c61 = load8(cov, i + 6, j), load8(cov, i + 6, j + 8)
    c70, c71 = load8(cov, i + 7, j), load8(cov, i + 7, j + 8)
    for q in range(6):  # the propagation's terms, lt[q]ᵀ rt[q]
        x0, x1 = load8(rt, q, j), load8(rt, q, j + 8)
        a = splat8(lt[q, i])
        c00, c01 = fma8(a, x0, c00), fma8(a, x1, c01)
        a = splat8(lt[q, i + 1])
        c10, c11 = fma8(a, x0, c10), fma8(a, x1, c11)
        a = splat8(lt[q, i + 2])
        c20, c21 = fma8(a, x0, c20), fma8(a, x1, c21)
        a = splat8(lt[q, i + 3])
        c30, c31 = fma8(a, x0, c30), fma8(a, x1, c31)
        a = splat8(lt[q, i + 4])
        c40, c41 = fma8(a, x0, c40), fma8(a, x1, c41)
        a = splat8(lt[q, i + 5])
        c50, c51 = fma8(a, x0, c50), fma8(a, x1, c51)
        a = splat8(lt[q, i + 6])
        c60, c61 = fma8(a, x0, c60), fma8(a, x1, c61)
        a = splat8(lt[q, i + 7])
        c70, c71 = fma8(a, x0, c70), fma8(a, x1, c71)
    for q in range(6, k):  # the downdate's, −lt[q]ᵀ lt[q]
        x0, x1 = load8(lt, q, j), load8(lt, q, j + 8)
        a = splat8(-lt[q, i])
        c00, c01 = fma8(a, x0, c00), fma8(a, x1, c01)
        a = splat8(-lt[q, i + 1])
        c10, c11 = fma8(a, x0, c10), fma8(a, x1, c11)
        a = splat8(-lt[q, i + 2])
        c20, c21 = fma8(a, x0, c20), fma8(a, x1, c21)
        a = splat8(-lt[q, i + 3])
        c30, c31 = fma8(a, x0, c30), fma8(a, x1, c31)
        a = splat8(-lt[q, i + 4])
        c40, c41 = fma8(a, x0, c40), fma8(a, x1, c41)
        a = splat8(-lt[q, i + 5])
        c50, c51 = fma8(a, x0, c50), fma8(a, x1, c51)
        a = splat8(-lt[q, i + 6])
        c60, c61 = fma8(a, x0, c60), fma8(a, x1, c61)
        a = splat8(-lt[q, i + 7])
        c70, c71 = fma8(a, x0, c70), fma8(a, x1, c71)
    store8(cov, i, j, c00)
    store8(cov, i, j + 8, c01)
    store8(cov, i + 1, j, c10)
    store8(cov, i + 1, j + 8, c11)
    store8(cov, i + 2, j, c20)
    store8(cov, i + 2, j + 8, c21)
    store8(cov, i + 3, j, c30)
    store8(cov, i + 3, j + 8, c31)
    store8(cov, i + 4, j, c40)
    store8(cov, i + 4, j + 8, c41)
    store8(cov, i + 5, j, c50)
    store8(cov, i + 5, j + 8, c51)
    store8(cov, i + 6, j, c60)
    store8(cov, i + 6, j + 8, c61)
    store8(cov, i + 7, j, c70)
    store8(cov, i + 7, j + 8, c71)


@subroutine(types.none)
def _rows8x8(cov, i, j, lt, rt, k):
    """:func:`_rows8x16` on columns ``j .. j + 7`` (a row's last eight when its length is an odd number of eights)."""
    c0, c1, c2, c3 = load8(cov, i, j), load8(cov, i + 1, j), load8(cov, i + 2, j), load8(cov, i + 3, j)
    c4, c5, c6, c7 = load8(cov, i + 4, j), load8(cov, i + 5, j), load8(cov, i + 6, j), load8(cov, i + 7, j)
    for q in range(6):
        x = load8(rt, q, j)
        c0, c1 = fma8(splat8(lt[q, i]), x, c0), fma8(splat8(lt[q, i + 1]), x, c1)
        c2, c3 = fma8(splat8(lt[q, i + 2]), x, c2), fma8(splat8(lt[q, i + 3]), x, c3)
        c4, c5 = fma8(splat8(lt[q, i + 4]), x, c4), fma8(splat8(lt[q, i + 5]), x, c5)
        c6, c7 = fma8(splat8(lt[q, i + 6]), x, c6), fma8(splat8(lt[q, i + 7]), x, c7)
    for q in range(6, k):
        x = load8(lt, q, j)
        c0, c1 = fma8(splat8(-lt[q, i]), x, c0), fma8(splat8(-lt[q, i + 1]), x, c1)
        c2, c3 = fma8(splat8(-lt[q, i + 2]), x, c2), fma8(splat8(-lt[q, i + 3]), x, c3)
        c4, c5 = fma8(splat8(-lt[q, i + 4]), x, c4), fma8(splat8(-lt[q, i + 5]), x, c5)
        c6, c7 = fma8(splat8(-lt[q, i + 6]), x, c6), fma8(splat8(-lt[q, i + 7]), x, c7)
    store8(cov, i, j, c0)
    store8(cov, i + 1, j, c1)
    store8(cov, i + 2, j, c2)
    store8(cov, i + 3, j, c3)
    store8(cov, i + 4, j, c4)
    store8(cov, i + 5, j, c5)
    store8(cov, i + 6, j, c6)
    store8(cov, i + 7, j, c7)


@njit(cache=True, fastmath=CONTRACT)
def apply(cov, d, lt, rt, k, dp, rows, n_rows):
    """``Σ ← Σ + Σ_(q<6) lt[q]ᵀ rt[q] − Σ_(6≤q<k) lt[q]ᵀ lt[q]`` (the propagation's six terms and the downdate's
    ``−UUᵀ``, ``Uᵀ`` in rows 6.. of ``lt``: each entry loaded and stored once), plus the position rows' ``dp``;
    the upper triangle in tiles of eight rows by sixteen columns held in registers across all ``k`` terms
    (:func:`_rows8x16`), then mirrored: ``Σ`` stays exactly symmetric (``n_rows < 0``), or only what the next
    frame reads of the lower triangle is (:func:`_mirror_read`, the landmark rows starting at ``rows[:n_rows]``).
    Each entry's terms are added one at a time in their order, each product fused into its addition (one
    rounding), in the tiles as in the rows left over: the same bits whatever the padding, compiled or loaded
    from the cache.
    The tiles run from the diagonal's multiple of ``PAD`` to the end of the arrays (``_State`` pads them to a
    multiple of ``PAD`` rows and columns, zeros past ``d`` in ``lt``, ``rt``: they add zeros); arrays that are not
    padded (tests) are summed row by row.
    Public: tests/test_riekf_exactness.py checks it; benchmarks/riekf_stage.py times it."""
    end = min(cov.shape[1], lt.shape[1], rt.shape[1])
    end -= end % PAD
    tiles = min(d + (-d) % PAD, cov.shape[0] - cov.shape[0] % PAD) if end >= d else 0
    i = 0
    while i < tiles:
        j = i
        while j + 2 * PAD <= end:
            _rows8x16(cov, i, j, lt, rt, k)
            j += 2 * PAD
        if j < end:
            _rows8x8(cov, i, j, lt, rt, k)
        i += PAD
    for r in range(i, d):  # rows left when the arrays are not padded (tests)
        cr = cov[r, r:d]
        for q in range(k):
            a, rq = (lt[q, r], rt[q, r:d]) if q < 6 else (-lt[q, r], lt[q, r:d])
            for j in range(d - r):
                cr[j] += a * rq[j]
    for a in range(3):
        for j in range(3 + a, d):
            cov[3 + a, j] += dp[a, j]
        for b in range(3):
            cov[b, 3 + a] += dp[a, b]
    if n_rows < 0:
        _mirror(cov, d)
    else:
        _mirror_read(cov, rows, n_rows)


@njit(cache=True)
def _mirror(cov, d):
    """The upper triangle of the first ``d`` dimensions copied into the lower, four rows at a time (four
    neighbouring stores per column instead of one store per row)."""
    i = 0
    while i + 4 <= d:
        for r in range(i, i + 3):
            for j in range(r + 1, i + 4):
                cov[j, r] = cov[r, j]
        c0, c1, c2, c3 = cov[i], cov[i + 1], cov[i + 2], cov[i + 3]
        for j in range(i + 4, d):
            cj = cov[j]
            cj[i], cj[i + 1], cj[i + 2], cj[i + 3] = c0[j], c1[j], c2[j], c3[j]
        i += 4
    for r in range(i, d):
        for j in range(r + 1, d):
            cov[j, r] = cov[r, j]


@njit(cache=True)
def _mirror_read(cov, rows, n_rows):
    """The lower-triangle entries a frame reads (the filter's other kernels read the upper triangle or these): the
    fixed block's (``N_FIXED`` rows: bias and position rows, the pose covariance) and the rows of the landmarks
    the frame detects (slots starting at ``rows[:n_rows]``: the gates and ``HΣ⁻`` read them whole). The rest of
    the lower triangle is left as it was until :func:`_advance` returns (a full :func:`_mirror`)."""
    for r in range(N_FIXED - 1):
        for j in range(r + 1, N_FIXED):
            cov[j, r] = cov[r, j]
    for q in range(n_rows):
        o = rows[q]
        l0, l1, l2 = cov[o], cov[o + 1], cov[o + 2]
        for j in range(o):
            cj = cov[j]
            l0[j], l1[j], l2[j] = cj[o], cj[o + 1], cj[o + 2]
        l1[o], l2[o], l2[o + 1] = l0[o + 1], l0[o + 2], l1[o + 2]


@njit(cache=True)
def flush(cov, d, lm, slot_lm, acc, acc_dt, q_bw, q_bv, lt, rt, dp):
    """Apply the accumulated transition and noise to the covariance now (first ``d`` dimensions; ``lt``, ``rt``
    (at least 6 × D) and ``dp`` (3 × D) are scratch): :func:`propagation_terms` then :func:`apply`.
    Public: tests/test_riekf.py checks the kernel against dense algebra."""
    if propagation_terms(cov, d, lm, slot_lm, acc, acc_dt, q_bw, q_bv, lt, rt, dp):
        _settle(cov, d, lt, rt, dp)


@njit(cache=True, fastmath=CONTRACT)
def _pose_covariance(cov, acc, acc_dt, q_bw, q_bv, p_hat, out, o, w):
    """``out[o]`` (6×6): the pose covariance as :func:`flush` would make it now (the pending sums applied to a
    copy, the state untouched, so a run's estimate does not depend on how often it is asked), turned from the
    filter's ``(ξ_R, ξ_P)`` into the written convention ``(δθ, δp)``: ``R̂ = Exp(δθ)R``, ``p̂ = p + δp`` (map
    frame), i.e. ``δθ = ξ_R``, ``δp = ξ_P − [P̂]×ξ_R`` to first order. ``w``: (3, 6, 6) scratch.
    Output only (nothing the filter reads again), so its sums are free to be regrouped: ``FΣ_b + (FΣ_b)ᵀ +
    FΣ_bbFᵀ = K + Kᵀ`` with ``K = F(Σ_b + ½Σ_bbFᵀ)``, two 6×6 products (F's zero block skipped) instead of three,
    the upper triangle summed and mirrored, each ``a * b + c`` fused (``CONTRACT``): the same covariance to a few
    units in the last place of its largest entries (docs/benchmarks.md, session 23)."""
    # F = [[ΣR̂h, 0], [Σ[P̂]×R̂h, ΣR̂h]] (rows ξ_R, ξ_P; columns b̃_Ω, b̃_V)
    sr, spr = acc[_SR], acc[_SPR]
    cb, hh, s = w[0], w[1], w[2]  # ½ the pending bias block; H = Σ_(b, pose) + ½ Σ_bb Fᵀ; S
    for e in range(6):
        for c in range(6):
            cb[e, c] = 0.5 * cov[6 + e, 6 + c]
    for c in range(3):
        cb[c, c] += 0.5 * (q_bw * q_bw * acc_dt)
        cb[3 + c, 3 + c] += 0.5 * (q_bv * q_bv * acc_dt)
    for e in range(6):
        c0, c1, c2, c3, c4, c5 = cb[e, 0], cb[e, 1], cb[e, 2], cb[e, 3], cb[e, 4], cb[e, 5]
        for a in range(3):
            hh[e, a] = cov[6 + e, a] + (c0 * sr[a, 0] + c1 * sr[a, 1] + c2 * sr[a, 2])
            v = c0 * spr[a, 0] + c1 * spr[a, 1] + c2 * spr[a, 2] + c3 * sr[a, 0] + c4 * sr[a, 1] + c5 * sr[a, 2]
            hh[e, 3 + a] = cov[6 + e, 3 + a] + v
    for k in range(6):  # s = K = F H
        h0, h1, h2, h3, h4, h5 = hh[0, k], hh[1, k], hh[2, k], hh[3, k], hh[4, k], hh[5, k]
        for a in range(3):
            s[a, k] = sr[a, 0] * h0 + sr[a, 1] * h1 + sr[a, 2] * h2
            v = spr[a, 0] * h0 + spr[a, 1] * h1 + spr[a, 2] * h2
            s[3 + a, k] = v + sr[a, 0] * h3 + sr[a, 1] * h4 + sr[a, 2] * h5
    for i in range(6):  # Σ_pose + K + Kᵀ, upper triangle, mirrored
        for k in range(i, 6):
            v = cov[i, k] + (s[i, k] + s[k, i])
            out[o, i, k] = v
            out[o, k, i] = v
    for a in range(3):
        for b in range(3):
            out[o, a, b] += acc[_QRR, a, b]
            out[o, 3 + a, 3 + b] += acc[_QPP, a, b]
            out[o, 3 + a, b] += acc[_QPR, a, b]
            out[o, b, 3 + a] += acc[_QPR, a, b]
    # J s Jᵀ with J = [[I, 0], [−[P̂]×, I]]: δp = ξ_P − [P̂]× ξ_R
    px, py, pz = p_hat[0], p_hat[1], p_hat[2]
    for k in range(6):  # rows 3..5 of J s: s_P· − [P̂]× s_R·
        r0, r1, r2 = out[o, 0, k], out[o, 1, k], out[o, 2, k]
        out[o, 3, k] -= py * r2 - pz * r1
        out[o, 4, k] -= pz * r0 - px * r2
        out[o, 5, k] -= px * r1 - py * r0
    for i in range(6):  # columns 3..5 of (J s) Jᵀ
        c0, c1, c2 = out[o, i, 0], out[o, i, 1], out[o, i, 2]
        out[o, i, 3] -= py * c2 - pz * c1
        out[o, i, 4] -= pz * c0 - px * c2
        out[o, i, 5] -= px * c1 - py * c0


@subroutine(types.float64, fastmath=CONTRACT)
def _pending_sum(v, lt, rt, i, j):
    """``v`` plus the pending propagation's change to entry ``(i, j)`` off the position rows and columns,
    ``Σ_(k<6) lt[k, i] rt[k, j]`` (:func:`propagation_terms`), each term added in turn as one fused multiply-add:
    with ``v = Σ_ij`` the entry of ``Σ⁻``. The one scalar sum of the gate, the linearisation's ``Σ⁻_RR`` and
    :func:`_hp_rows`' unpadded columns (its padded ones are the same terms in the same order, eight at a time)."""
    for k in range(6):
        v += lt[k, i] * rt[k, j]
    return v


@subroutine(types.float64, fastmath=CONTRACT)
def _gate(cov, z, sl, sigma2, ues, j, lt, rt, dp, s):
    """Mahalanobis distance² of one innovation against ``Σ_PP − Σ_Ps − Σ_sP + Σ_ss + σ²I + u uᵀ`` of ``Σ⁻`` (the
    pending propagation added, each term read once; ``u = ues[j]``: the range's extra standard deviation along the
    line of sight, indexed in the whole array: a row view per detection took and dropped a reference; ``s``: 3×3
    scratch). It, :func:`_mahalanobis3`, ``cholesky_lower`` and :func:`_blind_start` are subroutines (compiled into
    the event loop without numba's runtime): as kernels of their own each call took and dropped a reference to each
    array it was given, ~20 a detection (docs/benchmarks.md, "riekf's filter stage without reference counts")."""
    for a in range(3):
        for b in range(3):
            v = cov[3 + a, 3 + b] + dp[a, 3 + b]  # Σ⁻_PP
            v -= cov[3 + a, sl + b] + dp[a, sl + b]  # Σ⁻_Ps
            v -= cov[sl + a, 3 + b] + dp[b, sl + a]  # Σ⁻_sP
            v = _pending_sum(v + cov[sl + a, sl + b], lt, rt, sl + a, sl + b)  # Σ⁻_ss
            s[a, b] = v + ues[j, a] * ues[j, b]
        s[a, a] += sigma2
    return _mahalanobis3(s, z)


@subroutine(types.none, fastmath=CONTRACT)
def _linearisation(z, srr, sigma2, gate, lin):
    """``lin = [z]× Σ⁻_RR [z]×ᵀ`` when ``|z|² tr Σ⁻_RR`` exceeds ``gate`` times the detection's variance
    ``sigma2`` (as a detection error it alone would fail the gate), else left zero: the covariance of the term the
    invariant model's ``H = [0, I, −I]`` drops, the correction's turn of the innovation itself (``−[z]× ξ_R``),
    second order for a small innovation and metres after a blind stretch (docs/benchmarks.md, "riekf's
    re-acquisition after a blind stretch"). Added to the detection's noise in the update (not in the gate) of a
    frame whose only update is this detection: one detection of one point then moves the pose less along what it
    cannot see; with two or more in the frame the update is the plain one (on all, the real logs' MR.CLAM runs lost
    up to 0.09 m). Not while :func:`_blind_check` judges a return after ``BLIND_S`` or more without a known landmark
    (its first ``BLIND_WINDOW`` detections): its verdict (the pose beyond its covariance when nearly all fail the
    gate) is on the plain updates (damped, the floor's gap log let later ones through a pose 45° off: the check
    did not act, a recovery took the track later)."""
    if (z[0] * z[0] + z[1] * z[1] + z[2] * z[2]) * (srr[0, 0] + srr[1, 1] + srr[2, 2]) <= gate * sigma2:
        return
    k = ((0.0, -z[2], z[1]), (z[2], 0.0, -z[0]), (-z[1], z[0], 0.0))
    for a in range(3):
        for b in range(3):
            v = 0.0
            for c in range(3):
                for e in range(3):
                    v += k[a][c] * srr[c, e] * k[b][e]
            lin[a, b] = v


@subroutine(types.float64, fastmath=CONTRACT)
def _mahalanobis3(s, z):
    """``zᵀ S⁻¹ z`` for the 3×3 ``s`` (overwritten by its Cholesky factor L: ``|L⁻¹ z|²``); inf when S is not
    positive definite."""
    if not cholesky_lower(s, np.int64(3)):
        return np.inf
    w0 = z[0] / s[0, 0]
    w1 = (z[1] - s[1, 0] * w0) / s[1, 1]
    w2 = (z[2] - s[2, 0] * w0 - s[2, 1] * w1) / s[2, 2]
    return w0 * w0 + w1 * w1 + w2 * w2


@njit(cache=True, fastmath=CONTRACT)
def _correct(xi, d, r_hat, p_hat, b_om, b_v, lm, slot_lm):
    """``X̂ ← exp(−ξ̂) X̂`` on SE_{1+n}(3) (the exponential of docs/observers.md §1, applied on the left) and
    ``b̂ ← b̂ + b̃̂``."""
    a = np.empty((3, 3))
    unused = np.empty(3)
    w0, w1, w2 = -xi[0], -xi[1], -xi[2]
    se3_exp_into(w0, w1, w2, 0.0, 0.0, 0.0, a, unused)
    for c in range(3):  # R̂ ← A R̂, column by column from the column's old values
        x0, x1, x2 = r_hat[0, c], r_hat[1, c], r_hat[2, c]
        for r in range(3):
            r_hat[r, c] = a[r, 0] * x0 + a[r, 1] * x1 + a[r, 2] * x2
    t0, t1, t2 = so3_left_jacobian_apply(w0, w1, w2, -xi[3], -xi[4], -xi[5])
    q0 = a[0, 0] * p_hat[0] + a[0, 1] * p_hat[1] + a[0, 2] * p_hat[2] + t0
    q1 = a[1, 0] * p_hat[0] + a[1, 1] * p_hat[1] + a[1, 2] * p_hat[2] + t1
    q2 = a[2, 0] * p_hat[0] + a[2, 1] * p_hat[1] + a[2, 2] * p_hat[2] + t2
    p_hat[0], p_hat[1], p_hat[2] = q0, q1, q2
    for c in range(3):
        b_om[c] += xi[6 + c]
        b_v[c] += xi[9 + c]
    for s in range((d - N_FIXED) // 3):
        i = slot_lm[s]
        o = N_FIXED + 3 * s
        t0, t1, t2 = so3_left_jacobian_apply(w0, w1, w2, -xi[o], -xi[o + 1], -xi[o + 2])
        q0 = a[0, 0] * lm[i, 0] + a[0, 1] * lm[i, 1] + a[0, 2] * lm[i, 2] + t0
        q1 = a[1, 0] * lm[i, 0] + a[1, 1] * lm[i, 1] + a[1, 2] * lm[i, 2] + t1
        q2 = a[2, 0] * lm[i, 0] + a[2, 1] * lm[i, 1] + a[2, 2] * lm[i, 2] + t2
        lm[i, 0], lm[i, 1], lm[i, 2] = q0, q1, q2


@subroutine(types.none)
def _solve4(hp, chol, c, end):
    """Rows ``c .. c + 3`` of ``L⁻¹ HΣ⁻`` in place (:func:`_gain`), the rows above them done: sixteen columns at a
    time (two vectors of :mod:`pipeline.simd` a row: each of ``L``'s entries broadcast once for both), eight for the
    last when the row is an odd number of vectors long; each row above subtracted as one fused multiply-add in
    order, then the four rows among themselves."""
    i0, i1 = splat8(1.0 / chol[c, c]), splat8(1.0 / chol[c + 1, c + 1])
    i2, i3 = splat8(1.0 / chol[c + 2, c + 2]), splat8(1.0 / chol[c + 3, c + 3])
    l10, l20, l21 = splat8(-chol[c + 1, c]), splat8(-chol[c + 2, c]), splat8(-chol[c + 2, c + 1])
    l30, l31, l32 = splat8(-chol[c + 3, c]), splat8(-chol[c + 3, c + 1]), splat8(-chol[c + 3, c + 2])
    j = 0
    while j + 2 * PAD <= end:
        x0, x1, x2, x3 = load8(hp, c, j), load8(hp, c + 1, j), load8(hp, c + 2, j), load8(hp, c + 3, j)
        y0, y1 = load8(hp, c, j + PAD), load8(hp, c + 1, j + PAD)
        y2, y3 = load8(hp, c + 2, j + PAD), load8(hp, c + 3, j + PAD)
        for k in range(c):
            h, g = load8(hp, k, j), load8(hp, k, j + PAD)
            a0, a1, a2, a3 = (
                splat8(-chol[c, k]),
                splat8(-chol[c + 1, k]),
                splat8(-chol[c + 2, k]),
                splat8(-chol[c + 3, k]),
            )
            x0, x1, x2, x3 = fma8(a0, h, x0), fma8(a1, h, x1), fma8(a2, h, x2), fma8(a3, h, x3)
            y0, y1, y2, y3 = fma8(a0, g, y0), fma8(a1, g, y1), fma8(a2, g, y2), fma8(a3, g, y3)
        for q, v0, v1, v2, v3 in ((j, x0, x1, x2, x3), (j + PAD, y0, y1, y2, y3)):
            u = mul8(v0, i0)
            v = mul8(fma8(l10, u, v1), i1)
            w = mul8(fma8(l21, v, fma8(l20, u, v2)), i2)
            store8(hp, c, q, u)
            store8(hp, c + 1, q, v)
            store8(hp, c + 2, q, w)
            store8(hp, c + 3, q, mul8(fma8(l32, w, fma8(l31, v, fma8(l30, u, v3))), i3))
        j += 2 * PAD
    if j < end:
        x0, x1, x2, x3 = load8(hp, c, j), load8(hp, c + 1, j), load8(hp, c + 2, j), load8(hp, c + 3, j)
        for k in range(c):
            h = load8(hp, k, j)
            x0, x1 = fma8(splat8(-chol[c, k]), h, x0), fma8(splat8(-chol[c + 1, k]), h, x1)
            x2, x3 = fma8(splat8(-chol[c + 2, k]), h, x2), fma8(splat8(-chol[c + 3, k]), h, x3)
        u = mul8(x0, i0)
        v = mul8(fma8(l10, u, x1), i1)
        w = mul8(fma8(l21, v, fma8(l20, u, x2)), i2)
        store8(hp, c, j, u)
        store8(hp, c + 1, j, v)
        store8(hp, c + 2, j, w)
        store8(hp, c + 3, j, mul8(fma8(l32, w, fma8(l31, v, fma8(l30, u, x3))), i3))


@njit(cache=True, fastmath=CONTRACT)
def _gain(hp, chol, z, k3, d):
    """With ``chol`` = L (S = L Lᵀ) and ``hp`` = H Σ⁻ (k3 × d): ``Uᵀ = L⁻¹ H Σ⁻`` (in place: the downdate is
    ``Σ⁻ − U Uᵀ``, :func:`apply`) and ``w = L⁻¹ z`` (in place of ``z``); returns ``ξ̂ = U w``. Every loop runs
    along rows of ``hp`` (it vectorises), four rows written at a time with four terms a pass."""
    c = 0
    end = hp.shape[1] - hp.shape[1] % PAD
    while c + 4 <= k3 and end >= d:  # padded rows: four at a time, eight columns a vector (_solve4)
        _solve4(hp, chol, c, end)
        c += 4
    while c + 4 <= k3:  # four rows at a time: the rows above them first, four terms a pass, then among themselves
        x0, x1, x2, x3 = hp[c, :d], hp[c + 1, :d], hp[c + 2, :d], hp[c + 3, :d]
        for k in range(0, c, 4):  # c is a multiple of 4
            h0, h1, h2, h3 = hp[k, :d], hp[k + 1, :d], hp[k + 2, :d], hp[k + 3, :d]
            a0, a1, a2, a3 = chol[c, k], chol[c, k + 1], chol[c, k + 2], chol[c, k + 3]
            b0, b1, b2, b3 = chol[c + 1, k], chol[c + 1, k + 1], chol[c + 1, k + 2], chol[c + 1, k + 3]
            e0, e1, e2, e3 = chol[c + 2, k], chol[c + 2, k + 1], chol[c + 2, k + 2], chol[c + 2, k + 3]
            f0, f1, f2, f3 = chol[c + 3, k], chol[c + 3, k + 1], chol[c + 3, k + 2], chol[c + 3, k + 3]
            for r in range(d):
                u, v, w, y = h0[r], h1[r], h2[r], h3[r]
                x0[r] -= a0 * u + a1 * v + a2 * w + a3 * y
                x1[r] -= b0 * u + b1 * v + b2 * w + b3 * y
                x2[r] -= e0 * u + e1 * v + e2 * w + e3 * y
                x3[r] -= f0 * u + f1 * v + f2 * w + f3 * y
        i0 = 1.0 / chol[c, c]
        i1 = 1.0 / chol[c + 1, c + 1]
        i2 = 1.0 / chol[c + 2, c + 2]
        i3 = 1.0 / chol[c + 3, c + 3]
        l10, l20, l21 = chol[c + 1, c], chol[c + 2, c], chol[c + 2, c + 1]
        l30, l31, l32 = chol[c + 3, c], chol[c + 3, c + 1], chol[c + 3, c + 2]
        for r in range(d):
            u = x0[r] * i0
            v = (x1[r] - l10 * u) * i1
            w = (x2[r] - l20 * u - l21 * v) * i2
            x0[r], x1[r], x2[r] = u, v, w
            x3[r] = (x3[r] - l30 * u - l31 * v - l32 * w) * i3
        c += 4
    while c < k3 and end >= d:  # padded rows left (fewer than four): one at a time, eight columns a vector
        inv = splat8(1.0 / chol[c, c])
        for j in range(0, end, PAD):
            x = load8(hp, c, j)
            for k in range(c):
                x = fma8(splat8(-chol[c, k]), load8(hp, k, j), x)
            store8(hp, c, j, mul8(x, inv))
        c += 1
    for c in range(c, k3):  # the rows left, one at a time
        x = hp[c, :d]
        for k in range(c):
            s_ck, hk = chol[c, k], hp[k, :d]
            for r in range(d):
                x[r] -= hk[r] * s_ck
        inv = 1.0 / chol[c, c]
        for r in range(d):
            x[r] *= inv
    for c in range(k3):  # w = L⁻¹ z in place of z (z[c] read before it is written)
        v = z[c]
        for k in range(c):
            v -= chol[c, k] * z[k]
        z[c] = v / chol[c, c]
    xi = np.zeros(d)
    for c in range(k3):
        wc, hc = z[c], hp[c, :d]
        for r in range(d):
            xi[r] += hc[r] * wc
    return xi


@njit(cache=True)
def whitened_update(cov, d, hs, chol, z, k, gate, lo, hi, r_hat, p_hat, b_om, b_v, lm, slot_lm):
    """One Kalman update of the whole (mirrored) state from ``k`` rows without a pending propagation (the floor's,
    :func:`_planar_update`, and a still window's, :func:`_still_update`): with ``hs`` = H Σ (k × d, overwritten by
    W = L⁻¹ H Σ) and ``chol`` = L (S = L Lᵀ), :func:`_gain` gives W, y = L⁻¹ z (in place of ``z``) and ξ̂ = Wᵀ y;
    skipped (False) when the innovation's d² = |y|² exceeds ``gate``; else Σ ← Σ − WᵀW and :func:`_correct`.
    Rows ``lo .. hi − 1`` and their correlations only (a Schmidt update: the other rows' ξ̂ zero, their block of Σ
    unchanged); ``0 .. d − 1`` is the plain update. A detection frame's downdate is in :func:`apply`, the pending
    propagation's pass (:func:`update`). Public: tests/test_riekf_exactness.py checks it against dense algebra."""
    xi = _gain(hs, chol, z, k, d)
    d2 = 0.0
    for r in range(k):
        d2 += z[r] * z[r]
    if d2 > gate:
        return False
    for j in range(d):
        if not lo <= j < hi:
            xi[j] = 0.0
    for i in range(d):  # Σ ← Σ − WᵀW
        for j in range(d):
            if not (lo <= i < hi or lo <= j < hi):
                continue
            v = 0.0
            for r in range(k):
                v += hs[r, i] * hs[r, j]
            cov[i, j] -= v
    _correct(xi, d, r_hat, p_hat, b_om, b_v, lm, slot_lm)
    return True


@njit(cache=True)
def _planar_update(cov, d, r_hat, p_hat, b_om, b_v, lm, slot_lm, plane):
    """The floor's pseudo-measurements (module docstring, "Planar motion"): the body's up axis ``R e3`` has no part
    along the floor's tangents ``t1``, ``t2`` and the position's height ``nᵀP`` is the start's. ``plane``: on, ``n``
    (3), the height, ``t1`` (3), ``t2`` (3), the tilt's and the height's σ, the period, the median range. With
    ``R ≈ exp(−ξ_R)R̂``, ``P ≈ P̂ − ξ_P + [P̂]×ξ_R``: ``z_k = t_kᵀR̂e3`` with ``H_k = −t_kᵀ[R̂e3]×`` on ``ξ_R``,
    ``z_3 = nᵀP̂ − h`` with ``H_3 = (−nᵀ[P̂]×, nᵀ)``; one Kalman update of the whole (mirrored) state
    (:func:`whitened_update`)."""
    _mirror(cov, d)
    h = np.zeros((3, 6))
    z = np.empty(3)
    u = np.empty(3)
    for c in range(3):
        u[c] = r_hat[c, 2]
    n = plane[1:4]
    for k in range(2):  # −tᵀ[u]×ξ = (u × t)·ξ, less its heading about n (the smoother's floor rows' too)
        t = plane[5 + 3 * k : 8 + 3 * k]
        z[k] = t[0] * u[0] + t[1] * u[1] + t[2] * u[2]
        h[k, 0], h[k, 1], h[k, 2] = floor_tilt_row(u, t, n)
    z[2] = n[0] * p_hat[0] + n[1] * p_hat[1] + n[2] * p_hat[2] - plane[4]
    h[2, 0] = p_hat[1] * n[2] - p_hat[2] * n[1]  # −nᵀ[P̂]×ξ = (P̂ × n)·ξ: the invariant error's, not graph's
    h[2, 1] = p_hat[2] * n[0] - p_hat[0] * n[2]
    h[2, 2] = p_hat[0] * n[1] - p_hat[1] * n[0]
    for c in range(3):
        h[2, 3 + c] = n[c]
    b = np.zeros((3, d))  # H Σ
    for r in range(3):
        for c in range(6):
            if h[r, c] != 0.0:
                for j in range(d):
                    b[r, j] += h[r, c] * cov[c, j]
    s = np.empty((3, 3))
    for r in range(3):
        for q in range(3):
            v = 0.0
            for c in range(6):
                v += b[r, c] * h[q, c]
            s[r, q] = v
    s[0, 0] += plane[11] ** 2  # the body's tilt on the floor: its wobble, new at each
    s[1, 1] += plane[11] ** 2
    f = plane[12] ** 2  # the floor's height error is the same each time: its variance brought down to f, no further
    s[2, 2] += s[2, 2] * f / (s[2, 2] - f) if s[2, 2] > 1.001 * f else 1e6 * (s[2, 2] + f)
    if not cholesky_lower(s, np.int64(3)):
        return
    whitened_update(cov, d, b, s, z, np.int64(3), np.inf, np.int64(0), d, r_hat, p_hat, b_om, b_v, lm, slot_lm)


@njit(cache=True)
def _still_update(cov, d, r_hat, p_hat, b_om, b_v, lm, slot_lm, fs, q_om, q_v, gate):
    """A still stretch's pseudo-measurement (module docstring, "At rest"): over the ``fs[_STILL_N]`` samples summed
    since ``fs[_STILL_T0]`` the body neither turned nor moved, so the gyro's mean reads its bias and the velocity's
    its bias, each with its density's variance over the span (``q_om``, ``q_v``); ``H`` the identity on the bias
    rows; skipped when the innovation's d² exceeds ``gate``. One Kalman update of the whole (mirrored) state
    (:func:`whitened_update`); while a rotation row's variance exceeds ``HEADING_UNKNOWN_VAR`` (the heading
    unknown) the biases' rows and their correlations only (a Schmidt update: the pose and the map neither move nor
    narrow, since the correlations that would move them were propagated about a heading that may be turns off)."""
    n = fs[_STILL_N]
    span = (fs[_T] - fs[_STILL_T0]) * n / max(n - 1.0, 1.0)
    if n < 2.0 or span <= 0.0:
        return
    _mirror(cov, d)
    z = np.empty(6)
    s = np.empty((6, 6))
    for r in range(3):
        z[r] = fs[_STILL_SUM + r] / n - b_om[r]
        z[3 + r] = fs[_STILL_SUM + 3 + r] / n - b_v[r]
    for r in range(6):
        for q in range(6):
            s[r, q] = cov[6 + r, 6 + q]
    for r in range(3):
        s[r, r] += q_om[r] / span
        s[3 + r, 3 + r] += q_v[r] / span
    if not cholesky_lower(s, np.int64(6)):
        return
    hs = np.empty((6, d))  # H Σ: the bias rows
    for r in range(6):
        for j in range(d):
            hs[r, j] = cov[6 + r, j]
    lo, hi = np.int64(0), d
    if max(cov[0, 0], cov[1, 1], cov[2, 2]) > HEADING_UNKNOWN_VAR:  # the heading unknown: the bias rows only
        lo, hi = np.int64(6), np.int64(N_FIXED)
    whitened_update(cov, d, hs, s, z, np.int64(6), gate, lo, hi, r_hat, p_hat, b_om, b_v, lm, slot_lm)


@njit(cache=True)
def _settle(cov, d, lt, rt, dp):
    """Apply the pending propagation (:func:`propagation_terms`) to the covariance now, and clear it."""
    # int64s, not literals: numba compiles a callee once per literal argument (literal 6 and -1 here compiled apply and
    # _mirror_read a second time beside update's int64 call, as a literal 3 did cholesky_lower, a literal row 0
    # _pose_covariance: ~2 s of a first run's compile, docs/benchmarks.md, session 19)
    apply(cov, d, lt, rt, np.int64(6), dp, np.zeros(0, np.int64), np.int64(-1))
    lt[:6, :d] = 0.0
    rt[:6, :d] = 0.0
    dp[:, :d] = 0.0


@njit(cache=True, fastmath=CONTRACT)
def _hp_rows(hp, h, cov, dp, lt, rt, s, d):
    """Rows ``h .. h + 2`` of ``HΣ⁻``: ``Σ⁻[3 + c, :] − Σ⁻[s + c, :]`` (position axis ``c``, the landmark's rows from
    ``s``) with the pending propagation (``dp``, the six terms) added: eight columns of the three rows at a time
    (:mod:`pipeline.simd`; the six rows of ``rt`` loaded once for the three) over padded rows, else one at a time, the
    same operations in the same order either way."""
    end = min(hp.shape[1], cov.shape[1], dp.shape[1], rt.shape[1])
    end = end - end % PAD if end - end % PAD >= d else 0
    for j in range(0, end, PAD):
        r0, r1, r2 = load8(rt, 0, j), load8(rt, 1, j), load8(rt, 2, j)
        r3, r4, r5 = load8(rt, 3, j), load8(rt, 4, j), load8(rt, 5, j)
        for c in range(3):
            sc = s + c
            v = fma8(splat8(lt[0, sc]), r0, load8(cov, sc, j))
            v = fma8(splat8(lt[3, sc]), r3, fma8(splat8(lt[2, sc]), r2, fma8(splat8(lt[1, sc]), r1, v)))
            v = fma8(splat8(lt[5, sc]), r5, fma8(splat8(lt[4, sc]), r4, v))
            store8(hp, h + c, j, sub8(add8(load8(cov, 3 + c, j), load8(dp, c, j)), v))
    for c in range(3):
        for r in range(end, d):
            hp[h + c, r] = (cov[3 + c, r] + dp[c, r]) - _pending_sum(cov[s + c, r], lt, rt, s + c, r)


@njit(cache=True, fastmath=CONTRACT)
def update(
    a0,
    nd,
    det_idx,
    det_y,
    det_law,
    cov,
    d,
    r_hat,
    p_hat,
    b_om,
    b_v,
    lm,
    slot_of,
    slot_lm,
    sel,
    z,
    lt,
    rt,
    dp,
    smat,
    innov,
    trk_p,
    row,
    ns,
    gate,
    scale,
    win_d2,
    win_z,
    win_f,
    gated_lm,
    reinit,
    win_sum,
    blind_z2,
    corr_w,
    corr_n,
    corr_sum,
    next_a0=0,
    next_nd=-1,
):
    """One detection frame (detections ``a0 .. a0 + nd − 1``): innovations recorded, known landmarks update the
    state (or are re-initialised when the recovery asked for it), new ones are augmented; every tested detection
    is counted in the recovery's window. The propagation since the last frame is pending in ``lt``, ``rt``, ``dp``
    (:func:`propagation_terms`): it is applied in the same pass as the downdate (:func:`apply`), the gain read
    from the rows of ``Σ⁻`` it needs (rows 6.. of ``lt`` are the downdate's scratch). ``next_a0``, ``next_nd``:
    the next frame's detections, whose rows of ``Σ`` are all of its lower triangle that is mirrored
    (:func:`_mirror_read`; ``next_nd < 0``: all of it). Returns the new state dimension.
    Public: tests/test_riekf.py and tests/test_riekf_exactness.py check it against dense algebra."""
    for j in range(nd):  # a re-initialisation copies rows of Σ⁻: apply the propagation first
        i = det_idx[a0 + j]
        if slot_of[i] >= 0 and reinit[i]:
            _settle(cov, d, lt, rt, dp)
            break
    m = 0
    passed, failed = 0, 0  # known landmarks' detections that passed, failed the gate in this frame
    e = np.empty(3)  # scratch: a detection's e_i and z_i = −e_i, the gate's 3×3
    zi = np.empty(3)
    s3 = np.empty((3, 3))
    ues = np.zeros((nd, 3))  # each detection's range noise beyond the across one, along its line of sight R̂y/|y|
    sig2 = np.empty(nd)  # each detection's variance across its line of sight
    for j in range(nd):
        i = det_idx[a0 + j]
        y0, y1, y2 = det_y[a0 + j, 0], det_y[a0 + j, 1], det_y[a0 + j, 2]  # no view per detection
        for c in range(3):
            e[c] = lm[i, c] - (r_hat[c, 0] * y0 + r_hat[c, 1] * y1 + r_hat[c, 2] * y2) - p_hat[c]
        if slot_of[i] >= 0 and not reinit[i]:  # σ(r) at the range the state predicts (module docstring)
            rr = np.sqrt((lm[i, 0] - p_hat[0]) ** 2 + (lm[i, 1] - p_hat[1]) ** 2 + (lm[i, 2] - p_hat[2]) ** 2)
        else:  # a new or re-initialised landmark's at its measured range
            rr = np.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
        sg = det_law[0] + det_law[1] * rr + det_law[2] * rr * rr
        sig2[j] = det_law[3] * (sg * sg) * scale
        extra = det_law[4] * sig2[j]
        if extra > 0.0:
            f = np.sqrt(extra / (y0 * y0 + y1 * y1 + y2 * y2))
            for c in range(3):
                ues[j, c] = f * (r_hat[c, 0] * y0 + r_hat[c, 1] * y1 + r_hat[c, 2] * y2)
        if slot_of[i] < 0:
            continue  # new: recorded after augmentation
        for c in range(3):
            innov[row + j, c] = e[c]
            trk_p[row + j, c] = lm[i, c]
        if reinit[i]:
            _reset_landmark(cov, d, N_FIXED + 3 * slot_of[i], sig2[j], ues, j)
            for c in range(3):
                lm[i, c] = lm[i, c] - e[c]
                trk_p[row + j, c] = lm[i, c]
            reinit[i] = False
            ns[_REINIT] += 1
            continue
        for c in range(3):
            zi[c] = -e[c]
        d2 = _gate(cov, zi, N_FIXED + 3 * slot_of[i], sig2[j], ues, j, lt, rt, dp, s3)
        if ns[_WIN_N] < win_d2.shape[0]:
            win_d2[ns[_WIN_N]] = d2
            win_f[ns[_WIN_N]] = a0
            for c in range(3):
                win_z[ns[_WIN_N], c] = zi[c]
        ns[_WIN_N] += 1
        ns[_PB_N] += ns[_ARMED]
        if ns[_ARMED] and ns[_PB_N] <= blind_z2.shape[0]:  # the squared innovations since (_blind_check)
            blind_z2[ns[_PB_N] - 1] = zi[0] * zi[0] + zi[1] * zi[1] + zi[2] * zi[2]
        if d2 < np.inf:  # the innovation deviance: log det S + d², a gated detection's d² at the gate (likelihood)
            win_sum[8, 4] += 2.0 * (np.log(s3[0, 0]) + np.log(s3[1, 1]) + np.log(s3[2, 2])) + min(d2, gate)
            win_sum[8, 5] += 1.0
            if zi[2] == 0.0:  # no error on the vertical axis (a planar rig): its marginal over x, y (ratio_deviance)
                w0 = zi[0] / s3[0, 0]
                w1 = (zi[1] - s3[1, 0] * w0) / s3[1, 1]
                win_sum[8, 6] += 2.0 * (np.log(s3[0, 0]) + np.log(s3[1, 1])) + min(w0 * w0 + w1 * w1, gate)
            else:
                win_sum[8, 6] += 2.0 * (np.log(s3[0, 0]) + np.log(s3[1, 1]) + np.log(s3[2, 2])) + min(d2, gate)
        if d2 > gate:
            ns[_GATED] += 1
            ns[_TAIL_GATED] += 1
            ns[_WIN_GATED] += 1
            ns[_PB_GATED] += ns[_ARMED]
            gated_lm[i] = True
            failed += 1
            ns[_OPEN_GATED] += 1
            continue
        passed += 1
        ns[_TAIL_GATED] = 0
        win_sum[8, 0] += d2  # the run's accepted innovations' NIS (innovation_consistency)
        win_sum[8, 1] += 1.0
        _correlation_sums(i, zi, d2, corr_w, corr_n, corr_sum)
        sel[m] = j
        for c in range(3):
            z[3 * m + c] = zi[c]
        m += 1
    if passed > failed:  # an open run ends at a frame whose detections mostly pass
        ns[_LONGEST_GATED] = max(ns[_LONGEST_GATED], ns[_OPEN_GATED])
        ns[_OPEN_GATED] = 0
    terms = 6  # the propagation's; the downdate's 3m follow when the frame updates
    xi = np.zeros(0)
    lin = np.zeros((3, 3))  # the frame's only update's linearisation term (_linearisation)
    if m == 1 and ns[_ARMED] == 0:  # two or more landmarks constrain the pose's turn, and a return the blind check
        srr = np.empty((3, 3))  # judges is updated plainly; Σ⁻_RR: the attitude block with the pending propagation
        for a in range(3):
            for b in range(3):
                srr[a, b] = _pending_sum(cov[a, b], lt, rt, a, b)
        _linearisation(z, srr, sig2[sel[0]], gate, lin)
    if m > 0:
        k3 = 3 * m
        hp = lt[6:]
        # H Σ⁻ (3m × d): row block q = Σ⁻[P, :] − Σ⁻[slot of q, :], the pending propagation added; whole vectors
        # to the padded end (zeros past d), each entry's terms in the order of the scalar sum (fused as it was)
        for q in range(m):
            sl = N_FIXED + 3 * slot_of[det_idx[a0 + sel[q]]]
            _hp_rows(hp, 3 * q, cov, dp, lt, rt, sl, d)
            for c in range(3):
                for b in range(3):  # rt is zero in the position columns: their propagation is in dp
                    hp[3 * q + c, 3 + b] -= dp[b, sl + c]
        # S = H Σ⁻ Hᵀ + σ² I
        for q in range(m):
            sl = N_FIXED + 3 * slot_of[det_idx[a0 + sel[q]]]
            s2 = sig2[sel[q]]
            jq = sel[q]
            for c in range(3):
                for k in range(k3):
                    smat[3 * q + c, k] = hp[k, 3 + c] - hp[k, sl + c]
                for b in range(3):
                    smat[3 * q + c, 3 * q + b] += ues[jq, c] * ues[jq, b] + lin[c, b]
                smat[3 * q + c, 3 * q + c] += s2
        for r in range(k3):  # symmetrise the round-off
            for c in range(r + 1, k3):
                v = 0.5 * (smat[r, c] + smat[c, r])
                smat[r, c] = v
                smat[c, r] = v
        _sum_innovations(z, smat, k3, win_sum)
        if not cholesky_lower(smat, k3):
            ns[_SKIPPED] += 1
        else:
            xi = _gain(hp, smat, z, k3, d)
            _bias_corrections(xi, hp, k3, win_sum)
            terms += k3
    rows = np.empty(max(next_nd, 0), np.int64)  # the next frame's known landmarks: their rows of Σ mirrored
    n_rows = next_nd if next_nd < 0 else 0
    for j in range(next_nd):
        o = slot_of[det_idx[next_a0 + j]]
        if o >= 0:
            rows[n_rows] = N_FIXED + 3 * o
            n_rows += 1
    apply(cov, d, lt, rt, terms, dp, rows, n_rows)  # Σ⁺ = Σ + ΔΣ − U Uᵀ in one pass
    if xi.shape[0] > 0:
        _correct(xi, d, r_hat, p_hat, b_om, b_v, lm, slot_lm)
        ns[_UPDATES] += 1
    # augmentation with the corrected pose
    for j in range(nd):
        i = det_idx[a0 + j]
        if slot_of[i] >= 0:
            continue
        y0, y1, y2 = det_y[a0 + j, 0], det_y[a0 + j, 1], det_y[a0 + j, 2]  # no view per detection
        for c in range(3):
            lm[i, c] = p_hat[c] + r_hat[c, 0] * y0 + r_hat[c, 1] * y1 + r_hat[c, 2] * y2
            innov[row + j, c] = 0.0
            trk_p[row + j, c] = lm[i, c]
        s = (d - N_FIXED) // 3
        slot_of[i] = s
        slot_lm[s] = i
        _reset_landmark(cov, d, d, sig2[j], ues, j)
        d += 3
    return d


def correlation_arrays(n_landmarks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What :func:`_correlation_sums` keeps, empty: each landmark's last ``CORRELATION_LAGS`` whitened innovations,
    their count, and the pooled lag sums. Public: tests that call :func:`update` allocate them."""
    return np.zeros((n_landmarks, CORRELATION_LAGS, 3)), np.zeros(n_landmarks, np.int64), np.zeros(CORRELATION_LAGS + 1)


@njit(cache=True)
def _correlation_sums(i, zi, d2, corr_w, corr_n, corr_sum):
    """Landmark ``i``'s accepted innovation ``zi``, whitened by its gate distance (``zi / |zi| · √d²``), into the
    pooled lag sums ``corr_sum`` (0: the squares, k: the products with the landmark's k-th last, up to
    ``CORRELATION_LAGS``) and into its ring ``corr_w[i]`` (``corr_n[i]`` innovations so far). Changes nothing else."""
    q = zi[0] * zi[0] + zi[1] * zi[1] + zi[2] * zi[2]
    f = np.sqrt(d2 / q) if q > 0.0 else 0.0
    w0, w1, w2 = f * zi[0], f * zi[1], f * zi[2]
    n, lags = corr_n[i], corr_w.shape[1]
    here = n % lags  # the ring's slot of this one; the k-th last is k slots before it (one modulo per detection)
    corr_sum[0] += w0 * w0 + w1 * w1 + w2 * w2
    s = here
    for k in range(1, min(n, lags) + 1):
        s = s - 1 if s > 0 else lags - 1
        corr_sum[k] += w0 * corr_w[i, s, 0] + w1 * corr_w[i, s, 1] + w2 * corr_w[i, s, 2]
    corr_w[i, here, 0], corr_w[i, here, 1], corr_w[i, here, 2] = w0, w1, w2
    corr_n[i] = n + 1


@njit(cache=True)
def _sum_innovations(z, smat, k3, win_sum):
    """The window's sum of the frame's accepted innovations (row 0 of ``win_sum``) and of their joint covariance
    (rows 1..3: every 3×3 block of ``S``, the cross blocks of a frame's common pose error included)."""
    for r in range(k3):  # k3 is a multiple of 3: row r's three cells summed in registers, in the order of c as before
        a = 1 + r % 3
        win_sum[0, r % 3] += z[r]
        w0, w1, w2 = win_sum[a, 0], win_sum[a, 1], win_sum[a, 2]
        for c in range(0, k3, 3):
            w0 += smat[r, c]
            w1 += smat[r, c + 1]
            w2 += smat[r, c + 2]
        win_sum[a, 0], win_sum[a, 1], win_sum[a, 2] = w0, w1, w2


@njit(cache=True, fastmath=CONTRACT)
def _bias_corrections(xi, u, k3, win_sum):
    """The window's squared velocity-bias corrections ``|δb̂_V|²`` (``win_sum[5, 0]``) and what a consistent filter
    expects of them, the trace of the downdate ``U Uᵀ`` on the velocity-bias rows (``win_sum[5, 1]``; ``u`` = ``Uᵀ``,
    k3 × d), and the gyro bias's likewise (``win_sum[5, 2:4]``): the variance matching of the bias walks (module
    docstring, "Velocity-bias walk", "Gyro-bias walk")."""
    for b in range(6, 12):
        e = 0.0
        for k in range(k3):
            e += u[k, b] * u[k, b]
        c = 0 if b >= 9 else 2
        win_sum[5, c] += xi[b] * xi[b]
        win_sum[5, c + 1] += e


@njit(cache=True, fastmath=CONTRACT)
def _reset_landmark(cov, d, o, sigma2, ues, j):
    """Landmark slot ``o`` (re-)initialised from the pose, for a new landmark (``o == d``) or one that failed the
    gate: its rows copy ``P̂``'s and its own block is ``Σ_PP + σ²I + u uᵀ`` (``u = ues[j]``; its mean is set by the
    caller)."""
    for c in range(3):
        for k in range(d):
            cov[o + c, k] = cov[3 + c, k]
            cov[k, o + c] = cov[3 + c, k]
    for a in range(3):
        for c in range(3):
            cov[o + a, o + c] = cov[3 + a, 3 + c] + ues[j, a] * ues[j, c]
        cov[o + a, o + a] += sigma2


@njit(cache=True)
def _common_share(n, win_z, win_f):
    """How much of the window's innovations the frames share: ``Σ n_f |z̄_f|²`` over ``Σ |z_i − z̄_f|² n_f/(n_f−1)``
    over frames with two or more detections (about 1 for independent detection errors; large when a pose error
    moves all of a frame's innovations alike). −1 without such frames: unknown (one detection per frame)."""
    common, spread = 0.0, 0.0
    a = 0
    while a < n:
        b = a
        while b < n and win_f[b] == win_f[a]:
            b += 1
        m = b - a
        if m >= 2:
            mean = np.zeros(3)
            for k in range(a, b):
                mean += win_z[k]
            mean /= m
            dev = 0.0
            for k in range(a, b):
                for c in range(3):
                    dev += (win_z[k, c] - mean[c]) ** 2
            common += m * (mean[0] ** 2 + mean[1] ** 2 + mean[2] ** 2)
            spread += dev * m / (m - 1)
        a = b
    return common / spread if spread > 0.0 else -1.0


@subroutine(types.none)
def _blind_start(t, nd, a0, det_idx, slot_of, reinit, fs, ns):
    """Before a frame: when it holds a known landmark's detection, the first after ``BLIND_S`` or more without
    one, the check of the detections that follow is armed (module docstring, "Blind stretches")."""
    for j in range(nd):
        i = det_idx[a0 + j]
        if slot_of[i] >= 0 and not reinit[i]:
            if t - fs[_KNOWN_T] >= BLIND_S and ns[_LOST] == 0:
                ns[_ARMED], ns[_PB_N], ns[_PB_GATED] = 1, 0, 0
                fs[_BLIND_T] = fs[_KNOWN_T]
            fs[_KNOWN_T] = t
            return


@njit(cache=True)
def _blind_check(t, d, cov, fs, ns, win_sum, blind_z2, gated_lm, blind_log):
    """After the first ``BLIND_WINDOW`` known-landmark detections that follow a blind stretch: when nearly all
    failed the gate (over ``BLIND_SHARE``), the pose error is beyond the covariance: the position's covariance is
    re-opened to the landmarks' median squared innovation on each axis (uncorrelated with the rest of the state, as
    at a segment start), so that the re-observed landmarks re-anchor the pose; the recovery's window starts again.
    Recorded when it acts; nothing changes when it does not."""
    ns[_ARMED] = 0
    n, gated = ns[_PB_N], ns[_PB_GATED]
    if gated <= BLIND_SHARE * n:
        return
    v = np.median(blind_z2[: min(n, blind_z2.shape[0])])  # the position's error as the landmarks see it
    for r in range(3, 6):
        v = max(v, cov[r, r])  # never below what the filter had
    for r in range(3, 6):
        for c in range(d):
            cov[r, c] = 0.0
            cov[c, r] = 0.0
        cov[r, r] = v
    ns[_WIN_N], ns[_WIN_GATED] = 0, 0
    ns[_OPEN_GATED] = 0  # a run this re-anchoring handled (module docstring, "Bias priors narrowed")
    win_sum[:4, :] = 0.0
    gated_lm[:] = False
    k = ns[_RELOCS]
    if k < blind_log.shape[0]:
        blind_log[k, 0], blind_log[k, 1] = t, t - fs[_BLIND_T]
        blind_log[k, 2], blind_log[k, 3] = gated / n, math.sqrt(v)
    ns[_RELOCS] += 1


@njit(cache=True)
def _reopen_heading(cov, d, p_hat, lm, slot_lm, plane, sigma_p):
    """After a blind stretch on the floor (:func:`_blind_check` acted): the heading relative to the map re-opened,
    the robot turned about the floor's normal ``n`` in place with the map kept: ``Σ += σ² u uᵀ``, ``u = (n, P̂×n,
    0, L̂ᵢ×n ...)`` (with ``X̂ ← exp(−ξ)X̂`` that moves neither ``P̂`` nor a landmark), ``σ`` the re-opened position's
    over the median range (``plane[14]``)."""
    var = (sigma_p / plane[14]) ** 2
    n = plane[1:4]
    u = np.zeros(d)
    u[0], u[1], u[2] = n[0], n[1], n[2]
    u[3] = p_hat[1] * n[2] - p_hat[2] * n[1]
    u[4] = p_hat[2] * n[0] - p_hat[0] * n[2]
    u[5] = p_hat[0] * n[1] - p_hat[1] * n[0]
    for s in range((d - N_FIXED) // 3):
        i, o = slot_lm[s], N_FIXED + 3 * s
        u[o] = lm[i, 1] * n[2] - lm[i, 2] * n[1]
        u[o + 1] = lm[i, 2] * n[0] - lm[i, 0] * n[2]
        u[o + 2] = lm[i, 0] * n[1] - lm[i, 1] * n[0]
    for r in range(d):
        for c in range(d):
            cov[r, c] += var * u[r] * u[c]


@njit(cache=True)
def _consistency_check(t, ns, win_sum, consistency_log):
    """A window that passed the gate: the Mahalanobis distance² of the sum of its accepted innovations joins the
    ring of the last ``CONSISTENCY_WINDOWS``; when their median exceeds ``OVERCONFIDENT_D2`` the filter is
    overconfident (module docstring, "Overconfidence"): recorded, and the ring starts again. Changes no estimate."""
    d2 = _mahalanobis3(win_sum[1:4, :3].copy(), win_sum[0])  # the summed innovations under their summed covariance
    if d2 == np.inf:  # no accepted innovation
        return
    win_sum[8, 2] += d2  # the run's windows' d² (innovation_consistency)
    win_sum[8, 3] += 1.0
    hist = win_sum[4]  # the last CONSISTENCY_WINDOWS windows' d2, in a ring
    hist[ns[_CONSISTENCY_N] % CONSISTENCY_WINDOWS] = d2
    ns[_CONSISTENCY_N] += 1
    if ns[_CONSISTENCY_N] < CONSISTENCY_WINDOWS or ns[_LOST] != 0:
        return
    median_d2 = np.median(hist)
    if median_d2 <= OVERCONFIDENT_D2:
        return
    ns[_CONSISTENCY_N] = 0
    r = ns[_OVERCONFIDENT]
    if r < consistency_log.shape[0]:
        consistency_log[r, 0], consistency_log[r, 1] = t, median_d2
    ns[_OVERCONFIDENT] += 1


@njit(cache=True)
def _walk_check(t, fs, ns, win_sum, walk_log):
    """A window that passed the gate: each bias's squared corrections and their expectation
    (:func:`_bias_corrections`) join the ring of the last ``CONSISTENCY_WINDOWS`` (``win_sum`` rows 6 and 7 for the
    velocity's, 9 and 10 for the gyro's); when a bias's corrections over the ring exceed ``WALK_RATIO`` times their
    expectation (``WALK_RATIO_AGAIN`` once raised), its walk's standard deviation is multiplied by that ratio squared
    (up to ``MAX_WALK_FACTOR`` in all), recorded, and the ring starts again (module docstring, "Velocity-bias walk",
    "Gyro-bias walk"). True when a walk changed."""
    if ns[_LOST] != 0 or win_sum[5, 1] <= 0.0:
        return False
    k = ns[_WALK_N] % CONSISTENCY_WINDOWS
    for w in range(2):
        c, ring = 2 - 2 * w, _WALK_SLOTS[w][4]
        win_sum[ring, k], win_sum[ring + 1, k] = win_sum[5, c], win_sum[5, c + 1]
    ns[_WALK_N] += 1
    if ns[_WALK_N] < CONSISTENCY_WINDOWS:
        return False
    changed = False
    for w in range(2):
        f, fmax, raises, fixed, ring = _WALK_SLOTS[w]
        if ns[fixed] or win_sum[ring + 1].sum() <= 0.0:
            continue
        ratio = win_sum[ring].sum() / win_sum[ring + 1].sum()
        fs[fmax] = max(fs[fmax], ratio)
        if ratio <= (WALK_RATIO_AGAIN if ns[raises] else WALK_RATIO) or fs[f] >= MAX_WALK_FACTOR**2:
            continue
        fs[f] = min(fs[f] * ratio**4, MAX_WALK_FACTOR**2)
        r = ns[_WALK_RAISES] + ns[_GWALK_RAISES]
        if r < walk_log.shape[0]:
            walk_log[r, 0], walk_log[r, 1], walk_log[r, 2], walk_log[r, 3] = t, ratio, math.sqrt(fs[f]), w
        ns[raises] += 1
        changed = True
    if changed:
        ns[_WALK_N] = 0
    return changed


@njit(cache=True)
def _window_check(
    t,
    d,
    cov,
    fs,
    ns,
    win_d2,
    win_z,
    win_f,
    win_sum,
    gated_lm,
    reinit,
    slot_of,
    corr_n,
    rec_log,
    consistency_log,
    walk_log,
    max_scale,
):
    """At the end of a window of ``WINDOW`` tested detections: recover when most failed the gate (module
    docstring, "Recovery"), or give up; else check its consistency (:func:`_consistency_check`) and the velocity-bias
    walk (:func:`_walk_check`); the window starts again. True when a noise factor changed."""
    n, gated = ns[_WIN_N], ns[_WIN_GATED]
    ns[_WIN_N], ns[_WIN_GATED] = 0, 0
    changed = False
    if gated <= RECOVER_SHARE * n:
        ns[_FAILING] = 0
        if ns[_LOST] and fs[_AGAIN_T] <= fs[_LOST_T]:  # passing again after the give-up: the first window of a run
            fs[_AGAIN_T] = t
        _consistency_check(t, ns, win_sum, consistency_log)
        changed = _walk_check(t, fs, ns, win_sum, walk_log)
    elif ns[_LOST] == 0:
        m = min(n, win_d2.shape[0])
        step = min(max(np.median(win_d2[:m]) / CHI2_MEDIAN_3, MIN_STEP), MAX_STEP)
        failing = ns[_FAILING] + 1
        # first: the detections, or, when the frames' innovations move together, the motion (a pose error);
        # again: both; from the third on the landmarks that failed also start afresh. With one detection per frame
        # the share is unknown: a factor beyond what the detections can be (``max_scale``) leaves the motion alone
        share = _common_share(m, win_z, win_f)
        beyond = share < 0.0 and fs[_DSCALE] * step > max_scale
        motion = failing >= 2 or share > COMMON_SHARE or beyond
        detections = (failing >= 2 or not motion) and not beyond
        det = fs[_DSCALE] * step if detections else fs[_DSCALE]
        # a factor no detection can have, where landmarks that never passed the gate failed: those start afresh
        # (each holds only the detection it was started from, which may have carried another landmark's id), no
        # noise changed; with none, the filter gives up
        unproven = 0
        if det > max_scale:
            for i in range(gated_lm.shape[0]):
                if gated_lm[i] and slot_of[i] >= 0 and corr_n[i] == 0:
                    unproven += 1
        if ns[_FAILING] >= MAX_FAILING or (det > max_scale and unproven == 0):
            ns[_LOST] = 1
            fs[_LOST_T] = t
        else:
            fresh = det > max_scale
            if fresh:
                det, motion = fs[_DSCALE], False
            ns[_FAILING] = failing
            fs[_DSCALE] = det
            if motion:
                fs[_SCALE] *= step
                cov[:d, :d] *= step
            for i in range(gated_lm.shape[0]):
                if gated_lm[i] and slot_of[i] >= 0 and (corr_n[i] == 0 if fresh else failing >= 3):
                    reinit[i] = True
            ns[_OPEN_GATED] = 0  # a run this recovery handled (module docstring, "Bias priors narrowed")
            r = ns[_RECOVERIES]
            if r < rec_log.shape[0]:
                rec_log[r, 0], rec_log[r, 1], rec_log[r, 2] = t, step, fs[_DSCALE]
                plain = 3 if failing >= 3 else 2 if detections and motion else 1 if detections else 0
                rec_log[r, 3] = 4 if fresh else plain
            ns[_RECOVERIES] += 1
            changed = True
    else:  # failing again after the give-up: a passing run starts afresh
        fs[_AGAIN_T] = 0.0
    gated_lm[:] = False
    win_sum[:4, :] = 0.0
    win_sum[5, :4] = 0.0
    return changed


@njit(cache=True, nogil=True)
def _advance(
    vel_t,
    omega,
    vel,
    vel_gap,
    om_gap,
    det_t,
    det_offsets,
    det_idx,
    det_y,
    det_law,
    lm,
    q_om,
    q_v,
    q_bw,
    q_bv,
    gate,
    max_scale,
    plane,
    still,
    out_every,
    iv_stop,
    budget,
    r_hat,
    p_hat,
    b_om,
    b_v,
    om_m,
    v_m,
    counter,
    fs,
    ns,
    cov,
    slot_of,
    slot_lm,
    acc,
    lt,
    rt,
    dp,
    sel,
    z,
    smat,
    win_d2,
    win_z,
    win_f,
    win_sum,
    blind_z2,
    corr_w,
    corr_n,
    corr_sum,
    gated_lm,
    reinit,
    rec_log,
    consistency_log,
    walk_log,
    blind_log,
    out_k,
    out_r,
    out_p,
    out_b,
    trk_p,
    innov,
    det_base,
    cov_out,
    pose_out,
):
    """The event loop from the state in the arrays until the next event is velocity sample ``iv_stop`` (all
    events when it is the sample count) or ``budget`` work units are spent; returns the number of rows recorded.
    ``cov_out`` (rows, 12, 12) receives the pose-and-bias covariance at each recorded row when it has rows
    (tests), else nothing; ``pose_out`` (rows, 6, 6) the pose covariance in the written convention
    (:func:`_pose_covariance`). The noise enters multiplied by the recovery's variance factors (``fs[_SCALE]``
    the motion noise, ``fs[_DSCALE]`` the detections')."""
    n_vel = vel_t.shape[0]
    n_frames = det_t.shape[0]
    t, acc_dt = fs[_T], fs[_ACC_DT]
    iv, jf, started, steps = ns[_IV], ns[_JF], ns[_STARTED] != 0, ns[_STEPS]
    d = N_FIXED + 3 * ns[_NSEEN]
    d_r = np.empty((3, 3))
    d_p = np.empty(3)
    bias = np.empty(6)
    pc_w = np.empty((3, 6, 6))  # _pose_covariance's scratch
    acc_w = np.empty((3, 3, 3))  # accumulate's
    qg_om, qg_v = np.empty(3), np.empty(3)  # the motion noise times an interval's gap factors (an array per step cost)
    o = np.int64(0)  # int64 from the start: a literal 0 compiles _pose_covariance a second time (_settle's comment)
    want_cov = cov_out.shape[0] > 0
    work = 0
    scale, det_scale = fs[_SCALE], fs[_DSCALE]
    qs_om, qs_v, qs_bw, qs_bv = (
        q_om * scale,
        q_v * scale,
        q_bw * math.sqrt(scale * fs[_GWALK]),
        q_bv * math.sqrt(scale * fs[_WALK]),
    )
    gap_om, gap_v = fs[_GAP_OM], fs[_GAP_V]
    while (iv < n_vel or jf < n_frames) and work < budget:
        is_frame = jf < n_frames and (iv >= n_vel or det_t[jf] < vel_t[iv])
        if not is_frame and iv >= iv_stop:
            break
        work += 1
        t_next = det_t[jf] if is_frame else vel_t[iv]
        if started and t_next > t:
            dt = t_next - t
            m = max(1, int(math.ceil(dt / MAX_STEP_S)))
            h = dt / m
            bias[0], bias[1], bias[2], bias[3], bias[4], bias[5] = b_om[0], b_om[1], b_om[2], b_v[0], b_v[1], b_v[2]
            span = vel_t[iv] - vel_t[iv - 1] if 0 < iv < n_vel else 0.0
            g_om, g_v = gap_factor(span, gap_om), gap_factor(span, gap_v)
            if 0 < iv < n_vel:  # a gap of the linear velocity's own topic, a clipped gyro's stretch (gap_levels)
                g_v = max(g_v, vel_gap[iv])
                g_om = max(g_om, om_gap[iv])
            for c in range(3):
                qg_om[c], qg_v[c] = qs_om[c] * g_om, qs_v[c] * g_v
            for step in range(m):
                o0, o1, o2, v0, v1, v2 = twist_at(vel_t, omega, vel, iv - 1, t + (step + 0.5) * h, bias)
                accumulate(h, r_hat, p_hat, qg_om, qg_v, acc, acc_w)
                se3_exp_into(h * o0, h * o1, h * o2, h * v0, h * v1, h * v2, d_r, d_p)
                for c in range(3):
                    p_hat[c] += r_hat[c, 0] * d_p[0] + r_hat[c, 1] * d_p[1] + r_hat[c, 2] * d_p[2]
                for r in range(3):  # R̂ ← R̂ dR, row by row from the row's old values
                    x0, x1, x2 = r_hat[r, 0], r_hat[r, 1], r_hat[r, 2]
                    for c in range(3):
                        r_hat[r, c] = x0 * d_r[0, c] + x1 * d_r[1, c] + x2 * d_r[2, c]
                counter[0] += 1
                if counter[0] % REORTHO_EVERY == 0:
                    r_hat[:, :] = project_so3(r_hat)
            acc_dt += dt
            steps += m
            work += m
            t = t_next
        if is_frame:
            propagation_terms(cov, d, lm, slot_lm, acc, acc_dt, qs_bw, qs_bv, lt, rt, dp)
            acc_dt = 0.0
            a0 = det_offsets[jf]
            nd = det_offsets[jf + 1] - a0
            work += d * d * (3 * nd + 6) // _FRAME_WORK_SCALE
            _blind_start(t_next, nd, a0, det_idx, slot_of, reinit, fs, ns)
            next_nd = det_offsets[jf + 2] - det_offsets[jf + 1] if jf + 1 < n_frames else -1
            d = update(
                a0,
                nd,
                det_idx,
                det_y,
                det_law,
                cov,
                d,
                r_hat,
                p_hat,
                b_om,
                b_v,
                lm,
                slot_of,
                slot_lm,
                sel,
                z,
                lt,
                rt,
                dp,
                smat,
                innov,
                trk_p,
                a0 - det_base,
                ns,
                gate,
                det_scale,
                win_d2,
                win_z,
                win_f,
                gated_lm,
                reinit,
                win_sum,
                blind_z2,
                corr_w,
                corr_n,
                corr_sum,
                det_offsets[jf + 1],
                next_nd,
            )
            if ns[_ARMED] and ns[_PB_N] >= BLIND_WINDOW:
                relocs = ns[_RELOCS]
                _blind_check(t_next, d, cov, fs, ns, win_sum, blind_z2, gated_lm, blind_log)
                if plane[0] > 0.0 and ns[_RELOCS] > relocs:  # on the floor the heading is re-opened too
                    _reopen_heading(cov, d, p_hat, lm, slot_lm, plane, blind_log[min(relocs, MAX_LOG - 1), 3])
            if ns[_WIN_N] >= WINDOW and _window_check(
                t_next,
                d,
                cov,
                fs,
                ns,
                win_d2,
                win_z,
                win_f,
                win_sum,
                gated_lm,
                reinit,
                slot_of,
                corr_n,
                rec_log,
                consistency_log,
                walk_log,
                max_scale,
            ):
                scale, det_scale = fs[_SCALE], fs[_DSCALE]
                qs_om, qs_v = q_om * scale, q_v * scale
                qs_bw, qs_bv = q_bw * math.sqrt(scale * fs[_GWALK]), q_bv * math.sqrt(scale * fs[_WALK])
            fs[_MEAS_T] = t_next
            jf += 1
        else:
            for c in range(3):
                om_m[c] = omega[iv, c]
                v_m[c] = vel[iv, c]
            if not started:
                started = True
                t = t_next
            if plane[0] > 0.0 and t_next - fs[_PLANE_T] >= plane[13]:  # the floor (module docstring)
                flush(cov, d, lm, slot_lm, acc, acc_dt, qs_bw, qs_bv, lt, rt, dp)
                acc_dt = 0.0
                _planar_update(cov, d, r_hat, p_hat, b_om, b_v, lm, slot_lm, plane)
                fs[_PLANE_T] = t_next
            if still[iv]:  # at rest (module docstring, "At rest"): the biases read over each still window
                if fs[_STILL_N] == 0.0:
                    fs[_STILL_T0] = t_next
                fs[_STILL_N] += 1.0
                for c in range(3):
                    fs[_STILL_SUM + c] += omega[iv, c]
                    fs[_STILL_SUM + 3 + c] += vel[iv, c]
                if t_next - fs[_STILL_T0] >= MOTION_MEAN_WINDOW_S:
                    flush(cov, d, lm, slot_lm, acc, acc_dt, qs_bw, qs_bv, lt, rt, dp)
                    acc_dt = 0.0
                    fs[_T] = t
                    _still_update(cov, d, r_hat, p_hat, b_om, b_v, lm, slot_lm, fs, qs_om, qs_v, gate)
                    fs[_STILL_N] = 0.0
                    fs[_STILL_SUM : _STILL_SUM + 6] = 0.0
            elif fs[_STILL_N] > 0.0:
                fs[_STILL_N] = 0.0
                fs[_STILL_SUM : _STILL_SUM + 6] = 0.0
            if iv % out_every == 0 or iv == n_vel - 1:
                record_row(o, iv, r_hat, p_hat, b_om, b_v, out_k, out_r, out_p, out_b)
                _pose_covariance(cov, acc, acc_dt, qs_bw, qs_bv, p_hat, pose_out, o, pc_w)
                if want_cov:
                    flush(cov, d, lm, slot_lm, acc, acc_dt, qs_bw, qs_bv, lt, rt, dp)
                    acc_dt = 0.0
                    cov_out[o] = cov[:N_FIXED, :N_FIXED]
                o += 1
            iv += 1
    if iv >= n_vel and jf >= n_frames:  # the end: bring the covariance up to date for the final report
        flush(cov, d, lm, slot_lm, acc, acc_dt, qs_bw, qs_bv, lt, rt, dp)
        acc_dt = 0.0
    _mirror(cov, d)  # the frames mirrored only what the next one reads (_mirror_read): Σ whole for the caller
    fs[_T], fs[_ACC_DT] = t, acc_dt
    ns[_IV], ns[_JF], ns[_NSEEN], ns[_STARTED], ns[_STEPS] = iv, jf, (d - N_FIXED) // 3, 1 if started else 0, steps
    return o


class _State(KernelState):
    """The filter's state: the common estimate arrays, the covariance over every landmark slot the stream
    can need, the running sums and the update scratch."""

    def __init__(self, n_landmarks: int, n_max: int, r0, p0, sigma_bias: np.ndarray) -> None:
        super().__init__(n_max, r0, p0, np.zeros(3), np.zeros(3), n_clocks=_N_CLOCKS)
        self.fs[_SCALE] = 1.0
        self.fs[_WALK] = self.fs[_GWALK] = 1.0
        self.fs[_DSCALE] = 1.0
        self.fs[_KNOWN_T] = np.inf  # no known landmark's detection yet: no blind stretch either
        self.ns = np.concatenate([self.ns, np.zeros(N_SLOTS - self.ns.shape[0], dtype=np.int64)])
        dim = N_FIXED + 3 * n_landmarks
        dim += -dim % PAD  # whole vectors for the one-pass sums (apply); the dimensions past the state stay zero
        self.cov = np.zeros((dim, dim))
        for c in range(6):
            self.cov[6 + c, 6 + c] = sigma_bias[c] ** 2
        self.slot_of = np.full(n_landmarks, -1, dtype=np.int64)
        self.slot_lm = np.zeros(max(n_landmarks, 1), dtype=np.int64)
        self.acc = np.zeros((5, 3, 3))
        k3 = 3 * max(n_max, 1)
        # the pending propagation's terms and the downdate's (propagation_terms, update), the position rows'
        self.lt = np.zeros((6 + k3, dim))
        self.rt = np.zeros((6, dim))
        self.dp = np.zeros((3, dim))
        self.sel = np.zeros(max(n_max, 1), dtype=np.int64)
        self.z = np.zeros(k3)
        self.smat = np.zeros((k3, k3))
        self.win_d2 = np.zeros(WINDOW + 3 * max(n_max, 1))  # a window ends at the frame that fills it
        self.win_z = np.zeros((self.win_d2.shape[0], 3))  # the window's innovations and their frames
        self.win_f = np.zeros(self.win_d2.shape[0], dtype=np.int64)
        # the window's summed accepted innovations and their covariance; the last windows' d² (_consistency_check)
        self.win_sum = np.zeros((WIN_SUM_ROWS, CONSISTENCY_WINDOWS))
        self.blind_z2 = np.zeros(BLIND_WINDOW + max(n_max, 1))  # |z|² of the detections after a blind stretch
        self.corr_w, self.corr_n, self.corr_sum = correlation_arrays(n_landmarks)
        self.gated_lm = np.zeros(n_landmarks, dtype=np.bool_)
        self.reinit = np.zeros(n_landmarks, dtype=np.bool_)
        self.rec_log = np.zeros((MAX_LOG, 4))
        self.consistency_log = np.zeros((MAX_LOG, 2))  # the overconfidence check's findings: time, median d²
        self.walk_log = np.zeros((MAX_LOG, 4))  # a bias walk raised: time, ratio, factor on its σ, which (0 gyro)
        self.blind_log = np.zeros((MAX_LOG, 4))  # re-opened after a blind stretch: time, its length, gated share, σ

    def arrays(self) -> tuple:
        return (
            self.r_hat,
            self.p_hat,
            self.b_om,
            self.b_v,
            self.om_m,
            self.v_m,
            self.counter,
            self.fs,
            self.ns,
            self.cov,
            self.slot_of,
            self.slot_lm,
            self.acc,
            self.lt,
            self.rt,
            self.dp,
            self.sel,
            self.z,
            self.smat,
            self.win_d2,
            self.win_z,
            self.win_f,
            self.win_sum,
            self.blind_z2,
            self.corr_w,
            self.corr_n,
            self.corr_sum,
            self.gated_lm,
            self.reinit,
            self.rec_log,
            self.consistency_log,
            self.walk_log,
            self.blind_log,
        )


#: Pose standard deviations (rad, m) after a gap: re-anchored to the map (True) or held from before it (False).
GAP_SIGMA = {True: (0.05, 0.3), False: (0.5, 5.0)}
#: Largest state the filter builds (dimensions): its covariance is dense, (12 + 3n)² doubles.
MAX_DIM = 6012


class _OffsetApplied(Unwind):
    """The time offset, estimated while the filter ran on the recorded stamps, is applied (:meth:`RiEKF.advance`)."""


class RiEKF(Stepper):
    """The filter on an aligned stream, a stretch of samples at a time."""

    keeps_covariance = True
    gates_detections = True

    def __init__(self, stream, gains: dict[str, float], options, noise=None, r0=None, p0=None) -> None:
        from slamobs.pipeline.errors import InputError
        from slamobs.pipeline.noise import resolve_noise
        from slamobs.pipeline.observers import time_offset

        n_lm = int(stream.landmark_ids.shape[0])
        if N_FIXED + 3 * n_lm > MAX_DIM:
            raise InputError(
                options.source,
                f"riekf keeps every landmark in a dense covariance; "
                f"{n_lm} landmarks exceed its limit of {(MAX_DIM - N_FIXED) // 3}",
            )
        white = noise if noise is not None else options.noise if options.noise is not None else resolve_noise()
        self._white, self.noise = white, unresolved_gyro(white)
        self.pair_prior = pair_bias_prior(stream, self.noise)
        self.cov_rows: np.ndarray | None = None  # set by tests: (rows, 12, 12) receives Σ at each output row
        # the time offset is estimated on the other core while the filter starts on the stamps as recorded: the
        # filter's first stretch is kept when the estimate is not applied (most logs), started again when it is
        # (:meth:`advance`); either way the outputs are those of the filter on the stamps the estimate says
        self._recorded, self._start = stream, (options, r0, p0)
        self._offset: time_offset.Background | None = time_offset.Background(stream)
        self._time_offset: dict | None = None  # None while it is being estimated
        self._known = False  # whether the estimate is applied is known and acted upon (:meth:`_offset_applied`)
        # the walks' variance factors a pass starts from (gyro, velocity), the passes over the first stretch, whether
        # one was returned
        self._walk0, self._passes, self._returned = [1.0, 1.0], 1, False
        # the bias priors' narrowing: the passes with narrowed priors, and each earlier pass's gated run at its end
        self._prior_passes, self._lost_runs, self._noise0 = 0, [], self.noise
        self._prior_kept = True  # False once the narrowing failed and the priors were put back
        # each narrowed pass that kept the track (its evidence), and whether the best of them was chosen
        self._tried: list[dict] = []
        self._prior_chosen = False
        # stated levels above the samples': the candidate levels, each one's first-stretch evidence, and the choice
        self._white0, self._levels = white, level_candidates(white)
        self._levels_tried: list[dict] = []
        self._levels_chosen: int | None = None if len(self._levels) > 1 else 0
        if self._offset.done():  # one core: estimated already, nothing to overlap
            self._time_offset, self._offset = self._offset.result(), None
            stream = time_offset.shifted(stream, self._time_offset)
        self._setup(stream)

    def _setup(self, stream) -> None:
        """The filter at the start of ``stream`` (the detection stamps moved by the time offset or not)."""
        options, r0, p0 = self._start
        super().__init__(stream, options)
        nz = self.noise
        sigma_b = np.r_[np.full(3, nz.gyro_bias), np.full(3, nz.velocity_bias)]
        pp = self.pair_prior
        if pp["used"]:  # from detection pairs, narrowed as the defaults would be after a lost track
            sigma_b = np.asarray(pp["sigma"]) * (nz.gyro_bias / self._noise0.gyro_bias)
        self._start_sigma = [round(float(x), 6) for x in sigma_b]  # what run.json's bias_priors says was used
        self.state = _State(
            int(stream.landmark_ids.shape[0]),
            self.n_max,
            np.eye(3) if r0 is None else r0,
            np.zeros(3) if p0 is None else p0,
            sigma_b,
        )
        # a walk given in the configuration is kept; else it is learned from the log (module docstring)
        self.state.ns[_WALK_FIXED] = int(nz.sources.get("velocity_bias_walk") == "config")
        if pp["used"]:
            self.state.b_om[:], self.state.b_v[:] = pp["bias"][:3], pp["bias"][3:]
        self.state.fs[_GWALK], self.state.fs[_WALK] = self._walk0
        # the detection law (σ0, k, a) and the factors of σ(r)² across the line of sight and of what the range
        # adds (the ratio's split): the kernel evaluates it at each detection's predicted (or measured) range
        self.det_law = np.array(
            [nz.detection, nz.detection_per_m, nz.detection_per_m2, nz.ratio_split()[0], nz.detection_ratio**2 - 1.0]
        )
        walks = (float(nz.gyro_bias_walk), float(nz.velocity_bias_walk))
        self.params = (nz.gyro**2, nz.velocity**2, *walks, GATE_CHI2, max_variance_factor(stream.det_y, nz))
        # the floor's evidence: the white level (the rotation a slow gyro misses is motion, not noise)
        white = replace(nz, gyro=self._white.gyro)
        self.planar = floor_decision(self.vel_t, stream.omega, stream.velocity, white, stream.velocity_period_ns * 1e-9)
        self.plane = floor_plane(r0, p0, stream.det_y) if self.planar["held"] else np.zeros(15)
        # the samples at rest (module docstring, "At rest"), judged on the white levels
        self.still = still_mask(stream.vel_t_ns, stream.omega, stream.velocity, white.gyro**2, nz.velocity**2, nz.held)
        # the gyro's only where the angular velocity is an IMU's gyro (its own topic, not held) on a ground robot on
        # its floor: an odometry's or a VIO's angular velocity has no gyro bias that walks, and off the floor other
        # errors passed its ratio where no walk was seen to (module docstring, "Gyro-bias walk")
        imu_gyro = getattr(stream, "two_twist_topics", False) and "gyro" not in nz.held and self.planar["held"]
        self.state.ns[_GWALK_FIXED] = int(nz.sources.get("gyro_bias_walk") == "config" or not imu_gyro)
        # the gap factor on the streams' white densities; not on a held (commanded) stream, whose intervals are no gaps
        self.state.fs[_GAP_OM], self.state.fs[_GAP_V], self.vel_gap, self.om_gap = gap_levels(
            stream, self.vel_t, nz.held, nz.velocity, nz.gyro
        )
        self.stats.update({"noise": self.noise.as_dict()})
        self._corr_factors: list[float] = []  # each written stretch's pose covariance factor (:meth:`_widened`)

    @property
    def time_offset(self) -> dict:
        """The time-offset estimate (``run.json`` ``observer.time_offset``), waited for while it is being made; when
        it is applied and the filter ran on the recorded stamps meanwhile, the filter starts again on the moved ones."""
        if self._offset is not None:
            self._offset_applied()
            self._time_offset, self._offset = self._offset.result(), None
        return self._time_offset

    def _offset_applied(self) -> bool:
        """Whether the time offset being estimated is applied, waited for only until that is known (the estimate's
        reporting checks may still run); when it is, the filter starts again on the moved stamps, once."""
        from slamobs.pipeline.observers import time_offset

        decision = self._offset.decision()
        if decision["applied"] and not self._known:
            self._setup(time_offset.shifted(self._recorded, decision))
        self._known = True
        return decision["applied"]

    def advance(self, iv_stop: int):
        """:meth:`Stepper.advance` (:meth:`_advance_stretch`); the first stretch is run again from the start with the
        walk it learned as long as its velocity-bias corrections say the walk is too small (:meth:`_walk_restart`)."""
        res = self._settled(iv_stop, self._advance_stretch(iv_stop))
        while not self._returned and self._levels_chosen is None:
            again = self._level_restart(diverged=False)
            while again:
                try:
                    res = self._settled(iv_stop, self._advance_stretch(iv_stop))
                    break
                except ObserverDiverged:  # a candidate level the filter cannot run on: the worst of them
                    again = self._level_restart(diverged=True)
        if not self._returned and (
            self._tried or self._levels_tried
        ):  # the kept pass's own evidence came after its statistics
            self._describe()
            res = replace(res, stats=dict(self.stats))
        self._returned = True
        return self._widened(res)

    def _settled(self, iv_stop: int, res):
        """``res``, the first stretch run again while the walk's or the bias priors' restarts ask for it."""
        while not self._returned and (self._walk_restart() or self._prior_restart()):
            res = self._advance_stretch(iv_stop)
        return res

    def _level_restart(self, diverged: bool) -> bool:
        """Whether the first stretch is run again at another candidate level (module docstring, "Stated levels above
        the samples"): the pass just run (the last of its level's walk and bias-prior restarts) is recorded
        (``diverged``: it raised, its deviance infinite); the next candidate is run while any is left; then the
        lowest deviance per tested detection is chosen, the stated levels kept unless another's deviance over the
        stated pass's tested detections is lower by more than the χ² quantile ``LEVEL_CHOICE_P`` for the keys it
        changes (:func:`chosen_level`), and run again when it was not the last pass."""
        i = len(self._levels_tried)
        lik = (ratio_deviance if _RATIO in self._levels[i]["which"] else innovation_likelihood)(self.state.win_sum[8])
        self._levels_tried.append(
            {
                "levels": self._levels[i]["which"],
                "deviance_mean": None if diverged else lik["mean"],
                "tested": 0 if diverged else lik["tested"],
                "gated": None if diverged else int(self.state.ns[_GATED]),
                **({"diverged": True} if diverged else {}),
            }
        )
        if i + 1 < len(self._levels) and (not self._ratio_ladder or ratio_climbing(self._levels_tried)):
            self._use_levels(i + 1)
            return True
        self._levels_chosen = chosen_level(self._levels_tried)
        if _RATIO in self._levels[0]["which"]:  # the ratio's method says the deviances and the choice
            rec = self._levels[self._levels_chosen]
            rec["noise"] = replace(
                rec["noise"],
                sources={**rec["noise"].sources, _RATIO: "estimated"},
                methods={**rec["noise"].methods, _RATIO: ratio_method(self._levels_tried, self._levels_chosen)},
            )
            if self._levels_chosen == i and not diverged:  # the pass just run: its levels said so
                self._white = rec["noise"]
                self.noise = self._noise0 = unresolved_gyro(self._white)
        if self._levels_chosen == i and not diverged:
            return False
        self._use_levels(self._levels_chosen)
        return True

    def _use_levels(self, i: int) -> None:
        """The filter started again at candidate level ``i`` (:func:`level_candidates`): its white levels, riekf's
        gyro from them, the detection pairs' prior on them."""
        self._white = self._levels[i]["noise"]
        self.noise = self._noise0 = unresolved_gyro(self._white)
        self.pair_prior = pair_bias_prior(self._recorded, self.noise)
        # the walk's and the bias priors' restarts start over at these levels (:meth:`_settled`)
        self._walk0, self._passes, self._prior_passes, self._lost_runs = [1.0, 1.0], 1, 0, []
        self._prior_kept, self._tried, self._prior_chosen = True, [], False
        self._setup(self.stream)

    def _walk_restart(self) -> bool:
        """Whether the first stretch is run again (module docstring, "Velocity-bias walk", "Gyro-bias walk"): when the
        largest ratio of a bias's corrections to their expectation over the stretch exceeded ``RESTART_RATIO``, the
        filter starts again with that walk's standard deviation multiplied by the ratio squared (or the walk the
        stretch raised to, if larger), up to ``MAX_WALK_PASSES`` passes and ``MAX_WALK_FACTOR``: the velocity's on a
        ground robot on its floor only, the gyro's where the angular velocity is an IMU's gyro (:meth:`_setup`)."""
        ns, fs = self.state.ns, self.state.fs
        if self._passes >= MAX_WALK_PASSES:
            return False
        # the velocity's given; or its slow error is in the velocity level (held commands); or not a ground robot on
        # its floor. The gyro's given or not an IMU's (:meth:`_setup`)
        learn = (
            not ns[_GWALK_FIXED],
            not ns[_WALK_FIXED] and "velocity" not in self.noise.held and self.planar["held"],
        )
        raised = False
        for w, (f, fmax) in enumerate(((_GWALK, _GWALK_MAX), (_WALK, _WALK_MAX))):
            if learn[w] and fs[fmax] > RESTART_RATIO and self._walk0[w] < MAX_WALK_FACTOR**2:
                self._walk0[w] = min(max(self._walk0[w] * fs[fmax] ** 4, fs[f]), MAX_WALK_FACTOR**2)
                raised = True
        if raised:
            self._passes += 1
            self._setup(self.stream)
        return raised

    def _prior_restart(self) -> bool:
        """Whether the first stretch is run again with narrower bias priors (module docstring, "Bias priors
        narrowed"): when it holds ``LOST_IN_A_ROW`` or more known-landmark detections in a row failing the gate,
        both priors' standard deviations are multiplied by ``PRIOR_NARROWING`` (once more each pass, up to
        ``MAX_PRIOR_PASSES``); when the last of those still ends so, the narrowing did not keep the track (not the
        biases: a landmark moved, say) and a last pass runs with the priors as they were. From the first narrowed
        pass that keeps the track, once more each pass while its innovation deviance per tested detection falls
        (``_tried``): the lowest one's narrowing is kept, run again when a narrower pass came after it (or one that
        lost the track or gave up). Not when either prior is given in the configuration, nor when the filter gave up
        in a pass before any narrowed one kept the track (status ``lost``: the recovery found no noise level that
        explains the detections, and says so)."""
        ns = self.state.ns
        # a run before the end counts where no recovery acted in the pass (TagSLAM test_11's recovered run of 43:
        # counted, its narrowing passes dropped the pairs' start for nothing; docs/benchmarks.md, session 32)
        longest = max(ns[_TAIL_GATED], ns[_LONGEST_GATED], ns[_OPEN_GATED])  # the open run: up to the end
        run = int(ns[_TAIL_GATED] if ns[_RECOVERIES] or ns[_RELOCS] else longest)
        if self.pair_prior["used"] and (run >= LOST_IN_A_ROW or ns[_LOST]):  # the pairs' start first, then main's
            why = "the filter gave up" if ns[_LOST] else f"{run} of its detections in a row failed the gate"
            self.pair_prior = {**self.pair_prior, "used": False, "dropped": f"the pass started with it ended so: {why}"}
            self._setup(self.stream)
            return True
        given = {k for k in ("gyro_bias", "velocity_bias") if self._noise0.sources.get(k) == "config"}
        if given or not self._prior_kept or self._prior_chosen:
            return False
        if run < LOST_IN_A_ROW and not ns[_LOST]:
            if not self._prior_passes:  # never narrowed: as it was
                return False
            # a narrowed pass that kept the track: one narrower while the innovations' deviance falls (the first
            # prior that keeps the track is not the best: docs/benchmarks.md, session 33 (h-cascade2))
            self._tried.append(self._pass_evidence(run))
            best = min(self._tried, key=_deviance)  # the first (the wider) on a tie
            if best is self._tried[-1] and self._prior_passes < MAX_PRIOR_PASSES:
                return self._narrow(self._prior_passes + 1)
            if best is self._tried[-1]:
                return False
            self._prior_chosen = True  # the narrower pass explains the detections worse: the best one again
            return self._narrow(best["pass"])
        if self._tried:  # a wider narrowed pass kept the track and this narrower one did not: that one again
            self._tried.append(self._pass_evidence(run))
            self._prior_chosen = True
            return self._narrow(min(self._tried[:-1], key=_deviance)["pass"])
        if ns[_LOST]:
            return False
        self._lost_runs.append(run)
        if self._prior_passes >= MAX_PRIOR_PASSES:
            self._prior_kept, self.noise = False, self._noise0
            self._setup(self.stream)
            return True
        return self._narrow(self._prior_passes + 1)

    def _narrow(self, passes: int) -> bool:
        """The filter started again with both bias priors' standard deviations ``PRIOR_NARROWING**passes`` times
        the resolved ones (:meth:`_prior_restart`)."""
        self._prior_passes = passes
        f = PRIOR_NARROWING**passes
        why = "riekf, its track lost with wider priors"
        self.noise = self._noise0.scaled({"gyro_bias": f, "velocity_bias": f}, by=why)
        self._setup(self.stream)
        return True

    def _pass_evidence(self, run: int) -> dict:
        """What a narrowed pass over the first stretch ended with (run.json ``bias_priors.narrowed_tried``): its
        narrowing, the innovations' deviance per tested detection (:func:`innovation_likelihood`, the gated ones
        at the gate), the detections gated and the run of them in a row the narrowing judges (``run``: the longest,
        or the one at the end where a recovery or a re-anchoring acted)."""
        lik = innovation_likelihood(self.state.win_sum[8])
        return {
            "pass": self._prior_passes,
            "factor": PRIOR_NARROWING**self._prior_passes,
            "deviance_mean": lik["mean"],
            "tested": lik["tested"],
            "gated": int(self.state.ns[_GATED]),
            "gated_in_a_row": run,
        }

    def _advance_stretch(self, iv_stop: int):
        """One stretch. While the time offset is being estimated, the filter runs on the recorded
        stamps; it stops as soon as the estimate is known to be applied (:meth:`_kernel`) and starts again on the
        moved stamps, and the first stretch is returned only once that is known. The estimate's reporting checks
        (:func:`time_offset.estimate`'s ``decided``) may go on meanwhile: the stretches' statistics hold the estimate
        from the first call that finds it done, and the last stretch's (``iv_stop`` at the end) always."""
        if self._offset is None:
            return super().advance(iv_stop)
        if self._known:  # only the estimate's record is awaited
            return self._with_estimate(super().advance(iv_stop), iv_stop)
        try:
            first = super().advance(iv_stop)
        except (ObserverDiverged, _OffsetApplied):
            if not self._offset_applied():  # waits for the decision (the filter started again if applied)
                raise  # diverged on the stamps the estimate keeps: as without the overlap
            return self._with_estimate(super().advance(iv_stop), iv_stop)
        if self._offset_applied():
            return self._with_estimate(super().advance(iv_stop), iv_stop)
        return self._with_estimate(first, iv_stop)

    def _with_estimate(self, res, iv_stop: int):
        """``res`` with the statistics as they are now, the time-offset estimate in them once it is done (waited for
        at the last stretch)."""
        if self._offset is not None and (iv_stop >= self.n_vel or self._offset.done()):
            self._time_offset, self._offset = self._offset.result(), None
        self._describe()
        return replace(res, stats=dict(self.stats))

    reanchors_bridged = False

    def _relocalise(self, iv: int) -> bool:
        """After a gap (a new segment): the pose re-anchored to the map as the observers do it, and its
        covariance replaced by that of a fresh start (``GAP_SIGMA``, uncorrelated with map and biases), larger
        when no frame allowed the re-anchoring and the pose is held from before the gap."""
        st = self.state
        d = N_FIXED + 3 * int(st.ns[_NSEEN])
        walks = np.sqrt(st.fs[_SCALE] * np.array([st.fs[_GWALK], st.fs[_WALK]])) * np.array(self.params[2:4])
        flush(st.cov, d, self.lm, st.slot_lm, st.acc, st.fs[_ACC_DT], *walks, st.lt, st.rt, st.dp)
        st.fs[_ACC_DT] = 0.0
        self.lm_init[:] = st.slot_of >= 0
        moved = super()._relocalise(iv)
        rot, pos = GAP_SIGMA[moved]
        bias = st.cov[6:12, 6:12].copy()
        st.cov[:6, :d] = 0.0
        st.cov[:d, :6] = 0.0
        st.cov[6:12, 6:12] = bias
        st.cov[:3, :3] = rot**2 * np.eye(3)
        st.cov[3:6, 3:6] = pos**2 * np.eye(3)
        return moved

    def _kernel(self, iv_stop: int, out: Outputs, budget: int) -> int:
        if (
            self._offset is not None
            and not self._known
            and self._offset.decided()
            and self._offset.decision()["applied"]
        ):
            raise _OffsetApplied  # the filter ran on the recorded stamps meanwhile: no use going on (advance)
        s, o = self.stream, self.options
        if self.cov_rows is not None:  # the rows of this call: those not yet written
            cov_out = self.cov_rows[self.cov_rows.shape[0] - out.k.shape[0] :]
        else:
            cov_out = np.zeros((0, N_FIXED, N_FIXED))
        rows = _advance(
            self.vel_t,
            s.omega,
            s.velocity,
            self.vel_gap,
            self.om_gap,
            self.det_t,
            s.det_offsets,
            s.det_idx,
            s.det_y,
            self.det_law,
            self.lm,
            *self.params,
            self.plane,
            self.still,
            o.out_every,
            iv_stop,
            budget,
            *self.state.arrays(),
            *out.arrays(),
            cov_out,
            out.cov,
        )
        st = self.state
        # the statistics when the kernel reached the stop (the last call of Stepper.advance's loop: every stretch's
        # and segment's) or diverged, not at every work budget's return (0.4 ms each, 100 on an hour's log)
        if st.ns[_IV] >= iv_stop or not (np.isfinite(st.r_hat).all() and np.isfinite(st.p_hat).all()):
            self._describe()
        return rows

    def _describe(self) -> None:
        """The run's statistics and notes as they are now (``stats``)."""
        s, ns = self.stream, self.state.ns
        self.stats["substeps"] = int(ns[_STEPS])
        bias_sd = np.sqrt(np.clip(np.diag(self.state.cov)[6:12], 0.0, None))
        self.stats["metadata"] = {
            "filter": {
                "updates": int(ns[_UPDATES]),
                "gated_detections": int(ns[_GATED]),
                "skipped_frames": int(ns[_SKIPPED]),
                "landmarks_in_state": int(ns[_NSEEN]),
                "gate_chi2": GATE_CHI2,
                "final_bias_sigma": {"gyro": bias_sd[:3].tolist(), "velocity": bias_sd[3:].tolist()},
                "noise": self.noise.as_dict(),
                "planar": self._planar_record(),
                "innovation_consistency": innovation_consistency(self.state.win_sum[8]),
                "likelihood": innovation_likelihood(self.state.win_sum[8]),
                "correlation": self._correlation(),
                **({"stated_levels": self._stated_levels()} if self._levels_tried and not self._ratio_ladder else {}),
                **self._recovery(),
            },
            "time_offset": self._time_offset,
        }
        self.stats["notes"] = _unused_note(
            int(ns[_SKIPPED]), int(self.det_t.shape[0]), int(ns[_GATED]), int(s.det_idx.shape[0])
        ) + recovery_notes(self.stats["metadata"]["filter"])
        if self._time_offset is not None:  # None while it is being estimated (:meth:`advance`)
            self.stats["notes"] += time_offset_note("riekf", self._time_offset)
        if self.planar["planar"] or self.planar["held"]:
            self.stats["notes"].append(self._planar_note())
        self.stats["notes"] += innovation_note(self.stats["metadata"]["filter"]["innovation_consistency"])
        self.stats["notes"] += correlation_note(self.stats["metadata"]["filter"]["correlation"])
        self.stats["notes"] += unresolved_note(self._white, self.noise)
        if self._levels_chosen is not None and self._levels_tried:  # said once chosen
            self.stats["notes"] += (
                [f"riekf: detection_ratio {self.noise.detection_ratio:g} by {self.noise.methods[_RATIO]}"]
                if self._ratio_ladder
                else stated_levels_note(self.stats["metadata"]["filter"]["stated_levels"])
            )

    @property
    def _ratio_ladder(self) -> bool:
        """Whether the candidates are the detection ratios (:func:`level_candidates`), not stated levels."""
        return _RATIO in self._levels[0]["which"]

    def _stated_levels(self) -> dict:
        """run.json ``observer.filter.stated_levels``: each candidate tried over the first stretch (which keys at the
        samples' level, its deviance per tested detection, tested and gated), the one used, the stated and the
        samples' levels."""
        used = self._levels_chosen if self._levels_chosen is not None else len(self._levels_tried) - 1
        keys = list(self._white0.above_samples)
        return {
            "tried": self._levels_tried,
            "used": self._levels_tried[used]["levels"],
            "stated": {k: _plain_list(getattr(self._white0, k)) for k in keys},
            "samples": {k: _plain_list(self._white0.above_samples[k]) for k in keys},
            "chi2_threshold": {str(n): round(chi2_quantile(LEVEL_CHOICE_P, n), 3) for n in range(1, len(keys) + 1)},
        }

    def _correlation(self) -> dict:
        """:func:`correlation_factor` of the pass so far, with the factor each written stretch got and this one's
        (``factors``: ν where applied, else 1; a written stretch is never rescaled)."""
        st = self.state
        rec = correlation_factor(st.corr_sum, int(st.corr_n.sum()))
        return {**rec, "factors": [*self._corr_factors, rec["nu"] if rec["applied"] else 1.0]}

    def _widened(self, res):
        """``res`` with its pose covariance times the factor its statistics give it (:meth:`_correlation`)."""
        rec = res.stats.get("metadata", {}).get("filter", {}).get("correlation")  # none: the kernel never ran
        f = rec["factors"][-1] if rec else 1.0
        self._corr_factors.append(f)
        if f == 1.0 or res.pose_cov is None:
            return res
        return replace(res, pose_cov=res.pose_cov * f)

    def _planar_note(self) -> str:
        """The note of a floor held, or of planar motion seen with the floor switched off (``noise.floor``)."""
        r, pl = self.planar["ratios"], self.planar
        seen = "planar motion" if pl["planar"] else "motion not planar"
        if r is not None:
            ratios = f"{r[0]:.2g} / {r[1]:.2g} / {r[2]:.2g}"
            tilt = pl.get("tilt_rad") or [None, None]
            if None not in tilt:
                spread = f"{tilt[0]:.2g} / {tilt[1]:.2g} rad"
            elif tilt == [None, None]:
                spread = "not needed: the rates and the vertical velocity decide"
            else:  # the angle integrated only where it decides (planar_evidence)
                spread = " / ".join("not needed" if a is None else f"{a:.2g} rad" for a in tilt)
            seen += f" (roll rate, pitch rate, vertical velocity {ratios} times their noise; "
            seen += f"roll and pitch spread {spread})"
        if not pl["held"]:
            return f"riekf: {seen}, the floor not held (noise.floor: false)"
        why = "" if pl["floor"] == "auto" else " (noise.floor: true)"
        return (
            f"riekf: {seen}: the floor held{why} as pseudo-measurements every {PLANAR_EVERY_S:g} s "
            f"(tilt {PLANAR_TILT:g} rad, height {PLANAR_HEIGHT:g} m, the height no tighter than that over the log)"
        )

    def _planar_record(self) -> dict:
        """Planar motion for run.json: the evidence (:func:`planar_evidence`), the setting (``noise.floor``),
        whether the floor is held and, when held, its levels."""
        rec = dict(self.planar)
        if rec["held"]:
            rec.update(tilt_sigma_rad=PLANAR_TILT, height_sigma_m=PLANAR_HEIGHT, every_s=PLANAR_EVERY_S)
        return rec

    def landmark_covariance(self) -> np.ndarray:
        """Each landmark's position covariance in the map frame: ``δp_i = ξ_i − [p̂_i]×ξ_R`` from the filter's
        landmark and attitude blocks (NaN for landmarks not in the state yet)."""
        st = self.state
        out = np.full((self.lm.shape[0], 3, 3), np.nan)
        seen = np.flatnonzero(st.slot_of >= 0)
        rows = N_FIXED + 3 * st.slot_of[seen][:, None] + np.arange(3)
        idx = np.concatenate([np.broadcast_to(np.arange(3), rows.shape), rows], axis=1)  # (n, 6): ξ_R, ξ_i
        block = st.cov[idx[:, :, None], idx[:, None, :]]
        j = np.zeros((seen.size, 3, 6))
        j[:, :, 3:] = np.eye(3)
        for n, i in enumerate(seen):
            j[n, :, :3] = -skew(self.lm[i, :3])
        out[seen] = np.einsum("nij,njk,nlk->nil", j, block, j)
        factor = innovation_consistency(st.win_sum[8])["landmark_covariance_factor"]
        return out * factor if factor != 1.0 else out

    def _recovery(self) -> dict:
        """The recovery's record for run.json: status (:func:`filter_status`) and what it checked, each recovery
        (log seconds, variance factor of the step and in total), landmarks re-initialised, when it gave up."""
        ns, fs = self.state.ns, self.state.fs
        n = int(ns[_RECOVERIES])
        t0 = float(self.vel_t[0]) if self.vel_t.size else 0.0
        log = [
            {
                "t_s": round(float(r[0]) - t0, 3),
                "action": RECOVERY_ACTIONS[int(r[3])],
                "factor": float(r[1]),
                "detection_factor": float(r[2]),
            }
            for r in self.state.rec_log[: min(n, MAX_LOG)]
        ]
        status = filter_status(bool(ns[_LOST]), n, int(ns[_TAIL_GATED]))
        return {
            "status": status,
            "status_checked": STATUSES[status],
            "recoveries": n,
            "recovery_log": log,
            "noise_factor": float(fs[_SCALE]),
            "detection_noise_factor": float(fs[_DSCALE]),
            "landmarks_reinitialised": int(ns[_REINIT]),
            "lost_at_s": round(float(fs[_LOST_T]) - t0, 3) if ns[_LOST] else None,
            "passing_again_at_s": round(float(fs[_AGAIN_T]) - t0, 3) if ns[_LOST] and fs[_AGAIN_T] > 0 else None,
            "blind": [
                {
                    "t_s": round(float(r[0]) - t0, 3),
                    "blind_s": round(float(r[1]), 3),
                    "gated_share": round(float(r[2]), 3),
                    "position_sigma_m": round(float(r[3]), 3),
                }
                for r in self.state.blind_log[: min(int(ns[_RELOCS]), MAX_LOG)]
            ],
            "walk": self._walk(),
            "bias_priors": {
                "from_pairs": self.pair_prior,
                "narrowed_passes": self._prior_passes,
                "kept": self._prior_kept,
                "factor": PRIOR_NARROWING ** (self._prior_passes * self._prior_kept),
                "gyro_bias": float(self.noise.gyro_bias),
                "velocity_bias": float(self.noise.velocity_bias),
                "start_sigma": self._start_sigma,
                "gated_in_a_row_before": list(self._lost_runs),
                "narrowed_tried": [
                    {k: round(v, 4) if isinstance(v, float) else v for k, v in t.items()} for t in self._tried
                ],
                "gated_in_a_row_at_end": int(ns[_TAIL_GATED]),
                "gated_in_a_row_longest": int(max(ns[_LONGEST_GATED], ns[_OPEN_GATED])),
            },
            "consistency": {
                "overconfident": int(ns[_OVERCONFIDENT]),
                "log": [
                    {"t_s": round(float(r[0]) - t0, 3), "median_d2": round(float(r[1]), 3)}
                    for r in self.state.consistency_log[: min(int(ns[_OVERCONFIDENT]), MAX_LOG)]
                ],
            },
        }

    def _walk(self) -> dict:
        """The bias walks for run.json: each given (configuration) or learned, the passes over the first stretch and
        the walks the last one started from (:meth:`_walk_restart`), their values now and each raise of the last pass
        (log seconds, which walk, the ratio of the bias corrections to their expectation, the walk after it)."""
        ns, fs = self.state.ns, self.state.fs
        t0 = float(self.vel_t[0]) if self.vel_t.size else 0.0
        given = [float(self.params[2]), float(self.params[3])]
        n = min(int(ns[_WALK_RAISES] + ns[_GWALK_RAISES]), MAX_LOG)
        return {
            "learned": not ns[_WALK_FIXED],
            "given_m_s_sqrt_s": given[1],
            "passes": self._passes,
            "start_walk": given[1] * float(np.sqrt(self._walk0[1])),
            "velocity_bias_walk": given[1] * float(np.sqrt(fs[_WALK])),
            "gyro": {
                "learned": not ns[_GWALK_FIXED],
                "given_rad_s_sqrt_s": given[0],
                "start_walk": given[0] * float(np.sqrt(self._walk0[0])),
                "gyro_bias_walk": given[0] * float(np.sqrt(fs[_GWALK])),
            },
            "raises": [
                {
                    "t_s": round(float(r[0]) - t0, 3),
                    "bias": "gyro" if r[3] == 0 else "velocity",
                    "ratio": round(float(r[1]), 3),
                    "walk": given[int(r[3] != 0)] * float(r[2]),
                }
                for r in self.state.walk_log[:n]
            ],
        }


#: The confidence of the bound on the run's mean window d² above which the map's covariance is scaled (two-sided, as
#: the report's NEES bounds: its upper 97.5 %).
INNOVATION_CONFIDENCE = 0.95
INNOVATION_METHOD = (
    "mean_nis: the mean Mahalanobis distance² of each accepted detection's innovation under its covariance S (3 DoF: "
    "3 when S is right); mean_window_d2: the mean over the run's passing windows (WINDOW tested detections each) of "
    "the d² of the window's summed accepted innovations under their summed covariances (a frame's cross blocks "
    "included; 3 when the innovations are white with covariance S, larger when their errors are correlated); bound: "
    "the upper 97.5 % bound of a mean of that many χ²(3) values, χ²(3n)/n; landmark_covariance_factor: "
    "mean_window_d2 / 3 above the bound, else 1: the written landmark covariance is the filter's times it"
)


def innovation_consistency(tally: np.ndarray) -> dict:
    """The run's innovations against their covariance (module docstring, "The map's covariance scaled by the
    innovations"), from ``tally`` (row 8 of the state's ``win_sum``: the accepted detections' summed d² and count,
    the passing windows' summed d² and count). Public: tests/test_riekf.py checks the factor."""
    n_det, n_win = int(tally[1]), int(tally[3])
    mean_d2 = float(tally[2] / n_win) if n_win else None
    bound = nees_bounds(3, n_win, INNOVATION_CONFIDENCE)[1] if n_win else None
    above = mean_d2 is not None and mean_d2 > bound
    return {
        "detections": n_det,
        "mean_nis": float(tally[0] / n_det) if n_det else None,
        "windows": n_win,
        "mean_window_d2": mean_d2,
        "bound": bound,
        "landmark_covariance_factor": mean_d2 / 3.0 if above else 1.0,
        "method": INNOVATION_METHOD,
    }


def _tried_words(tried: list[dict], factor: float) -> str:
    """The narrowed passes tried and why the kept one, for the narrowing's note ('' with one pass)."""
    if len(tried) < 2:
        return ""
    each = ", ".join(f"{t['factor']:.3g}x {t['deviance_mean']:.3g}" for t in tried if t["deviance_mean"] is not None)
    return (
        f"; of the narrowings tried ({each}: the innovations' deviance per detection, lower explains the detections "
        f"better) {factor:.3g}x explains them best (run.json observer.filter.bias_priors.narrowed_tried)"
    )


def _deviance(tried: dict) -> float:
    """A narrowed pass's innovation deviance per tested detection (``inf`` when none was tested)."""
    return np.inf if tried["deviance_mean"] is None else tried["deviance_mean"]


def _deviance_gain(base: dict, other: dict) -> float:
    """How much lower ``other`` pass's innovation deviance is than ``base``'s, over ``base``'s tested detections
    (per-detection means: the passes may test different counts), the figure :func:`chosen_level`,
    :func:`ratio_climbing`, :func:`ratio_method` and :func:`stated_levels_note` hold against a χ² quantile."""
    return (base["deviance_mean"] - other["deviance_mean"]) * base["tested"]


def innovation_likelihood(tally: np.ndarray) -> dict:
    """The run's innovation deviance (−2 log-likelihood of the prediction errors, constants dropped) from ``tally``
    (row 8 of the state's ``win_sum``): the sum over the tested known-landmark detections of ``log det S + d²``,
    a gated detection's ``d²`` taken at the gate (``GATE_CHI2``: a level that gates everything pays for it), and
    their count; the mean per detection compares noise levels on one log (lower: the levels explain it better)."""
    n = int(tally[5])
    return {"tested": n, "deviance": float(tally[4]), "mean": float(tally[4] / n) if n else None}


def correlation_factor(lag_sums: np.ndarray, n: int, window: float = CORRELATION_WINDOW) -> dict:
    """The integrated autocorrelation ``ν = 1 + 2 Σ_{k≤M} ρ_k`` of the landmarks' consecutive whitened innovations
    (module docstring, "The pose's covariance widened"), from ``lag_sums`` (0: their summed squares, k: the summed
    products of each with its landmark's k-th last, pooled over the landmarks) and ``n`` innovations: ``ρ_k`` the
    lag sums over the squares, the window ``M`` the first with ``M ≥ window · ν`` (Sokal's; the last lag when none
    is), the standard error ``ν √(2 (2M + 1) / n)`` (Madras & Sokal 1988), applied when ``ν`` exceeds 1 by more than
    ``CORRELATION_SES`` of them. Public: tests/test_riekf.py checks it."""
    rec = {"nu": 1.0, "se": None, "window": 0, "innovations": int(n), "applied": False}
    if n < 2 or lag_sums[0] <= 0.0:
        return rec
    nu_m = 1.0 + 2.0 * np.cumsum(lag_sums[1:] / lag_sums[0])
    lags = np.arange(1, nu_m.shape[0] + 1)
    ok = np.flatnonzero(lags >= window * nu_m)
    m = int(lags[ok[0]] if ok.shape[0] else lags[-1])
    nu = float(nu_m[m - 1])
    se = abs(nu) * float(np.sqrt(2.0 * (2 * m + 1) / n))
    return {**rec, "nu": nu, "se": se, "window": m, "applied": bool(nu - CORRELATION_SES * se > 1.0)}


def correlation_note(rec: dict) -> list[str]:
    """The note of a pose covariance widened by :func:`correlation_factor`, else []."""
    if not rec["applied"]:
        return []
    return [
        f"riekf: the detections' errors are correlated over time (integrated autocorrelation ν = {rec['nu']:.3g} ± "
        f"{rec['se']:.2g} of {rec['innovations']} accepted innovations; 1 when independent): the same information "
        f"counted about ν times, the written pose σ is widened ×√ν (covariance ×ν; "
        f"observer.filter.correlation); the estimate and the map are unchanged"
    ]


def innovation_note(rec: dict) -> list[str]:
    """The note of a map covariance scaled by :func:`innovation_consistency`, else []."""
    if rec["landmark_covariance_factor"] == 1.0:
        return []
    return [
        f"riekf: the innovations are larger or more correlated than their covariance says (mean d² of "
        f"{rec['windows']} windows' summed innovations {rec['mean_window_d2']:.3g}, above the 97.5 % bound "
        f"{rec['bound']:.3g} of 3 DoF): the written landmark covariance is the filter's times "
        f"{rec['landmark_covariance_factor']:.3g} (observer.filter.innovation_consistency); the poses' is not scaled"
    ]


#: The noise key of the range-against-bearing ratio (``noise.ratio_by_deviance``: candidates of its own).
_RATIO = "detection_ratio"


def ratio_deviance(tally: np.ndarray) -> dict:
    """:func:`innovation_likelihood` with the vertical axis left out of each detection whose vertical innovation is
    exactly 0 (``tally[6]``: a planar rig's, whose vertical variance is the prior's and the detection's across share
    ``3/(ρ² + 2)`` of ``σ(r)²``, so that its ``log det`` falls with ρ at no cost in ``d²``: the trap batch's evidence
    met in riekf's shape, ``smoother.anisotropy``); the deviance that chooses ``detection_ratio``."""
    n = int(tally[5])
    return {"tested": n, "deviance": float(tally[6]), "mean": float(tally[6] / n) if n else None}


def ratio_climbing(tried: list[dict]) -> bool:
    """Whether riekf's ratio ladder goes on to the next ratio: while each pass's deviance falls below the one
    before by more than the χ² quantile ``LEVEL_CHOICE_P`` of one degree of freedom over that one's tested
    detections (batch's climb, ``smoother.anisotropy``: the deviance is not smooth in ρ, each pass's walk and
    bias-prior restarts its own, and the whole ladder's lowest took 6-r4 and 7-r4 of MR.CLAM to 16, 0.11-0.14 m
    worse; docs/benchmarks.md, "riekf learns the range-against-bearing ratio from its own innovations")."""
    if len(tried) < 2:
        return True
    last, before = tried[-1], tried[-2]
    if last["deviance_mean"] is None or before["deviance_mean"] is None:
        return False
    return _deviance_gain(before, last) > chi2_quantile(LEVEL_CHOICE_P, 1)


def ratio_method(tried: list[dict], chosen: int) -> str:
    """``detection_ratio``'s method once riekf chose it (run.json ``noise.levels``, the note): each ratio's
    deviance per tested detection and why the one used was kept."""

    def dev(t: dict) -> str:
        return "diverged" if t["deviance_mean"] is None else f"{t['deviance_mean']:.4g}"

    each = "; ".join(f"{t['levels'][_RATIO]:g}: {dev(t)}" for t in tried)
    one, used = tried[0], tried[chosen]
    best = min(tried, key=_deviance)
    if best is one or one["deviance_mean"] is None or best["deviance_mean"] is None:
        why = f"{used['levels'][_RATIO]:g} the lowest"
    else:
        gain = _deviance_gain(one, best)
        q = chi2_quantile(LEVEL_CHOICE_P, 1)
        why = f"{best['levels'][_RATIO]:g} the lowest, below 1's by {gain:.4g} over its {one['tested']} tested " + (
            f"detections, above the χ² quantile {q:.3g}" if used is best else f"detections, within {q:.3g}: 1 kept"
        )
    return f"{DEVIANCE_RATIO_METHOD}; per tested detection {each}; {why}"


def level_candidates(white) -> list[dict]:
    """The levels riekf tries where a stated covariance is more than ``1 / noise.STATED_LOW`` times above the
    samples' white-noise estimate (``white.above_samples``): the stated (as resolved) first, then every stated key
    above its samples' level (the other key too when it is above by less: with one key tight and the other loose
    riekf did worse than with both as stated, seed=3458 and seed=3626) at the samples' level, then (two keys) each
    alone; one candidate (the levels as resolved) elsewhere. A key whose odometry's own drift supports its stated
    level (``white.disputed()``, ``noise.drift_evidence``) is not tried. Each:
    ``which`` (key -> "stated" or "samples") and ``noise`` (the white levels, the swapped keys' source saying so)."""
    keys = white.disputed()
    if not any(stated_above(getattr(white, k), white.above_samples[k]) is not None for k in keys):
        if ratio_by_deviance(white):  # the detection ratios, one candidate each (noise.ratio_by_deviance)
            return [
                {"which": {_RATIO: r}, "noise": replace(white, detection_ratio=r)} for r in (1.0, *DETECTION_RATIOS)
            ]
        return [{"which": {}, "noise": white}]
    subsets = [(), tuple(keys)] + ([(k,) for k in keys] if len(keys) > 1 else [])
    out = []
    for swap in subsets:
        noise = white
        if swap:
            sources, methods = dict(white.sources), dict(white.methods)
            for k in swap:
                sources[k] = "the samples' white-noise estimate (riekf, over the stated covariance)"
                methods[k] = f"{white.sources.get(k)}, {white.methods.get(k)}; riekf tried the samples' level"
            noise = replace(
                white,
                **{k: np.asarray(white.above_samples[k], dtype=float) for k in swap},
                sources=sources,
                methods=methods,
            )
        out.append({"which": {k: "samples" if k in swap else "stated" for k in keys}, "noise": noise})
    return out


def chosen_level(tried: list[dict]) -> int:
    """Which of the candidate levels' passes (:func:`level_candidates`' order, the stated first) riekf keeps: the
    lowest innovation deviance per tested detection, unless the stated's is within the χ² quantile
    ``LEVEL_CHOICE_P`` (one degree of freedom per key changed) of it over the stated pass's tested detections (a
    tie keeps the stated: the message's word stands unless the detections say otherwise)."""
    best = min(range(len(tried)), key=lambda i: _deviance(tried[i]))
    stated = tried[0]
    if best == 0 or stated["deviance_mean"] is None:
        return best
    changed = sum(v != stated["levels"][k] for k, v in tried[best]["levels"].items())
    return best if _deviance_gain(stated, tried[best]) > chi2_quantile(LEVEL_CHOICE_P, changed) else 0


def stated_levels_note(rec: dict) -> list[str]:
    """The note of riekf's choice between stated levels above the samples' and the samples' (run.json
    ``observer.filter.stated_levels``)."""
    tried = rec["tried"]
    used = next(t for t in tried if t["levels"] == rec["used"])
    stated = tried[0]

    def dev(t: dict) -> str:
        return "diverged" if t["deviance_mean"] is None else f"{t['deviance_mean']:.3g}"

    each = "; ".join(f"{', '.join(f'{k} {v}' for k, v in t['levels'].items())}: {dev(t)}" for t in tried)
    samples = [k for k, v in rec["used"].items() if v == "samples"]
    kept = [k for k, v in rec["used"].items() if v == "stated"]
    said = []
    if samples:
        said.append(
            " and ".join(f"{k} at the samples' white-noise estimate {format_level(rec['samples'][k])}" for k in samples)
            + ", not the stated "
            + " and ".join(format_level(rec["stated"][k]) for k in samples)
        )
    if kept:
        said.append(
            " and ".join(f"{k} at the stated {format_level(rec['stated'][k])}" for k in kept)
            + " (above the samples' "
            + " and ".join(format_level(rec["samples"][k]) for k in kept)
            + ")"
        )
    best = min(tried[1:], key=_deviance)
    if samples:
        why = f"its innovations' deviance per tested detection {dev(used)} against {dev(stated)} as stated"
    elif best["deviance_mean"] is None or stated["deviance_mean"] is None:
        why = "the samples' level diverged"
    else:
        gain = _deviance_gain(stated, best)
        changed = sum(v == "samples" for v in best["levels"].values())
        by = (
            f"{-gain:.3g} higher"
            if gain <= 0
            else f"{gain:.3g} lower, not more than {rec['chi2_threshold'][str(changed)]:.3g}, the χ² quantile at "
            f"{LEVEL_CHOICE_P:.0%}"
        )
        why = (
            f"the samples' level{'s explain' if changed > 1 else ' explains'} the detections no better by a "
            f"likelihood-ratio test (its deviance over the {stated['tested']} tested detections {by})"
        )
    return [
        f"riekf: {'; '.join(said)}: {why} (tried over the first stretch: {each}; lower explains the detections "
        "better; run.json observer.filter.stated_levels; noise.gyro / noise.velocity in run.yaml set a level)"
    ]


def _plain_list(value) -> list[float]:
    return [float(x) for x in np.broadcast_to(np.asarray(value, dtype=float), (3,))]


def unresolved_gyro(noise):
    """riekf's levels (module docstring, "A gyro slower than its motion"): ``noise`` with its gyro level per axis at
    least ``UNRESOLVED_FACTOR`` times ``noise.gyro_unresolved`` (``noise`` itself when that is None or changes no
    axis), the gyro's method saying so."""
    if noise.gyro_unresolved is None:
        return noise
    raised = np.maximum(noise.gyro, UNRESOLVED_FACTOR * np.asarray(noise.gyro_unresolved, dtype=float))
    if np.array_equal(raised, noise.gyro):
        return noise
    return noise.scaled(
        {"gyro": raised / np.maximum(noise.gyro, 1e-300)}, by=f"riekf to {UNRESOLVED_FACTOR:g}x gyro_unresolved"
    )


def unresolved_note(white, used) -> list[str]:
    """The note of a gyro level raised by :func:`unresolved_gyro`, else []."""
    if np.array_equal(white.gyro, used.gyro):
        return []
    axes = ", ".join("xyz"[k] for k in np.flatnonzero(used.gyro != white.gyro))
    missed = format_level(np.asarray(white.gyro_unresolved).tolist())
    return [
        f"riekf: the gyro's rate does not resolve its motion on {axes} (the rotation its linear interpolation misses, "
        f"{missed} rad/s/sqrt(Hz), run.json noise.levels.gyro_unresolved): its level taken at "
        f"{format_level(used.gyro.tolist())} instead of the white {format_level(white.gyro.tolist())}; the floor's "
        "evidence and batch keep the white level"
    ]


def planar_evidence(
    vel_t: np.ndarray, omega: np.ndarray, velocity: np.ndarray, noise, velocity_period: float = 0.0
) -> dict:
    """Whether the body moves in a plane, from the log (module docstring, "Planar motion"): the standard deviation of
    the roll and pitch rates and of the vertical velocity over their noise per sample, each at its own stream's
    interval (:func:`noise_per_sample`); planar when none exceeds ``PLANAR_RATIO`` (what they measure is noise) and
    they are not all exactly zero, or where the roll or pitch rate exceeds it, the angle it integrates to spreads no
    more than ``PLANAR_TILT`` (:func:`tilt_spread`). That angle is computed only where it decides, ``tilt_rad`` null
    for a rate it was not needed for. ``velocity_period``: the linear velocity's own median interval (s) when it is
    interpolated onto the time base from a topic of its own (``AlignedStream.velocity_period_ns``), else 0.
    ``intervals_s``: the gyro's and the velocity's interval the noise was taken at; ``interpolated``: the share of
    the velocity's noise variance its interpolated samples keep (1 when not interpolated)."""
    if vel_t.shape[0] < 3:
        return {"planar": False, "ratios": None}
    span = float(vel_t[-1] - vel_t[0])
    sig_om, dt_om, _ = noise_per_sample(noise.gyro, omega, span)
    sig_v, dt_v, kept = noise_per_sample(noise.velocity, velocity, span, velocity_period)
    spread = (np.std(omega[:, 0]), np.std(omega[:, 1]), np.std(velocity[:, 2]))
    ratios = [
        float(x / sg) if sg > 0 else (0.0 if x == 0 else np.inf) for x, sg in zip(spread, (*sig_om[:2], sig_v[2]))
    ]
    # samples with no roll, pitch or vertical part at all (a planar log by construction: MR.CLAM's held commands)
    # keep the filter in its plane without the floor, which would only reshape the covariance
    planar = bool(ratios[2] <= PLANAR_RATIO and max(spread) > 0.0)
    tilt: list[float | None] = [None, None]
    for k in (0, 1):  # a wheeled robot on an uneven floor: real roll and pitch rates, a bounded roll and pitch
        # the angle integrated only where it decides (not when the vertical velocity, the rate or the other angle
        # has): 0.05 CPU s a rate on an hour's log, run.json's tilt_rad null where not computed
        if planar and not ratios[k] <= PLANAR_RATIO:
            angle = tilt_spread(vel_t, omega[:, k])
            tilt[k], planar = round(angle, 4), bool(angle <= PLANAR_TILT)
    return {
        "planar": planar,
        "ratios": [round(r, 3) for r in ratios],
        "tilt_rad": tilt,
        "intervals_s": [round(dt_om, 6), round(dt_v, 6)],
        "interpolated": round(kept, 4),
    }


def noise_per_sample(density, x: np.ndarray, span: float, period: float = 0.0) -> tuple[np.ndarray, float, float]:
    """A stream's white noise per sample as its samples ``x`` (N, 3) over ``span`` seconds show it: the density over
    the square root of its own interval, the longer of the mean interval between new values (a held command's noise
    is per command) and ``period`` (a stream's own interval when it is interpolated onto a faster time base, whose
    every sample is new); the standard deviation there times the square root of the share of the variance linearly
    interpolated samples keep, ``2/3 + 1/(3k²)`` for ``k`` time-base samples per own sample (1 at ``k = 1``, 2/3
    for many: between two samples of independent noise the interpolated value's variance is ``(1-a)² + a²`` of
    theirs, averaged over the phases ``a``). Returns the (3,) standard deviations, the interval and that share."""
    new = np.diff(x, axis=0) != 0.0  # the columns or'ed: np.any(axis=1) over rows of 3 took 3x as long
    between = span / max(1, int(np.count_nonzero(new[:, 0] | new[:, 1] | new[:, 2])))
    dt = max(between, float(period))
    k = dt / max(between, 1e-12)
    kept = 2.0 / 3.0 + 1.0 / (3.0 * k * k)
    sigma = np.broadcast_to(np.asarray(density, float), (3,)) / math.sqrt(max(dt, 1e-9)) * math.sqrt(kept)
    return sigma, dt, kept


def floor_decision(
    vel_t: np.ndarray, omega: np.ndarray, velocity: np.ndarray, noise, velocity_period: float = 0.0
) -> dict:
    """Whether the floor is held (module docstring, "Planar motion"; riekf's and batch's): the evidence of
    :func:`planar_evidence` with ``held`` (``noise.floor`` true, or ``auto`` and planar) and ``floor`` (the
    setting), run.json's ``planar`` record."""
    rec = planar_evidence(vel_t, omega, velocity, noise, velocity_period)
    rec["held"] = noise.floor is True or (noise.floor == "auto" and rec["planar"])
    rec["floor"] = noise.floor
    return rec


def pair_bias_prior(stream, noise) -> dict:
    """Where the biases start (module docstring, "Bias priors from detection pairs"): the estimate of
    :func:`pipeline.noise_estimation.pair_bias_estimate` with ``PAIR_PRIOR_SDS`` of its per-axis spreads as the
    prior's standard deviations, when both priors are the defaults and the pairs see at least
    ``PAIR_PRIOR_LANDMARKS`` landmarks; else ``used`` false and why (run.json ``observer.filter.bias_priors``)."""
    from slamobs.pipeline.noise_estimation import pair_bias_estimate

    if any(noise.sources.get(k, "default") != "default" for k in ("gyro_bias", "velocity_bias")):
        return {"used": False, "why": "a bias prior is given or estimated (noise: gyro_bias, velocity_bias)"}
    t0 = stream.t0_ns
    end = stream.vel_t_ns[0] + round(PAIR_PRIOR_WINDOW_S * 1e9)  # the log's first PAIR_PRIOR_WINDOW_S
    nv, nf = int(np.searchsorted(stream.vel_t_ns, end, side="right")), int(np.searchsorted(stream.det_t_ns, end))
    nd = int(stream.det_offsets[nf])
    est = pair_bias_estimate(
        (stream.vel_t_ns[:nv] - t0) * 1e-9,
        stream.omega[:nv],
        stream.velocity[:nv],
        (stream.det_t_ns[:nf] - t0) * 1e-9,
        stream.det_offsets[: nf + 1],
        stream.det_idx[:nd],
        stream.det_y[:nd],
        noise.detection_sigma,
        stream.segment_starts[stream.segment_starts < nv],
        (float(np.mean(np.square(noise.gyro))), float(np.mean(np.square(noise.velocity)))),
    )
    if est is None or est["landmarks"] < PAIR_PRIOR_LANDMARKS:
        seen = 0 if est is None else est["landmarks"]
        return {"used": False, "why": f"detection pairs of {seen} landmark(s), fewer than {PAIR_PRIOR_LANDMARKS}"}
    chi2 = round(est["chi2"], 4)
    if not chi2 <= PAIR_PRIOR_CHI2:
        return {"used": False, "chi2": chi2, "landmarks": est["landmarks"], "pairs": est["pairs"],
                "why": f"the pairs' residuals are {chi2:.3g} times their variance (at most {PAIR_PRIOR_CHI2:g}): "
                "constant biases, the detection law and the motion noise do not explain them"}  # fmt: skip
    # an estimate over a span knows the start's bias no better than the bias walks over it
    walk = np.repeat([noise.gyro_bias_walk, noise.velocity_bias_walk], 3) * math.sqrt(max(est["seconds"], 0.0))
    sigma = np.maximum(PAIR_PRIOR_SDS * np.maximum(est["sd"], est["sd_time"]) * math.sqrt(max(chi2, 1.0)), walk)
    return {
        "used": True,
        "bias": [round(float(x), 6) for x in est["bias"]],
        "sd": [round(float(x), 6) for x in est["sd"]],
        "sigma": [round(max(float(x), 1e-9), 6) for x in sigma],
        "landmarks": est["landmarks"],
        "pairs": est["pairs"],
        "seconds": round(est["seconds"], 3),
        "chi2": chi2,
        "sd_time": [round(float(x), 6) for x in est["sd_time"]],
        "what": "gyro (rad/s) then velocity (m/s) bias, body frame, measured = true + bias; sigma, the prior's "
        f"standard deviations: {PAIR_PRIOR_SDS:g} sd (the spread over resampled landmarks of a fit weighing each "
        "pair by its detections' and its dead reckoning's covariance) times sqrt(chi2) when above 1, at least the "
        "bias walk over the seconds it is made from; chi2, the mean squared whitened residual of the pairs",
    }


def tilt_spread(t: np.ndarray, rate: np.ndarray) -> float:
    """The standard deviation of the angle one rate integrates to, its mean (a constant bias) and then a linear trend
    (the bias's error) taken off: a wobble on a floor stays bounded, a body that rolls or pitches does not."""
    w = rate - np.mean(rate)
    ang = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))))
    ang -= np.polyval(np.polyfit(t - t[0], ang, 1), t - t[0])
    return float(np.std(ang))


def floor_plane(r0, p0, det_y: np.ndarray) -> np.ndarray:
    """The floor of :func:`_planar_update` through the start pose (its up axis the normal, its height the floor's),
    with the pseudo-measurements' levels and period, and the detections' median range (:func:`_reopen_heading`)."""
    n = np.array([0.0, 0.0, 1.0]) if r0 is None else np.asarray(r0, float)[:, 2]
    h = 0.0 if p0 is None else float(n @ np.asarray(p0, float))
    t1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    return np.r_[1.0, n, h, t1, t2, PLANAR_TILT, PLANAR_HEIGHT, PLANAR_EVERY_S, median_range(det_y)]


def median_range(det_y: np.ndarray) -> float:
    """The detections' median range (m); 1 without detections."""
    return float(np.median(np.linalg.norm(det_y, axis=1))) if det_y.shape[0] else 1.0


def max_variance_factor(det_y: np.ndarray, noise) -> float:
    """The largest variance factor a recovery may reach: the detection noise at the median range up to
    ``MAX_SIGMA_SHARE`` of that range (module docstring, "Recovery"); unbounded without detections."""
    if det_y.shape[0] == 0:
        return np.inf
    r = median_range(det_y)
    sigma = float(noise.detection_sigma(np.array([r]))[0])
    return (MAX_SIGMA_SHARE * r / sigma) ** 2 if sigma > 0 else np.inf


def _prior_notes(pri: dict) -> list[str]:
    """The note of the bias priors narrowed after a lost track, or of a narrowing that did not keep it
    (``observer.filter.bias_priors``; module docstring, "Bias priors narrowed")."""
    notes = []
    pp = pri.get("from_pairs") or {}
    if pp.get("used"):
        g, v = np.asarray(pp["bias"][:3]), np.asarray(pp["bias"][3:])
        notes.append(
            f"riekf: the biases start at the detection pairs' estimate ({pp['landmarks']} landmarks; gyro "
            f"{np.linalg.norm(g):.3g} rad/s, velocity {np.linalg.norm(v):.3g} m/s in norm; the pairs' residuals "
            f"{pp['chi2']:.3g} times their variance) with {PAIR_PRIOR_SDS:g} times its spread (over resampled "
            "landmarks and blocks of time; at least the bias walk over the seconds used) as the priors, not 0 with "
            "the gyro_bias and velocity_bias levels (run.json observer.filter.bias_priors.from_pairs)"
        )
    elif "dropped" in pp:
        notes.append(
            f"riekf: the biases started at the detection pairs' estimate and {pp['dropped']}; run again from the "
            "start at 0 with the gyro_bias and velocity_bias priors (run.json observer.filter.bias_priors.from_pairs)"
        )
    elif "chi2" in pp:  # estimated and not used: say why
        notes.append(
            f"riekf: the detection pairs' bias estimate is not used ({pp['why']}: slip, a walking bias or motion "
            "noisier than its level?); the biases start at 0 with the gyro_bias and velocity_bias priors (run.json "
            "observer.filter.bias_priors.from_pairs)"
        )
    runs = ", ".join(str(r) for r in pri.get("gated_in_a_row_before", []))
    if pri.get("narrowed_passes") and not pri["kept"]:
        notes.append(
            f"riekf: {max(pri['gated_in_a_row_at_end'], pri.get('gated_in_a_row_longest', 0))} known-landmark "
            "detections in a row failed the gate (the track lost); with the bias priors narrowed up to "
            f"{PRIOR_NARROWING ** pri['narrowed_passes']:.3g}x the runs held such a run too ({runs} in a row), so "
            "they stay as they were: most likely not the biases (a moved "
            "landmark, a clock or frame error; run.json observer.filter.bias_priors)"
        )
    elif pri.get("narrowed_passes"):
        notes.append(
            f"riekf: run again from the start with the bias priors narrowed {pri['factor']:.3g}x (gyro_bias "
            f"{pri['gyro_bias']:.3g} rad/s, velocity_bias {pri['velocity_bias']:.3g} m/s): with wider ones "
            f"{runs} known-landmark detection(s) in a row failed the gate (the track lost; a bias learned from few "
            "landmarks most likely carried the pose off; run.json observer.filter.bias_priors; noise: gyro_bias, "
            "velocity_bias fix them)" + _tried_words(pri.get("narrowed_tried") or [], pri["factor"])
        )
    tail = int(pri.get("gated_in_a_row_at_end") or 0)
    if tail >= TAIL_NOTE_IN_A_ROW and not (pri.get("narrowed_passes") and not pri["kept"]):
        notes.append(
            f"riekf: its last {tail} known-landmark detections in a row failed the gate (status gated_at_end): the "
            "pose at the log's end is most likely off by more than its σ says (a bias carried through a stretch "
            "without landmarks, say) or those detections are wrong"
            + (
                f"; under {LOST_IN_A_ROW} in a row the run is not started again with narrower bias priors"
                if tail < LOST_IN_A_ROW
                else ""
            )
            + " (run.json observer.filter.bias_priors.gated_in_a_row_at_end)"
        )
    return notes


def recovery_notes(filt: dict) -> list[str]:
    """What the recovery did, for the run's notes: one line per recovery (the first few), and an ``error:``
    line when the filter gave up (its trajectory is not to be trusted after that time)."""
    notes = []
    for r in filt["recovery_log"][:5]:
        grown = np.sqrt(r["detection_factor"])  # 'now x1 in standard deviation' said it was left alone
        det = "unchanged" if grown == 1.0 else f"{grown:.3g} times its standard deviation"
        if r["action"] == RECOVERY_ACTIONS[4]:  # the give-up's factor, not applied (module docstring, "Recovery")
            notes.append(
                f"riekf: at {r['t_s']:.2f} s most detections of a window of {WINDOW} failed the gate: recovered by "
                f"re-initialising the landmarks that failed it before any of their detections passed, no noise "
                f"changed (the detection variances would have needed a factor of {r['factor']:.3g}, beyond what a "
                "detection can have)"
            )
            continue
        notes.append(
            f"riekf: at {r['t_s']:.2f} s most detections of a window of {WINDOW} failed the gate: recovered by "
            f"multiplying {r['action']} by {r['factor']:.3g} (detection noise {det})"
        )
    for r in filt.get("blind", [])[:5]:
        notes.append(
            f"riekf: at {r['t_s']:.2f} s, after {r['blind_s']:.1f} s without a known landmark's detection, the first "
            f"{BLIND_WINDOW} that followed did not fit the pose ({100 * r['gated_share']:.0f} % failed the gate): "
            f"the position's covariance was re-opened to {r['position_sigma_m']:.3g} m on each axis and the "
            "re-observed landmarks re-anchored it (run.json observer.filter.blind)"
        )
    walk = filt.get("walk") or {}
    gyro = walk.get("gyro") or {}
    said = (
        ("velocity", "m/s/sqrt(s)", "a slowly varying velocity error, such as wheel slip", walk, "given_m_s_sqrt_s"),
        ("gyro", "rad/s/sqrt(s)", "a gyro bias that drifts", gyro, "given_rad_s_sqrt_s"),
    )
    for name, unit, what, w, given in said:
        if w and w["start_walk"] > w[given]:
            notes.append(
                f"riekf: {name}-bias walk learned from the log: {w[given]:.3g} -> {w['start_walk']:.3g} {unit} from "
                f"the start ({walk['passes'] - 1} run(s) again): the {name}-bias corrections over "
                f"{CONSISTENCY_WINDOWS} windows of {WINDOW} detections reached over {RESTART_RATIO:g} times the size "
                f"(squared) a consistent filter expects: {what}, that the noise model lacked (run.json "
                f"observer.filter.walk; noise: {name}_bias_walk fixes it)"
            )
        raises = [r for r in walk.get("raises") or [] if r.get("bias", "velocity") == name]
        if raises:
            first = raises[0]
            notes.append(
                f"riekf: {name}-bias walk learned from the log: {w[given]:.3g} -> "
                f"{w[f'{name}_bias_walk']:.3g} {unit} ({len(raises)} raise(s), the first at {first['t_s']:.2f} s): "
                f"over {CONSISTENCY_WINDOWS} windows of {WINDOW} detections the {name}-bias corrections were "
                f"{first['ratio']:.3g} times the size (squared) a consistent filter expects: {what} (run.json "
                f"observer.filter.walk; noise: {name}_bias_walk fixes it)"
            )
    notes += _prior_notes(filt.get("bias_priors") or {})
    con = filt.get("consistency") or {}
    if con.get("overconfident"):
        first = con["log"][0]
        notes.append(
            f"riekf: overconfident from {first['t_s']:.2f} s ({con['overconfident']} time(s)): over "
            f"{CONSISTENCY_WINDOWS} windows of {WINDOW} detections that passed the gate, the Mahalanobis distance² "
            f"of each window's summed innovations had a median of {first['median_d2']:.3g} (a consistent filter: "
            f"{CHI2_MEDIAN_3}): its errors are correlated in time, the covariance understates them and the trajectory "
            "may be further off than it says (a slowly varying error the noise model lacks, such as wheel slip; "
            "run.json observer.filter.consistency)"
        )
    if filt["recoveries"] > 5:
        notes.append(f"riekf: {filt['recoveries']} recoveries in all (run.json observer.filter.recovery_log)")
    if filt["landmarks_reinitialised"]:
        notes.append(
            f"riekf: {filt['landmarks_reinitialised']} landmark(s) re-initialised from the pose after failing "
            "the gate through two recoveries in a row, or before ever passing it in a window no noise explains"
        )
    if filt["status"] == "lost":
        again = filt.get("passing_again_at_s")
        tail = (
            "keep failing the gate after {} recoveries ({}); the trajectory after that time is not an estimate"
            if again is None
            else "failed the gate after {} recoveries ({}); they passed it again, at that noise, from "
            f"{again:.2f} s to the end (the filter kept updating, without recoveries): the trajectory from "
            f"{filt['lost_at_s']:.2f} s to {again:.2f} s is not an estimate, and after it no closer than that noise "
            "lets the gate tell"
        )
        factor = f"detection noise factor {filt['detection_noise_factor']:.3g}"
        notes.append(
            f"error: riekf: lost the log at {filt['lost_at_s']:.2f} s: most detections "
            f"{tail.format(filt['recoveries'], factor)} (check the noise settings, the detections' frames and the "
            "time stamps)"
        )
    return notes


#: Share of the detections rejected by the gate above which the run says so (a few are outliers; most, a noise model
#: that does not fit the log).
GATED_NOTE_SHARE = 0.5


def _unused_note(skipped: int, frames: int, gated: int, detections: int) -> list[str]:
    """Say when the filter left much of the log unused: frames whose innovation covariance was not positive
    definite, or detections gated as outliers (noise.gyro 1e6 left 896 of 898 frames unused, and the run
    reported a 14 m map error without a word on why)."""
    notes = []
    if skipped:
        notes.append(
            f"riekf: {skipped} of {frames} detection frames not used: their innovation covariance was not "
            "positive definite (the noise settings are far from this log's; see run.json observer.filter)"
        )
    if detections and gated > GATED_NOTE_SHARE * detections:
        notes.append(
            f"riekf: {gated} of {detections} detections rejected by the chi-square gate ({GATE_CHI2}): "
            "noise.detection is too small for these detections, or the estimate is lost"
        )
    return notes


SPEC = ObserverSpec(
    name="riekf",
    algorithm="RI-EKF",
    paper="Barrau & Bonnabel: An EKF-SLAM algorithm with consistency properties (2015); state on SE_{1+n}(3) + biases",
    summary="right-invariant EKF SLAM with gyro and velocity biases; noise from the `noise` section of run.yaml",
    gains=(),
    start=RiEKF,
    takes_known_map=False,
    uses_noise=True,
    own_time_offset=True,
    interpolates=True,
)
