"""Option spellings shared by the commands: one documented name per option, old spellings kept working.

Every command writes to ``-o/--out`` and is silenced by ``-q/--quiet``; names that earlier versions used
(``simulate --output``, ``evaluate --silent``) stay accepted as hidden aliases so scripts do not break, but
``--help`` shows only the current spelling.
"""

from __future__ import annotations

import math
from pathlib import Path

import click


class Finite(click.FloatRange):
    """A number option within the bounds given, and never NaN or ±inf: click's FloatRange lets NaN through (every
    comparison with it is false), and a NaN rate or tolerance failed deep inside a command with a traceback."""

    name = "float"

    def _describe_range(self) -> str:
        """Nothing for an unbounded number (click printed ``[x<=None]`` in the help)."""
        return "" if self.min is None and self.max is None else super()._describe_range()

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return number


class OutPath(click.Path):
    """The path of ``-o/--out``: empty (or only blanks) is a usage error. ``Path("")`` is ``.``: the output went into
    the current directory (a batch wrote its dataset there) or a message named "." for it."""

    def convert(self, value, param, ctx):
        if isinstance(value, str) and not value.strip():
            self.fail(f"{value!r} is empty: name the output to write", param, ctx)
        return super().convert(value, param, ctx)


class Spelled(click.Choice):
    """Choices spelled with dashes, as the help shows them (the CLI turns ``_`` into ``-``), that also take evo's
    underscores (``trans_part``) when the command runs outside the ``slamobs`` group; the command gets the
    underscore spelling its code uses."""

    def __init__(self, choices) -> None:
        super().__init__([c.replace("_", "-") for c in choices])

    def convert(self, value, param, ctx):
        return super().convert(str(value).replace("_", "-"), param, ctx).replace("-", "_")


#: Largest time option in seconds: times become int64 nanoseconds (9.2e9 s), and 1e9 s is 31 years.
MAX_SECONDS = 1e9


class Seconds(Finite):
    """A time option in seconds, within ±:data:`MAX_SECONDS` (1e300 s overflowed the nanoseconds: a traceback)."""

    name = "seconds"

    def convert(self, value, param, ctx):
        seconds = super().convert(value, param, ctx)
        if abs(seconds) > MAX_SECONDS:
            self.fail(f"{value!r} s is more than {MAX_SECONDS:g} s", param, ctx)
        return seconds


#: Seeds of NumPy's and Optuna's generators: a negative one was a traceback (and left tune.journal behind).
SEED = click.IntRange(0, 2**32 - 1)


def offset_seconds(text: str) -> float | str:
    """``--t-offset``: seconds (finite) or ``auto``."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        seconds = float(text)
    except ValueError:
        seconds = math.nan
    if not abs(seconds) <= MAX_SECONDS:  # NaN too
        raise click.BadParameter(
            f"{text!r} is neither seconds (at most {MAX_SECONDS:g} in size) nor 'auto'", param_hint="--t-offset"
        )
    return seconds


class AliasedOption(click.Option):
    """A click option whose ``hidden_aliases`` parse like its other names but are left out of ``--help``."""

    def __init__(self, *args, hidden_aliases: tuple[str, ...] = (), **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.hidden_aliases = tuple(hidden_aliases)

    def get_help_record(self, ctx: click.Context):
        shown = self.opts
        self.opts = [o for o in shown if o not in self.hidden_aliases]
        try:
            return super().get_help_record(ctx)
        finally:
            self.opts = shown


def quiet_option(help: str = "print nothing but errors"):
    """``-q/--quiet`` (``--silent`` too, hidden: evaluate's former name)."""
    return click.option(
        "-q", "--quiet", "--silent", "quiet", is_flag=True, cls=AliasedOption, hidden_aliases=("--silent",), help=help
    )


def _kinds(allowed: tuple[str, ...]):
    def parse(ctx: click.Context, param: click.Parameter, value: str | None) -> tuple[str, ...] | None:
        if value is None:
            return None
        from slamobs.pipeline.config import export_kinds

        kinds = [k.strip().lower() for k in value.split(",") if k.strip()]
        bad = sorted(set(kinds) - set(allowed) - {"none"})
        if bad or not kinds:
            raise click.BadParameter(
                f"{value!r}: expected a comma-separated list of {', '.join(allowed)} (or none)", ctx, param
            )
        return export_kinds(kinds)

    return parse


def export_option(
    allowed: tuple[str, ...] = ("tum", "evo", "mcap"), default: str = "output.export of the config, else none"
):
    """``--export tum,evo,...``: the optional extra files of a run directory (replaces ``output.export``)."""
    described = {
        "tum": "tum (estimate_tum.txt, truth_tum.txt)",
        "evo": "evo (ape_evo.zip for evo_res)",
        "mcap": "mcap (results.mcap for Foxglove)",
    }
    return click.option(
        "--export",
        "export",
        default=None,
        metavar="LIST",
        callback=_kinds(allowed),
        help="extra files, comma-separated: "
        + ", ".join(described[k] for k in allowed)
        + f"; none writes none [default: {default}]",
    )


def plots_option(default: str = "evaluation.plots of the config"):
    """``--plots/--no-plots``: draw the figures, or none, whatever ``evaluation.plots`` says (unset: as it says;
    ``config.plots_setting``)."""
    return click.option(
        "--plots/--no-plots",
        "plots",
        default=None,
        help=f"draw the figures (--no-plots: none, e.g. for thousands of logs) [default: {default}]",
    )


#: --start / --end: absolute stamps are Unix seconds, below 2**63 ns
_WINDOW_BOUND = Finite(min=0.0, max=9.2e9)
_WINDOW_RULE = "seconds from the log's start (its first angular-velocity sample), or an absolute stamp in s if > 1e9"


def msg_dir_option(help: str = "pkg/msg/Type.msg definitions for types the log does not store", exists: bool = False):
    """``--msg-dir DIR``: ``.msg`` definitions for the message types a log does not store (``exists``: checked
    before the command runs)."""
    return click.option(
        "--msg-dir", type=click.Path(path_type=Path, file_okay=False, exists=exists), default=None, help=help
    )


#: ``--wait-workers`` of batch and tune: how long a Dask run waits for its first worker
wait_workers_option = click.option(
    "--wait-workers",
    type=Finite(min=0),
    default=60.0,
    show_default=True,
    metavar="SECONDS",
    help="Dask: give up (exit 3) when no worker is there for this long",
)


def config_option(help: str = "run.yaml"):
    """``--config FILE``: a run.yaml, read by ``pipeline.config.load_config`` (one spelling in every command)."""
    return click.option("--config", "config_path", type=click.Path(path_type=Path), default=None, help=help)


#: ``--truth`` of run and compare: the one truth grammar (pipeline.readers.trajectory_files.parse_truth)
truth_option = click.option(
    "--truth",
    default=None,
    help="ground truth: a topic of LOG, a TF edge parent->child, a TUM / EuRoC CSV / KITTI file, or LOG:TOPIC of "
    "another log; 'none': no truth, not even a detected one (no APE; a landmark truth still gives the map error) "
    "[default: topics.truth of the config, else detected]",
)


def window_options(command):
    """``--start`` / ``--end``: the part of the log a run uses (``time.start`` / ``time.end`` of run.yaml)."""
    command = click.option(
        "--end", type=_WINDOW_BOUND, default=None, help=f"use the log up to this time: {_WINDOW_RULE}"
    )(command)
    return click.option(
        "--start", type=_WINDOW_BOUND, default=None, help=f"use the log from this time: {_WINDOW_RULE}"
    )(command)


def log_run_options(command):
    """The options ``run`` and ``compare`` share, in this order: ``--config``, ``--msg-dir``, ``--force``, the window
    (``--start``/``--end``), ``--truth``, ``--export``, ``--plots/--no-plots`` and ``--quiet``."""
    for option in (
        quiet_option(),
        plots_option(),
        export_option(),
        truth_option,
        window_options,
        click.option("--force", is_flag=True, help="replace an existing output directory"),
        msg_dir_option(),
        config_option(),
    ):
        command = option(command)
    return command


def log_run_config(config, truth, start, end, plots, msg_dir, export):
    """``config`` with what :func:`log_run_options` gave applied, as ``run`` and ``compare`` read it: ``--truth``,
    the window, ``--plots/--no-plots``, ``--msg-dir`` and ``--export`` (None: the config's own)."""
    from dataclasses import replace

    from slamobs.pipeline.config import with_truth

    config = with_truth(config, truth).with_window(start, end).with_plots(plots)
    if msg_dir:
        config = replace(config, msg_dir=str(msg_dir))
    if export is not None:
        config = config.with_section("output", export=export)
    return config
