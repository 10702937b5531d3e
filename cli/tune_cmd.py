"""``slamobs tune``: search an observer's gains on logs with ground truth (Optuna TPE over the batch pools)."""

from __future__ import annotations

import signal
import sys
from pathlib import Path

import click

from slamobs.cli.jobs import EXIT_INFRA, EXIT_SIGNAL, Stopped, on_signal, signals_to_the_main_thread
from slamobs.pipeline.cores import cores
from slamobs.cli.errors import exit_input_error
from slamobs.cli.listing import wrote_line
from slamobs.cli.options import SEED, OutPath, config_option, wait_workers_option
from slamobs.pipeline.errors import plural

TUNE_MISSING = "slamobs tune needs Optuna: pip install 'slamobs[tune]' (or: pip install optuna)"


@click.command()
@click.argument("logs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--observer", required=True, help="observer whose gains are tuned (see `slamobs observers`)")
@click.option(
    "-o",
    "--out",
    "out_dir",
    required=True,
    type=OutPath(path_type=Path, file_okay=False),
    help="tune directory (created; the same command continues an interrupted tune in it)",
)
@click.option(
    "--trials",
    type=click.IntRange(min=1),
    default=50,
    show_default=True,
    help="trials in total (a re-run with more trials extends the tune)",
)
@click.option(
    "--objective",
    type=click.Choice(["ape", "rotation", "landmarks"]),
    default="ape",
    show_default=True,
    help="minimised over the logs (median): APE translation RMSE, APE rotation RMSE, map error RMSE",
)
@click.option(
    "--target",
    type=click.Choice(["truth", "batch"]),
    default="truth",
    show_default=True,
    help="what the objective is measured against: each log's ground truth, or the batch smoother's solution on "
    "the same log (logs without truth can be tuned; --holdout logs are still checked against their truth)",
)
@config_option("run.yaml for every log (topics, frames, ...); its gains for the observer are ignored")
@click.option(
    "-j", "--jobs", type=click.IntRange(min=1), default=None, help="local worker processes (default: all cores)"
)
@click.option("--scheduler", default=None, metavar="ADDRESS", help="run the trials on this Dask scheduler instead")
@click.option(
    "--holdout",
    "holdout",
    multiple=True,
    type=click.Path(path_type=Path),
    metavar="LOG",
    help="a log with truth the sampler never sees: defaults and tuned gains are compared on it at the end (repeatable)",
)
@click.option("--seed", type=SEED, default=0, show_default=True, help="sampler seed")
@click.option(
    "--force",
    is_flag=True,
    help="start over: the tune in OUT is replaced once the new one has results (kept if it fails)",
)
@wait_workers_option
@click.option("-q", "--quiet", is_flag=True, help="print only the final lines")
def tune(
    logs: tuple[Path, ...],
    observer: str,
    out_dir: Path,
    trials: int,
    objective: str,
    target: str,
    config_path: Path | None,
    jobs: int | None,
    scheduler: str | None,
    holdout: tuple[Path, ...],
    seed: int,
    force: bool,
    wait_workers: float,
    quiet: bool,
) -> None:
    """Search OBSERVER's gains on LOGS (with ground truth, or any logs with --target batch) and write OUT.

    Optuna's TPE sampler searches every gain log-uniformly within its range and the observer's stability
    conditions; the objective is the median over the logs. Trial 0 runs the defaults. OUT gets gains.yaml (use
    it with --config), trials.parquet, objective.png, tune.md/tune.json with leave-one-log-out validation and the
    --holdout logs' comparison (the honest check that the gains transfer), and tune.journal (the state: the
    same command continues an interrupted tune).

    \b
    Exit codes:
      0    done
      2    bad arguments, a log that cannot be tuned on (no truth, unreadable), OUT in use or of another tune
      3    infrastructure: Dask scheduler unreachable or lost, no workers, workers with another slamobs
      130  interrupted (SIGINT), 143 terminated (SIGTERM), 129 hangup (SIGHUP): workers stopped, finished
           trials kept; run the same command to continue
    """
    import importlib.util

    if importlib.util.find_spec("optuna") is None:
        exit_input_error(TUNE_MISSING)
    from slamobs.pipeline.batch.executor import InfrastructureError
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.errors import GainError, InputError
    from slamobs.pipeline.interrupts import take_pending
    from slamobs.pipeline.tune.results import defaults_won, lost_words
    from slamobs.pipeline.tune.study import TuneFailed, TuneOptions, run_tune

    handlers = {sig: signal.signal(sig, on_signal) for sig in EXIT_SIGNAL}

    def on_round(done: int, total: int, best: float | None) -> None:
        if not quiet:
            click.echo(
                f"tune: {done}/{total} trials, best median {objective} {'-' if best is None else f'{best:.4g}'}",
                err=True,
            )

    try:
        if (pending := take_pending()) is not None:  # arrived before these handlers: stop as they would
            on_signal(pending, None)
        options = TuneOptions(
            out=out_dir,
            observer=observer,
            config=load_config(config_path),
            trials=trials,
            objective=objective,
            jobs=jobs or cores(),
            scheduler=scheduler,
            seed=seed,
            force=force,
            wait_workers=wait_workers,
            holdout=holdout,
            target=target,
        )
        if not quiet:
            where = (
                f"Dask at {scheduler}"
                if scheduler
                else plural(options.jobs, "local worker process", "local worker processes")
            )
            against = " against the batch smoother's solution" if target == "batch" else ""
            click.echo(
                f"tune: {observer} on {plural(len(logs), 'log')}{against}, {plural(trials, 'trial')}, on {where}",
                err=True,
            )
            if given := options.config.gains.get(observer):  # the run the user made used them; the tune does not
                click.echo(
                    f"tune: {config_path} sets {observer}'s gains ({', '.join(f'{k} {v:g}' for k, v in given.items())}"
                    "): a tune does not use them; its trial 0 and 'defaults' are the observer's own defaults "
                    f"(`slamobs observers`); `slamobs run LOG --config {config_path}` scores yours",
                    err=True,
                )
        with signals_to_the_main_thread():  # a Dask cluster's start waits on a lock
            result = run_tune(list(logs), options, on_round=on_round)
    except (InputError, GainError, TuneFailed) as err:
        exit_input_error(str(err))
    except InfrastructureError as err:
        click.echo(f"error: {err}", err=True)
        sys.exit(EXIT_INFRA)
    except KeyboardInterrupt as err:
        signum = err.signum if isinstance(err, Stopped) else signal.SIGINT
        kept = (  # a forced tune keeps nothing before its results: OUT holds the tune it was to replace
            f"the tune that was in {out_dir} is kept as it was (a forced tune replaces it only once it has results)"
            if force
            else f"finished trials are kept in {out_dir}; run the same command again to continue"
        )
        click.echo(f"\n{signal.Signals(signum).name}: tune stopped, its workers killed; {kept}", err=True)
        sys.exit(EXIT_SIGNAL[signum])
    finally:
        for sig, old in handlers.items():
            signal.signal(sig, old)
    s = result.summary
    best, default = s["best"], s["defaults"]
    unit = s["objective"]["unit"]
    if best:
        which = f" ({said})" if (said := defaults_won(s)) else ""
        click.echo(
            f"best         trial {best['trial']}{which}: median {s['objective']['metric']} "
            f"{best['objective']:.4g} {unit}"
            + (
                f" (defaults {default['objective']:.4g} {unit})"
                if default and default["objective"] is not None and default["objective"] != float("inf")
                else ""
            )
        )
        click.echo("gains        " + ", ".join(f"{k} {v:.4g}" for k, v in best["gains"].items()))
        if said := lost_words(s):
            click.echo(f"warning      {said}")
    val = s["validation"]
    if val.get("rows"):
        click.echo(
            f"validation   leave-one-log-out: gains chosen without a log beat the defaults on it for "
            f"{val['held_out_better_than_default']} of {val['logs']} logs (tune.md)"
        )
    held = s.get("holdout")
    if held:
        click.echo(
            f"holdout      tuned gains beat the defaults on {held['tuned_better']} of {held['logs']} logs the "
            f"tune never saw (median {held['median_defaults']:.4g} -> {held['median_tuned']:.4g} {unit})"
            + ("" if 2 * held["tuned_better"] > held["logs"] else ": they do not transfer, keep the defaults")
        )
    files = ("gains.yaml", "trials.parquet", "objective.png", "tune.md", "tune.json")
    click.echo(f"wrote        {wrote_line(out_dir, files)}; {plural(result.ran, 'trial')} run now")
