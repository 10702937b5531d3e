"""A tune: Optuna's TPE sampler over an observer's gains, every trial scored on every log by the batch pools.

State lives in ``OUT/tune.journal`` (Optuna's append-only journal storage): a killed tune, re-run with the same
command, continues where it stopped (trials that were running are run again with the same gains); ``--trials`` is
the total. Trials run in rounds of as many trials as there are workers, each trial on every log, through the
batch package's pools (:class:`LocalPool` with its workers kept across rounds, or :class:`DaskPool`), so each
worker reads each log once (:mod:`worker`). The first trial is the observer's defaults: the baseline the report
compares with. The result files are rewritten at the end (:mod:`results`), each atomically.
"""

from __future__ import annotations

import functools

import math
import os
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

from slamobs.pipeline.config import RunConfig
from slamobs.pipeline.errors import BadInput, InputError, Unwind
from slamobs.pipeline.tune import space
from slamobs.pipeline.tune.worker import OBJECTIVES, TARGET_KEY, TARGETS

JOURNAL = "tune.journal"
LOCK = ".tune.lock"
STUDY = "slamobs-tune"
#: The tune's own files in OUT (what --force replaces).
OWN_FILES = (JOURNAL, "gains.yaml", "trials.parquet", "objective.png", "tune.json", "tune.md")
#: Where --force keeps the previous tune's journal until the new tune has written its results.
PREVIOUS = ".tune.journal.previous"


#: Rounds in a row whose every trial failed (workers dying, timeouts) after which the tune gives up.
MAX_FAILED_ROUNDS = 3


class TuneFailed(BadInput, RuntimeError):
    """A log cannot be tuned on (no truth, unreadable, observer cannot run on it): one line naming the log."""


@dataclass(frozen=True)
class TuneOptions:
    out: Path
    observer: str
    config: RunConfig = field(default_factory=RunConfig)
    trials: int = 50
    objective: str = "ape"  # a key of worker.OBJECTIVES
    jobs: int = 1
    scheduler: str | None = None  # a Dask scheduler address: the trials run there
    seed: int = 0
    force: bool = False  # start afresh: the previous study in OUT is removed
    timeout: float | None = 3600.0  # seconds per (trial, log) on local workers
    wait_workers: float = 60.0
    holdout: tuple[Path, ...] = ()  # logs the sampler never sees: defaults and best gains scored on them at the end
    target: str = "truth"  # a key of worker.TARGETS: what a trial is measured against (holdout logs: their truth)


@dataclass
class TuneResult:
    out: Path
    ran: int  # trials run by this call
    summary: dict  # tune.json


class _NoLock:
    """Optuna's journal lock, not needed: one tune per OUT holds :data:`LOCK` (a flock the kernel releases when
    the process dies, unlike Optuna's lock files, which a killed tune would leave behind)."""

    def acquire(self) -> bool:
        return True

    def release(self) -> None:
        pass


def _exclusive(out: Path):
    from slamobs.pipeline.paths import exclusive

    return exclusive(out / LOCK, out, "another tune")


def _repair_journal(path: Path) -> None:
    """Cut a last line a kill left half-written (Optuna skips it when reading, but would append after it)."""
    if not path.is_file() or path.stat().st_size == 0:
        return
    with open(path, "rb+") as fh:
        data = fh.read()
        if not data.endswith(b"\n"):
            fh.truncate(data.rfind(b"\n") + 1)


def journal_storage(out: Path):
    """The tune's Optuna storage in ``out`` (public: tests/test_tune.py opens it)."""
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    _repair_journal(out / JOURNAL)
    return JournalStorage(JournalFileBackend(str(out / JOURNAL), lock_obj=_NoLock()))


def _setup(spec, logs: list[Path], hashes: list[str], options: TuneOptions) -> dict:
    from slamobs.pipeline.batch.runner import config_hash

    setup = {
        "observer": spec.name,
        "objective": options.objective,
        "logs": [str(p) for p in logs],
        "content_hashes": hashes,
        "config_hash": config_hash(replace(options.config, gains={})),
        "space": space.describe(spec),
    }
    if options.target != "truth":  # a tune against the truth keeps the setup tunes had before targets existed
        setup["target"] = options.target
    return setup


def _check_same(out: Path, had: dict, now: dict) -> None:
    for key, what in (
        ("observer", "observer"),
        ("objective", "objective"),
        ("target", "target"),
        ("content_hashes", "set of logs"),
        ("config_hash", "config"),
        ("space", "search space"),
    ):
        if had.get(key) != now.get(key):
            raise InputError(
                out,
                f"holds a tune of another {what}; re-run its own command to continue it, "
                "or use another -o (or --force to start over)",
            )


def _prepare_out(out: Path, inputs: list, force: bool) -> bool:
    """Check OUT; True when it holds a tune to continue."""
    from slamobs.pipeline.paths import check_output

    resume = (out / JOURNAL).is_file()
    check_output(out, inputs, force=force, in_place=resume and not force)  # --force: only a tune's own files
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise InputError(out, f"cannot create the output directory: {err.strerror or err}") from None
    return resume


def set_aside(out: Path) -> None:
    """--force: the previous tune's journal is kept hidden (under the lock: never under a running tune) and its
    result files stay, until the new tune replaces them with its own (:func:`replace_results`); a forced tune that
    ends without results puts the journal back (:func:`put_back`): an existing tune is unchanged by a failed one.
    Public: tests/test_tune.py checks the forced tune's steps one by one."""
    if (out / JOURNAL).is_file():
        os.replace(out / JOURNAL, out / PREVIOUS)


def put_back(out: Path) -> bool:
    """The journal a forced tune set aside back in place, the forced tune's own dropped (it ended without results,
    or was killed: the next tune in OUT finds it here first); True when there was one.
    Public: tests/test_tune.py checks the forced tune's steps one by one."""
    if not (out / PREVIOUS).is_file():
        return False
    os.replace(out / PREVIOUS, out / JOURNAL)
    return True


def replace_results(out: Path, write: Callable[[], dict]) -> dict:
    """A forced tune's results in place of the previous tune's (whose files it may not all write again); the
    previous journal goes once they are written.
    Public: tests/test_tune.py checks the forced tune's steps one by one."""
    for name in OWN_FILES[1:]:
        (out / name).unlink(missing_ok=True)
    summary = write()
    (out / PREVIOUS).unlink(missing_ok=True)
    return summary


def run_tune(
    logs: Sequence[Path],
    options: TuneOptions,
    on_round: Callable[[int, int, float | None], None] = lambda _done, _total, _best: None,
    run=None,
) -> TuneResult:
    """Tune ``options.observer``'s gains on ``logs`` into ``options.out`` (see the module doc).

    ``on_round(done, total, best)`` is called after every round. ``run`` replaces the workers' task function
    (tests). Raises InputError (bad logs, OUT, options), TuneFailed (a log cannot be tuned on) and the batch's
    InfrastructureError (Dask problems).
    """
    import optuna

    from slamobs.pipeline.batch.identity import content_hash
    from slamobs.pipeline.config import with_observer
    from slamobs.pipeline.paths import check_input
    from slamobs.pipeline.readers.container import detect_container
    from slamobs.pipeline.run import resolve_estimator, run_inputs
    from slamobs.pipeline.tune.worker import run_trial_log

    if options.objective not in OBJECTIVES:
        raise InputError(
            "--objective", f"unknown objective {options.objective!r} (choose from {', '.join(OBJECTIVES)})"
        )
    if options.trials < 1:
        raise InputError("--trials", "needs at least 1 trial")
    if options.target not in TARGETS:
        raise InputError("--target", f"unknown target {options.target!r} (choose from {', '.join(TARGETS)})")
    config = with_observer(options.config, options.observer)
    spec = resolve_estimator(config)
    if not logs:
        raise InputError("LOGS", "no log given")
    paths = []
    for log in logs:
        check_input(log, "log")
        paths.append(Path(os.path.realpath(log)))
    if len(set(paths)) != len(paths):
        raise InputError(logs[0], "a log is given twice")
    holdout = []
    for log in options.holdout:
        check_input(log, "log")
        detect_container(log)  # not a log at all: said now, not after the trials
        holdout.append(Path(os.path.realpath(log)))
        if holdout[-1] in paths:
            raise InputError(log, "is both a tuning log and a --holdout log")
    out = Path(options.out)
    inputs = [p for log in paths + holdout for p in run_inputs(log, config)]
    created = not out.exists()
    resume = _prepare_out(out, inputs, options.force)
    hashes = [content_hash(p) for p in paths]
    setup = _setup(spec, paths, hashes, options)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    try:
        return _run_study(out, resume, spec, config, paths, holdout, setup, options, on_round, run or run_trial_log)
    except _NothingKept as err:  # a new tune that could not score a single trial leaves no output behind
        if not err.put_back:  # a forced one's previous tune is back in place, as it was
            _remove_unfinished(out, created)
        raise err.failure from None


class _NothingKept(Unwind):
    """A new tune failed on a log before any trial completed: its journal holds nothing worth resuming."""

    def __init__(self, failure: BadInput) -> None:
        self.failure = failure
        self.put_back = False  # a forced tune's: the previous tune's journal is back in place


def _remove_unfinished(out: Path, created: bool) -> None:
    """The journal and lock of a tune that completed no trial, and OUT itself when this tune created it."""
    for name in (JOURNAL, LOCK):
        (out / name).unlink(missing_ok=True)
    if created:
        try:
            out.rmdir()
        except OSError:  # something else appeared in it meanwhile: it stays
            pass


def _run_study(out, resume, spec, config, paths, holdout, setup, options, on_round, run) -> TuneResult:
    with _exclusive(out):
        if put_back(out):  # a forced tune was killed here: the tune it replaced is what OUT holds
            resume = (out / JOURNAL).is_file()
        if options.force:
            set_aside(out)
            resume = False
        try:
            return _study_in(out, resume, spec, config, paths, holdout, setup, options, on_round, run)
        except BaseException as err:  # interrupted too: a forced tune without results leaves the previous one
            if options.force and put_back(out) and isinstance(err, _NothingKept):
                err.put_back = True  # the previous tune is back: run_tune leaves OUT as it is
            raise


def _study_in(out, resume, spec, config, paths, holdout, setup, options, on_round, run) -> TuneResult:
    """The study in OUT (resumed, or new), its trials and its result files."""
    import optuna

    from slamobs.pipeline.tune import results

    study = optuna.create_study(
        study_name=STUDY,
        storage=journal_storage(out),
        direction="minimize",
        load_if_exists=True,
        sampler=_sampler(options.seed, 0),
    )
    if earlier := len(study.get_trials(deepcopy=False)):  # resumed: new draws, not the first ones again
        study.sampler = _sampler(options.seed, earlier)
    if resume and "setup" in study.user_attrs:
        _check_same(out, study.user_attrs["setup"], setup)
    else:
        with _deferred():
            study.set_user_attr("setup", setup)
    if not any(t.user_attrs.get("default") for t in study.get_trials(deepcopy=False)):
        # two journal lines: a tune SIGKILLed between them left the setup without the defaults' trial, and the
        # resumed tune never scored the defaults (kill_matrix seed 30)
        with _deferred():
            study.enqueue_trial(space.params_of(spec, spec.resolve_gains(None)), user_attrs={"default": True})
    _requeue_interrupted(study)
    try:
        ran, held, held_failed = _optimise(study, spec, config, paths, holdout, options, on_round, run)
    except BadInput as err:
        if not resume and _complete(study) == 0:
            raise _NothingKept(err) from None
        raise
    write = functools.partial(results.write_results, out, study, spec, setup, options, held)
    summary = replace_results(out, write) if options.force else write()
    if held_failed:  # the tune's own results are written; the holdout log is what failed
        raise TuneFailed(held_failed)
    return TuneResult(out, ran, summary)


def _sampler(seed: int | None, earlier: int):
    """TPE seeded by the tune's seed and the number of trials the journal already holds: a sampler seeded alike
    on resume would repeat its first random draws, the gains of trials already run."""
    import optuna

    seed = seed if seed is None or not earlier else (seed * 1_000_003 + earlier) % 2**32
    return optuna.samplers.TPESampler(seed=seed, multivariate=True, constant_liar=True)


@contextmanager
def _deferred():
    from slamobs.pipeline.batch.runner import signals_deferred

    with signals_deferred():  # a journal line is written whole
        yield


def _requeue_interrupted(study) -> None:
    """Trials a killed tune left running: failed in the journal, their gains queued to run again."""
    import optuna

    waiting = [  # a queued trial's gains are its fixed parameters (its params are set when it is asked for)
        t.system_attrs.get("fixed_params", t.params)
        for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.WAITING,))
    ]
    for t in study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,)):
        with _deferred():
            if t.params not in waiting:  # queued already by a resume SIGKILLed before its next line (the FAIL)
                study.enqueue_trial(t.params, user_attrs={k: v for k, v in t.user_attrs.items() if k == "default"})
            study.tell(t.number, state=optuna.trial.TrialState.FAIL)


def _complete(study) -> int:
    import optuna

    return len(study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,)))


def _optimise(
    study, spec, config: RunConfig, logs: list[Path], holdout: list[Path], options: TuneOptions, on_round, run
) -> tuple[int, list[dict], str | None]:
    """Run trials until ``options.trials`` are complete, then score the defaults and the best gains on the
    ``holdout`` logs; (trials run, one row per holdout log, why a holdout log could not be scored)."""
    import optuna

    from slamobs.pipeline.batch.dask_exec import DaskPool, dask_available
    from slamobs.pipeline.batch.executor import Task
    from slamobs.pipeline.batch.local import LocalPool
    from slamobs.pipeline.batch.runner import DASK_MISSING
    from slamobs.pipeline.tune.worker import objective_value

    if _complete(study) >= options.trials and not holdout:
        return 0, [], None
    if options.scheduler:
        if not dask_available():
            raise InputError("--scheduler", DASK_MISSING)
        pool = DaskPool(options.jobs, options.scheduler, None, options.wait_workers, run)
    else:
        pool = LocalPool(options.jobs, run, options.timeout, keep_workers=True)
    distributions = space.distributions(spec)
    base = Task.make("", str(logs[0]), str(options.out), replace(config, gains={}))
    ran = failed_rounds = 0
    try:
        slots = pool.connect() if options.scheduler else options.jobs
        while (done := _complete(study)) < options.trials:
            with _deferred():
                trials = [study.ask(distributions) for _ in range(min(slots, options.trials - done))]
            tasks, gains = [], {}
            for trial in trials:
                gains[trial.number] = space.gains_of(spec, trial.params)
                cfg = {**base.config, "gains": {spec.name: gains[trial.number]}, **_target(options)}
                tasks += [
                    replace(base, run_id=f"trial{trial.number}-log{i}", log=str(log), config=cfg)
                    for i, log in enumerate(logs)
                ]
            rows: dict[int, list[dict]] = {t.number: [None] * len(logs) for t in trials}
            for task, row in pool.results(tasks):
                number, index = (int(x) for x in task.run_id[len("trial") :].split("-log"))
                if row.get("fatal"):
                    raise TuneFailed(row["error"])
                if (
                    row["status"] == "ok"
                    and options.objective != "ape"
                    and row.get(OBJECTIVES[options.objective]) is None
                ):
                    raise TuneFailed(
                        f"{task.log}: has no "
                        f"{'landmark truth' if options.objective == 'landmarks' else 'rotation truth'}"
                        f": --objective {options.objective} needs it"
                    )
                rows[number][index] = {k: row.get(k) for k in _ROW_KEYS}
            values = {t.number: objective_value(rows[t.number], options.objective) for t in trials}
            failed_rounds = failed_rounds + 1 if all(math.isnan(v) for v in values.values()) else 0
            for trial in trials:
                value = values[trial.number]
                with _deferred():
                    trial.set_user_attr("gains", gains[trial.number])
                    trial.set_user_attr("logs", rows[trial.number])
                    if math.isnan(value):
                        study.tell(trial, state=optuna.trial.TrialState.FAIL)
                    else:
                        study.tell(trial, value)
                ran += 1
            if failed_rounds >= MAX_FAILED_ROUNDS:
                why = next(r["error"] for rs in rows.values() for r in rs if r["status"] == "failed")
                raise TuneFailed(f"{MAX_FAILED_ROUNDS} rounds in a row failed, last: {why}")
            on_round(_complete(study), options.trials, _best_value(study))
        try:
            held, held_failed = _score_holdout(study, spec, base, holdout, options, pool), None
        except TuneFailed as err:
            held, held_failed = [], str(err)
    finally:
        pool.close()
    return ran, held, held_failed


def _target(options: TuneOptions) -> dict:
    """What a tuning task's config says about its target (nothing for the truth: holdout tasks always use it)."""
    return {} if options.target == "truth" else {TARGET_KEY: options.target}


def _score_holdout(study, spec, base, holdout: list[Path], options: TuneOptions, pool) -> list[dict]:
    """The defaults and the best trial's gains on each holdout log: whether the tuned gains transfer to logs
    the sampler never saw (what a user's logs without truth are)."""
    import optuna

    complete = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))
    finite = [t for t in complete if math.isfinite(t.value)]
    if not holdout or not finite:
        return []
    best = min(finite, key=lambda t: (t.value, t.number))
    variants = {"defaults": spec.resolve_gains(None), "tuned": best.user_attrs["gains"]}
    tasks = [
        replace(base, run_id=f"{name}-log{i}", log=str(log), config={**base.config, "gains": {spec.name: gains}})
        for name, gains in variants.items()
        for i, log in enumerate(holdout)
    ]
    rows = [{"log": str(log), "best_trial": best.number} for log in holdout]
    for task, row in pool.results(tasks):
        name, index = task.run_id.split("-log")
        if row.get("fatal"):
            raise TuneFailed(row["error"])
        rows[int(index)][name] = {k: row.get(k) for k in _ROW_KEYS}
    return rows


_ROW_KEYS = (
    "status",
    "likely_lost",
    "error",
    "ape_trans_rmse_m",
    "ape_rot_rmse_deg",
    "landmark_rmse_m",
    "read_s",
    "observer_s",
    "total_s",
    "worker",
    "capped_intervals",
)


def _best_value(study) -> float | None:
    try:
        return float(study.best_value)
    except ValueError:
        return None
