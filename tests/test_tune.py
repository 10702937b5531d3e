"""``slamobs tune``: the search space keeps every observer's stability conditions, tuned gains beat the defaults
on a log the tune never saw, a tune resumes, runs on a real Dask cluster, and a killed tune leaves no process and
no half-written file."""

from __future__ import annotations

import json
import math
import os
import random
import signal
import subprocess
from dataclasses import replace
from pathlib import Path

import pytest

from batch_checks import CLI, wait_for, wait_gone
from kill_checks import dask_worker, stop
from kill_checks import scheduler  # noqa: F401 - a fixture: a real Dask scheduler process, as the batch tests

pytest.importorskip("optuna")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    from slamobs.pipeline.simulate import simulate, write_log

    base = tmp_path_factory.mktemp("tune_logs")
    return [write_log(simulate("figure8", duration=10.0, seed=70 + i), base / f"f{i}.mcap") for i in range(3)]


def test_search_space_stays_within_each_observers_conditions():
    from slamobs.pipeline.estimators import ESTIMATORS
    from slamobs.pipeline.tune import space

    rng = random.Random(5)
    for spec in ESTIMATORS.values():
        defaults = spec.resolve_gains(None)
        assert space.in_range(spec, space.params_of(spec, defaults)), spec.name  # trial 0 is a point of the space
        assert space.gains_of(spec, space.params_of(spec, defaults)) == pytest.approx(defaults)
        dists = space.distributions(spec)
        for _ in range(200):  # the corners of the space too
            params = {
                k: math.exp(
                    rng.choice([math.log(d.low), math.log(d.high), rng.uniform(math.log(d.low), math.log(d.high))])
                )
                for k, d in dists.items()
            }
            spec.resolve_gains(space.gains_of(spec, params))  # raises GainError on a broken condition


def _run_ape(log: Path, out: Path, config: Path | None = None) -> float:
    """What ``slamobs run`` reports for ``log`` (translation APE), with ``config`` (e.g. a tune's gains.yaml) or the
    defaults: the holdout's numbers are promised to be these (README, "Do the gains transfer?")."""
    extra = ["--config", str(config)] if config is not None else []
    done = subprocess.run(
        [*CLI, "run", str(log), "-o", str(out), "-q", *extra], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return json.loads((out / "report.json").read_text())["ape"]["translation_m"]["rmse"]


def test_tuned_gains_beat_the_defaults_on_a_held_back_log_and_a_rerun_extends(logs, tmp_path):
    import pandas as pd

    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.errors import InputError
    from slamobs.pipeline.tune.study import TuneOptions, run_tune

    out = tmp_path / "tune"
    options = TuneOptions(out=out, observer="fast-adaptation", trials=24, jobs=2, seed=1)
    result = run_tune(logs[:2], options)
    assert result.ran == 24
    summary = json.loads((out / "tune.json").read_text())
    # trial 0 runs the defaults, so best <= defaults always holds: the search must have found better gains
    assert summary["defaults"]["trial"] == 0 and summary["best"]["objective"] < summary["defaults"]["objective"]
    trials = pd.read_parquet(out / "trials.parquet")
    assert len(trials) == 24 * 2 and set(trials["status"]) <= {"ok", "diverged"}
    # each worker read each log once, not once per trial
    reads = trials[trials["read_s"] > 0].groupby("worker")["log_index"]
    assert (reads.count() == reads.nunique()).all() and reads.count().sum() <= 2 * 2
    assert (out / "objective.png").stat().st_size > 0
    assert [r["log"] for r in summary["validation"]["rows"]] == [str(p) for p in logs[:2]]

    assert load_config(out / "gains.yaml").observer == "fast-adaptation"
    held_back = logs[2]
    # the tuned gains beat the defaults where the tune never looked, as `slamobs run` reports them
    default_ape = _run_ape(held_back, tmp_path / "run_defaults")
    tuned_ape = _run_ape(held_back, tmp_path / "run_tuned", out / "gains.yaml")  # gains.yaml is a --config
    assert tuned_ape < default_ape, (tuned_ape, default_ape)

    # the same command with more trials runs only the new ones; a holdout log is scored as `slamobs run` scores it
    again = run_tune(logs[:2], replace(options, trials=26, holdout=(held_back,)))
    assert again.ran == 2 and len(pd.read_parquet(out / "trials.parquet")) == 26 * 2
    held = again.summary["holdout"]
    final_ape = _run_ape(held_back, tmp_path / "run_final", out / "gains.yaml")
    # equal up to the run's tables storing positions in steps of 2**-20 m (docs/outputs.md), which its report
    # reads: the holdout scores the unrounded poses; an RMSE (its best alignment's too) moves by at most the
    # largest position change, 3**0.5 * 2**-21 m < 2**-20 m (measured 1.5e-8 m apart)
    assert held["rows"][0]["defaults"] == pytest.approx(default_ape, rel=0, abs=2.0**-20)
    assert held["rows"][0]["tuned"] == pytest.approx(final_ape, rel=0, abs=2.0**-20)
    assert held["tuned_better"] == int(final_ape < default_ape)
    assert "## Holdout logs" in (out / "tune.md").read_text()
    with pytest.raises(InputError, match="both a tuning log and a --holdout log"):
        run_tune(logs[:2], replace(options, trials=26, holdout=(logs[0],)))
    with pytest.raises(InputError, match="another observer"):  # OUT holds this tune: never mixed with another
        run_tune(logs[:2], replace(options, observer="hashim"))
    with pytest.raises(InputError, match="another set of logs"):
        run_tune(logs[1:], options)


def _tune_args(logs, out: Path, *extra) -> list[str]:
    return [*CLI, "tune", *map(str, logs[:2]), "--observer", "fast-adaptation", "-o", str(out), *map(str, extra)]


def _complete_trials(out: Path) -> int:
    import optuna

    from slamobs.pipeline.tune.study import STUDY, journal_storage

    study = optuna.load_study(study_name=STUDY, storage=journal_storage(out))
    return len(study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)))


def test_killed_tune_leaves_no_process_nor_partial_file_and_resumes(logs, tmp_path):
    out = tmp_path / "tune"
    err = tmp_path / "tune.err"
    for sig in (signal.SIGTERM, signal.SIGKILL):
        with open(err, "w") as fh:
            proc = subprocess.Popen(
                _tune_args(logs, out, "--trials", 400, "-j", 2),
                stdout=subprocess.DEVNULL,
                stderr=fh,
                start_new_session=True,
            )
        try:
            assert wait_for(
                lambda: "tune: " in err.read_text() and "trials, best" in err.read_text() or proc.poll() is not None,
                180,
            ), err.read_text()
            os.kill(proc.pid, sig)
            code = proc.wait(timeout=60)
            assert code == (143 if sig == signal.SIGTERM else -9), err.read_text()
            if sig == signal.SIGTERM:
                assert "SIGTERM: tune stopped" in err.read_text() and "Traceback" not in err.read_text()
            assert wait_gone(proc.pid) == []
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
        assert not [p.name for p in out.iterdir() if ".tmp-" in p.name]
        assert not (out / "gains.yaml").exists()  # results only once a tune has finished
    done_before = _complete_trials(out)
    assert done_before >= 2
    total = done_before + 4
    done = subprocess.run(
        _tune_args(logs, out, "--trials", total, "-j", 2), capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert "4 trials run now" in done.stdout, done.stdout
    summary = json.loads((out / "tune.json").read_text())
    assert summary["trials"]["complete"] == total and summary["defaults"]["trial"] == 0


def test_a_killed_forced_tune_leaves_the_previous_tune(logs, tmp_path):
    """A forced tune stopped (SIGTERM) or killed (SIGKILL) before its results: OUT keeps the tune it was to replace,
    the same bytes after SIGTERM, and after SIGKILL once the next tune in OUT has put its journal back."""
    out, err = tmp_path / "tune", tmp_path / "tune.err"
    done = subprocess.run(_tune_args(logs, out, "--trials", 2, "-j", 1), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    for sig in (signal.SIGTERM, signal.SIGKILL):
        with open(err, "w") as fh:
            proc = subprocess.Popen(
                _tune_args(logs, out, "--trials", 400, "-j", 2, "--force"),
                stdout=subprocess.DEVNULL,
                stderr=fh,
                start_new_session=True,
            )
        try:
            assert wait_for(lambda: "trials, best" in err.read_text() or proc.poll() is not None, 180)
            os.kill(proc.pid, sig)
            assert proc.wait(timeout=60) == (143 if sig == signal.SIGTERM else -9), err.read_text()
            assert wait_gone(proc.pid) == []
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
        if sig == signal.SIGTERM:
            assert "is kept as it was" in err.read_text() and "run the same command" not in err.read_text()
            assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    done = subprocess.run(_tune_args(logs, out, "--trials", 2, "-j", 1), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "0 trials run now" in done.stdout, done.stdout + done.stderr
    journal = (out / "tune.journal").read_bytes()  # the previous tune's, which the resumed tune may append to
    assert _complete_trials(out) == 2 and journal.startswith(before["tune.journal"])
    assert not (out / ".tune.journal.previous").exists()


def test_tune_on_a_dask_cluster(logs, tmp_path, scheduler):
    import pandas as pd

    from slamobs.pipeline.tune.study import TuneOptions, run_tune

    _, address = scheduler
    worker = dask_worker(address, tmp_path, "w1")
    try:
        result = run_tune(
            logs[:2],
            TuneOptions(
                out=tmp_path / "tune", observer="fast-adaptation", trials=3, scheduler=address, wait_workers=60
            ),
        )
    finally:
        stop(worker)
    assert result.ran == 3
    trials = pd.read_parquet(tmp_path / "tune" / "trials.parquet")
    assert len(trials) == 6 and trials["worker"].str.startswith("tcp://127.0.0.1:").all()
    assert (trials["read_s"] > 0).sum() == 2  # one worker: each log read once


def test_a_log_without_truth_is_a_one_line_error(logs, tmp_path):
    cfg = tmp_path / "no_truth.yaml"
    cfg.write_text("topics:\n  truth: ''\n")  # the truth role switched off: nothing to tune against
    done = subprocess.run(
        _tune_args(logs, tmp_path / "t", "--trials", 2, "-j", 1, "--config", cfg),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith(f"error: {logs[0]}: no ground truth"), last
    assert "unless the tune is --target batch" in last, last  # the way out for logs without truth, said
    # no trial completed: no output behind (README: a command that cannot finish leaves none), not a journal and
    # lock that a re-run with the log fixed would have to be told to --force past
    assert not (tmp_path / "t").exists()


def test_a_tune_says_the_configs_gains_for_its_observer_are_not_what_it_compares_with(logs, tmp_path):
    """TagSLAM test_11 with examples/tagslam_test11.yaml (gamma 0.01), `tune --target batch`: "best 1.537 m
    (defaults 3.88 m)", the defaults being gamma 1, not the gains the user's runs had, and nothing said so (only
    --help); the start line now names them and how to score them."""
    cfg = tmp_path / "gains.yaml"
    cfg.write_text("gains:\n  fast-adaptation:\n    gamma: 0.01\n")
    done = subprocess.run(
        _tune_args(logs, tmp_path / "t", "--trials", 1, "-j", 1, "--config", cfg),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert (
        f"tune: {cfg} sets fast-adaptation's gains (gamma 0.01): a tune does not use them; its trial 0 and "
        "'defaults' are the observer's own defaults" in done.stderr
    ), done.stderr


def test_a_holdout_log_that_cannot_be_scored_keeps_the_tunes_results(logs, tmp_path):
    from mcap.reader import make_reader
    from mcap.writer import Writer

    no_truth = tmp_path / "no_truth.mcap"  # logs[2] without its motion-capture topic
    with open(logs[2], "rb") as src, open(no_truth, "wb") as dst:
        writer, ids = Writer(dst), {}
        writer.start(profile="ros2")
        for schema, channel, message in make_reader(src).iter_messages():
            if channel.topic == "/mocap/pose":
                continue
            if channel.id not in ids:
                sid = writer.register_schema(schema.name, schema.encoding, schema.data) if schema else 0
                ids[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, sid, channel.metadata
                )
            writer.add_message(ids[channel.id], message.log_time, message.data, message.publish_time)
        writer.finish()
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not a log")
    done = subprocess.run(
        _tune_args(logs, tmp_path / "j", "--trials", 2, "--holdout", junk), capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 2 and done.stderr.strip().splitlines()[-1].startswith(f"error: {junk}: not a ")
    assert not (tmp_path / "j").exists()  # refused before any trial
    done = subprocess.run(
        _tune_args(logs, tmp_path / "t", "--trials", 2, "-j", 1, "--holdout", no_truth),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines()[-1].startswith(f"error: {no_truth}: no ground truth")
    assert (tmp_path / "t" / "gains.yaml").is_file() and (tmp_path / "t" / "tune.md").is_file()  # trials kept


def test_a_forced_tune_that_fails_leaves_the_previous_tune_unchanged(logs, tmp_path):
    """--force on a tune in OUT that then fails before a trial completes (here: no truth) leaves the previous tune as
    it was, every file the same bytes (it deleted them first); a forced tune that finishes replaces them."""
    out = tmp_path / "t"
    done = subprocess.run(_tune_args(logs, out, "--trials", 2, "-j", 1), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert "tune.journal" in before and "gains.yaml" in before
    cfg = tmp_path / "no_truth.yaml"
    cfg.write_text("topics:\n  truth: ''\n")
    args = _tune_args(logs, out, "--trials", 2, "-j", 1, "--force", "--config", cfg)
    done = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and "no ground truth" in done.stderr, done.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    done = subprocess.run(_tune_args(logs, out, "--trials", 1, "-j", 1, "--force"), capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert _complete_trials(out) == 1 and sorted(p.name for p in out.iterdir()) == sorted(before)


def test_a_killed_forced_tune_gives_the_previous_tune_back_to_the_next(tmp_path):
    """A forced tune killed before its results leaves the previous journal set aside: the next tune in OUT puts it
    back before anything else (the killed tune's own journal dropped)."""
    from slamobs.pipeline.tune import study

    (tmp_path / study.JOURNAL).write_text("previous")
    (tmp_path / "gains.yaml").write_text("previous gains")
    study.set_aside(tmp_path)
    (tmp_path / study.JOURNAL).write_text("the killed forced tune's")
    assert study.put_back(tmp_path) and not study.put_back(tmp_path)
    assert (tmp_path / study.JOURNAL).read_text() == "previous" and not (tmp_path / study.PREVIOUS).exists()
    study.set_aside(tmp_path)
    assert study.replace_results(tmp_path, lambda: {"written": 1}) == {"written": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # the new results are the writer's to write


def test_a_resumed_tune_samples_new_gains_not_the_earlier_ones_again(logs, tmp_path):
    """A resumed (or extended) tune's sampler does not start its random draws over: its first draw would be the
    gains of the first sampled trial again (found by benchmarks/kill_matrix.py: a tune killed in its first round
    and run again ran one gain set twice and one never)."""
    import pandas as pd

    from slamobs.pipeline.tune.study import TuneOptions, run_tune

    options = TuneOptions(out=tmp_path / "tune", observer="fast-adaptation", trials=2, jobs=1, seed=1)
    run_tune(logs[:1], options)
    run_tune(logs[:1], replace(options, trials=4))
    trials = pd.read_parquet(tmp_path / "tune" / "trials.parquet")
    gains = trials[trials["state"] == "COMPLETE"][[c for c in trials.columns if c.startswith("gain_")]]
    assert len(gains) == 4 and not gains.duplicated().any(), gains


#: ``slamobs`` whose tune SIGKILLs itself as soon as its journal holds the setup: the defaults' trial, the next
#: journal line, not yet written.
KILLED_AFTER_THE_SETUP = """
import os, signal, optuna
from slamobs.cli.main import entry
set_user_attr = optuna.study.Study.set_user_attr
def set_and_die(study, key, value):
    set_user_attr(study, key, value)
    if key == "setup":
        os.kill(os.getpid(), signal.SIGKILL)
optuna.study.Study.set_user_attr = set_and_die
entry()
"""


def test_a_tune_killed_between_its_setup_and_the_defaults_trial_scores_the_defaults_on_resume(logs, tmp_path):
    """The setup and the defaults' trial are two journal lines: a tune SIGKILLed between them (kill_matrix seed 30,
    SIGKILL at 1.5 s) was resumed without the defaults' trial, its results without the defaults' score."""
    import pandas as pd

    out = tmp_path / "tune"
    args = _tune_args(logs[:1], out, "--trials", 2, "-j", 1)[len(CLI) :]
    killed = subprocess.run([CLI[0], "-c", KILLED_AFTER_THE_SETUP, *args], capture_output=True, text=True)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    done = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    trials = pd.read_parquet(out / "trials.parquet")
    defaults = trials[trials["is_default"]]
    assert list(defaults["state"]) == ["COMPLETE"], trials
    assert json.loads((out / "tune.json").read_text())["defaults"]["trial"] == defaults["trial"].iloc[0]


#: ``slamobs`` SIGKILLed at the first call of a ``Study`` method (``tell``: a round's first result; ``enqueue_trial``:
#: a resume's first re-queued trial), right after that call's journal line when ``after``.
KILLED_AT = """
import os, signal, sys, optuna
from slamobs.cli.main import entry
name, after = sys.argv.pop(1), sys.argv.pop(1) == "after"
method = getattr(optuna.study.Study, name)
def die(study, *args, **kwargs):
    if after:
        method(study, *args, **kwargs)
    os.kill(os.getpid(), signal.SIGKILL)
setattr(optuna.study.Study, name, die)
entry()
"""


def test_a_resume_killed_between_requeueing_a_trial_and_failing_it_runs_its_gains_once(logs, tmp_path):
    """A resume re-queues each trial the killed tune left running, then fails it: two journal lines. SIGKILLed
    between them, the next resume queued the same gains a second time and ran them twice."""
    import pandas as pd

    out = tmp_path / "tune"
    args = _tune_args(logs[:1], out, "--trials", 3, "-j", 2)[len(CLI) :]
    for name, after in (("tell", "before"), ("enqueue_trial", "after")):  # trials 0 and 1 left running, then
        killed = subprocess.run([CLI[0], "-c", KILLED_AT, name, after, *args], capture_output=True, text=True)
        assert killed.returncode == -signal.SIGKILL, killed.stderr
    done = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    trials = pd.read_parquet(out / "trials.parquet")
    complete = trials[trials["state"] == "COMPLETE"]
    gains = complete[[c for c in complete.columns if c.startswith("gain_")]]
    assert len(complete) == 3 and not gains.duplicated().any(), trials
    assert complete["is_default"].sum() == 1


def test_the_objective_figure_counts_trials_in_whole_numbers_and_plain_errors(tmp_path, monkeypatch):
    """objective.png of a 3-trial tune ticked trial 0.25, 0.5, ... and labelled its log axis 5×10⁻², 6×10⁻²."""
    from types import SimpleNamespace

    from matplotlib.figure import Figure

    from slamobs.pipeline.tune import results

    drawn = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, tmp, **k: drawn.append(fig) or Path(tmp).write_bytes(b""))
    trials = [SimpleNamespace(number=i, value=v) for i, v in enumerate((0.0423, 0.0708, 0.0521))]
    results.plot_objective(tmp_path / "objective.png", trials, trials[0], "ape")
    (ax,) = drawn[0].axes
    drawn[0].canvas.draw()
    lo, hi = ax.get_xlim()
    xs = [t for t in ax.get_xticks() if lo <= t <= hi]
    assert xs and all(float(t).is_integer() for t in xs), xs
    labels = [t.get_text() for t in ax.get_yticklabels() + ax.yaxis.get_minorticklabels() if t.get_text()]
    assert labels and not [x for x in labels if "×" in x or "^" in x], labels


def test_best_gains_whose_run_says_likely_lost_are_warned_of(logs):
    """A tune scores each trial by its objective alone: on MR.CLAM 6 r3 (`--target batch --trials 6`) its best
    fast-adaptation gains (alpha 1.014, gamma 26.53, k_p 0.1387, k_w 0.01826: 1.87 m against batch, defaults
    2.81 m) gave a run that warned 'its estimate is likely lost: its velocity bias estimate wanders by 796x the
    velocity's rms', and the tune said nothing of it. A trial now records the run's own check; tune.md and the
    command say when the best gains' runs are likely lost. The same gains on a generated figure 8 wander too, the
    defaults do not."""
    from slamobs.pipeline.config import RunConfig
    from slamobs.pipeline.tune.results import lost_words, render_markdown
    from slamobs.pipeline.tune.worker import prepared_log, score

    rows = {}
    for name, gains in (("defaults", {}), ("best", {"alpha": 1.014, "gamma": 26.53, "k_p": 0.1387, "k_w": 0.01826})):
        config = RunConfig.from_dict({"observer": "fast-adaptation", "gains": {"fast-adaptation": gains}})
        prepared, _ = prepared_log(str(logs[0]), config, False)
        rows[name] = score(prepared, config)
    assert rows["defaults"]["likely_lost"] is None, rows["defaults"]
    assert rows["best"]["likely_lost"].startswith("its velocity bias estimate wanders by"), rows["best"]
    log = str(logs[0])
    summary = {
        "observer": "fast-adaptation",
        "objective": {"metric": "ape_trans_rmse_m", "unit": "m"},
        "trials": {"complete": 2, "failed": 0, "requested": 2},
        "setup": {"logs": [log]},
        "validation": {"rows": [], "note": "needs two or more logs"},
    }
    for name, row in rows.items():
        lost = {log: row["likely_lost"]} if row["likely_lost"] else {}
        summary[name] = {"trial": int(name == "best"), "objective": 1.0, "gains": {}, "per_log": {log: 1.0}}
        summary[name]["likely_lost"] = lost
    said = lost_words(summary)
    assert said.startswith("with the best gains the run's own check says its estimate is likely lost on 1 of 1 log")
    assert f"(f0.mcap: {rows['best']['likely_lost']}); with the defaults on 0 of 1" in said
    assert f"Warning: {said}" in render_markdown(summary)
    summary["best"]["likely_lost"] = {}
    assert lost_words(summary) is None and "Warning" not in render_markdown(summary)


def test_a_tune_whose_best_trial_is_the_defaults_says_so():
    """`tune a.mcap --observer fast-adaptation --target batch --trials 4` (a generated circle, seed=3600) printed
    `best trial 0: median ... 0.01086 m (defaults 0.01086 m)` and gains alpha 1, gamma 1, ...: the defaults, which
    only docs/tuning.md's "trial 0 runs the defaults" told; the command and tune.md now say it, and that gains.yaml
    holds them. A best trial other than the defaults' reads as before."""
    from slamobs.pipeline.tune.results import defaults_won, render_markdown

    log = "/logs/a.mcap"
    summary = {
        "observer": "fast-adaptation",
        "objective": {"metric": "ape_trans_rmse_m", "unit": "m"},
        "trials": {"complete": 4, "failed": 0, "requested": 4},
        "setup": {"logs": [log]},
        "validation": {"rows": [], "note": "needs two or more logs"},
        "defaults": {"trial": 0, "objective": 0.01, "gains": {"gamma": 1.0}, "per_log": {log: 0.01}},
    }
    summary["best"] = dict(summary["defaults"])
    said = defaults_won(summary)
    assert said == "the defaults: no other trial scored lower; gains.yaml holds them"
    assert f"Best gains (trial 0, {said}): gamma 1" in render_markdown(summary)
    summary["best"] = {"trial": 3, "objective": 0.008, "gains": {"gamma": 2.0}, "per_log": {log: 0.008}}
    assert defaults_won(summary) == "" and "Best gains (trial 3): gamma 2" in render_markdown(summary)


def test_a_tunes_trials_on_one_log_decide_its_time_offset_once(tmp_path, monkeypatch):
    """Each trial's observer decided the time offset again on the same stream (0.06-0.15 CPU s each, session 33);
    a worker now decides once per prepared log and starts every trial's observer on that decision, the same as
    deciding afresh (seed=3470: a figure 8 whose detections are 0.3 s late, so the decision applies)."""
    from slamobs.pipeline.config import RunConfig
    from slamobs.pipeline.observers import time_offset
    from slamobs.pipeline.simulate import simulate, write_log
    from slamobs.pipeline.tune.worker import prepared_log, score

    log = write_log(simulate("figure8", duration=20.0, seed=3470, detection_offset=0.3), tmp_path / "late.mcap")
    decisions = []
    decide = time_offset.decide
    monkeypatch.setattr(time_offset, "decide", lambda stream: decisions.append(decide(stream)) or decisions[-1])
    rows = []
    for gains in ({}, {"k_p": 0.2}, {}):
        config = RunConfig.from_dict({"observer": "fast-adaptation", "gains": {"fast-adaptation": gains}})
        prepared, _ = prepared_log(str(log), config, False)
        rows.append(score(prepared, config))
    assert len(decisions) == 1 and decisions[0]["applied"], decisions
    assert rows[0] == rows[2] and rows[0] != rows[1], rows
