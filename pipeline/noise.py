"""Noise levels of the reference estimators (``batch``, ``riekf``): the ``noise`` section of ``run.yaml``
key by key, else what the log's own samples show (``auto``, the default: :mod:`pipeline.noise_estimation`),
with the log's message covariances (:mod:`pipeline.readers.covariance`) preferred where they are plausible,
else documented defaults.

Velocity noises are white-noise densities, so that one number describes a sensor at any rate: a
per-sample standard deviation σ at period T is the density σ·√T. The defaults are the simulator's sensors
(:class:`pipeline.simulate.NoiseModel` at its default rates); a detection's standard deviation per axis grows
with range r: ``detection + detection_per_m * r + detection_per_m2 * r²`` (a fiducial detector's linear law,
the stereo / PnP law in r²), the mean over the three axes: with ``detection_ratio`` ρ the range's variance is
``3ρ²/(ρ² + 2)`` times that and each axis across it ``3/(ρ² + 2)`` times (riekf, and batch when the key is set
in the configuration; otherwise batch weighs range and bearing apart by its own evidence).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from slamobs.pipeline.alignment import stream_topics
from slamobs.pipeline.noise_estimation import (
    median_rate,
    LAWS,
    MIN_LEVEL,
    DetectionLaw,
    Estimate,
    HeldMotion,
    azimuths_from_degrees,
    detection_law,
    detection_ratio,
    held_motion_noise,
    log_triplets,
    twist_drift,
    unresolved_motion_density,
    white_noise_density,
)

if TYPE_CHECKING:
    from collections.abc import Mapping

    from slamobs.pipeline.readers.covariance import StatedNoise

#: the keys of the detection law (the ratio apart)
DETECTION_LAW_KEYS = ("detection", "detection_per_m", "detection_per_m2")
#: key -> (default, unit, meaning); the config schema lists the same keys.
DEFAULTS: dict[str, tuple[float, str, str]] = {
    "gyro": (0.005 * np.sqrt(1 / 200), "rad/s/sqrt(Hz)", "angular-velocity white-noise density"),
    "velocity": (0.02 * np.sqrt(1 / 50), "m/s/sqrt(Hz)", "linear-velocity white-noise density"),
    "detection": (0.01, "m", "detection standard deviation per axis at zero range"),
    "detection_per_m": (0.002, "m/m", "growth of the detection standard deviation with range"),
    "detection_per_m2": (0.0, "m/m^2", "growth of the detection standard deviation with range squared"),
    "detection_ratio": (
        1.0,
        "",
        "a detection's standard deviation along its line of sight over that across (riekf; batch when set)",
    ),
    "gyro_bias": (0.2, "rad/s", "prior standard deviation of each gyro-bias component (unknown start)"),
    "velocity_bias": (0.2, "m/s", "prior standard deviation of each velocity-bias component"),
    "gyro_bias_walk": (1e-4, "rad/s/sqrt(s)", "gyro-bias random walk (riekf; batch with bias: random-walk)"),
    "velocity_bias_walk": (1e-4, "m/s/sqrt(s)", "velocity-bias random walk (as gyro_bias_walk)"),
}
#: The detections "scatter" when the estimated law's σ at their middle range (the geometric mean of the 5th and 95th
#: percentile the law was fitted on) is over this share of that range: their directions look random within 1 s, no
#: noise an estimator can weigh (bearings in degrees: MR.CLAM 6 r1 0.52, generated figure 8s 0.28-0.29, missed on a
#: ground robot, a circle and a loop at 0.10-0.17; as recorded, 13 real logs 0.0017-0.021, 16 generated and sample
#: logs 0.0013-0.10, the most on 7 px stereo: docs/benchmarks.md "Silent wrong results, round 5").
SCATTERED_SHARE = 0.25
#: Below ``SCATTERED_SHARE`` the detections' azimuths are read again as degrees (:func:`degrees_note`) when their
#: scatter share is over ``DEGREES_FROM_SHARE``; they are named when that reading scatters ``DEGREES_RATIO`` times
#: less than as read (bearings in degrees on generated ground, circle, loop logs: 0.10-0.17 as read, 30-40x less;
#: as recorded 0.62-1.0 on MR.CLAM, whose shares stay under 0.03 anyway, 1.0 on the 5-7 px stereo logs over
#: 0.03, 1.2-1.3 on generated figure 8s, loops, circles; docs/benchmarks.md "Silent wrong results, round 6").
DEGREES_FROM_SHARE, DEGREES_RATIO = 0.03, 8.0
#: The held streams' fit (:func:`held_levels`) may scale the detection law by no less than this: the detections
#: cannot be quieter over seconds than they scatter within 1 s. Below it the fit gave the pairs' whole spread to
#: the motion (MR.CLAM 6 r1 mirrored: 1e-6, σ 1.9e-8 m; a generated figure 8 with its velocities held for 3-30
#: samples: 1e-6); as recorded the 10 MR.CLAM robots give 1.18-3.33 (docs/benchmarks.md "Silent wrong results,
#: round 6").
HELD_SCALE_FLOOR = 0.1
#: keys that may come from the log's message covariances, and the role whose topic states them
STATED = {"gyro": "angular_velocity", "velocity": "linear_velocity"}
#: a stated density more than ``1 / STATED_LOW`` times below or above the samples' estimate (the worst axis) is
#: named in a run's notes and ``info --noise``, not called plausible (robot_localization test2's IMU 0.47 and the
#: ETH MSF dataset's 0.79-1.07 are plausible; docs/benchmarks.md "A new user's first hour, round 17", "Logs nobody
#: has run yet", session 31)
STATED_LOW = 1 / 3
#: a stated density under ``STATED_BELOW`` times the samples' estimate on any axis is not believed (the sensor
#: claims less noise than its samples show; the samples' level is used): a VIO's optimistic covariance believed at
#: 0.15x-0.3x its samples cost riekf up to 5.8x its APE with the true levels on generated logs, and TagSLAM 22's
#: T265 gyro (0.14x) is now rejected: riekf 0.200 -> 0.241 m, batch 0.171 -> 0.108 (docs/benchmarks.md "A stated
#: covariance 3-10x below its samples", session 32). Up to ``STATED_ABOVE`` times the estimate it is believed: the
#: samples' high-frequency content is a lower bound of noise that is coloured (a VIO's or a filtered
#: odometry's), which a driver may know better
STATED_BELOW, STATED_ABOVE = STATED_LOW, 100.0
#: The χ² probability of the likelihood-ratio tests between a stated level above the samples' and the samples'
#: (one degree of freedom per key changed): riekf's on its detections (``observers.riekf.chosen_level``) and the
#: odometry's own drift (:func:`drift_evidence`).
LEVEL_CHOICE_P = 0.99
#: Ratios of a detection's range standard deviation to its across-the-line one tried after 1 (isotropic): batch's
#: evidence climbs them (``smoother.anisotropy``); riekf runs each as a pass and keeps the lowest innovation deviance
#: where the turn rate is held and the triplets found no ratio (:func:`ratio_by_deviance`).
DETECTION_RATIOS = (2.0, 4.0, 8.0, 16.0, 32.0)
#: ``detection_ratio``'s method where riekf chooses it (:func:`ratio_by_deviance`): ``info --noise`` says it, riekf's
#: run.json adds the deviances and the choice.
DEVIANCE_RATIO_METHOD = (
    "riekf's innovation deviance over ρ = 1, "
    + ", ".join(f"{r:g}" for r in DETECTION_RATIOS)
    + " (a pass each, upwards while the deviance falls by more than the χ² quantile "
    + f"{LEVEL_CHOICE_P:g}; the vertical axis left out of a detection whose vertical innovation is 0), the lowest kept "
    "unless 1's is within that quantile of it: the turn rate is held and the triplets within 1 s cannot see a range "
    "error that changes slowly"
)
#: Horizons (s) over which an odometry's twist is integrated against its own poses (:func:`drift_evidence`): the
#: longest of them the stream holds ``DRIFT_WINDOWS`` disjoint windows of is tested (a choice, not fitted: the
#: horizons a filter dead-reckons between detections run from about one second to the blind stretches of tens of
#: seconds; eight windows give 24 squared differences; past 16 s a VIO's own pose drift enters the difference)
DRIFT_HORIZONS_S = (1.0, 2.0, 4.0, 8.0, 16.0)
DRIFT_WINDOWS = 8


@dataclass(frozen=True)
class NoiseConfig:
    """The ``noise`` section of run.yaml as given: None = not set (estimated from the log when ``auto``, the log's
    plausible message covariance for ``gyro`` and ``velocity``, else the default in :data:`DEFAULTS`)."""

    auto: bool = True
    gyro: float | tuple[float, float, float] | None = None
    velocity: float | tuple[float, float, float] | None = None
    detection: float | None = None
    detection_per_m: float | None = None
    detection_per_m2: float | None = None
    detection_ratio: float | None = None
    gyro_bias: float | None = None
    velocity_bias: float | None = None
    gyro_bias_walk: float | None = None
    velocity_bias_walk: float | None = None
    #: the floor of riekf and batch (pipeline.observers.riekf, "Planar motion"): "auto" held when the log shows
    #: planar motion, true always, false never
    floor: str | bool = "auto"

    @classmethod
    def from_section(cls, section: dict | str | None) -> NoiseConfig:
        if section is None or section == "auto":
            return cls()
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in (section or {}).items()})

    def given(self) -> dict:
        """The keys set, with their values."""
        return {k: v for k in DEFAULTS if (v := getattr(self, k)) is not None}


@dataclass(frozen=True)
class NoiseSettings:
    gyro: np.ndarray  # (3,) rad/s/sqrt(Hz)
    velocity: np.ndarray  # (3,) m/s/sqrt(Hz)
    detection: float
    detection_per_m: float
    detection_per_m2: float
    gyro_bias: float
    velocity_bias: float
    gyro_bias_walk: float
    velocity_bias_walk: float
    detection_ratio: float = 1.0
    #: the factor on the estimated detection law for the detections' slow error (held streams: from pairs of
    #: detections over seconds), which batch leaves out where it models that error by their correlation in time
    detection_held_scale: float = 1.0
    #: key -> "config", "default", "<topic> covariance (<rate> Hz by the median interval)" or "estimated"
    sources: dict[str, str] = field(default_factory=dict)
    #: key -> how an estimated level was found, and its standard error (same shape as the value)
    methods: dict[str, str] = field(default_factory=dict)
    uncertainty: dict[str, object] = field(default_factory=dict)
    #: what was estimated, rejected or could not be told, in words
    notes: tuple[str, ...] = ()
    #: keys estimated from the detections because their stream holds its values (commanded velocities)
    held: tuple[str, ...] = ()
    #: detection-law keys the estimated law has no term for (0 by its form, not measured): :meth:`lines` leaves
    #: them out, run.json's ``levels`` says so in their method
    absent: tuple[str, ...] = ()
    #: the floor (riekf's and batch's) as configured (:attr:`NoiseConfig.floor`)
    floor: str | bool = "auto"
    #: (3,) rad/s/sqrt(Hz): the rotation the gyro's rate does not resolve, as a density (``LogNoise.gyro_unresolved``;
    #: None when the gyro's level is configured or the log cannot tell); riekf's gyro level takes it
    #: (``observers.riekf.unresolved_gyro``), batch and the floor's evidence read ``gyro``, the white level
    gyro_unresolved: np.ndarray | None = None
    #: key (gyro, velocity) -> the samples' white-noise estimate, where the level is a message's stated covariance
    #: above it on some axis: where one is more than ``1 / STATED_LOW`` times above (:func:`stated_above`), riekf
    #: runs its first stretch at both and keeps the one its innovations explain better (``observers.riekf``,
    #: "Stated levels above the samples")
    above_samples: dict[str, np.ndarray] = field(default_factory=dict)
    #: key -> :func:`drift_evidence` of the stream's twist against its own poses, where ``above_samples`` holds
    #: the key and the messages carry poses: ``stated`` True keeps the stated level without riekf's test
    #: (:meth:`disputed`)
    drift: dict[str, dict] = field(default_factory=dict)

    def of_estimator(self, name: str) -> NoiseSettings:
        """These levels as estimator ``name`` takes them: the choice of ``detection_ratio`` by riekf's passes
        (:func:`ratio_by_deviance`, its method :data:`DEVIANCE_RATIO_METHOD`) is riekf's alone; batch starts from
        the default 1 and weighs range against bearing by its own evidence (``smoother.anisotropy``, its note), so
        its notes and run.json name no method of riekf's."""
        if name == "riekf" or self.methods.get("detection_ratio") != DEVIANCE_RATIO_METHOD:
            return self
        return replace(self, methods={k: v for k, v in self.methods.items() if k != "detection_ratio"})

    def disputed(self) -> list[str]:
        """The keys of ``above_samples`` whose stated level riekf tests against the samples' on its detections:
        every one but those the odometry's own long-horizon drift supports at the stated level (``drift``)."""
        return [k for k in self.above_samples if not self.drift.get(k, {}).get("stated")]

    def as_dict(self) -> dict:
        """For run.json: every value and where it came from, and per key its unit, method and uncertainty."""
        out = {k: _plain(getattr(self, k)) for k in DEFAULTS}
        levels = {
            k: {
                "value": out[k],
                "unit": DEFAULTS[k][1],
                "source": self.sources.get(k, "default"),
                "method": self.methods.get(k),
                "uncertainty": _plain(self.uncertainty.get(k)),
            }
            for k in DEFAULTS
        }
        if self.gyro_unresolved is not None:
            levels["gyro_unresolved"] = {
                "value": _plain(self.gyro_unresolved),
                "unit": DEFAULTS["gyro"][1],
                "source": "estimated",
                "method": self.methods.get("gyro_unresolved"),
                "uncertainty": _plain(self.uncertainty.get("gyro_unresolved")),
            }
        return {**out, "sources": dict(self.sources), "levels": levels, "notes": list(self.notes)}

    def scaled(self, factors: dict[str, float | np.ndarray], by: str | None = None) -> NoiseSettings:
        """These levels with each key of ``factors`` multiplied by its factor (a factor of 1 leaves the key as it
        is; an array scales a three-axis level per axis); ``by`` (what chose the factors) is added to the scaled
        keys' methods."""
        changes = {k: getattr(self, k) * f for k, f in factors.items() if np.any(np.asarray(f) != 1.0)}
        if not changes:
            return self
        if by is None:
            return replace(self, **changes)
        methods = dict(self.methods)
        for k in changes:
            was = methods.get(k) or self.sources.get(k, "default")
            f = np.asarray(factors[k], dtype=float)
            said = f"{float(f):g}" if f.ndim == 0 else f"({', '.join(f'{x:g}' for x in f)}) per axis"
            methods[k] = f"{was}; scaled by {said} by {by}"
        return replace(self, **changes, methods=methods)

    def detection_sigma(self, ranges: np.ndarray) -> np.ndarray:
        r = np.asarray(ranges, dtype=float)
        return self.detection + self.detection_per_m * r + self.detection_per_m2 * r * r

    def ratio_split(self) -> tuple[float, float]:
        """The factors of the law's ``σ(r)²`` across the line of sight and along it for ``detection_ratio``,
        their trace kept (``σ(r)`` is the mean over the three axes): ``3/(ρ² + 2)`` and ``3ρ²/(ρ² + 2)``."""
        ratio2 = self.detection_ratio**2
        return 3.0 / (ratio2 + 2.0), 3.0 * ratio2 / (ratio2 + 2.0)

    def lines(self) -> list[str]:
        """One line per level: value, unit, source, uncertainty and method."""
        out, said = [], {}
        for k, (_, unit, _meaning) in DEFAULTS.items():
            if k in self.absent:
                continue
            value, se = _plain(getattr(self, k)), _plain(self.uncertainty.get(k))
            text = f"{k} = {format_level(value)}{' ' * bool(unit)}{unit} ({self.sources.get(k, 'default')}"
            text += f", ± {format_level(se)}" if se is not None else ""
            method = self.methods.get(k)
            if k == "detection_ratio" and method == DEVIANCE_RATIO_METHOD:  # no value before riekf's passes
                out.append(
                    "detection_ratio: chosen in riekf's run by its passes, ρ = 1 only the first (riekf's note names"
                    f" the one kept): {method}"
                )
                continue
            text += ")" if method is None else ": the same fit)" if method in said else f": {_told(method, said)})"
            said.setdefault(method, k)
            out.append(text)
        if self.gyro_unresolved is not None:
            se = self.uncertainty.get("gyro_unresolved")
            out.append(
                f"gyro_unresolved = {format_level(_plain(self.gyro_unresolved))} {DEFAULTS['gyro'][1]} (estimated"
                + (f", ± {format_level(_plain(se))}" if se is not None else "")
                + f": {self.methods.get('gyro_unresolved')}; riekf's gyro level takes it where above the white one, "
                "batch's does not)"
            )
        return out


def _told(method: str, said: dict) -> str:
    """``method`` with a method a line above gave in full (a fit that scaled this level too) named by its level."""
    for m, k in said.items():
        if m and f"({m})" in method:
            method = method.replace(f"({m})", f"(the same fit as {k})")
    return method


def _plain(value):
    """A NumPy value as plain Python for JSON."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    return float(value) if isinstance(value, np.floating) else value


def format_level(value, digits: int = 3, brackets: bool = True) -> str:
    """A level (one number, or a list of one per axis) in ``digits`` significant digits, a list in brackets unless
    ``brackets`` is False: the notes' form here, and ``info --noise``'s (4 digits, no brackets)."""
    if isinstance(value, list):
        inner = ", ".join(f"{v:.{digits}g}" for v in value)
        return f"[{inner}]" if brackets else inner
    return f"{value:.{digits}g}"


@dataclass(frozen=True)
class LogNoise:
    """What a log's own samples say about its noise (``noise: auto``): an estimate per stream, None where the
    log cannot tell (too short, no repeated landmark), and notes saying so."""

    gyro: Estimate | None
    velocity: Estimate | None
    detection: DetectionLaw | None
    notes: tuple[str, ...] = ()
    #: levels of held (commanded) streams and their bias priors, from detection pairs (:func:`held_levels`)
    held: dict[str, Estimate] = field(default_factory=dict)
    #: a detection's standard deviation along its line of sight over that across (None: not told from 1)
    ratio: Estimate | None = None
    #: the density of the rotation the gyro's rate does not resolve (``noise_estimation.unresolved_motion_density``)
    gyro_unresolved: Estimate | None = None

    def levels(self) -> dict[str, Estimate]:
        """Key of :data:`DEFAULTS` -> its estimate (the detection law sets all three detection keys)."""
        out = {k: e for k, e in (("gyro", self.gyro), ("velocity", self.velocity)) if e is not None}
        out.update(self.held)
        law = self.detection
        if law is not None:
            out["detection"] = law.base
            for _, (power, key) in LAWS.items():
                out[key] = law.slope if power == law.power else Estimate(0.0, 0.0, law.slope.method, law.slope.samples)
        if self.ratio is not None:
            out["detection_ratio"] = self.ratio
        return out

    def absent_terms(self) -> tuple[str, ...]:
        """The detection-law keys the chosen law has no term for (the linear law has no r² term)."""
        law = self.detection
        return () if law is None else tuple(key for power, key in LAWS.values() if power != law.power)


def stream_density(t_ns: np.ndarray, xyz: np.ndarray) -> Estimate | None:
    """The white-noise density of one velocity stream as recorded (stamps in ns)."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    return white_noise_density((t_ns - (t_ns.min() if t_ns.size else 0)) * 1e-9, xyz) if t_ns.size else None


#: The levels a log's own sensor streams show with none of the other inputs (``slamobs info --noise`` on a log that
#: cannot run): the level's name, the stream's role (``LogStreams``) and unit; the accelerometer's and the
#: magnetometer's are no estimator's.
SENSOR_LEVELS = (
    ("gyro", "angular_velocity", DEFAULTS["gyro"][1]),
    ("velocity", "linear_velocity", DEFAULTS["velocity"][1]),
    ("accelerometer", "accel", "m/s^2/sqrt(Hz)"),
    ("magnetometer", "magnetic", "T/sqrt(Hz)"),
)


def sensor_levels(streams) -> dict[str, dict]:
    """The white-noise density of each of ``SENSOR_LEVELS``' streams a read log (``LogStreams``) holds, each on its
    own stamps (:func:`stream_density`), without aligning it to anything: name -> value (per axis), unit, topic,
    standard error, method; or, where it has no stream or too few samples, why not (``why``, with what the reader
    said of the topic: e.g. its NaN/Inf samples dropped, which leave the level to the finite ones). Where the messages
    state a covariance (gyro, velocity), ``stated``: its density, topic, rate, and whether riekf and batch would
    use it in place of the samples' level (``used``, as :func:`resolve_noise` judges it; ``why`` not)."""
    out: dict[str, dict] = {}
    for name, role, unit in SENSOR_LEVELS:
        stream = getattr(streams, role, None)
        found = stream_density(stream.t_ns, stream.xyz) if stream is not None and len(stream) else None
        if found is None:
            if stream is None:
                out[name] = {"why": f"no {role} stream"}
                continue
            said = [w for w in streams.warnings if w.startswith(f"{stream.topic}:")]  # e.g. every other sample NaN
            out[name] = {
                "why": f"too few consecutive samples on {stream.topic} ({len(stream)} read"
                + "".join(f"; {w}" for w in said)
                + ")"
            }
            continue
        if found.held and all(found.held):  # sparkfun_razor's /imu/mag: 103 values in 2144 messages, "7.9e-22 T"
            out[name] = {"why": f"the samples on {stream.topic} {HELD_SAMPLES}"}
            continue
        out[name] = {
            "value": _plain(found.value),
            "unit": unit,
            "topic": stream.topic,
            "uncertainty": _plain(found.uncertainty),
            "method": found.method,
        }
        stated = streams.stated_covariance.get(STATED.get(name, ""))
        if stated is not None:  # what riekf and batch would take before the samples' level (resolve_noise)
            said: list[str] = []
            used = _believed(name, stated, found, said) is not None
            out[name]["stated"] = {
                "value": _plain(stated.density) if stated.problem is None else None,
                "topic": stated.topic,
                "rate_hz": 1.0 / stated.period_s,  # one over the median interval (noise_estimation.median_rate)
                "rate": median_rate(stated.period_s),
                "used": used,
                "why": stated.problem or "; ".join(n.removeprefix("noise: ") for n in said),
                #: how many times quieter than the samples' level, when more than 1 / STATED_LOW (else None)
                "below": stated_below(stated.density, found.value) if stated.problem is None else None,
                #: how many times louder than the samples' level, when more than 1 / STATED_LOW (else None)
                "above": stated_above(stated.density, found.value) if stated.problem is None else None,
            }
    return out


def _stream_arrays(aligned) -> tuple:
    """What the detection-based estimators read of an aligned stream: velocity stamps (s from the start), angular
    and linear velocity, detection stamps (s), the frames' offsets, landmark ids and body-frame points."""
    t = (aligned.vel_t_ns - aligned.t0_ns) * 1e-9
    det_t = (aligned.det_t_ns - aligned.t0_ns) * 1e-9
    return t, aligned.omega, aligned.velocity, det_t, aligned.det_offsets, aligned.det_idx, aligned.det_y


def of_derived(settings: NoiseSettings, how: str | None) -> NoiseSettings:
    """``settings`` with the gyro level's method saying that the angular velocity it is the noise of was not measured
    but derived, ``how`` (run.json ``input.derived``'s words: an angular velocity differentiated from an odometry's
    orientations, TagSLAM test_11's VIO twist having no angular part, gives a gyro level of that differentiation, not
    of a gyro); unchanged without ``how`` or for a level of the config or the default. The one wording of
    ``info --noise``'s gyro line and run.json's gyro ``method``."""
    if not how or settings.sources.get("gyro", "default") in ("config", "default"):
        return settings
    said = f"of an angular velocity not measured but derived, {how} (run.json input.derived)"
    method = settings.methods.get("gyro")
    return replace(settings, methods={**settings.methods, "gyro": f"{said}: {method}" if method else said})


def estimate_log_noise(aligned, velocity: Estimate | None | str = "aligned") -> LogNoise:
    """:class:`LogNoise` of an aligned stream (``pipeline.alignment.AlignedStream``): the gyro density from its
    angular velocity (on its own stamps), the detection law from its detections; the velocity density is
    ``velocity`` (:func:`stream_density` of the stream before alignment interpolated it onto the angular
    velocity's stamps), or with ``"aligned"`` that of the aligned velocity."""
    vel_t = (aligned.vel_t_ns - aligned.t0_ns) * 1e-9
    gyro = white_noise_density(vel_t, aligned.omega)
    if isinstance(velocity, str):
        velocity = white_noise_density(vel_t, aligned.velocity)
    notes = [
        f"noise: the log is too short to estimate the {name} noise"
        for name, e in (("gyro", gyro), ("velocity", velocity))
        if e is None
    ]
    topics = getattr(aligned, "topics", {})
    gyro, velocity = (
        visible_noise(e, name, notes, stream_topics(topics, role))
        for name, e, role in (("gyro", gyro, "gyro"), ("velocity", velocity, "odometry"))
    )
    g = float(np.sqrt(np.mean(np.square(gyro.value)))) if gyro is not None else DEFAULTS["gyro"][0]
    v = float(np.sqrt(np.mean(np.square(velocity.value)))) if velocity is not None else DEFAULTS["velocity"][0]
    triplets = log_triplets(*_stream_arrays(aligned), g, v)
    robust = gyro is not None and velocity is not None  # a held stream's commands: docs/noise.md, "Wild detections"
    law = detection_law(triplets, robust=robust)
    ratio = None
    if law is None:
        notes.append("noise: too few landmarks seen three times within 1 s to estimate the detection noise")
    elif (ratio := detection_ratio(triplets, law)) is None:
        notes.append("noise: the detections' error along the line of sight is not told from that across it")
    elif ratio.value < 1.0:  # no range sensor sees direction worse than distance: the turning's error shows there
        notes.append(
            f"noise: the detections' error across the line of sight is {1.0 / ratio.value:.2g}x that along it within "
            f"1 s, most likely the dead reckoning's turning error: no ratio taken from it (detection_ratio's line says "
            "what is used)"
        )
        ratio = None
    else:  # a steep range error: the law again, its outliers judged along and across the line of sight
        law = detection_law(triplets, ratio=ratio.value, robust=robust) or law
    held: dict[str, Estimate] = {}
    if gyro is None or velocity is None:
        law, held = held_levels(aligned, law, ("gyro",) * (gyro is None) + ("velocity",) * (velocity is None), notes)
    gyro_said = gyro_degrees_note(aligned, law, g, v, robust)  # the gyro's misread, not the detections', scatters them
    notes += [w + stream_topics(topics, "gyro") for w in gyro_said] or [
        w + stream_topics(topics, "detections", "camera")
        for w in scattered_note(law) or degrees_note(aligned, law, g, v, robust)
    ]
    unresolved = None if gyro is None else unresolved_motion_density(vel_t, aligned.omega, gyro.value)
    return LogNoise(gyro, velocity, law, tuple(notes), held, ratio, unresolved)


def scattered_note(law: DetectionLaw | None) -> list[str]:
    """A warning when the detections scatter (``SCATTERED_SHARE``): bearings in degrees read as radians, an angle
    or frame that turns with them; riekf and batch take it for noise and say nothing else (MR.CLAM 6 r1 in
    degrees: riekf APE 0.49 -> 4.2 m)."""
    if law is None:
        return []
    share, r = _scatter_share(law)
    if share <= SCATTERED_SHARE:
        return []
    return [
        f"warning: noise: the detections scatter by {float(law.sigma(r)):.3g} m at their middle range {r:.3g} m "
        f"({share:.2f} of it) within 1 s: their directions look random, not noisy (a bearing in degrees read as "
        "radians? a frame that turns with the detections?): check the detections' unit and frame; estimates from "
        "them cannot be trusted"
    ]


def gyro_degrees_note(
    aligned, law: DetectionLaw | None, gyro: float, velocity: float, robust: bool = True
) -> list[str]:
    """A warning when the detections scatter (``SCATTERED_SHARE``) as the gyro reads and ``DEGREES_RATIO`` times
    less with its angular velocity divided by 57.3: a gyro in deg/s turns the dead reckoning between a triplet's
    detections 57.3x too far, and :func:`scattered_note` would blame the detections (a generated hand-held rig
    with its gyro in deg/s: 0.60 of the range as read; docs/benchmarks.md, "Logs nobody has run yet, round 6").
    Fitted again only where the detections scatter, from the start ``law`` was (``robust``, :func:`.detection_law`)."""
    if law is None or (share := _scatter_share(law)[0]) <= SCATTERED_SHARE:
        return []
    t, omega, *rest = _stream_arrays(aligned)
    law_rad = detection_law(log_triplets(t, np.radians(omega), *rest, float(np.radians(gyro)), velocity), robust=robust)
    if (rad := _reread_share(law_rad, share)) is None:
        return []
    return [
        f"warning: noise: the detections scatter {share / rad:.3g}x less within 1 s with the gyro's angular "
        f"velocity divided by 57.3 ({rad:.2g} of their range against {share:.2g} as read): a gyro in deg/s read as "
        "rad/s? check the gyro's unit; estimates from it cannot be trusted"
    ]


def _scatter_share(law: DetectionLaw) -> tuple[float, float]:
    """The law's σ at the detections' middle range (the geometric mean of the ranges it was fitted on) over that
    range, and the range."""
    r = float(np.sqrt(max(law.ranges[0], 1e-3) * max(law.ranges[1], 1e-3)))
    return float(law.sigma(r)) / r, r


def _reread_share(law: DetectionLaw | None, share: float) -> float | None:
    """The scatter share (:func:`_scatter_share`) of a law fitted again on a stream read in another unit, where it is
    at least ``DEGREES_RATIO`` times less than ``share`` as read (the unit is then named), else None."""
    if law is None or (again := _scatter_share(law)[0]) * DEGREES_RATIO > share:
        return None
    return again


def degrees_note(aligned, law: DetectionLaw | None, gyro: float, velocity: float, robust: bool = True) -> list[str]:
    """A warning when the detections scatter ``DEGREES_RATIO`` times less with their azimuths read as degrees
    (:func:`pipeline.noise_estimation.azimuths_from_degrees`): a bearing in degrees read as radians on a body
    that turns slowly scatters under ``SCATTERED_SHARE`` (its error is 57.3x, its wraps few); fitted from the start
    ``law`` was (``robust``, :func:`.detection_law`)."""
    if law is None or (share := _scatter_share(law)[0] / law.held_scale) <= DEGREES_FROM_SHARE:  # as the triplets saw
        return []
    arrays = _stream_arrays(aligned)
    reread = azimuths_from_degrees(*arrays[3:])
    law_deg = detection_law(log_triplets(*arrays[:6], reread, gyro, velocity), robust=robust)
    if (deg := _reread_share(law_deg, share)) is None:
        return []
    return [
        f"warning: noise: the detections scatter {share / deg:.3g}x less with their azimuths read as degrees "
        f"({deg:.2g} of their range within 1 s against {share:.2g} as read): a bearing in degrees read as radians? "
        "check the detections' unit; estimates from them cannot be trusted"
    ]


def held_levels(aligned, law: DetectionLaw | None, streams: tuple[str, ...], notes: list[str]):
    """The levels of held (commanded) velocity streams (``streams``: "gyro", "velocity"), whose samples show no
    noise, and their bias priors, from what pairs of detections of one landmark see over lags of seconds
    (:func:`pipeline.noise_estimation.held_motion_noise`); the detection law rescaled by the same fit (the
    triplets within 1 s miss detection errors that change slowly). The law and the levels found."""
    sigma = law.sigma if law is not None else (lambda r: DEFAULTS["detection"][0] + DEFAULTS["detection_per_m"][0] * r)
    fit: HeldMotion | None = held_motion_noise(*_stream_arrays(aligned), sigma, aligned.segment_starts)
    if fit is None:
        notes.append("noise: too few landmarks seen twice to estimate the held streams' noise from the detections")
        return law, {}
    keys = [*streams, *(f"{k}_bias" for k in streams)]
    notes.append(f"noise: {', '.join(keys)} estimated from the detections ({fit.levels[streams[0]].method})")
    f = fit.levels["detection_scale"]
    if law is not None and f.value < HELD_SCALE_FLOOR:
        r = _scatter_share(law)[1]
        notes.append(
            f"noise: the held streams' fit put the detections' own error at {f.value:.3g}x what they scatter by "
            f"within 1 s ({float(law.sigma(r)) * f.value:.3g} m against {float(law.sigma(r)):.3g} m at {r:.3g} m), "
            "not a level a sensor has: it gave the detection pairs' whole spread to the motion (as it does when "
            "the detections and the velocities disagree on the turns, e.g. mirrored detections); the detection law "
            "kept as the triplets measured it, unscaled"
        )
    elif law is not None:
        law = replace(law, base=_scaled(law.base, f), slope=_scaled(law.slope, f), held_scale=float(f.value))
        notes.append(f"noise: the detection law scaled by {f.value:.3g} by the same fit")
    return law, {k: floored(k, fit.levels[k]) for k in keys}


def floored(key: str, e: Estimate) -> Estimate:
    """A held stream's level as the pairs' fit gave it, its method saying so when it is the fit's floor
    (``noise_estimation.MIN_LEVEL``: the pairs saw nothing of it above zero, MR.CLAM's velocity biases); a prior
    or density that small holds that part of the motion as if known, which a run's notes must say."""
    if float(np.max(e.value)) > MIN_LEVEL:
        return e
    unit = DEFAULTS[key][1]
    return replace(
        e,
        method=f"the same fit, at its floor {MIN_LEVEL:g} {unit}: the detection pairs show no {key} above zero, "
        f"so riekf and batch take it as all but known (noise.{key} in run.yaml sets another)",
    )


def _scaled(e: Estimate, factor: Estimate) -> Estimate:
    """``e`` times ``factor`` (its method and uncertainty carried along)."""
    value = float(e.value) * factor.value
    unc = value * float(np.hypot(float(e.uncertainty) / max(float(e.value), 1e-300), factor.uncertainty / factor.value))
    return Estimate(value, unc, f"{e.method}; scaled by {factor.value:.3g} ({factor.method})", e.samples)


#: What a stream's samples are when every axis holds its values (``Estimate.held``): a run's note and
#: ``info --noise``'s line on a log that cannot run say it in these words.
HELD_SAMPLES = (
    "hold their values (commanded or quantised: most repeat the previous one), so their noise cannot be seen in them"
)


def visible_noise(estimate: Estimate | None, name: str, notes: list[str], where: str = "") -> Estimate | None:
    """``estimate``, or None when every axis of its stream holds its values (a commanded or quantised stream,
    e.g. MR.CLAM's commanded velocities): zero noise there would make riekf and batch trust it blindly. ``where``
    ends the note (``alignment.stream_topics``: the stream's topic)."""
    if estimate is None or not estimate.held or not all(estimate.held):
        return estimate
    notes.append(
        f"noise: the {name} samples {HELD_SAMPLES} (estimated from the detections instead, where they allow it){where}"
    )
    return None


def _vec(value) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()


def resolve_noise(
    config: NoiseConfig | None = None,
    log: str | Path | None = None,
    topics: dict[str, str] | None = None,
    estimated: LogNoise | None = None,
    stated: Mapping[str, StatedNoise] | None = None,
    odometry: Mapping[str, tuple] | None = None,
) -> NoiseSettings:
    """The settings of a run, key by key: what ``config`` (the run's ``noise`` section) sets; for the velocity
    densities the message covariances where they are plausible (and, with an estimate, between
    :data:`STATED_BELOW` and :data:`STATED_ABOVE` times it): ``stated`` (role -> what the read found,
    ``LogStreams.stated_covariance``), else read from ``log``'s ``topics``; what the log's samples show
    (``estimated``, used when ``config.auto``); else the defaults. A stated level above the samples' on a stream
    whose messages carry poses (``odometry``: role -> (its poses, its velocity stream),
    ``LogStreams.odometry_poses``) is tested against the stream's own drift (:func:`drift_evidence`)."""
    cfg = config or NoiseConfig()
    section = cfg.given()
    found = estimated.levels() if estimated is not None and cfg.auto else {}
    notes = list(estimated.notes) if estimated is not None and cfg.auto else []
    absent = estimated.absent_terms() if estimated is not None and cfg.auto else ()
    if stated is None and log is not None and topics and any(k not in section for k in STATED):
        from slamobs.pipeline.readers.covariance import stated_noise

        stated = stated_noise(log, topics, tuple(STATED[k] for k in STATED if k not in section))
    stated = {STATED[k]: stated[STATED[k]] for k in STATED if k not in section and STATED[k] in (stated or {})}
    values: dict = {}
    sources: dict[str, str] = {}
    methods: dict[str, str] = {}
    uncertainty: dict[str, object] = {}
    unresolved = None  # a configured gyro level is the user's: nothing added to it
    above: dict[str, np.ndarray] = {}
    drift: dict[str, dict] = {}
    if estimated is not None and cfg.auto and estimated.gyro_unresolved is not None and "gyro" not in section:
        found_u = estimated.gyro_unresolved
        unresolved = _vec(found_u.value)
        methods["gyro_unresolved"], uncertainty["gyro_unresolved"] = found_u.method, found_u.uncertainty
    for key, (default, _, _) in DEFAULTS.items():
        covariance = _believed(key, stated.get(STATED.get(key, "")), found.get(key), notes)
        if key in section:
            values[key], sources[key] = section[key], "config"
        elif covariance is not None:
            values[key] = covariance.density
            sources[key] = f"{covariance.topic} covariance ({median_rate(covariance.period_s)})"
            if key in found:
                methods[key] = stated_judgement(key, covariance.density, found[key].value)
                if np.any(np.asarray(covariance.density) > np.asarray(found[key].value)):
                    above[key] = _vec(found[key].value)
                    if (pair := (odometry or {}).get(STATED[key])) is not None and (
                        rec := drift_evidence(*pair, _vec(covariance.density), above[key])
                    ) is not None:
                        drift[key] = rec
                        methods[key] += "; " + drift_judgement(rec)
                        if rec["stated"]:
                            notes.append(
                                f"noise: {key} stated {format_level(_plain(covariance.density))}, "
                                f"above the samples' {format_level(_plain(above[key]))}: " + drift_judgement(rec)
                            )
        elif key in absent:
            values[key], sources[key] = 0.0, "estimated"
            methods[key] = f"not a term of the law chosen, {estimated.detection.law}"
        elif key in found:
            values[key], sources[key] = found[key].value, "estimated"
            methods[key], uncertainty[key] = found[key].method, found[key].uncertainty
        else:
            values[key], sources[key] = default, "default"
    settings = NoiseSettings(
        gyro=_vec(values["gyro"]),
        velocity=_vec(values["velocity"]),
        **{k: float(values[k]) for k in DEFAULTS if k not in ("gyro", "velocity")},
        sources=sources,
        methods=methods,
        uncertainty=uncertainty,
        notes=tuple(notes),
        held=tuple(
            k for k in (estimated.held if estimated is not None and cfg.auto else ()) if sources[k] == "estimated"
        ),
        absent=tuple(k for k in absent if k not in section),
        floor=cfg.floor,
        gyro_unresolved=unresolved,
        above_samples=above,
        drift=drift,
        detection_held_scale=(
            estimated.detection.held_scale
            if estimated is not None
            and cfg.auto
            and estimated.detection is not None
            and all(sources[k] == "estimated" for k in DETECTION_LAW_KEYS)
            else 1.0
        ),
    )
    if ratio_by_deviance(settings):
        settings = replace(settings, methods={**methods, "detection_ratio": DEVIANCE_RATIO_METHOD})
    return settings


def ratio_by_deviance(settings: NoiseSettings) -> bool:
    """Whether riekf chooses ``detection_ratio`` by its innovation deviance over ``DETECTION_RATIOS``
    (``observers.riekf.level_candidates``): the turn rate held (commanded: the held streams' fit estimated its
    level) and the ratio neither configured nor found by the triplets. The triplets difference detections within 1 s
    and miss a range error that changes more slowly (MR.CLAM's: 92-97 % shared within 1 s; docs/benchmarks.md,
    "riekf's range-against-bearing ratio on MR.CLAM from the log alone"); a gyro's or a VIO's log keeps the triplets'
    word (TagSLAM, stereo-like and hand-held logs do not change)."""
    return "gyro" in settings.held and settings.sources.get("detection_ratio", "default") == "default"


def stated_below(density, estimate) -> float | None:
    """How many times quieter a stated density is than the samples' estimate (the worst axis) when that is more
    than ``1 / STATED_LOW`` times, else None (run.json's sensor levels ``stated.below``; such a level is not used:
    :data:`STATED_BELOW`, whose note says so)."""
    ratio = np.asarray(density, dtype=float) / np.maximum(np.asarray(estimate, dtype=float), 1e-300)
    low = float(np.min(ratio))
    return 1.0 / low if low < STATED_LOW else None


def stated_above(density, estimate) -> float | None:
    """How many times louder a stated density is than the samples' estimate (the worst axis) when that is more
    than ``1 / STATED_LOW`` times, else None (the mirror of :func:`stated_below`)."""
    ratio = np.asarray(density, dtype=float) / np.maximum(np.asarray(estimate, dtype=float), 1e-300)
    high = float(np.max(ratio))
    return high if high > 1.0 / STATED_LOW else None


def drift_evidence(poses, velocity, stated, samples) -> dict | None:
    """A stated velocity level above the samples' white-noise estimate tested on what an odometry message carries
    besides its twist, its pose: over disjoint windows of the longest of :data:`DRIFT_HORIZONS_S` the stream holds
    :data:`DRIFT_WINDOWS` of, the twist integrated minus the messages' own displacement
    (:func:`.noise_estimation.twist_drift`), less a constant body-frame bias (the one riekf and batch estimate,
    fitted at each level), is, for a white velocity noise of density ``q`` per body axis, a random walk
    ``N(0, q² τ)`` per axis. The deviance ``Σ log(q² τ) + d² / (q² τ)`` at the stated level and at the samples'
    is compared: ``stated`` is True where the samples' is higher by more than the χ² quantile ``LEVEL_CHOICE_P``
    (one degree of freedom), the stated level then right over the horizons a filter dead-reckons (a VIO's coloured
    twist, its pose corrected by vision). A pose that is the twist's own integral (a wheel odometry's) leaves
    nothing to measure and favours the samples' level: riekf's test goes on as before. None when ``poses`` and
    ``velocity`` are not on the same stamps or no horizon holds enough windows."""
    if poses is None or velocity is None or not np.array_equal(poses.t_ns, velocity.t_ns) or len(poses) < 3:
        return None
    span = (int(poses.t_ns[-1]) - int(poses.t_ns[0])) * 1e-9
    fits = [h for h in DRIFT_HORIZONS_S if span >= DRIFT_WINDOWS * h]
    if not fits:
        return None
    horizon = fits[-1]
    diffs, spans, gains = twist_drift(poses.t_ns, velocity.xyz, poses.position, poses.quat_xyzw, horizon)
    if diffs.shape[0] < DRIFT_WINDOWS or not np.all(np.isfinite(diffs)):
        return None

    def deviance(q) -> tuple[float, np.ndarray]:
        # the constant bias riekf and batch estimate (its prior wide) fitted at this level and taken out first
        var = np.maximum(np.asarray(q, dtype=float) ** 2, 1e-300)[None, :] * spans[:, None]
        weighted = gains / var[:, :, None]
        bias = np.linalg.lstsq(
            np.einsum("wai,waj->ij", gains, weighted), np.einsum("wai,wa->i", weighted, diffs), rcond=None
        )[0]
        left = diffs - np.einsum("wai,i->wa", gains, bias)
        return float(np.sum(np.log(var) + left**2 / var)), left

    (stated_dev, left), (samples_dev, _) = deviance(stated), deviance(samples)
    threshold = chi2_quantile(LEVEL_CHOICE_P, 1)
    density = np.sqrt(np.mean(left**2 / spans[:, None], axis=0))  # the stated level's bias taken out
    return {
        "topic": poses.topic,
        "horizon_s": horizon,
        "windows": int(diffs.shape[0]),
        "density": density,
        "deviance_stated": stated_dev,
        "deviance_samples": samples_dev,
        "threshold": threshold,
        "stated": samples_dev - stated_dev > threshold,
    }


def drift_judgement(rec: dict) -> str:
    """The words of :func:`drift_evidence`'s verdict, for the level's method and the run's notes."""
    gain = rec["deviance_samples"] - rec["deviance_stated"]
    what = (
        "kept as stated without riekf's test on its detections" if rec["stated"] else "riekf tests it on its detections"
    )
    return (
        f"the twist integrated over {rec['windows']} windows of {rec['horizon_s']:g} s drifts from {rec['topic']}'s "
        f"own poses, a constant bias taken out, as a density {format_level(_plain(rec['density']))} (the deviance "
        f"of that drift {gain:.3g} lower at the stated level than at the samples', χ² quantile at {LEVEL_CHOICE_P:.0%} "
        f"{rec['threshold']:.3g}): {what}"
    )


def stated_judgement(key: str, density, estimate) -> str:
    """What a run's notes say of a believed stated density beside the samples' estimate (``key``: gyro, velocity):
    plausible, or how many times above it (a level 10x above its white samples, believed, costs riekf 1.9x its APE
    with the true level on a generated log: docs/benchmarks.md "Logs nobody has run yet", session 31); one more than
    ``1 / STATED_LOW`` times below it is not believed (:data:`STATED_BELOW`)."""
    level = format_level(_plain(estimate))
    if (above := stated_above(density, estimate)) is not None:
        return (
            f"{above:.3g}x above the samples' white-noise estimate {level}, used as stated (a coloured noise, a "
            f"VIO's or a filtered odometry's, is louder than its samples show): riekf and batch take a stated level "
            f"up to {STATED_ABOVE:g}x the estimate (riekf keeps the stated or the estimate, whichever its "
            f"innovations explain better: its note says which); if the sensor is white, noise.{key} in run.yaml at "
            "the estimate weighs it as it is"
        )
    return f"plausible; the samples' white-noise estimate is {level}"


def _believed(key: str, stated, estimate: Estimate | None, notes: list[str]):
    """The stated covariance of ``key`` when it is plausible and agrees with the estimate; else None, with a
    note saying why it was rejected."""
    if stated is None:
        return None
    if stated.problem is not None:  # what the key takes instead: the samples' estimate, else its default
        instead = "the samples' estimate" if estimate is not None else "the default"
        notes.append(f"noise: {stated.topic} covariance not used for {key}: {stated.problem}; {instead} used instead")
        return None
    if stated.rejected is not None:
        notes.append(f"noise: {stated.topic} covariance for {key}: {stated.rejected}")
    if estimate is not None:
        ratio = np.broadcast_to(stated.density / np.maximum(np.asarray(estimate.value, dtype=float), 1e-300), (3,))
        worst = float(ratio.min() if ratio.min() < STATED_BELOW else ratio.max())
        if not STATED_BELOW <= worst <= STATED_ABOVE:
            notes.append(
                f"noise: {stated.topic} covariance not used for {key}: it states {worst:.3g}x the density "
                f"estimated from the samples (riekf and batch take a stated level from {STATED_BELOW:.2g}x to "
                f"{STATED_ABOVE:g}x it); the samples' estimate used instead, noise.{key} in run.yaml sets another"
            )
            return None
    return stated


#: Degrees of freedom from which the χ² quantile is the Wilson–Hilferty approximation (below: exact).
WILSON_HILFERTY_DOF = 30


def chi2_quantile(p: float, dof: int) -> float:
    """The ``p`` quantile of the χ² distribution with ``dof`` degrees of freedom: bisection on the CDF (the
    incomplete gamma series) below ``WILSON_HILFERTY_DOF``, the Wilson–Hilferty approximation from there on
    (relative error below 0.5 % at 2.5 % and 97.5 % for 30 degrees of freedom, smaller for more)."""
    import math
    from statistics import NormalDist

    if dof >= WILSON_HILFERTY_DOF:
        z = NormalDist().inv_cdf(p)
        return dof * max(1.0 - 2.0 / (9 * dof) + z * math.sqrt(2.0 / (9 * dof)), 0.0) ** 3

    def cdf(x: float) -> float:
        a, h = dof / 2.0, x / 2.0
        term = total = 1.0 / a
        n = 0
        while term > 1e-16 * total:
            n += 1
            term *= h / (a + n)
            total += term
        return math.exp(a * math.log(h) - h - math.lgamma(a)) * total if h > 0 else 0.0

    lo, hi = 0.0, dof + 20.0 * math.sqrt(2.0 * dof) + 20.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cdf(mid) < p else (lo, mid)
    return 0.5 * (lo + hi)


def nees_bounds(dof: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided ``confidence`` bounds of the average of ``n`` independent NEES values of ``dof`` degrees of
    freedom (ov_eval's consistency bounds): ``χ²(dof·n)`` quantiles divided by ``n``."""
    a = (1.0 - confidence) / 2.0
    return chi2_quantile(a, dof * n) / n, chi2_quantile(1.0 - a, dof * n) / n
