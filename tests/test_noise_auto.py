"""``noise: auto`` (issue 23, part 1): the noise levels learned from a log's own samples, against the truth the
simulator drew them with; config keys override one key each; implausible message covariances are rejected with
a note; riekf and batch given the estimates do as well as given the truth."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.lie import umeyama
from slamobs.pipeline.noise import NoiseConfig, estimate_log_noise, resolve_noise, stream_density
from slamobs.pipeline.noise_estimation import Triplets, robust_scale, white_noise_density
from slamobs.pipeline.readers.covariance import implausible, implausible_rows
from slamobs.pipeline.simulate import NoiseModel, expected_streams, get_scenario, simulate, write_log
from slamobs.pipeline.simulate.scenarios import customize
from cli_checks import invoke

TOLERANCE = 0.25
GYRO = (0.004, 0.009, 0.006)  # rad/s per sample, per axis
VELOCITY = (0.03, 0.012, 0.02)  # m/s per sample, per axis


def per_axis_model(law: str) -> NoiseModel:
    """Per-axis velocity noises and a detection law: ``linear`` (σ0 + k·r) or ``square`` (b + a·r²)."""
    detection = (
        {"detection_base": 0.008, "detection_per_m": 0.003}
        if law == "linear"
        else {"detection_base": 0.004, "detection_per_m": 0.0, "detection_per_m2": 0.0008}
    )
    return replace(NoiseModel(), gyro=GYRO, odom_linear=VELOCITY, **detection)


def true_sigma(nm: NoiseModel, r: np.ndarray) -> np.ndarray:
    return nm.detection_base + nm.detection_per_m * r + nm.detection_per_m2 * r * r


def within(estimate, truth, tol: float = TOLERANCE) -> bool:
    ratio = np.asarray(estimate, float) / np.asarray(truth, float)
    return bool(np.all(np.abs(ratio - 1.0) <= tol))


@pytest.mark.parametrize(
    ("rate", "seed", "law"), [(10, 1, "linear"), (50, 2, "square"), (200, 3, "linear"), (400, 4, "square")]
)
def test_every_level_is_within_25_percent_of_the_truth(rate, seed, law):
    """Gyro and odometry at the same rate (10-400 Hz), per-axis densities, and the detection law at the 5th,
    50th and 95th percentile of the ranges seen."""
    nm = per_axis_model(law)
    sim = simulate("figure8", duration=60.0 if rate < 50 else 30.0, seed=seed, noise=nm, imu_rate=rate, odom_rate=rate)
    stream = align(expected_streams(sim), keep_directions=False)
    found = estimate_log_noise(stream, stream_density(sim.odom.t_ns, sim.odom.linear))
    period = 1.0 / rate
    assert within(found.gyro.value, np.array(GYRO) * np.sqrt(period)), found.gyro.value / np.sqrt(period)
    assert within(found.velocity.value, np.array(VELOCITY) * np.sqrt(period)), found.velocity.value / np.sqrt(period)
    assert np.all(found.gyro.uncertainty < 0.1 * found.gyro.value)  # a standard error, not a placeholder
    law_found = found.detection
    r = np.linspace(*law_found.ranges, 3)
    assert within(law_found.sigma(r), true_sigma(nm, r)), (law_found.law, law_found.sigma(r), true_sigma(nm, r))
    assert ("r^2" in law_found.law) == (law == "square")


def test_jittered_irregular_stamps_and_a_manoeuvre_are_not_counted_as_noise():
    """Stamps jittered by ±30 % of the period with dropped samples, on a fast figure-8 sampled at 20 Hz: the
    quintic through the neighbours at their own stamps leaves the white noise only."""
    rng = np.random.default_rng(5)
    sc = get_scenario("figure8")
    period = 0.05
    t = np.arange(0.0, 120.0, period) + rng.uniform(-0.3, 0.3, 2400) * period
    t = np.sort(t[rng.random(t.size) > 0.1])
    sigma = np.array([0.01, 0.002, 0.005])
    x = 3.0 * sc.sample(t).omega + sigma * rng.standard_normal((t.size, 3))  # three times the scenario's turns
    found = white_noise_density(t, x)
    assert within(found.value, sigma * np.sqrt(np.median(np.diff(t)))), found.value / np.sqrt(period)


def test_motion_faster_than_a_slow_stream_resolves_is_not_taken_for_noise():
    """A hand-held rig's odometry at 4 Hz (a VIO's twist, one instant's sample): the walker's 1.8 Hz step bob of
    4 cm is a vertical velocity of 0.45 m/s that no quintic through 4 Hz samples follows; its residuals made the
    vertical level 15x the white noise (batch's APE 1.5x its run at the true level on such logs). The means of
    sample pairs cancel it: that axis's level is within 25 % of the truth, said; a white stream keeps its own."""
    rng = np.random.default_rng(7)
    t = np.arange(0.0, 300.0, 0.25)
    sigma = 0.05  # per sample, m/s
    bob = np.zeros((t.size, 3))
    bob[:, 2] = 0.04 * 2 * np.pi * 1.8 * np.cos(2 * np.pi * 1.8 * t)
    walk = 0.3 * get_scenario("figure8").sample(t).v  # the figure 8 slowed to a walk: resolved at 4 Hz
    found = white_noise_density(t, walk + bob + sigma * rng.standard_normal((t.size, 3)))
    assert within(found.value, sigma * np.sqrt(0.25)), found.value / np.sqrt(0.25)
    assert "z from the means of sample pairs" in found.method and "x," not in found.method, found.method
    # the samples' own level stays for what is built of them (the detection pairs' velocity-scale check, whose
    # regressor carries the motion they miss: at the pairs' level it called the axes misread, 1.65-20x)
    assert found.sampled is not None and found.sampled[2] > 5 * found.value[2], found.sampled
    white = white_noise_density(t, walk + sigma * rng.standard_normal((t.size, 3)))
    assert "pairs" not in white.method and within(white.value, sigma * np.sqrt(0.25)), white.value
    assert white.sampled is None


def test_config_keys_override_that_key_alone():
    sim = simulate("figure8", duration=20.0, seed=6, noise=per_axis_model("square"))
    found = estimate_log_noise(align(expected_streams(sim), keep_directions=False))
    nz = resolve_noise(NoiseConfig(gyro=1e-3, detection=0.05), estimated=found)
    assert nz.gyro.tolist() == [1e-3] * 3 and nz.sources["gyro"] == "config"
    assert nz.detection == 0.05 and nz.sources["detection"] == "config"
    assert nz.sources["velocity"] == "estimated" and np.allclose(nz.velocity, found.velocity.value)
    assert nz.detection_per_m2 == pytest.approx(found.detection.slope.value) and nz.detection_per_m2 > 0
    assert nz.sources["gyro_bias"] == "default"
    off = resolve_noise(NoiseConfig(auto=False), estimated=found)  # noise: {auto: false}: the defaults
    assert set(off.sources.values()) == {"default"}


def test_run_yaml_spells_auto_and_turns_it_off():
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.errors import InputError

    assert parse_config({"noise": "auto"}).noise == NoiseConfig() == parse_config({}).noise
    given = parse_config({"noise": {"auto": False, "detection_per_m2": 0.001}}).noise
    assert given.auto is False and given.given() == {"detection_per_m2": 0.001}
    with pytest.raises(InputError, match="noise"):
        parse_config({"noise": "guess"})


@pytest.mark.parametrize(
    ("diag", "why"),
    [
        ([-1, 0, 0], "REP 145"),
        ([0, 0, 0], "zero"),
        ([1e-9] * 3, "placeholder"),
        ([1e3] * 3, "placeholder"),
        ([1e6, 1e6, 1e6], "placeholder"),
        ([np.nan, 1, 1], "not finite"),
        ([2.5e-5, 3e-5, 1e-4], None),
    ],
)
def test_implausible_covariances(diag, why):
    problem = implausible(np.array(diag, dtype=float))
    assert (problem is None) if why is None else (why in problem)
    assert (implausible_rows(np.array([diag, diag], dtype=float)) == 0).all() == (why is None)  # the whole stream's


@pytest.fixture(scope="module")
def stated_logs(tmp_path_factory):
    """One 10 s log whose messages state placeholders (1e6 for the gyro), one whose odometry states a variance
    400 times (density 20 times) below its real noise."""
    sim = simulate("circle", duration=10.0, seed=7)
    out = tmp_path_factory.mktemp("stated")
    placeholder = out / "placeholder.mcap"
    write_log(replace(sim, noise=replace(sim.noise, gyro=1e3)), placeholder)  # variance 1e6 on the diagonal
    inconsistent = out / "inconsistent.mcap"
    write_log(replace(sim, noise=replace(sim.noise, odom_linear=sim.noise.odom_linear / 20)), inconsistent)
    return placeholder, inconsistent, sim


def test_implausible_covariances_are_rejected_with_a_note(stated_logs):
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import log_noise, prepare_log

    placeholder, inconsistent, sim = stated_logs
    config = parse_config({"observer": "riekf"})
    nz = log_noise(prepare_log(placeholder, config, directions=False), config)
    assert nz.sources["gyro"] == "estimated" and nz.sources["velocity"].startswith("/odom covariance")
    assert any("/imu/data covariance not used for gyro: placeholder" in n for n in nz.notes), nz.notes
    assert within(nz.gyro, sim.noise.gyro * np.sqrt(1 / 200), 0.3)
    nz = log_noise(prepare_log(inconsistent, config, directions=False), config)
    assert nz.sources["velocity"] == "estimated" and nz.sources["gyro"].startswith("/imu/data covariance")
    (note,) = [n for n in nz.notes if "/odom covariance not used for velocity" in n]
    stated = float(note.split("it states ")[1].split("x the density")[0])
    assert 0.04 < stated < 0.06  # the odometry states a twentieth of its noise


def _stated_velocity_run(sim, log, factor: float):
    """``sim`` written to ``log`` with its odometry's (stated and drawn) noise times ``factor``, and the noise levels
    riekf would use there (the velocity's from the message covariance)."""
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import log_noise, prepare_log

    write_log(replace(sim, noise=replace(sim.noise, odom_linear=sim.noise.odom_linear * factor)), log)
    config = parse_config({"observer": "riekf"})
    nz = log_noise(prepare_log(log, config, directions=False), config)
    assert nz.sources["velocity"].startswith("/odom covariance"), nz.sources
    return log, nz


def test_a_stated_level_well_below_its_samples_is_not_believed(stated_logs, tmp_path):
    """A log whose odometry states a fifth of its noise (TagSLAM 22's T265 gyro states 0.14x its samples): it was
    believed (over the old bound of 0.1x) and riekf weighed the velocity five times too tight. It is rejected under
    STATED_BELOW (1/3): the samples' level is used, and the run's note and `info --noise` say why and which key sets
    another."""
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import log_noise, prepare_log

    sim, log = stated_logs[2], tmp_path / "fifth.mcap"
    write_log(replace(sim, noise=replace(sim.noise, odom_linear=sim.noise.odom_linear / 5)), log)
    config = parse_config({"observer": "riekf"})
    nz = log_noise(prepare_log(log, config, directions=False), config)
    assert nz.sources["velocity"] == "estimated" and nz.sources["gyro"].startswith("/imu/data covariance"), nz.sources
    (note,) = [n for n in nz.notes if "/odom covariance not used for velocity" in n]
    assert 0.14 < float(note.split("it states ")[1].split("x the density")[0]) < 0.3, note
    assert "the samples' estimate used instead" in note and "noise.velocity in run.yaml" in note, note
    assert within(nz.velocity, sim.noise.odom_linear * np.sqrt(1 / 50), 0.3)  # the samples' level, not a fifth
    res = invoke("info", "--noise", str(log))
    line = next(x for x in res.output.splitlines() if "/odom covariance not used for velocity" in x)
    assert "the samples' estimate used instead" in line and "noise.velocity in run.yaml" in line, line


def _stated_rig_runs(tmp_path, seed: int, factor: float) -> tuple[dict, dict]:
    """riekf on a 40 s circle (gyro 60x, velocity 20x the default densities) whose messages state ``factor`` times
    the noise drawn, with no noise configuration and given the truth: each run's APE and run.json by name."""
    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.noise import DEFAULTS

    gyro, velocity = 60 * DEFAULTS["gyro"][0], 20 * DEFAULTS["velocity"][0]  # densities
    nm = replace(
        NoiseModel(),
        gyro=gyro * np.sqrt(100),
        odom_linear=velocity * np.sqrt(20),
        detection_base=0.05,
        detection_per_m=0.01,
    )
    sim = simulate("circle", noise=nm, duration=40.0, seed=seed, imu_rate=100, odom_rate=20)
    log = tmp_path / "stated.mcap"
    write_log(replace(sim, noise=replace(nm, gyro=factor * nm.gyro, odom_linear=factor * nm.odom_linear)), log)
    truth = {"gyro": gyro, "velocity": velocity, "detection": 0.05, "detection_per_m": 0.01}
    truth |= {"detection_per_m2": 0.0, "detection_ratio": 1.0}
    ape, meta = {}, {}
    for name, noise in (("auto", None), ("true", truth)):
        cfg = {"evaluation": {"plots": False}, **({"noise": noise} if noise else {})}
        run_log(log, tmp_path / name, observer="riekf", config=cfg, force=True)
        ape[name] = json.loads((tmp_path / name / "report.json").read_text())["ape"]["translation_m"]["rmse"]
        meta[name] = json.loads((tmp_path / name / "run.json").read_text())
    return ape, meta


def test_riekf_on_a_log_stated_at_015x_its_noise_does_as_well_as_with_the_truth(tmp_path):
    """A VIO-like rig (gyro 60x, velocity 20x the default densities) whose messages state 0.15x the noise drawn:
    at the old bound (0.1x) riekf believed it and was 2.0x its APE with the true levels (0.158 m against 0.079;
    seed=9947's loop: 5.8x); with the samples' level it is within 1.2x of its run given the truth."""
    ape, _ = _stated_rig_runs(tmp_path, 3397, 0.15)
    assert ape["auto"] < 1.2 * ape["true"], ape


def test_a_stated_level_well_above_its_samples_is_named_not_called_plausible(stated_logs, tmp_path):
    """A log whose odometry states ten times its white noise (density): believed (under STATED_ABOVE, a coloured
    noise may be louder than its samples show) and was called `plausible`; riekf weighs the velocity ten times
    too loose (1.9x its APE with the true level on a generated circle). The note says how far above and the key
    that sets another."""
    log, nz = _stated_velocity_run(stated_logs[2], tmp_path / "tenfold.mcap", 10)
    said = nz.methods["velocity"]
    assert "above the samples' white-noise estimate" in said and "plausible" not in said, said
    assert 7.0 < float(said.split("x above")[0]) < 14.0 and "noise.velocity in run.yaml" in said, said
    assert nz.methods["gyro"].startswith("plausible;"), nz.methods  # the IMU states its own level
    res = invoke("info", "--noise", str(log))
    line = next(x for x in res.output.splitlines() if x.strip().startswith("velocity = "))
    assert "x above the samples' white-noise estimate" in line and "plausible" not in line, line
    blind = tmp_path / "tenfold-blind.mcap"  # no detection: info shows each sensor's own level and the stated one
    sim = simulate(customize(get_scenario("circle"), detections_until=0.0), duration=10.0, seed=7)
    write_log(replace(sim, noise=replace(sim.noise, odom_linear=sim.noise.odom_linear * 10)), blind)
    res = invoke("info", "--noise", str(blind))
    line = next(x for x in res.output.splitlines() if "its messages state /odom covariance" in x)
    assert "x above the level above" in line and "plausible" not in line, line


def test_run_json_report_and_info_state_every_level(stated_logs, tmp_path):
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import run_log

    placeholder = stated_logs[0]
    out = tmp_path / "run"
    run_log(placeholder, out, parse_config({"observer": "riekf", "evaluation": {"plots": False}}))
    levels = json.loads((out / "run.json").read_text())["observer"]["filter"]["noise"]["levels"]
    gyro = levels["gyro"]
    assert gyro["source"] == "estimated" and "quintic" in gyro["method"] and len(gyro["uncertainty"]) == 3
    assert levels["detection"]["source"] == "estimated" and levels["detection"]["uncertainty"] > 0
    assert levels["gyro_bias"] == {
        "value": 0.2,
        "unit": "rad/s",
        "source": "default",
        "method": None,
        "uncertainty": None,
    }
    report = (out / "report.md").read_text()
    assert "noise: gyro = [" in report and "noise: detection = " in report
    shown = invoke("info", "--noise", placeholder)
    assert shown.exit_code == 0 and "gyro = [" in shown.output and "(estimated, ± " in shown.output
    assert "covariance not used for gyro" in shown.output


def changing_imu_covariance(monkeypatch, tmp_path, name: str, head: float, before, after):
    """A 10 s log whose IMU messages state the variances ``before`` for the first ``head`` share of the messages
    and ``after`` from then on (a driver reset), written through the simulator's bulk rows."""
    from slamobs.pipeline.simulate.logwriter import Builder
    from slamobs.pipeline.simulate.sensors import TOPIC_IMU

    columns = Builder.columns

    def with_covariance(self, topic):
        cols = columns(self, topic)
        if topic == TOPIC_IMU and cols is not None:
            n = self.sim.imu.t_ns.shape[0]
            later = np.arange(n) >= int(head * n)
            for k in range(3):
                cols[("angular_velocity_covariance", str(4 * k))] = np.where(later, after[k], before[k])
        return cols

    monkeypatch.setattr(Builder, "columns", with_covariance)
    return write_log(simulate("circle", duration=10.0, seed=7), tmp_path / f"{name}.mcap")


def test_every_message_s_covariance_is_judged(monkeypatch, tmp_path):
    """Plausible variances in the first messages and REP 145's -1 after a reset (most of the log) are not used, the
    note saying how many messages state what and when; the reverse (placeholders first) uses the plausible ones and
    says how many were not. Before, the first 25 messages decided alone."""
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import log_noise, prepare_log

    config = parse_config({"observer": "riekf"})
    plausible, unknown, placeholder = [2.5e-5] * 3, [-1.0, 0.0, 0.0], [1e-9] * 3
    reset = changing_imu_covariance(monkeypatch, tmp_path, "reset", 0.1, plausible, unknown)
    nz = log_noise(prepare_log(reset, config, directions=False), config)
    assert nz.sources["gyro"] == "estimated", nz.sources
    (note,) = [n for n in nz.notes if "/imu/data covariance not used for gyro" in n]
    assert "1801 of 2001 messages state -1 (REP 145: no estimate) (between 1 and 10 s" in note, note
    late = changing_imu_covariance(monkeypatch, tmp_path, "late", 0.3, placeholder, plausible)
    nz = log_noise(prepare_log(late, config, directions=False), config)
    assert nz.sources["gyro"].startswith("/imu/data covariance"), nz.sources
    assert np.allclose(nz.gyro, 0.005 * np.sqrt(1 / 200))
    (note,) = [n for n in nz.notes if "/imu/data covariance for gyro" in n]
    assert "600 of 2001 messages state placeholder (1e-09, 1e-09, 1e-09)" in note and "other 1401 used" in note, note


def test_a_covariance_nan_in_some_or_all_messages_is_counted_and_says_what_was_used(monkeypatch, tmp_path):
    """NaN in part of a topic's covariances (a driver that loses its estimate after a while): the note counts the
    messages per topic and says the median of the others was used; NaN in every message: not used, the note says
    in how many and what the run took instead (before: "not finite" alone, no count, no word of the level used)."""
    from slamobs.pipeline.config import parse_config
    from slamobs.pipeline.run import log_noise, prepare_log

    config = parse_config({"observer": "riekf"})
    plausible, nan = [2.5e-5] * 3, [np.nan, 2.5e-5, 2.5e-5]
    part = changing_imu_covariance(monkeypatch, tmp_path, "part", 0.7, plausible, nan)
    nz = log_noise(prepare_log(part, config, directions=False), config)
    assert nz.sources["gyro"].startswith("/imu/data covariance") and np.allclose(nz.gyro, 0.005 * np.sqrt(1 / 200))
    (note,) = [n for n in nz.notes if "/imu/data covariance for gyro" in n]
    assert "601 of 2001 messages state not finite (between 7 and 10 s" in note and "other 1400 used" in note, note
    every = changing_imu_covariance(monkeypatch, tmp_path, "every", 1.0, nan, nan)
    nz = log_noise(prepare_log(every, config, directions=False), config)
    assert nz.sources["gyro"] == "estimated", nz.sources
    (note,) = [n for n in nz.notes if "/imu/data covariance not used for gyro" in n]
    assert note.endswith("not finite (all 2001 messages); the samples' estimate used instead"), note


# ------------------------------------------------------------------------- the estimators on learned noise


@pytest.fixture(scope="module")
def loud_log():
    """30 s of figure-8 with gyro noise 100 times the default and detections whose σ grows with r²."""
    nm = replace(
        NoiseModel(), gyro=100 * NoiseModel().gyro, detection_base=0.003, detection_per_m=0.0, detection_per_m2=0.001
    )
    sim = simulate("figure8", duration=30.0, seed=1, noise=nm)
    stream = align(expected_streams(sim), keep_directions=False)  # no message covariances: all estimated
    auto = resolve_noise(estimated=estimate_log_noise(stream, stream_density(sim.odom.t_ns, sim.odom.linear)))
    truth = resolve_noise(
        NoiseConfig(
            gyro=nm.gyro * np.sqrt(1 / 200),
            velocity=nm.odom_linear * np.sqrt(1 / 50),
            detection=0.003,
            detection_per_m=0.0,
            detection_per_m2=0.001,
        )
    )
    return sim, stream, auto, truth


def ape(sim, t_ns: np.ndarray, pos: np.ndarray) -> float:
    truth = get_scenario(sim.scenario).sample((t_ns - sim.start_ns) * 1e-9)
    r, t, _ = umeyama(pos, truth.P)
    return float(np.sqrt(np.mean(np.sum((pos @ r.T + t - truth.P) ** 2, axis=1))))


def test_riekf_on_learned_noise_is_within_1_5x_of_riekf_on_the_truth(loud_log):
    from slamobs.pipeline.observers import ObserverOptions
    from slamobs.pipeline.observers.riekf import RiEKF

    sim, stream, auto, truth = loud_log
    errors, gated = {}, {}
    for name, nz in (("auto", auto), ("truth", truth)):
        filt = RiEKF(stream, {}, ObserverOptions(out_every=10), noise=nz)
        res = filt.advance(filt.n_vel)
        errors[name] = ape(sim, res.t_ns, res.position)
        gated[name] = filt.stats["metadata"]["filter"]["gated_detections"] / stream.det_idx.shape[0]
    assert errors["auto"] <= 1.5 * errors["truth"], errors
    assert gated["auto"] < 0.05, gated


def test_batch_on_learned_noise_is_within_1_2x_of_batch_on_the_truth(loud_log):
    pytest.importorskip("gtsam")
    from slamobs.pipeline.observers import ObserverOptions
    from slamobs.pipeline.smoother.estimator import BatchSmoother

    sim, stream, auto, truth = loud_log
    errors = {}
    for name, nz in (("auto", auto), ("truth", truth)):
        smoother = BatchSmoother(stream, {}, ObserverOptions(), noise=nz)
        smoother.solve()
        kf_ns = stream.t0_ns + np.round(smoother.result["kf_t"] * 1e9).astype(np.int64)
        errors[name] = ape(sim, kf_ns, smoother.result["solution"].pos)
    assert errors["auto"] <= 1.2 * errors["truth"], errors


def test_simulate_writes_per_axis_noise_and_a_range_squared_law(tmp_path):
    """The simulator's new options: per-axis gyro and velocity noise (stated in the messages' covariances too)
    and the detection law S0 + K·r + A·r²; a wrong count of numbers is one error line."""
    out = tmp_path / "sim.mcap"
    args = ["simulate", "circle", "-o", out, "--duration", "4", "--gyro-noise", "0.01,0.02,0.03"]
    done = invoke(*args, "--velocity-noise", "0.05", "--detection-noise", "0.01,0,0.003", "-q")
    assert done.exit_code == 0, done.output
    topics = {"angular_velocity": "/imu/data", "linear_velocity": "/odom"}
    stated = resolve_noise(NoiseConfig(auto=False), out, topics)
    assert np.allclose(stated.gyro, np.array([0.01, 0.02, 0.03]) * np.sqrt(1 / 200))
    assert np.allclose(stated.velocity, 0.05 * np.sqrt(1 / 50))
    bad = invoke("simulate", "circle", "-o", tmp_path / "bad.mcap", "--gyro-noise", "0.01,0.02")
    assert bad.exit_code == 2 and "--gyro-noise" in bad.output and not (tmp_path / "bad.mcap").exists()


def test_per_axis_noise_draws_the_same_random_stream():
    """Three equal per-axis values and a zero r² term draw exactly what one value draws: the new fields leave
    the random stream of a default simulation (and so the sample logs) as it was."""
    nm = NoiseModel()
    assert nm.detection_per_m2 == 0.0 and np.isscalar(nm.gyro) and np.isscalar(nm.odom_linear)
    a = simulate("circle", duration=2.0, seed=3)
    b = simulate("circle", duration=2.0, seed=3, noise=replace(nm, gyro=(nm.gyro,) * 3, detection_per_m2=0.0))
    assert np.array_equal(a.imu.gyro, b.imu.gyro) and np.array_equal(a.detections.xyz, b.detections.xyz)


def test_held_streams_are_not_taken_for_noiseless():
    """A commanded velocity (MR.CLAM's odometry: each value held for ten samples) shows no high-frequency noise at
    all; it must not become a zero noise level that riekf and batch would trust blindly. An axis that is always
    zero (a wheel odometry's lateral speed) takes the level of the axes that move."""
    rng = np.random.default_rng(4)
    t = np.arange(4000) / 50.0
    held = np.repeat(rng.normal(0.0, 0.3, (400, 3)), 10, axis=0)
    found = white_noise_density(t, held)
    assert found is not None and all(found.held)
    notes: list[str] = []
    from slamobs.pipeline.noise import visible_noise

    assert visible_noise(found, "velocity", notes) is None and "hold their values" in notes[0]
    moving = np.c_[np.sin(t) + rng.normal(0.0, 0.02, t.size), np.zeros(t.size), np.zeros(t.size)]
    found = white_noise_density(t, moving)
    assert found.held == (False, True, True)
    assert np.allclose(found.value, found.value[0]) and found.value[0] == pytest.approx(
        0.02 * np.sqrt(1 / 50), rel=0.25
    )


def test_wrong_ids_and_absurd_ranges_do_not_widen_the_detection_law():
    """1.5 % of the detections carry another landmark's ID and 0.3 % sit 5-50x too far (a real tag or stereo
    matching failure): the law stays within 25 % of the truth (the Gaussian fit on every triplet came out 400x
    wide on such a log, wide enough that no outlier was beyond 4 σ of it)."""
    nm = replace(per_axis_model("square"), wrong_id=0.015, absurd_range=0.003)
    sim = simulate("figure8", duration=30.0, seed=5, noise=nm, imu_rate=50, odom_rate=50)
    assert np.any(np.linalg.norm(sim.detections.xyz, axis=1) > 60.0)  # the absurd ranges are in the log
    stream = align(expected_streams(sim), keep_directions=False)
    law = estimate_log_noise(stream, stream_density(sim.odom.t_ns, sim.odom.linear)).detection
    r = np.linspace(*law.ranges, 3)
    assert within(law.sigma(r), true_sigma(nm, r)), (law.law, law.sigma(r), true_sigma(nm, r))


@pytest.mark.parametrize("law", ["linear", "square"])
def test_five_percent_wild_detections_do_not_widen_the_detection_law(law):
    """5 % of the detections moved 1-3 m in a random direction (docs/benchmarks.md, "Logs nobody has run yet,
    round 6", finding 3): each sits in up to three triplets, and the first Gaussian fit on every triplet not
    gross came out 2-4x wide, three 4 σ rounds leaving it 2-4x (σ at the 5th percentile range). The first fit
    now reads the triplets within 4 σ of their range quantile's robust scale: the law within 25 % of the truth."""
    nm = per_axis_model(law)
    sim = simulate("figure8", duration=60.0, seed=3879, noise=nm, imu_rate=50, odom_rate=50)
    rng = np.random.default_rng(3879)
    xyz = sim.detections.xyz.copy()
    wild = rng.random(len(xyz)) < 0.05
    u = rng.standard_normal((int(wild.sum()), 3))
    xyz[wild] += u / np.linalg.norm(u, axis=1)[:, None] * rng.uniform(1.0, 3.0, (int(wild.sum()), 1))
    sim = replace(sim, detections=replace(sim.detections, xyz=xyz))
    stream = align(expected_streams(sim), keep_directions=False)
    found = estimate_log_noise(stream, stream_density(sim.odom.t_ns, sim.odom.linear)).detection
    r = np.linspace(*found.ranges, 3)
    assert within(found.sigma(r), true_sigma(nm, r)), (found.law, found.sigma(r), true_sigma(nm, r))


@pytest.mark.parametrize("ratio", [1.0, 3.0, 14.0])
def test_the_robust_scale_is_the_law_whatever_the_range_bearing_ratio(ratio):
    """PnP on sample_logs/figure8_camera.mcap: the detections' error along the line of sight is 14x that across it.
    The robust start's scale was the median of ``|e|²/Σc²`` over the χ²₃ median, 0.58 of the law's variance there
    (0.76x in σ; a χ²₃ only at ratio 1); now each part of the residual is whitened by its own share of the law
    before the median: Gaussian triplets at the law's variance, the dead reckoning's added, give it back."""
    rng = np.random.default_rng(3880)
    n, sigma = 20_000, 0.01
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    a = rng.standard_normal((n, 3))
    a -= np.sum(a * u, axis=1, keepdims=True) * u
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = np.cross(u, a)
    c2 = np.tile([0.25, 1.0, 0.25], (n, 1))
    motion_var = np.full(n, (0.3 * sigma) ** 2)
    k_along, k_across = 3.0 * ratio**2 / (ratio**2 + 2.0), 3.0 / (ratio**2 + 2.0)
    sd_along, sd_across = (np.sqrt(k * 1.5 * sigma**2 + motion_var) for k in (k_along, k_across))
    z = rng.standard_normal((n, 3))
    e = (z[:, :1] * u) * sd_along[:, None] + (z[:, 1:2] * a + z[:, 2:] * b) * sd_across[:, None]
    tri = Triplets(e, c2, np.full((n, 3), 8.0), motion_var, u)
    assert np.sqrt(robust_scale(tri, ratio)) == pytest.approx(sigma, rel=0.03)


def test_a_fit_told_in_full_above_is_named_not_repeated():
    """MR.CLAM 6 robot 1, riekf's report: the detection level's line repeated the held-velocity fit's whole
    description, already the gyro line's, inside its own ('scaled by 1.47 (variance components of 12936 ...)')."""
    from slamobs.pipeline.noise import NoiseSettings

    fit = "variance components of 12936 detection-pair residuals over lags of 0.5-32 s"
    levels = NoiseSettings(
        *(0.01,) * 9,
        sources={"gyro": "estimated", "velocity": "estimated", "detection": "estimated"},
        methods={"gyro": fit, "velocity": fit, "detection": f"635 detection triplets; scaled by 1.47 ({fit})"},
    )
    gyro, velocity, detection = levels.lines()[:3]
    assert gyro.endswith(f": {fit})") and velocity.endswith(": the same fit)")
    assert detection.endswith(": 635 detection triplets; scaled by 1.47 (the same fit as gyro))")


def test_the_term_the_chosen_law_lacks_is_not_shown_as_a_measured_zero():
    """figure8.mcap's detections fit b + a*r^2: 'detection_per_m = 0 m/m (estimated, ± 0: the same fit)' read as a
    measured zero; the line is left out (the detection line names the law chosen) and run.json's levels say why."""
    from cli_checks import SAMPLES

    shown = invoke("info", "--noise", SAMPLES / "figure8.mcap")
    assert shown.exit_code == 0, shown.output
    assert "law b + a*r^2 chosen over sigma0 + k*r" in shown.output and "detection_per_m2 = " in shown.output
    assert "detection_per_m = " not in shown.output
    levels = json.loads(invoke("info", "--noise", "--json", SAMPLES / "figure8.mcap").stdout)["levels"]
    assert levels["detection_per_m"] == {
        "value": 0.0,
        "unit": "m/m",
        "source": "estimated",
        "method": "not a term of the law chosen, b + a*r^2",
        "uncertainty": None,
    }


def test_info_noise_names_a_camera_extrinsic_turned_before_any_run(tmp_path):
    """A camera turned 90 deg about its z in /tf_static: riekf APE 9 m; `info --noise` said nothing of it (round 6).
    It now says what the detection pairs say, before any estimator runs; as recorded, nothing."""
    from slamobs.pipeline.lie import quats_to_rots, rots_to_quats, so3_exp

    sim = simulate("figure8", seed=2, duration=20.0)
    camera = sim.static_tf[0]
    turned = quats_to_rots(np.asarray(camera.quat_xyzw)[None])[0] @ so3_exp(np.array([0.0, 0.0, np.pi / 2]))
    tf = replace(camera, quat_xyzw=rots_to_quats(np.ascontiguousarray(turned[None]))[0])
    for name, s in (("clean", sim), ("turned", replace(sim, static_tf=[tf, *sim.static_tf[1:]]))):
        write_log(s, tmp_path / f"{name}.mcap")
        shown = invoke("info", "--noise", tmp_path / f"{name}.mcap")
        assert shown.exit_code == 0, shown.output
        said = [line for line in shown.output.splitlines() if "check the camera's extrinsic" in line]
        assert len(said) == (name == "turned") and "turned by 90 deg" in "".join(said or ["turned by 90 deg"]), said
    assert said[0].endswith("[detections /fiducial_transforms, camera frame camera]"), said


def test_info_noise_names_two_tags_that_share_an_id(tmp_path):
    """One tag's id given to another (two tag families): the run warned that two tags share the id, `info --noise`
    did not (it printed the detection pairs' checks only; session 18). Now it prints the alignment's warnings too."""
    sim = simulate("figure8", seed=5, duration=20.0)
    ids = sim.detections.ids.copy()
    ids[ids == 60] = 10
    for name, s in (("clean", sim), ("shared", replace(sim, detections=replace(sim.detections, ids=ids)))):
        write_log(s, tmp_path / f"{name}.mcap")
        shown = invoke("info", "--noise", tmp_path / f"{name}.mcap")
        assert shown.exit_code == 0, shown.output
        said = [line for line in shown.output.splitlines() if "two tags share the id" in line]
        assert len(said) == (name == "shared"), shown.output


def test_info_noise_names_an_imu_dropping_samples_in_short_bursts(tmp_path):
    """A 400 Hz IMU with 0.2 s dropped every 4 s, written to MCAP: `info` counted the gaps among its stamp notes, the
    run and `info --noise` said nothing (the run's gap note starts at 0.5 s; session 18)."""
    sim = simulate("figure8", seed=5, duration=20.0, imu_rate=400.0)
    t = (sim.imu.t_ns - sim.imu.t_ns[0]) * 1e-9
    keep = (t % 4.0) > 0.2
    imu = sim.imu
    dropped = replace(imu, t_ns=imu.t_ns[keep], rec_ns=imu.rec_ns[keep], gyro=imu.gyro[keep], accel=imu.accel[keep])
    for name, s in (("clean", sim), ("bursts", replace(sim, imu=dropped))):
        write_log(s, tmp_path / f"{name}.mcap")
        shown = invoke("info", "--noise", tmp_path / f"{name}.mcap")
        assert shown.exit_code == 0, shown.output
        said = [line for line in shown.output.splitlines() if "gaps over 5x its median interval" in line]
        assert len(said) == (name == "bursts"), shown.output
    assert "/imu/data: 4 gaps" in said[0] and "longest 0.205 s" in said[0], said


def test_info_noise_names_a_gyro_whose_x_and_z_are_swapped(tmp_path):
    """An IMU's gyro x and z swapped (mounted on its side with another's extrinsic), written to MCAP: riekf was lost
    (22 m on a 40 s figure 8) with only a velocity-scale warning that pointed at the velocity (session 19). The
    alignment's turned-gyro check sees the same turn (yaw on x, 88 deg from the odometry's): the pairs' misread line
    names that warning rather than a cause of its own, and the velocity-scale line says the turn upsets it too (two
    warnings naming two causes until session 26)."""
    sim = simulate("figure8", seed=5, duration=20.0)
    swapped = replace(sim, imu=replace(sim.imu, gyro=sim.imu.gyro[:, [2, 1, 0]].copy()))
    write_log(swapped, tmp_path / "swapped.mcap")
    shown = invoke("info", "--noise", tmp_path / "swapped.mcap")
    assert shown.exit_code == 0, shown.output
    said = [line for line in shown.output.splitlines() if "angular velocity's x and z swapped" in line]
    assert len(said) == 1 and "the same turn the warning on /imu/data's gyro measures" in said[0], shown.output
    assert "check the gyro's unit and axes" not in said[0] and "record the transform of 'imu_link'" in said[0], said
    (turned,) = [
        x for x in shown.output.splitlines() if "warning: /imu/data: in the body frame its gyro turns about" in x
    ]
    # info runs nothing: the warning says what a run will do (it said "the run used it as read" until session 27)
    assert "a run takes it as read" in turned and "the run used" not in shown.output, turned
    scaled = [line for line in shown.output.splitlines() if "the detections say the body moved" in line]
    assert scaled and all("the turned gyro upsets this reading too" in x for x in scaled), shown.output
    # which topics, on a log of many (alignment.stream_topics)
    assert said[0].endswith("[gyro /imu/data, odometry /odom, detections /fiducial_transforms]"), said


@pytest.mark.parametrize(
    ("axes", "said"),
    [
        (([1, 0, 2], [1.0, 1.0, 1.0]), "x and y were swapped"),
        (([0, 1, 2], [1.0, -1.0, 1.0]), "y were of the wrong sign"),
    ],
)
def test_info_noise_names_a_gyro_misread_about_x_or_y_by_its_accelerometer(tmp_path, axes, said):
    """An IMU's gyro x and y swapped (or y of the wrong sign), written to MCAP: riekf 0.87 m (0.21 m) against
    0.011 m on a 40 s figure 8, exit 0, no word (x and y swapped) or a velocity-scale warning pointing at the
    velocity (session 19): the detection pairs hardly see roll and pitch rates; the accelerometer's gravity
    direction does. The clean log's streams say nothing."""
    order, sign = axes
    sim = simulate("figure8", seed=5, duration=30.0)
    assert not [n for n in align(expected_streams(sim)).notes if "gyro reads as if" in n]
    misread = replace(sim, imu=replace(sim.imu, gyro=sim.imu.gyro[:, order] * np.asarray(sign)))
    write_log(misread, tmp_path / "misread.mcap")
    shown = invoke("info", "--noise", tmp_path / "misread.mcap")
    assert shown.exit_code == 0, shown.output
    lines = [line for line in shown.output.splitlines() if "gyro reads as if" in line]
    assert len(lines) == 1 and f"/imu/data: the gyro reads as if its {said}: " in lines[0], shown.output


def test_a_gyro_misread_in_an_imu_mounted_upside_down_is_named_in_its_own_frame():
    """The IMU upside down (its /tf_static extrinsic) with its gyro's x and y swapped in its own frame: in the body
    frame that is a swap with both signs, which the body-frame candidates fit 0.56-0.65x as well (no word); undone
    in the IMU's frame it fits 73.9x better."""
    sim = simulate("figure8-imu-flipped", seed=5, duration=30.0)
    assert not [n for n in align(expected_streams(sim)).notes if "gyro reads as if" in n]
    swapped = replace(sim, imu=replace(sim.imu, gyro=sim.imu.gyro[:, [1, 0, 2]].copy()))
    said = [n for n in align(expected_streams(swapped)).notes if "gyro reads as if" in n]
    assert len(said) == 1 and said[0].startswith("warning: /imu/data: the gyro reads as if its x and y were swapped"), (
        said
    )


@pytest.mark.parametrize("mount", [(0.0, 45.0, 0.0), (30.0, 0.0, 90.0), (20.0, -30.0, 135.0)])
def test_a_gyro_with_x_and_y_swapped_on_a_tilted_mount_is_named(mount):
    """The IMU mounted tilted (its /tf_static extrinsic), its gyro's x and y swapped in its own frame: the misread's
    ``omega x v`` moved the body acceleration so that 4 of 39 block pairs kept their samples near |g| as read, the
    check had no cost and said nothing (pitched 45 deg: riekf 10.1 m, exit 0; session 21). Each candidate's costs
    are now taken on the samples its own angular velocity keeps. The log as generated says nothing."""
    sim = simulate(customize(get_scenario("figure8"), imu_rpy_deg=mount), seed=5, duration=30.0)
    assert not [n for n in align(expected_streams(sim)).notes if "gyro reads as if" in n]
    swapped = replace(sim, imu=replace(sim.imu, gyro=sim.imu.gyro[:, [1, 0, 2]].copy()))
    said = [n for n in align(expected_streams(swapped)).notes if "gyro reads as if" in n]
    assert len(said) == 1 and said[0].startswith("warning: /imu/data: the gyro reads as if its x and y were swapped"), (
        said
    )


def test_info_noise_names_odometry_that_repeats_stamps_with_other_values(tmp_path):
    """Every 5th odometry message sent again with its stamp and zero velocity, written to MCAP: the readers keep
    both (a note counts them); riekf 0.053 m against 0.011 m with no warning (session 19)."""
    sim = simulate("figure8", seed=5, duration=20.0)
    o = sim.odom
    k = np.sort(np.r_[np.arange(o.t_ns.size), np.arange(0, o.t_ns.size, 5)])
    again = np.r_[False, k[1:] == k[:-1]]
    linear = o.linear[k].copy()
    linear[again] = 0.0
    odom = replace(
        o,
        t_ns=o.t_ns[k],
        rec_ns=o.rec_ns[k] + again,
        linear=linear,
        angular=o.angular[k],
        position=o.position[k],
        quat_xyzw=o.quat_xyzw[k],
    )
    write_log(replace(sim, odom=odom), tmp_path / "again.mcap")
    shown = invoke("info", "--noise", tmp_path / "again.mcap")
    assert shown.exit_code == 0, shown.output
    said = [line for line in shown.output.splitlines() if "share their stamp with the one before" in line]
    assert len(said) == 1 and "/odom: 200 of its 1200 samples" in said[0], shown.output


def test_info_noise_names_an_imu_stamped_off_the_odometrys_clock(tmp_path):
    """The IMU's stamps and record times 0.3 s late against every other topic's, written to MCAP: every clock rule
    compares a topic's stamps with its record times, which agree here; riekf 0.53 m against 0.011 m, exit 0, no
    warning (session 21). The gyro against the odometry's own angular velocity names it."""
    sim = simulate("figure8", seed=5, duration=20.0)
    late = 300_000_000
    write_log(
        replace(sim, imu=replace(sim.imu, t_ns=sim.imu.t_ns + late, rec_ns=sim.imu.rec_ns + late)), tmp_path / "l.mcap"
    )
    shown = invoke("info", "--noise", tmp_path / "l.mcap")
    assert shown.exit_code == 0, shown.output
    said = [line for line in shown.output.splitlines() if "stamps look" in line]
    assert len(said) == 1 and "/imu/data: its angular velocity's stamps look 0.300 s late against /odom" in said[0], (
        shown.output
    )


def test_a_detection_law_at_its_floor_says_so(tmp_path):
    """Detections whose σ grows as r² with nothing at zero range, seen at 5-14 m: the fit's value at zero range is
    not fixed by the data and is raised to ``MIN_DETECTION_M``. TagSLAM test_11 printed that floor as
    "detection = 0.0001 m (estimated, ± 0)", a measurement it is not; the line now says the fit was raised to the
    floor and over which ranges."""
    nm = replace(NoiseModel(), detection_base=0.0, detection_per_m=0.0, detection_per_m2=0.004)
    write_log(simulate("figure8", duration=60.0, seed=9533, noise=nm), tmp_path / "r2.mcap")
    shown = invoke("info", "--noise", tmp_path / "r2.mcap")
    assert shown.exit_code == 0, shown.output
    (line,) = [x for x in shown.output.splitlines() if x.strip().startswith("detection = ")]
    assert "raised to the floor 0.0001 m" in line and "do not fix it" in line, line
    (law,) = [x for x in shown.output.splitlines() if x.strip().startswith("detection_per_m2 = ")]
    assert "floor" not in law, law


def test_info_noise_says_batch_re_estimates_a_held_velocitys_level(tmp_path):
    """MR.CLAM 6 robot 3: `info --noise` printed velocity = 0.0407 m/s/sqrt(Hz) "for batch and riekf", where batch's
    run used 0.0119 (its held velocity's level from its own solution, batch.held_velocity; h-user15). A held
    (commanded) velocity: the line says batch re-estimates it; with batch.held_velocity off it does not."""
    sim = simulate("circle", duration=20.0, seed=7)
    n = sim.odom.linear.shape[0]
    held_odom = replace(sim.odom, linear=np.repeat(sim.odom.linear[::10], 10, axis=0)[:n])
    write_log(replace(sim, odom=held_odom), tmp_path / "held.mcap")
    shown = invoke("info", "--noise", tmp_path / "held.mcap")
    assert shown.exit_code == 0, shown.output
    assert "riekf uses them, batch starts from them" in shown.output
    assert "velocity (batch): not the level above: batch re-estimates it" in shown.output, shown.output
    off = tmp_path / "off.yaml"
    off.write_text("batch:\n  held_velocity: off\n")
    shown = invoke("info", "--noise", tmp_path / "held.mcap", "--config", off)
    assert shown.exit_code == 0 and "velocity (batch)" not in shown.output, shown.output
    moving = invoke("info", "--noise", write_log(sim, tmp_path / "moving.mcap"))
    assert moving.exit_code == 0 and "velocity (batch)" not in moving.output, moving.output


def test_a_held_level_at_the_fit_s_floor_says_so():
    """MR.CLAM 6 r5: `velocity_bias = 1e-06 m/s (estimated, ± 0.00209: the same fit)`, a prior at the held fit's
    floor (noise_estimation.MIN_LEVEL) below its own standard error, said as a measurement."""
    from slamobs.pipeline.noise import floored
    from slamobs.pipeline.noise_estimation import MIN_LEVEL, Estimate

    e = floored("velocity_bias", Estimate(MIN_LEVEL, 0.00209, "variance components of ...", 100))
    assert e.value == MIN_LEVEL and "at its floor 1e-06 m/s" in e.method, e.method
    assert "noise.velocity_bias in run.yaml" in e.method, e.method
    above = Estimate(0.0055, 0.0002, "variance components of ...", 100)
    assert floored("gyro_bias", above) is above


def test_a_gyro_level_of_an_angular_velocity_differentiated_from_poses_says_so(tmp_path):
    """TagSLAM test_11 (its VIO twist has no angular part; the readers differentiate the orientations): `info
    --noise` printed `gyro = [0.000673, ...] rad/s/sqrt(Hz) (estimated, ...: quintic-prediction residuals ...)` as if
    a gyro had been measured. A generated figure 8 whose odometry's twist.angular is zero, read as the angular
    velocity: the gyro line and the level's method (run.json's) say what it is the noise of, in run.json
    input.derived's words; the same log's IMU read as the gyro says nothing of the kind."""
    from slamobs.pipeline.readers import read_log

    sim = simulate("figure8", duration=20.0, seed=3401)
    odom = replace(sim.odom, angular=np.zeros_like(sim.odom.angular))
    log = write_log(replace(sim, odom=odom, noise=replace(sim.noise, odom_angular=0.0)), tmp_path / "vio.mcap")
    config = tmp_path / "run.yaml"
    config.write_text("topics:\n  angular_velocity: /odom\n")
    how = read_log(log, {"angular_velocity": "/odom"}).derived["angular_velocity"]
    assert how.startswith("differentiated from the orientations of /odom"), how
    said = f"of an angular velocity not measured but derived, {how} (run.json input.derived): "
    res = invoke("info", "--noise", str(log), "--config", str(config))
    assert res.exit_code == 0, res.output
    line = next(x for x in res.output.splitlines() if x.strip().startswith("gyro = "))
    assert "(estimated, ± " in line and f": {said}" in line, line
    levels = json.loads(invoke("info", "--noise", "--json", str(log), "--config", str(config)).output)["levels"]
    assert levels["gyro"]["method"].startswith(said) and "derived" not in levels["velocity"]["method"], levels
    plain = invoke("info", "--noise", str(log))  # the IMU's gyro
    line = next(x for x in plain.output.splitlines() if x.strip().startswith("gyro = "))
    assert "derived" not in line, line


def test_riekf_on_a_log_stated_8x_above_its_noise_takes_the_level_its_innovations_explain_better(tmp_path):
    """A rig (gyro 60x, velocity 20x the default densities) whose messages state 8x the noise drawn: believed (a
    coloured noise may be louder than its samples show), riekf weighed both streams 8x too loose (1.2-1.9x its APE
    with the true levels on session 33's flights and hand-held rigs). It now runs its first stretch at the stated
    and at the samples' levels and keeps the one whose innovations explain the detections better: here the samples',
    within 1.2x of the run given the truth; run.json and the note say which and why."""
    ape, meta = _stated_rig_runs(tmp_path, 3640, 8)
    assert ape["auto"] < 1.2 * ape["true"], ape
    rec = meta["auto"]["observer"]["filter"]["stated_levels"]
    assert rec["used"] == {"gyro": "samples", "velocity": "samples"}, rec
    assert [t["levels"] for t in rec["tried"]][0] == {"gyro": "stated", "velocity": "stated"}, rec
    (note,) = [n for n in meta["auto"]["notes"] if n.startswith("riekf: gyro at the samples' white-noise estimate")]
    assert "not the stated" in note and "as stated" in note and "observer.filter.stated_levels" in note, note
    assert "stated_levels" not in meta["true"]["observer"]["filter"]  # levels given: nothing tried


def test_riekf_keeps_a_stated_velocity_level_a_coloured_odometry_earns(tmp_path):
    """The case a stated level above the samples' is believed for: an odometry whose error is coloured (AR(1), 0.95
    per sample at 10 Hz) states its low-frequency level, 3.4x above what its white-looking samples show. riekf tries
    the samples' level too and keeps the stated one: its innovations explain the detections worse at the samples'
    (seed=3652: APE 0.078 m there against 0.056 as stated)."""
    from slamobs.pipeline.api import run_log
    from slamobs.pipeline.lie import quats_to_rots
    from slamobs.pipeline.noise import DEFAULTS
    from slamobs.pipeline.simulate.scenarios import handheld

    phi, white = 0.95, 3 * DEFAULTS["velocity"][0]
    gyro = 30 * DEFAULTS["gyro"][0]
    nm = replace(
        NoiseModel(),
        gyro=gyro * np.sqrt(200),
        odom_linear=white * np.sqrt(10),
        detection_base=0.03,
        detection_per_m=0.006,
    )
    sim = simulate(handheld(), noise=nm, detection_rate=15, duration=90, seed=3652, imu_rate=200, odom_rate=10)
    rng = np.random.default_rng(3652 + 11)
    e = rng.standard_normal((len(sim.odom.t_ns), 3)) * 10 * DEFAULTS["velocity"][0] * np.sqrt(10) * (1 - phi)
    for k in range(1, len(e)):
        e[k] += phi * e[k - 1]
    linear = sim.odom.linear + e
    # the poses dead-reckoned from the coloured twist (a wheel odometry's): their drift says nothing of the level
    # (noise.drift_evidence), so riekf's own test decides; poses left as simulated (the twist before the coloured
    # error) would keep the stated level by that drift, tests/test_odometry_drift.py
    world = np.einsum("nij,nj->ni", quats_to_rots(sim.odom.quat_xyzw), linear)
    step = np.diff(sim.odom.t_ns)[:, None] * 1e-9
    position = np.vstack(
        [sim.odom.position[:1], sim.odom.position[0] + np.cumsum(0.5 * (world[1:] + world[:-1]) * step, 0)]
    )
    sim = replace(sim, odom=replace(sim.odom, linear=linear, position=position))
    low = np.hypot(10 * DEFAULTS["velocity"][0], white) * np.sqrt(10)  # per-sample σ of the low-frequency level
    log = tmp_path / "coloured.mcap"
    write_log(replace(sim, noise=replace(nm, odom_linear=low)), log)
    run_log(log, tmp_path / "auto", observer="riekf", config={"evaluation": {"plots": False}}, force=True)
    meta = json.loads((tmp_path / "auto" / "run.json").read_text())
    rec = meta["observer"]["filter"]["stated_levels"]
    assert rec["used"]["velocity"] == "stated", rec
    assert max(s / w for s, w in zip(rec["stated"]["velocity"], rec["samples"]["velocity"])) > 3, rec
    swapped = [t for t in rec["tried"] if t["levels"]["velocity"] == "samples"]
    assert swapped and all(t["deviance_mean"] > rec["tried"][0]["deviance_mean"] for t in swapped), rec
    (note,) = [n for n in meta["notes"] if n.startswith("riekf: gyro at the stated") or n.startswith("riekf: velocity")]
    assert "velocity at the stated" in note and "no better by a likelihood-ratio test" in note, note


def test_info_noise_with_a_config_says_the_tag_size_warning_a_run_gives(tmp_path):
    """Round 26 (h-newuser12): `slamobs info --noise --config CFG LOG` on TagSLAM test_21 with ``tags.size: 0.16``
    and its tagslam.yaml (tags 100-107 of 0.1 m) printed the noise levels and the camera warnings but not the size
    warning the run gives (``landmarks._size_against_stated``): the tag stage's warnings are the run's, so info says
    them too (``run.detection_checks``, its one list)."""
    from slamobs.pipeline.readers import read_log

    log = tmp_path / "corners.mcap"
    res = invoke("simulate", "circle", "-o", log, "--duration", "6", "--camera", "corners", "--tag-size", "0.6", "-q")
    assert res.exit_code == 0, res.output
    ids = sorted({int(i) for s in read_log(log).tag_corners for i in s.ids})
    listed = "".join(f"       - {{id: {i}, size: 0.3}}\n" for i in ids)
    (tmp_path / "tagslam.yaml").write_text(f"bodies:\n - world:\n     is_static: true\n     tags:\n{listed}")
    config = tmp_path / "run.yaml"
    config.write_text(f"cameras: [{tmp_path / 'tagslam.yaml'}]\ntags:\n  size: 0.6\n")
    shown = invoke("info", "--noise", "--config", config, log)
    assert shown.exit_code == 0, shown.output
    said = [line.strip() for line in shown.stdout.splitlines() if "tagslam.yaml states 0.3 m" in line]
    assert len(said) == 1 and said[0].startswith("warning: ") and "the run gave them 0.6 m (tags.size)" in said[0]
