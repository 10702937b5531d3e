"""(Re)computing the report of a finished run directory: find the truth, build the report, replace its files.

The run directory keeps the input log path, topics and time source in ``run.json``; the truth can be that
log's truth topic (default), another topic or a TF edge of it, or a TUM / EuRoC CSV / KITTI file. Landmark and
bias truth come from the log's simulation truth when the log is still there. Report files are written into a
temporary directory next to them and renamed into place one by one, so a reader never sees a half-written
file and a failure leaves the previous report untouched.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from slamobs.pipeline import interrupts
from slamobs.pipeline.alignment import TimeWindow
from slamobs.pipeline.errors import InputError, OutputError, SlamobsError, TruthUnusable
from slamobs.pipeline.lifetime import owner_marker
from slamobs.pipeline.paths import check_utf8, read_manifest, temporary_prefix
from slamobs.pipeline.evaluation.report import (
    REPORT_FILES,
    add_run_context,
    evaluate_report,
    with_verdict_warnings,
    write_report,
)
from slamobs.pipeline.evaluation.trajectory_evaluation import ReportOptions, recorded_offset, truth_in_body
from slamobs.pipeline.streams import PoseStream
from slamobs.pipeline.writers import NEW, OWNER, remove_stale_temporaries, update_manifest, write_json

if TYPE_CHECKING:
    from slamobs.pipeline.evaluation.sync import TimeOffset
    from slamobs.pipeline.evaluation.tables import Table

#: The tables of a run directory a report reads (every run writes them).
RUN_TABLES = ("poses", "biases", "landmarks")
#: The exports a report writes (``mcap`` is written by ``slamobs export`` or a run).
REPORT_EXPORTS = ("tum", "evo")


@dataclass
class RunTables:
    """What a run directory holds that the report needs."""

    path: Path
    meta: dict[str, Any]
    poses: Table
    biases: Table | None
    landmarks: Table | None
    innovations: Table | None = None
    landmark_tracks: Table | None = None


@dataclass
class TruthInput:
    """Ground truth for a report and where it came from."""

    stream: PoseStream
    landmark_truth: dict[int, np.ndarray] | None
    bias_truth: dict[str, np.ndarray] | None
    source: dict[str, Any]
    notes: list[str] = field(default_factory=list)


#: Sections of a run's JSON files that its readers look into: each must be an object when present.
_SECTIONS = ("input", "observer", "output", "counts", "options", "ape", "truth_source")


def read_json(path: Path) -> dict:
    """A JSON file of a run directory (``run.json``, ``report.json``); damaged, unreadable or not UTF-8 is one
    line naming it, and so is valid JSON of another shape (``[]``, or a section that is not an object): the
    readers look up keys in it."""
    name = Path(path).name
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as err:
        raise InputError(path, f"unreadable {name}: {' '.join(str(err).split())}"[:300]) from None
    bad = (
        "the file"
        if not isinstance(data, dict)
        else next((f"'{k}'" for k in _SECTIONS if data.get(k) is not None and not isinstance(data[k], dict)), None)
    )
    if bad is not None:
        value = data if bad == "the file" else data[bad.strip("'")]
        raise InputError(
            path,
            f"not a run's {name}: {bad} is a JSON {_json_kind(value)}, not an object "
            "(edited or damaged; run the command that wrote it again)",
        )
    return data


def _json_kind(value: Any) -> str:
    return {list: "array", str: "string", bool: "boolean", int: "number", float: "number"}.get(type(value), "null")


def run_meta(run_dir: str | Path) -> dict[str, Any]:
    """``run.json`` of a run directory whose report tables are all there (one line naming what is not), without
    reading the tables."""
    return _checked_run(Path(run_dir))[0]


def _checked_run(run_dir: Path) -> tuple[dict[str, Any], dict | None]:
    """``run.json`` and, for a batch run directory (``OUT/runs/<id>``), its tables in the dataset (else None)."""
    check_utf8(run_dir)
    meta_path = run_dir / "run.json"
    if not meta_path.is_file():
        from slamobs.pipeline.stored_runs import not_a_run

        raise not_a_run(run_dir)
    meta = read_json(meta_path)
    from slamobs.pipeline.stored_runs import run_tables

    in_dataset = run_tables(run_dir)  # a batch run directory (OUT/runs/<id>): its tables live in the dataset
    if in_dataset is None and not (run_dir / "poses.parquet").is_file():
        raise InputError(run_dir, "run directory has no poses.parquet")
    for name in RUN_TABLES if in_dataset is None else ():
        if not (run_dir / f"{name}.parquet").is_file():  # a report without it would drop its section and files
            raise InputError(
                run_dir / f"{name}.parquet",
                "missing: every run writes this table; the report needs it (run the log again)",
            )
    return meta, in_dataset


def load_run(run_dir: str | Path) -> RunTables:
    """``run.json`` and the Parquet tables of a run directory, read as a run's own report reads them
    (:func:`.writers.read_columns`: NumPy columns, without pandas; an observer's all-null uncertainty columns of
    the poses left out)."""
    from slamobs.pipeline.writers import read_columns

    run_dir = Path(run_dir)
    meta, in_dataset = _checked_run(run_dir)

    def table(name: str) -> Table | None:
        if in_dataset is not None:
            return in_dataset[name].to_pandas() if name in in_dataset else None
        path = run_dir / f"{name}.parquet"
        return read_columns(path, skip_null=name == "poses") if path.is_file() else None

    return RunTables(
        run_dir,
        meta,
        table("poses"),
        table("biases"),
        table("landmarks"),
        table("innovations"),
        table("landmark_tracks"),
    )


def _sim_truth(log: Path) -> tuple[dict | None, dict | None]:
    from slamobs.pipeline.readers import ROLES, read_log

    streams = read_log(log, {r: None for r in ROLES if r != "sim_truth"})
    return streams.landmark_truth, streams.bias_truth


def has_truth(meta: dict[str, Any]) -> bool:
    """Whether the run named a truth (a topic of its log or a trajectory file) that a report can use again."""
    inp = meta.get("input") or {}
    return bool(inp.get("truth_file") or (inp.get("topics") or {}).get("truth") or _earlier_truth(meta))


def _earlier_truth(meta: dict[str, Any]) -> str | None:
    """The truth an earlier ``slamobs report --truth`` used (a topic, TF edge or file), if any."""
    earlier = meta.get("report_truth")
    return str(earlier["name"]) if isinstance(earlier, dict) and earlier.get("name") else None


def resolve_truth(meta: dict[str, Any], source: str | None) -> TruthInput:
    """The truth for a run: ``source`` None -> the run's truth (its topic, TF edge or file); else a truth in the one
    grammar (``readers.parse_truth``): a TF edge or topic of the run's input log, a trajectory file (TUM, EuRoC
    CSV, KITTI with stamps), or another log's ``LOG:TOPIC``."""
    inp = meta.get("input") or {}
    log = Path(inp["path"]) if inp.get("path") else None
    time_source = inp.get("time_source", "header")
    notes: list[str] = []
    have_log = log is not None and log.exists()

    if source is None and not inp.get("truth_file") and not (inp.get("topics") or {}).get("truth"):
        source = _earlier_truth(meta)  # a run without truth reported on with --truth: that truth again
    given = inp.get("truth_file") if source is None else None  # the run's truth was a file: read it again
    if given is None and source is None and Path((inp.get("topics") or {}).get("truth") or "\0").is_file():
        given = {"path": inp["topics"]["truth"]}  # a run from before run.json named its truth file
    if given is None and source is not None and have_log and Path(source).resolve() == log.resolve():
        raise InputError(source, "the run's own log: name a topic of it, or give LOG:TOPIC")
    if given is None and source is None:
        source = (inp.get("topics") or {}).get("truth")
        if source is None:
            raise InputError(
                meta.get("input", {}).get("path", "run.json"),
                "the run's log has no truth topic: give --truth (a topic, a TF edge, a trajectory file or LOG:TOPIC)",
            )
    given = given or {"path": source}
    traj = _read_truth(given, log if have_log else None, inp.get("clocks") or {})
    if traj.format == "parquet":
        raise InputError(given["path"], "a poses.parquet is an estimate, not a ground-truth file")
    if not traj.timed:
        raise InputError(given["path"], "KITTI poses carry no stamps and cannot be matched to a run's clock")
    stream, desc = traj.stream, _truth_description(traj, given["path"], log)
    own = desc["kind"] != "file" and desc["log"] == str(log)  # a topic of the run's log: on the run's clock
    if own and time_source == "record":
        stream = PoseStream(**{**stream.__dict__, "t_ns": stream.rec_ns})
    desc["n_poses"] = len(stream)
    desc["time_source"] = time_source if own else "file stamps" if desc["kind"] == "file" else "header"
    lm_truth = bias_truth = None
    if have_log:
        lm_truth, bias_truth = _sim_truth(log)
    else:
        notes.append(f"input log {log} not found: no landmark or bias truth")
    return TruthInput(stream, lm_truth, bias_truth, desc, notes)


def recorded_run_offset(est: str | Path, truth: PoseStream) -> Callable[[], TimeOffset | None] | None:
    """The truth-clock search a run recorded (run.json ``truth_clock_offset``: the truth against the log's velocity
    samples, a gyro bias fitted, the halves' ``uncertainty_s``), for ``slamobs evaluate TRUTH RUN_DIR/poses.parquet``:
    where ``est`` is a run's poses.parquet and ``truth`` reads as that run's own truth (the same stamps, on the run's
    clock, and positions), the search ``slamobs report RUN_DIR`` checks again, so both say the same offset; else None
    (evaluate searches the estimate). Public for ``slamobs evaluate``."""
    path = Path(est)
    if path.name != "poses.parquet" or not (path.parent / "run.json").is_file():
        return None
    try:
        meta = json.loads((path.parent / "run.json").read_text(encoding="utf-8"))
        if not isinstance(meta, dict) or "truth_clock_offset" not in meta:
            return None
        own = resolve_truth(meta, None).stream
    except (OSError, ValueError, SlamobsError):  # no run's truth to compare with: the estimate is searched
        return None
    same = np.array_equal(np.asarray(own.t_ns), np.asarray(truth.t_ns)) and np.array_equal(
        np.asarray(own.position), np.asarray(truth.position), equal_nan=True
    )
    return partial(recorded_offset, meta["truth_clock_offset"]) if same else None


def _read_truth(given: dict, log: Path | None, clocks: dict[str, str]):
    """The truth ``given`` names (path, format, times), a topic or TF edge read from ``log``."""
    from slamobs.pipeline.readers import parse_truth, read_truth

    spec = parse_truth(given["path"]) if given.get("format") in (None, "topic") else None
    if spec is not None and spec.kind != "file" and spec.log is None and log is None:
        raise InputError("run.json", "the run's input log is not there; give --truth as a trajectory file or LOG:TOPIC")
    return read_truth(given["path"], log, fmt=given.get("format"), times=given.get("times"), clocks=clocks)


def _truth_description(traj, given: str, log: Path | None) -> dict:
    """``truth_source`` of report.json: what kind of truth, its name, and the log it came from."""
    if traj.format in ("topic", "tf_edge"):
        from slamobs.pipeline.readers import parse_truth

        spec = parse_truth(given)
        kind = "tf_edge" if spec.kind == "edge" else "topic"
        return {"kind": kind, "name": spec.name, "log": str(spec.log or log)}
    return {"kind": "file", "format": traj.format, "name": str(traj.name)}


def gravity_aligned(meta: dict[str, Any]) -> bool:
    """Whether a run's poses have observed roll and pitch: an observer with IMU directions, written in the gravity
    frame (``output.frame``; runs from before output frames existed were in the observer's inertial frame)."""
    uses = bool((meta.get("observer") or {}).get("directions"))
    frame = ((meta.get("output") or {}).get("frame") or {}).get("name", "gravity")
    return uses and frame == "gravity"


def options_for_run(meta: dict[str, Any], **overrides: Any) -> ReportOptions:
    """Report options for a run: 4-DoF alignment added when its poses are gravity-aligned by IMU directions, the
    truth carried to the body where run.json says TF places the truth's frame on it (``input.truth_body``)."""
    carried = truth_in_body((meta.get("input") or {}).get("truth_body"))
    given = {k: v for k, v in overrides.items() if v is not None}
    return ReportOptions(**{"gravity_aligned": gravity_aligned(meta), "truth_in_body": carried, **given})


def replace_files(run_dir: Path, staged: Path, owned: tuple[str, ...]) -> list[Path]:
    """Move every file of ``staged`` into ``run_dir`` with an atomic rename each; files in ``owned`` that the
    new set lacks are removed afterwards (a stale plot must not pass for the new report's)."""
    moved = []
    names = {p.name for p in staged.iterdir()}
    _check_own(run_dir, sorted(names | set(owned)))
    interrupts.check()  # a pending Ctrl-C/SIGTERM replaces nothing
    with interrupts.critical():  # one arriving now waits until the set is whole
        for p in sorted(staged.iterdir()):
            os.replace(p, run_dir / p.name)
            moved.append(run_dir / p.name)
        # once each: a name may be owned twice (biases.png is the run's figure and the report's)
        removed = [name for name in dict.fromkeys(owned) if name not in names and (run_dir / name).is_file()]
        for name in removed:
            (run_dir / name).unlink()
        update_manifest(run_dir, moved, removed)  # these files are still the run's (a later --force replaces them)
    interrupts.note_published(run_dir)
    return moved


def _check_own(run_dir: Path, names: list[str]) -> None:
    """Refuse (before anything is replaced) when a file the report would replace or remove is not the one slamobs
    wrote: in a run directory with a manifest, listed there with its size (an edited report.md is the user's)."""
    doc = read_manifest(run_dir)
    if doc is None:
        return
    for name in names:
        path = run_dir / name
        if os.path.lexists(path):
            size = os.lstat(path).st_size if path.is_file() and not path.is_symlink() else None
            if doc["files"].get(name) != size:
                raise OutputError(
                    path,
                    "not written by slamobs, or changed since: the report replaces only its own "
                    "files; move it away and report again",
                )


def _stage_run_json(meta: dict[str, Any], truth: dict[str, Any], staged: Path, exports: tuple[str, ...]) -> None:
    """run.json pointing at the new report and naming its truth and exports, staged with the report files."""
    meta = dict(meta)
    meta["report"] = "report.json"
    meta["report_truth"] = truth
    output = dict(meta.get("output") or {})
    output["export"] = [k for k in output.get("export", []) if k not in REPORT_EXPORTS] + list(exports)
    meta["output"] = output
    tmp = staged / "run.json"
    tmp.write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")


def report_plots(meta: dict[str, Any], plots: bool | None = None) -> str | bool:
    """The figures a new report of a run draws: every one (``"all"``), or none (False) where the run was made with
    ``evaluation.plots: false`` (``run.json`` ``output.plots``; a run.json without it drew figures) or ``plots``
    (``--plots`` / ``--no-plots``, None: as the run) says so."""
    from slamobs.pipeline.config import plots_setting

    return "all" if plots_setting((meta.get("output") or {}).get("plots", True), plots) else False


def report_run(
    run_dir: str | Path,
    truth: str | None = None,
    options: ReportOptions | None = None,
    exports: tuple[str, ...] | None = None,
    plots: bool | None = None,
    **overrides: Any,
) -> tuple[dict[str, Any], list[Path]]:
    """Recompute the report of ``run_dir`` against ``truth`` and replace its report files atomically.

    ``exports`` ("tum", "evo") are the optional files to write; None keeps the run's choice (``run.json``).
    ``plots``: draw the figures or not (None: as the run did, :func:`report_plots`). Returns the report and the
    paths written. ``overrides`` are :class:`ReportOptions` fields.
    """
    from slamobs.pipeline.evaluation.figure_jobs import run_figure_jobs

    run = load_run(run_dir)
    tables = _tables(run)
    drawn = report_plots(run.meta, plots)
    if exports is None:
        exports = tuple(k for k in (run.meta.get("output") or {}).get("export", []) if k in REPORT_EXPORTS)
    exports = tuple(k for k in exports if k in REPORT_EXPORTS)
    ti = resolve_truth(run.meta, truth)
    if run.meta.get("time_window"):  # the run used part of its log: so does its truth
        ti = replace(ti, stream=TimeWindow.described(run.meta["time_window"]).poses(ti.stream))
    options = options or options_for_run(run.meta, **overrides)
    # the run's own truth: the clock offset the run searched against its log's velocity samples, checked again
    found = None
    if truth is None and "truth_clock_offset" in run.meta:
        found = partial(recorded_offset, run.meta["truth_clock_offset"])
    try:
        report, evaluation = evaluate_report(
            run.poses,
            run.biases,
            run.landmarks,
            ti.stream,
            ti.landmark_truth,
            ti.bias_truth,
            options=options,
            found_offset=found,
        )
    except TruthUnusable:
        raise  # the caller may report as without truth, as ``run`` did
    except ValueError as err:
        raise InputError(run.path, f"no report: {err}") from None
    report["truth_source"] = ti.source
    report["notes"] = ti.notes + report["notes"]
    add_run_context(report, list(run.meta.get("notes") or []), run.meta)

    def fill(staged: Path) -> None:
        write_report(
            report,
            staged,
            run.poses,
            run.biases,
            run.landmarks,
            ti.stream,
            ti.landmark_truth,
            evaluation=evaluation,
            exports=exports,
            plots=drawn,
            metadata=run.meta,
            more_figures=run_figure_jobs(tables, with_biases=False) if drawn else [],
        )
        meta = {**run.meta, "figures": report.get("figures", []), "hints": report.get("hints") or []}
        meta["notes"] = with_verdict_warnings(list(run.meta.get("notes") or []), report, run.meta)
        _stage_run_json(meta, ti.source, staged, exports)

    return report, _replace_report_files(run, fill)


#: report.md's note when ``slamobs report --truth none`` sets a run's truth aside (its summary says the notes tell
#: why there are no error numbers).
TRUTH_SET_ASIDE = "no error report: --truth none set the run's own truth aside (`slamobs report RUN` reports on it)"


def summarise_run(
    run_dir: str | Path, plots: bool | None = None, set_aside: bool = False
) -> tuple[dict[str, Any], list[Path]]:
    """A run without truth: draw its figures (as :func:`report_run`, ``plots``) and write report.md (what the run
    did, the figures) again, replacing the report files atomically as :func:`report_run` does; returns what
    ``report --json`` prints (every number of report.md with its definition: ``figure_jobs.summary_json``) and the
    paths written. ``set_aside``: the run has truth, ``--truth none`` asked for none (:data:`TRUTH_SET_ASIDE`
    among report.md's notes)."""
    from slamobs.pipeline.evaluation.figure_jobs import summary, summary_json, write_run_figures

    run = load_run(run_dir)
    tables = _tables(run)
    notes, map_error = list(run.meta.get("notes") or []), run.meta.get("map_error")
    if set_aside:
        notes.insert(0, TRUTH_SET_ASIDE)
    figures: list[str] = []

    def fill(staged: Path) -> None:
        drawn = write_run_figures(staged, tables, notes, plots=report_plots(run.meta, plots), map_error=map_error)
        figures.extend(p.name for p in drawn if p.suffix == ".png")
        meta = {**run.meta, "figures": figures}
        (staged / "run.json").write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")

    written = _replace_report_files(run, fill)
    return summary_json(summary(tables), figures, notes, map_error), written


def _tables(run) -> dict[str, Any]:
    """The run's tables the figures are drawn from."""
    return {
        "poses": run.poses,
        "biases": run.biases,
        "landmarks": run.landmarks,
        "innovations": run.innovations,
        "landmark_tracks": run.landmark_tracks,
    }


def _replace_report_files(run, fill) -> list[Path]:
    """``fill(staged)`` writes the new report files into a hidden directory inside the run; they then replace the
    run's report files and figures at once (:func:`replace_files`), so a failure leaves the previous ones."""
    from slamobs.pipeline.evaluation.figure_jobs import RUN_FIGURES

    # A report SIGKILLed while staging left its hidden directory in the run, half-written Parquet files in it that
    # a recursive glob of the outputs reads: the staging is marked with its owner, and the next report removes
    # what killed ones left (kill matrix seed 61).
    remove_stale_temporaries(run.path)
    with interrupts.critical():  # a directory without its owner marker would never be removed
        container = Path(tempfile.mkdtemp(prefix=temporary_prefix("report"), dir=run.path))
        write_json(container / OWNER, owner_marker())
        drop = partial(shutil.rmtree, container, ignore_errors=True)
        interrupts.at_end(drop)  # a signal that ends the process inside numba's compiler removes it too
    try:
        staged = container / NEW
        staged.mkdir()
        fill(staged)
        for p in staged.iterdir():
            os.chmod(p, 0o644)
        return replace_files(run.path, staged, REPORT_FILES + RUN_FIGURES)
    finally:
        interrupts.not_at_end(drop)
        drop()
