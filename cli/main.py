"""``slamobs`` command line: composes the pipeline; heavy modules are imported inside the commands."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import click

from slamobs.cli.errors import handled
from slamobs.cli.options import OutPath, log_run_config, log_run_options
from slamobs.cli.progress import Progress, compile_notice

# One BLAS thread (set before NumPy loads): every matrix product here is tiny, (N, 3) x (3, 3), and OpenBLAS
# threads only add synchronisation (30x slower on a 2-core machine); results do not depend on the count.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _allocators_for_a_memory_limit() -> None:
    """Under an address-space limit (``ulimit -v``), which counts address space reserved ahead as used, allocators
    reserve less (before any thread starts and before pyarrow loads); without a limit nothing changes. pyarrow
    allocates with malloc, not mimalloc (under ``ulimit -v 600000`` mimalloc reserved 186 MB for a 1000-element
    array, malloc 58 MB); glibc's malloc keeps one arena instead of one per thread (each reserves 64 MB): the sample
    log's run then passes under ``ulimit -v 700000`` instead of needing 1000000."""
    try:
        import resource

        limited = resource.getrlimit(resource.RLIMIT_AS)[0] != resource.RLIM_INFINITY
    except (ImportError, OSError, ValueError):
        return
    if not limited:
        return
    os.environ.setdefault("ARROW_DEFAULT_MEMORY_POOL", "system")
    if "MALLOC_ARENA_MAX" not in os.environ:  # set by the user: glibc has read it already
        os.environ["MALLOC_ARENA_MAX"] = "1"  # for the processes this one starts (batch workers, figure helper)
        try:
            import ctypes

            ctypes.CDLL(None).mallopt(-8, 1)  # M_ARENA_MAX, for this process (glibc; elsewhere no such symbol)
        except (OSError, AttributeError):
            pass


_allocators_for_a_memory_limit()


class _Group(click.Group):
    """Every command ends the same way when it cannot finish (:mod:`cli.errors`): one ``error:`` line and exit
    code 2, or exit 130/143 after SIGINT/SIGTERM; never a traceback or click's usage text."""

    def invoke(self, ctx):
        with handled():
            return super().invoke(ctx)

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        """click's standalone mode, but a bad option or argument is one ``error:`` line (exit 2) like every other
        error, not four lines of usage text; a command given without arguments still shows its help."""
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, False, **extra)
        try:
            code = super().main(args, prog_name, complete_var, False, **extra)
        except click.exceptions.NoArgsIsHelpError as err:
            err.show()
            sys.exit(err.exit_code)
        except click.UsageError as err:
            where = f" (see {err.ctx.command_path} --help)" if err.ctx is not None else ""
            click.echo(f"error: {' '.join(err.format_message().split())}{where}", err=True)
            sys.exit(err.exit_code)
        except click.ClickException as err:
            err.show()
            sys.exit(err.exit_code)
        except click.Abort:
            click.echo("Aborted!", err=True)
            sys.exit(1)
        sys.exit(code if isinstance(code, int) and not isinstance(code, bool) else 0)


def _dashes(token: str) -> str:
    """Option names (and choices, commands) in either spelling: ``--msg_dir`` is ``--msg-dir``, as evo's tools
    spell them; click applies this to both the declared and the given name, never to paths or numbers."""
    return token.replace("_", "-")


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"], "token_normalize_func": _dashes})
@click.version_option(package_name="slamobs", prog_name="slamobs")
def main() -> None:
    """Run geometric nonlinear SLAM observers over MCAP files and ROS1/ROS2 bags.

    Outputs pose, landmark map and velocity-bias histories as Parquet, plus an error report
    against ground truth when the log has it.
    """


@main.command()
@click.argument("logs", nargs=-1, required=True, metavar="LOG...", type=click.Path(path_type=Path))
@click.option("-o", "--out", "out_dir", required=True, type=OutPath(path_type=Path), help="run directory to create")
@click.option("--observer", default=None, help="observer name (default fast-adaptation; see `slamobs observers`)")
@log_run_options
def run(
    logs: tuple[Path, ...],
    out_dir: Path,
    observer: str | None,
    config_path: Path | None,
    msg_dir: Path | None,
    force: bool,
    start: float | None,
    end: float | None,
    truth: str | None,
    export: tuple[str, ...] | None,
    plots: bool | None,
    quiet: bool,
) -> None:
    """Run an observer on LOG (.bag, .mcap or rosbag2 directory) and write OUT.

    A ROS1 recording split into NAME_0.bag, NAME_1.bag, ... is one LOG: its directory, or all its parts.
    """
    from slamobs.cli.errors import working_on
    from slamobs.pipeline.paths import run_memory_mb

    # named before the readers are imported: under a tight memory limit that import is what fails
    first = Path(logs[0]) if len(logs) == 1 else Path(logs[0]).parent
    working_on(first, "a run of this log", run_memory_mb(first))
    from slamobs.pipeline import compile_ahead
    from slamobs.pipeline.evaluation.plot_worker import PlotWorkers, free_cores, helper_wanted
    from slamobs.pipeline.lifetime import collected_after_imports

    spare = free_cores()
    # the figure helper imports matplotlib while this process imports the pipeline (~1 s of each on a short log)
    workers = PlotWorkers(1) if helper_wanted(spare) else None
    helper = None
    with collected_after_imports() as imported:
        try:
            helper = compile_ahead.start_early(spare)  # a first run's kernels, compiled while it imports and reads
            from slamobs.pipeline.readers.container import recording_of

            log = recording_of(logs)
            from slamobs.pipeline.config import load_config, with_observer
            from slamobs.pipeline.run import run_log

            imported()
            config = with_observer(load_config(config_path), observer)
            config = log_run_config(config, truth, start, end, plots, msg_dir, export)
            helper = compile_ahead.start(config.observer, spare, helper)
            with Progress(quiet) as progress, compile_notice(progress.status, quiet=quiet, lines=progress):
                summary = run_log(log, out_dir, config, force=force, plot_workers=workers, progress=progress)
        finally:
            if workers is not None:
                workers.close()
            compile_ahead.stop(helper)
    if quiet:
        return
    _print_summary(summary)


def _print_summary(summary) -> None:
    from slamobs.cli.listing import wrote_line
    from slamobs.pipeline.errors import plural

    m = summary.metadata
    c = m["counts"]
    click.echo(f"observer     {m['observer']['name']}  gains {m['observer']['gains']}")
    click.echo(f"input        {m['input']['path']}")
    click.echo(
        f"             {plural(c['velocity_samples'], 'velocity sample')}, "
        f"{plural(c['detection_frames'], 'detection frame')}, {plural(c['landmarks'], 'landmark')}, "
        f"{plural(c['internal_steps'], 'internal step')}"
    )
    t = summary.timings
    click.echo("time         " + ", ".join(f"{k[:-2]} {v:.2f} s" for k, v in t.items()))
    for note in summary.notes:
        click.echo(f"note         {note}")
    r = summary.report
    if r:
        from slamobs.cli.report_cmd import ALIGNED

        ape_t, ape_r = r["ape"]["translation_m"], r["ape"]["rotation_deg"]
        click.echo(  # the report's alignment (evaluation.align), as `slamobs report` names it
            f"APE          translation rmse {ape_t['rmse']:.4f} m (max {ape_t['max']:.4f} m), rotation rmse "
            f"{ape_r['rmse']:.3f} deg, {ape_t['n']} pairs, {ALIGNED[r['method']['alignment']['type']]}"
        )
        lm = r.get("landmarks") or {}
        if lm.get("error_m"):
            click.echo(f"landmarks    map error rmse {lm['error_m']['rmse']:.4f} m over {lm['error_m']['n']} landmarks")
        from slamobs.cli.report_cmd import clock_offset_line, clock_offset_matters, echo_biases_and_convergence

        echo_biases_and_convergence(r)
        if clock_offset_matters(off := r.get("time_offset") or {}):
            click.echo(f"clock offset {clock_offset_line(off, summary.out_dir)}")
        for hint in r.get("hints") or []:
            click.echo(f"hint         {hint}")
        for note in r.get("notes") or []:  # what the report found worth saying (e.g. a truth in another convention)
            if note not in summary.notes:  # the run's own (the noise levels) are in the report too: printed above
                click.echo(f"note         {note}")
    elif m.get("map_error"):  # landmark truth without trajectory truth: the map error is all there is
        from slamobs.cli.report_cmd import map_error_line

        click.echo(map_error_line(m["map_error"]))
    if m.get("figures"):
        click.echo(f"figures      {', '.join(m['figures'])} (report.md shows them)")
    click.echo(f"wrote        {wrote_line(summary.out_dir)}")


@main.command()
@click.argument("logs", nargs=-1, required=True, metavar="LOG...", type=click.Path(path_type=Path))
@click.option("-o", "--out", "out_dir", required=True, type=OutPath(path_type=Path), help="directory to create")
@click.option("--observers", "names", required=True, help="comma-separated observer names, e.g. fast-adaptation,hashim")
@log_run_options
def compare(
    logs: tuple[Path, ...],
    out_dir: Path,
    names: str,
    config_path: Path | None,
    msg_dir: Path | None,
    force: bool,
    start: float | None,
    end: float | None,
    truth: str | None,
    export: tuple[str, ...] | None,
    plots: bool | None,
    quiet: bool,
) -> None:
    """Run several observers on LOG and write a side-by-side table and an overlay plot (none with no plots).

    A ROS1 recording split into NAME_0.bag, NAME_1.bag, ... is one LOG: its directory, or all its parts.
    """
    from slamobs.cli.errors import working_on
    from slamobs.cli.listing import wrote_line
    from slamobs.pipeline.lifetime import collected_after_imports

    with collected_after_imports() as imported:  # as `run`: the collector off while the pipeline is imported
        from slamobs.pipeline.readers.container import recording_of

        log = recording_of(logs)
        working_on(log, "a comparison on this log")
        from slamobs.pipeline.compare import compare_log
        from slamobs.pipeline.config import load_config, with_observer
        from slamobs.pipeline.errors import InputError

        imported()
        observers = list(dict.fromkeys(n.strip() for n in names.split(",") if n.strip()))
        if not observers:
            raise InputError("--observers", "needs at least one observer name")
        config = log_run_config(load_config(config_path), truth, start, end, plots, msg_dir, export)
        for name in observers:
            with_observer(config, name, "--observers")
        # every stage on the status line of a terminal, else a line now and then; a line as each observer starts
        with Progress(quiet) as progress, compile_notice(progress.status, quiet=quiet, lines=progress):
            on_observer = progress if progress.status or quiet else lambda m: click.echo(f"compare: {m}", err=True)
            table = compare_log(
                log, out_dir, config, observers, force=force, progress=progress, on_observer=on_observer
            )
    if not quiet:
        with_values = table.astype(object).where(table.notna(), "")
        click.echo(with_values.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        if note := table.attrs.get("compile_note"):
            click.echo(f"note: {note}")
        for note in table.attrs.get("notes", []):  # what a blank or 180-degree cell means (comparison.md: Notes)
            click.echo(f"note: {note}")
        for hint in table.attrs.get("hints", []):  # each run's, once, prefixed by its estimator (comparison.md: Hints)
            click.echo(f"hint: {hint}")
        runs = "one run directory per observer" if any(p.is_dir() for p in out_dir.iterdir()) else ""
        files = ("comparison.parquet", "comparison.md", "comparison.json", "overlay.png")
        click.echo(f"wrote {wrote_line(out_dir, files, runs)}")
    if (table["status"] == "failed").all():
        sys.exit(1)


@main.command()
def observers() -> None:
    """List the observers and their gains (defaults in brackets; set them under `gains.<observer>` in run.yaml)."""
    from slamobs.pipeline.estimators import ESTIMATORS

    for spec in ESTIMATORS.values():
        click.echo(f"{spec.name}  (algorithm {spec.algorithm}) {spec.summary}")
        click.echo(f"    paper: {spec.paper}")
        if not spec.gains:
            click.echo(
                "    no gains: noise levels learned from each log (`slamobs info --noise LOG` prints them) unless set "
                "under `noise:` in run.yaml; the smoother's settings under `batch:`"
            )
        width = max((len(g.name) for g in spec.gains), default=0)
        for g in spec.gains:
            click.echo(f"    {g.name:<{width}}  [{g.default:g}]  {g.description}")
    click.echo(
        "Defaults in the first brackets; 'paper' is the paper's simulation value, 'reference' the value of "
        "the noise-free 100 Hz reference runs that check each observer against its paper. Equations, "
        "integration scheme and the reasons for the defaults: docs/observers.md in the slamobs repository."
    )


def entry() -> None:
    """The ``slamobs`` console script: :func:`main`, ending at once when it is done or interrupted (every output
    is complete and closed by then; the interpreter's teardown with numba, pyarrow and matplotlib loaded takes
    up to a second and would only delay the exit)."""
    from slamobs.cli import errors

    errors.EXIT_AT_ONCE = True
    errors.end_signals_at_once()  # until the command's handlers take over, and again when they put these back
    try:
        main()
    except SystemExit as done:
        errors.exit_at_once(done.code)
        raise


def _add_commands() -> None:
    """Commands that live in their own modules (each imports only click at module level)."""
    from slamobs.cli.batch_cmd import batch
    from slamobs.cli.evaluate_cmd import evaluate
    from slamobs.cli.export_cmd import export
    from slamobs.cli.import_cmd import import_group
    from slamobs.cli.info_cmd import info
    from slamobs.cli.report_cmd import report
    from slamobs.cli.simulate_cmd import simulate
    from slamobs.cli.stats_cmd import stats
    from slamobs.cli.tune_cmd import tune
    from slamobs.cli.view_cmd import view

    for command in (info, simulate, import_group, report, evaluate, export, batch, tune, stats, view):
        main.add_command(command)


_add_commands()

if __name__ == "__main__":  # `python -m slamobs.cli.main ...` ran nothing and exited 0 without this
    from slamobs.cli.main import entry as _installed_entry  # the imported module, as the console script runs it

    _installed_entry()
