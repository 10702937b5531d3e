"""The run's error report: estimate vs ground truth, as a JSON document, a Markdown page, plots and evo files.

``build_report`` is pure (tables in, dict out); ``write_report`` is the I/O edge. The report is composed of its
sections (:mod:`.sections`, one class each), computed on the one evaluation of the trajectory
(:mod:`.trajectory_evaluation`, the evo-compatible path of :mod:`.trajectory_error`); :mod:`.markdown` renders
it and :mod:`.figure_jobs` plans its figures. The report states how every number was obtained (association,
alignment, definitions). On request (``exports``) it also writes the estimate and the truth as TUM files and
the APE as an evo result zip, so an evo user can reproduce the headline with ``evo_ape`` and compare with
``evo_res``.
Beyond evo: APE under several alignments, landmark map error after the trajectory alignment and after a
map-only alignment, bias error and stability, convergence time, clock offset estimate, KITTI-style drift.
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from slamobs.pipeline.version import __version__
from slamobs.pipeline.blocks import row_blocks
from slamobs.pipeline.evaluation.figure_jobs import (
    bias_plot_job,
    chosen,
    error_plot_job,
    SEGMENT_PLOT,
    landmark_plot_jobs,
    plot_jobs,
    segment_plot_jobs,
    top_view_job,
    uncertainty_plot_jobs,
)
from slamobs.pipeline.evaluation.align import SCALED_ALIGNMENTS
from slamobs.pipeline.evaluation.markdown import extent_words, render_markdown
from slamobs.pipeline.evaluation.metrics import MATRICES_KEPT_ROWS, rotated, statistics
from slamobs.pipeline.evaluation.sections import (
    EVO_ALIGN_FLAGS,
    ApeByAlignmentSection,
    ApeSection,
    BiasSection,
    ConvergenceSection,
    DriftSection,
    LandmarkSection,
    RpeSection,
    SegmentErrorsSection,
    TimeOffsetSection,
    UncertaintySection,
    aligned_errors,
    alignment_dict,
    nees_against_offset_truth,
    nees_against_turned_truth,
)
from slamobs.pipeline.evaluation.tables import Table, column, column_names, columns, n_rows
from slamobs.pipeline.evaluation.trajectory_error import Paired
from slamobs.pipeline.evaluation.trajectory_evaluation import (
    SET_ONLY_OPTIONS,
    TUPLE_OPTIONS,
    Pending,
    ReportOptions,
    TrajectoryEvaluation,
    evaluate_trajectory,
    TruthSpikes,
    truth_spikes,
    valid_truth,
)
from slamobs.pipeline.lie import quats_to_rots, rots_to_quats
from slamobs.pipeline.streams import PoseStream

SCHEMA_VERSION = 1

#: files ``write_report`` may write into a run directory (all of them belong to the report)
TRUTH_TUM = "truth_tum.txt"
ESTIMATE_TUM = "estimate_tum.txt"
EVO_ZIP = "ape_evo.zip"
PLOTS = ("trajectory_top.png", "errors.png", "biases.png", "landmarks.png", SEGMENT_PLOT, "uncertainty.png", "nees.png")
#: the estimate moved into the truth's frame by the report's alignment (schemas/poses_aligned.json, ...)
ALIGNED_TABLES = ("poses_aligned.parquet", "landmarks_aligned.parquet")
REPORT_FILES = ("report.json", "report.md", *PLOTS, EVO_ZIP, ESTIMATE_TUM, TRUTH_TUM, *ALIGNED_TABLES)


def _evo_commands(options: ReportOptions, ev: TrajectoryEvaluation) -> dict[str, str | None]:
    flags = EVO_ALIGN_FLAGS.get(options.align)
    if flags is None:
        return {"ape": None, "note": f"evo has no {options.align} alignment"}
    off = f" --t_offset {ev.applied_offset_s!r}" if ev.applied_offset_s else ""
    base = f"evo_ape tum {TRUTH_TUM} {ESTIMATE_TUM}{flags} --t_max_diff {options.t_max_diff_s!r}{off}"
    return {
        "ape": base,
        "ape_rotation": base + " -r angle_deg",
        "note": f"run in the run directory; the TUM files are written with --export tum, {EVO_ZIP} (the "
        f"translation result, evo_res {EVO_ZIP}) with --export evo",
        **_evo_departs(ev),
    }


def _evo_departs(ev: TrajectoryEvaluation) -> dict[str, str]:
    """``departs`` where the report's fit is not evo's (``Alignment.umeyama``: ``align.upright_fit`` kept the
    estimate's up side up on a flat truth that evo's Umeyama turns over): the translation rmse evo gives on the
    same pairs beside this report's, by the path the report's APE takes (``aligned_errors``, ``statistics``);
    nothing elsewhere."""
    evo = ev.alignment.umeyama
    if evo is None:
        return {}
    trans, _ = aligned_errors({"evo": evo}, ev.paired)["evo"]
    evo_rmse = float(statistics(trans)["rmse"])
    return {
        "departs": f"evo's Umeyama fit turns the estimate over on this flat truth (the APE section's note; "
        f"align.upright_fit): evo_ape gives translation rmse about {evo_rmse:.4g} m, not this report's "
        f"{float(ev.translation.stats['rmse']):.4g} m"
    }


def build_report(
    poses: Table,
    biases: Table | None,
    landmarks: Table | None,
    truth: PoseStream,
    landmark_truth: dict[int, np.ndarray] | None = None,
    bias_truth: dict[str, np.ndarray] | None = None,
    *,
    options: ReportOptions | None = None,
    **overrides: Any,
) -> dict[str, Any]:
    """Errors of one run against ground truth, JSON-ready (plain Python numbers, None for unknowns).

    SLAM without absolute references determines the pose only up to a constant rigid transform
    (docs/observers.md §1.1), so with ``align="se3"`` the estimate is first mapped onto the truth frame by the
    least-squares SE(3) transform of the associated positions; ``align="none"`` compares the raw estimate.
    ``overrides`` are :class:`ReportOptions` fields (e.g. ``t_max_diff_s``, ``align``) on top of ``options``.
    """
    return evaluate_report(poses, biases, landmarks, truth, landmark_truth, bias_truth, options=options, **overrides)[0]


def evaluate_report(
    poses: Table,
    biases: Table | None,
    landmarks: Table | None,
    truth: PoseStream,
    landmark_truth: dict[int, np.ndarray] | None = None,
    bias_truth: dict[str, np.ndarray] | None = None,
    *,
    options: ReportOptions | None = None,
    found_offset: Callable[[], Any] | None = None,
    **overrides: Any,
) -> tuple[dict[str, Any], TrajectoryEvaluation]:
    """:func:`build_report` and the trajectory evaluation behind it (hand it to :func:`write_report`, which
    otherwise associates and aligns the trajectories again: seconds on a long log); ``found_offset`` as for
    :func:`evaluate_tables`."""
    return evaluate_tables(
        {"poses": poses, "biases": biases, "landmarks": landmarks},
        truth,
        landmark_truth,
        bias_truth,
        options=options,
        found_offset=found_offset,
        **overrides,
    )


def evaluate_tables(
    tables: dict[str, Table | None],
    truth: PoseStream,
    landmark_truth: dict[int, np.ndarray] | None = None,
    bias_truth: dict[str, np.ndarray] | None = None,
    *,
    options: ReportOptions | None = None,
    figures: Callable[[list], None] | None = None,
    drawn_biases: Table | None = None,
    aligned: Callable[[TrajectoryEvaluation], None] | None = None,
    found_offset: Callable[[], Any] | None = None,
    **overrides: Any,
) -> tuple[dict[str, Any], TrajectoryEvaluation]:
    """:func:`evaluate_report` of the ``poses``, ``biases`` and ``landmarks`` tables in ``tables``, each removed
    from the dict once it has been used: a caller that hands the dict over (keeps no other reference) has the
    bias table of a long run freed before the trajectory is evaluated.

    ``figures`` (e.g. :meth:`.plot_worker.PlotWorkers.submit`) is handed the report's figure jobs as soon as
    their sections are known (the bias figure, drawn from ``drawn_biases``, first), so that helper processes
    draw them while the rest of the report is computed. ``aligned(ev)`` is called once this thread's sections are
    done, before it waits for the work beside it (the clock-offset search, the segment errors): a run writes the
    aligned tables' rows there, where they would otherwise follow that wait with the second core idle.
    ``found_offset()`` gives the clock offset searched before (a run's, against its log's velocity samples:
    :func:`.trajectory_evaluation.log_time_offset`), checked here instead of searching the estimate."""
    options = replace(options or ReportOptions(), **overrides)
    truth, invalid = valid_truth(truth)
    truth, spikes = truth_spikes(truth)
    biases = BiasSection(bias_truth, options.bias_window_fraction)
    biases.process_data(tables.pop("biases", None))
    poses = tables.pop("poses")
    if figures is not None and n_rows(poses):  # the estimate's first stamp is the figures' time origin
        figures([bias_plot_job(biases.get_statistic(), drawn_biases, int(np.min(column(poses, "t_ns", np.int64))))])
    # the longest section, on a thread beside the others (array code and kernels without the GIL; the same numbers),
    # started once the trajectories are paired where the alignment has no scale (its scale is 1: the section needs
    # no more), else once the alignment is fitted
    segments, beside = SegmentErrorsSection(), []
    on_pairs = _segments_on_pairs(segments, options.align, beside)
    # ``ev.estimate`` holds all; judged: a truth too short to judge the run by is TruthUnusable
    ev = evaluate_trajectory(
        poses, truth, options, checked=True, judged=True, on_pairs=on_pairs, found_offset=found_offset
    )
    del poses
    segments_done = beside[0] if beside else _beside(segments.process_data, len(ev.paired), ev)
    landmarks = tables.pop("landmarks", None)
    landmark = _landmark_section(landmarks, landmark_truth, ev)
    if figures is not None:  # the top view and the landmark errors need no more than the landmark section
        figures(
            [
                top_view_job(landmark.get_statistic(), ev, landmarks, landmark_truth),
                *landmark_plot_jobs(landmark.get_statistic()),
            ]
        )
    convergence = ConvergenceSection(options.convergence_threshold_m)
    convergence.process_data(ev, _scene(landmarks, landmark_truth, ev))
    ape = ApeSection()
    ape.process_data(ev)  # before the error figure: it draws the attitude error less the truth frame's turn
    if figures is not None:
        figures([error_plot_job(convergence.get_statistic(), ev, ape.result.get("truth_frame_turn"))])
    time_offset = TimeOffsetSection(options)
    time_offset.unreliable_note(ev)
    uncertainty = UncertaintySection()
    uncertainty.process_data(ev)
    if figures is not None:
        figures(uncertainty_plot_jobs(uncertainty.get_statistic(), ev))
    by_alignment, rpe, drift = ApeByAlignmentSection(options), RpeSection(options), DriftSection(options)
    sections = {
        "ape": ape,
        "ape_by_alignment": by_alignment,
        "rpe": rpe,
        "drift": drift,
        "segment_errors": segments,
        "time_offset": time_offset,
        "landmarks": landmark,
        "biases": biases,
        "convergence": convergence,
        "uncertainty": uncertainty,
    }
    for section in (by_alignment, rpe, drift):
        section.process_data(ev)
    if aligned is not None:
        aligned(ev)
    time_offset.process_data(ev)  # waits for the search beside
    if segments_done is not None:
        segments_done.result()
    if figures is not None:
        figures(segment_plot_jobs(segments.arrays, ape.result.get("truth_frame_turn")))
    report = _report(sections, ev, truth, options, _report_notes(invalid, spikes, sections))
    if spikes is not None:
        report["truth_spikes"] = spikes.record()
    return report, ev


def _segments_on_pairs(segments: SegmentErrorsSection, align: str, beside: list) -> Callable | None:
    """Where the alignment has no scale (its scale is 1: the segment errors need no more), the callback that starts
    the segment errors beside the other sections (into ``beside``) once the trajectories are paired; else None (they
    start once the alignment is fitted)."""
    if align in SCALED_ALIGNMENTS:
        return None

    def on_pairs(paired: Paired, truth_sorted: PoseStream) -> None:
        beside.append(_beside(segments.process_pairs, len(paired), paired, truth_sorted, align, 1.0))

    return on_pairs


def _landmark_section(landmarks: Table | None, landmark_truth, ev: TrajectoryEvaluation) -> LandmarkSection:
    """The map's section: the ``landmarks`` table against ``landmark_truth`` through the trajectory's alignment, the
    map's Σ in the frame of the evaluation's gauge."""
    landmark = LandmarkSection(landmark_truth)
    gauge = None if ev.gauge is None else ev.gauge[1:]  # the frame the map's Σ is defined in
    landmark.process_data(landmarks, ev.alignment, ev.paired.ref_pos, float(ev.translation.stats["rmse"]), gauge)
    return landmark


def _scene(landmarks: Table | None, landmark_truth, ev: TrajectoryEvaluation) -> np.ndarray | None:
    """The landmarks the run mapped (M, 3) in the truth frame, the scale of a truth that does not translate
    (:func:`.sections.scene_extent`): their truth positions, else the estimate's own through the trajectory's
    alignment (the truth's whole map where the run mapped none; a room's far side the camera never saw is no
    scale of the run: 12.3 m RMS against 5.08 for the 6 of 30 a generated spin maps); None without either."""
    if landmarks is None or not n_rows(landmarks):
        return None if not landmark_truth else np.array([np.asarray(p, float) for p in landmark_truth.values()])
    ids = column(landmarks, "id", np.int64)
    if landmark_truth and any(int(i) in landmark_truth for i in ids):
        return np.array([np.asarray(landmark_truth[int(i)], float) for i in ids if int(i) in landmark_truth])
    return ev.alignment.positions(np.column_stack([column(landmarks, c, np.float64) for c in ("x", "y", "z")]))


def _report_notes(invalid: int, spikes: TruthSpikes | None, sections: dict) -> list[str]:
    """The report's notes: ``invalid`` truth poses dropped, the truth's ``spikes`` (:func:`.truth_spikes`), then the
    sections' own (APE, map, time offset, APE by alignment, RPE) and the NEES against a turned truth or one on a
    clock offset."""
    notes = []
    if invalid:
        notes.append(f"{invalid} ground-truth poses with a zero or non-finite quaternion (no rotation) dropped")
    if spikes is not None:
        notes.append(spikes.note())
    nees = nees_against_turned_truth(sections["ape"].result["truth_frame_turn"], sections["uncertainty"].notes)
    nees = nees_against_offset_truth(sections["time_offset"].result, nees)
    notes += sections["ape"].notes + sections["landmarks"].notes + sections["time_offset"].notes
    return notes + sections["ape_by_alignment"].notes + sections["rpe"].notes + nees


def _report(sections: dict, ev: TrajectoryEvaluation, truth: PoseStream, options: ReportOptions, notes: list) -> dict:
    """The report (``report.json``'s content): each section's statistic, the time spans, the truth's source, the evo
    commands, ``notes``, the options and the method."""
    return {
        "schema_version": SCHEMA_VERSION,
        **{name: section.get_statistic() for name, section in sections.items()},
        "time_span": {
            "estimate_ns": [int(ev.estimate.t_ns[0]), int(ev.estimate.t_ns[-1])],
            "truth_ns": [int(np.min(ev.truth.t_ns)), int(np.max(ev.truth.t_ns))],
        },
        "truth_source": {"kind": "stream", "name": truth.topic, "n_poses": len(truth)},
        "evo": _evo_commands(options, ev),
        "notes": notes,
        "options": {
            k: (list(v) if isinstance(v, tuple) else v)
            for k, v in asdict(options).items()
            if v is not None or k not in SET_ONLY_OPTIONS
        },
        "method": _method(ev, options, sections.values()),
    }


def _beside(func: Callable[..., None], n_pairs: int, *args) -> Pending | None:
    """``func(*args)`` started on a thread (:class:`.Pending`; wait with ``result()``), or done at once (then None)
    where the memory limit leaves no room for a second thread's buffers, or on a log of more pairs than
    ``MATRICES_KEPT_ROWS`` (~2.9 h at 100 Hz): there the segment errors convert and hold all the pairs' matrices
    (~300 MB on four hours) at the same time as the other sections' temporaries (four hours' peak RSS: 1462
    against 1348 MB computed in turn)."""
    if n_pairs > MATRICES_KEPT_ROWS:
        func(*args)
        return None
    try:
        return Pending(func, *args)
    except MemoryError:
        func(*args)
        return None


def _method(ev: TrajectoryEvaluation, options: ReportOptions, sections) -> dict[str, Any]:
    """How the numbers were obtained: the association and alignment, and each section's definitions."""
    n_pairs, n_est, n_ref = len(ev.paired), len(ev.estimate), len(ev.truth)
    method = {
        "tool": f"slamobs {__version__}, pipeline.evaluation (definitions as evo 1.38.1 evo_ape/evo_rpe)",
        "association": {
            "rule": (
                "nearest timestamp: every stamp of the series with fewer samples (the estimate on a tie) "
                "is paired with the nearest stamp of the other (earlier one on an exact tie); pairs more "
                "than t_max_diff_s apart are dropped (evo sync.associate_trajectories, nearest_time); "
                "t_offset_s is added to the estimate stamps first"
            ),
            "t_max_diff_s": float(options.t_max_diff_s),
            "t_offset_s": float(ev.applied_offset_s),
            "driving_series": "truth" if n_ref < n_est else "estimate",
            "n_pairs": n_pairs,
            "n_estimate": n_est,
            "n_truth": n_ref,
        },
        "alignment": alignment_dict(ev.alignment),
    }
    for section in sections:
        method.update(section.METHOD)
    return method


def report_schema() -> dict:
    """JSON Schema of report.json (``schemas/report.json``)."""
    from slamobs.schemas import HERE

    return json.loads((HERE / "report.json").read_text(encoding="utf-8"))


def validate_report(report: dict[str, Any]) -> None:
    """Raise ``jsonschema.ValidationError`` if ``report`` does not follow ``schemas/report.json``."""
    import jsonschema

    jsonschema.validate(report, report_schema(), cls=jsonschema.Draft202012Validator)


def _options_of(report: dict[str, Any]) -> ReportOptions:
    """The options a report was built with, the applied clock offset fixed (plots show the report's pairs)."""
    opts = dict(report.get("options") or {})
    opts["t_offset_s"] = report["method"]["association"]["t_offset_s"]
    opts["t_max_diff_s"] = report["method"]["association"]["t_max_diff_s"]
    al = report["method"]["alignment"]
    opts["align"] = al.get("requested") or al["type"]  # the kind asked for, when the truth chose another
    for key in TUPLE_OPTIONS:
        if opts.get(key) is not None:
            opts[key] = tuple(opts[key])
    fields = set(ReportOptions.__dataclass_fields__)
    return ReportOptions(**{k: v for k, v in opts.items() if k in fields})


def loose_hint(name: str, conv: dict, log: str, gains: dict | None = None) -> str | None:
    """What to try when an observer with fixed gains followed the motion loosely or not at all (``conv``: the
    report's ``convergence``). With ``gains`` (the run's) other than the observer's defaults, the gains came from a
    configuration (a tune's gains.yaml, say): the hint then says so rather than send the user to the tune they ran.
    Public: the wording of the hint, in one place for report.json, report.md and every command's summary."""
    from slamobs.pipeline.estimators import get_estimator

    if not (conv.get("coarse") or conv.get("lost")) or get_estimator(name).uses_noise:
        return None
    defaults = {g.name: g.default for g in get_estimator(name).gains}
    noise = "`--observer riekf` or `--observer batch` weigh this log's own noise"
    if gains and any(gains.get(k, v) != v for k, v in defaults.items()):
        return (
            f"{name} runs on fixed gains, these set in the configuration (not its defaults); {noise}; if they came "
            "from `slamobs tune`, the same command with a larger --trials extends that tune"
        )
    return (
        f"{name} runs on fixed gains; {noise}, and `slamobs tune {log} --observer {name} --target batch -o DIR` fits "
        f"{name}'s gains to it"
    )


def run_hints(report: dict[str, Any], metadata: dict[str, Any]) -> list[str]:
    """What the user can try next, given the report's convergence and the run's observer, gains and log (run.json):
    report.json's and run.json's ``hints``, report.md's and the summaries' ``hint`` lines."""
    observer, given = metadata.get("observer") or {}, metadata.get("input") or {}
    if not observer.get("name"):
        return []
    conv = report.get("convergence") or {}
    hint = loose_hint(observer["name"], conv, given.get("path", "LOG"), observer.get("gains"))
    return [] if hint is None else [hint]


#: What a warning of the truth's verdict says after ``warning: <estimator>: `` (:func:`verdict_warnings`): how a
#: report made again (``slamobs report``) finds the ones an earlier report left among the run's notes.
BY_TRUTH = "by the truth"
#: The lost verdict's warning after ``warning: <estimator>: ``.
LOST_BY_TRUTH = f"{BY_TRUTH} its estimate never locked on to the motion"
#: The warning of a truth too spiked to leave its spikes out (:func:`.trajectory_evaluation.truth_spikes`) where its
#: verdict says nothing, after ``warning: <estimator>: ``.
BAD_TRUTH = f"{BY_TRUTH} its errors are the truth's as much as its own"
#: A coarse verdict is warned of where the steady error level is at least this share of the extent it is judged by
#: (``slam_metrics.COARSE_SHARE`` qualifies the verdict from 0.1, lost is from 1): half the path's own RMS spread
#: about its centre, the path's shape is no longer resolved, only where it went. A round rule, not fitted: MR.CLAM's
#: riekf runs are coarse at 0.14-0.78 of their paths' 1.5-2.4 m RMS (6 r3 and 7 r4 at 0.78 and 0.67 warned; batch
#: does 0.07-0.11 m APE there); a hand-held rig whose camera sees 2.5 m only (seed=4393) is warned as not converged.
COARSE_WARN_SHARE = 0.5

#: What each kind of estimator is told to do when the truth finds it lost, not converged or coarse
#: (:func:`verdict_warnings`).
VERDICT_ADVICE = {
    # batch held where riekf was lost with 2 landmarks over 5 min (seed=4124: 0.149 m against 13.6 m) and ended 0.26 m
    # off where riekf ended 1.24 m off with a camera that sees 2.5 m (seed=4393)
    "riekf": (
        "batch smooths the whole log and holds where a filter loses the motion over long blind stretches with few "
        "landmarks in view: run `--observer batch` (or `slamobs compare`); more landmarks in view keep a filter on it"
    ),
    "batch": (
        "read the run's other warnings for an input it used as read, and run riekf beside it (`slamobs compare`); "
        "more landmarks in view, or a truth on the log's clock and frame"
    ),
}
#: The advice to an estimator on fixed gains (one without noise levels: :func:`loose_hint` adds the tune).
VERDICT_ADVICE_FIXED = "run riekf or batch, which weigh the log's own noise (`slamobs compare`)"


def verdict_warnings(report: dict[str, Any], metadata: dict[str, Any]) -> list[str]:
    """The run's warning of the truth's convergence verdict, for every estimator, with what to do
    (:data:`VERDICT_ADVICE`); none for a plain convergence, nor for a coarse one under ``COARSE_WARN_SHARE``. Lost
    (``convergence.lost``: the error level above the truth's own extent, the estimate never locked on to the
    motion): do not use it. Not converged (no convergence time, not lost: the error level grows at the end, recurs
    or ends above its band): the estimate's error has no steady level, its end is not to be read by its best
    stretch. Coarse from ``COARSE_WARN_SHARE`` of the extent. The verdict alone was said in report.md and the
    summaries' converged line, not among the ``warning:`` lines a user scans (riekf 13.6 m off on seed=4124, 1.24 m
    on seed=4393, no warning). A run's notes and its report's (:func:`add_run_context`) both hold
    it; a report made again replaces an earlier one's (:func:`with_verdict_warnings`)."""
    from slamobs.pipeline.evaluation.markdown import convergence_line

    conv, name = report.get("convergence") or {}, (metadata.get("observer") or {}).get("name")
    if not conv or not name:
        return []
    from slamobs.pipeline.estimators import get_estimator

    extent, whose, how = extent_words(conv)
    if conv.get("lost"):
        said = (
            f"{LOST_BY_TRUTH} (its error level, {conv['steady_level_m']:.3g} m over the last "
            f"{round(100 * conv['tail_fraction'])} % of the log, is above the {whose}, {extent:.3g} m {how}; "
            "report.json convergence.lost): do not use it"
        )
    elif conv.get("t_since_start_s") is None:
        said = (
            f"{BY_TRUTH} its error never settled ({convergence_line(conv).removeprefix('no: ')}; report.json "
            "convergence.t_since_start_s null): its error at the end is not its best stretch's"
        )
    elif conv.get("coarse") and (conv.get("steady_level_share") or 0.0) >= COARSE_WARN_SHARE:
        settled = (conv.get("tail_frame") or conv)["steady_level_m"]
        said = (
            f"{BY_TRUTH} its estimate follows the motion only coarsely (its error level, {settled:.3g} m, is "
            f"{100 * conv['steady_level_share']:.0f} % of the {whose}, {extent:.3g} m {how}; report.json "
            "convergence.coarse): it gives where the path went, not its shape"
        )
    elif (report.get("truth_spikes") or {}).get("dropped") is False:  # a bad truth: said whatever the verdict
        said = BAD_TRUTH
    else:
        return []
    if spikes := report.get("truth_spikes"):  # the truth's own glitches (:func:`.truth_spikes`)
        share = f"{spikes['count']} spikes ({100 * spikes['fraction']:.2g} % of its poses"
        said += (
            f"; the truth's {share}) left out (report.json truth_spikes)"
            if spikes["dropped"]
            else f"; the truth itself has {share}), too many to leave out: the verdict may be the truth's "
            "(report.json truth_spikes)"
        )
    if said.startswith(BAD_TRUTH):  # only the bad truth said: no advice to the estimator
        return [f"warning: {name}: {said}"]
    advice = VERDICT_ADVICE.get(name) or (VERDICT_ADVICE_FIXED if not get_estimator(name).uses_noise else "")
    return [f"warning: {name}: {said}{'; ' + advice if advice else ''}"]


def with_verdict_warnings(notes: list[str], report: dict[str, Any], metadata: dict[str, Any]) -> list[str]:
    """The run's ``notes`` with this report's :func:`verdict_warnings` in place of an earlier report's: run.json's
    notes as ``slamobs run`` and ``slamobs report`` write them, and the run notes the report reads."""
    own = f"warning: {(metadata.get('observer') or {}).get('name')}: {BY_TRUTH} "
    return [n for n in notes if not n.startswith(own)] + verdict_warnings(report, metadata)


def own_status(metadata: dict[str, Any]) -> dict[str, str] | None:
    """What the run's own record (run.json ``metadata``) says of its estimate where that is off, whatever the truth
    says: riekf's ``observer.filter.status`` ``lost`` or ``gated_at_end``, an observer without a gate likely lost
    (``observer.resightings`` or ``observer.velocity_bias``: :func:`.observers.base.lost_evidence`, the rule and the
    words of its warning), an estimator without noise levels that integrated a saturating gyro's rates as read
    (``input.gyro_clipped``: its equations assume a gyro that measures the rate; riekf and batch widen the gyro's
    noise there); None otherwise. ``status``, the run.json ``field`` it came from, and what it ``said``. The
    one place where the report's convergence verdict meets the run's own status (report.json
    ``convergence.own_status``, the converged line, compare's and a batch's notes)."""
    from slamobs.pipeline.observers.base import lost_evidence

    observer = metadata.get("observer") or {}
    if filt := observer.get("filter"):  # riekf's record: only its runs have one (and then its module is loaded)
        from slamobs.pipeline.observers.riekf import OFF_STATUSES, STATUSES

        if filt.get("status") not in OFF_STATUSES:  # riekf's own rule of which status says the estimate is off
            return None
        said = filt.get("status_checked") or STATUSES[filt["status"]]  # a run.json from before status_checked
        return {"status": filt["status"], "field": "observer.filter.status", "said": said}
    if found := lost_evidence(observer.get("resightings"), observer.get("velocity_bias")):
        return {"status": "likely_lost", "field": f"observer.{found[0]}", "said": found[1]}
    if clipped := (metadata.get("input") or {}).get("gyro_clipped"):  # riekf and batch widen the gyro's noise there
        from slamobs.pipeline.estimators import get_estimator

        if not get_estimator(observer.get("name")).uses_noise:
            return {
                "status": "gyro_clipped",
                "field": "input.gyro_clipped",
                "said": f"it integrated a saturating gyro's rates as read ({clipped['stretches']} stretches, "
                f"{clipped['seconds']:.3g} s at ±{clipped['range_rad_s']:.4g} rad/s): it assumes a gyro that "
                "measures the rate, and turned too little there",
            }
    return None


def add_run_context(report: dict[str, Any], run_notes: list[str], metadata: dict[str, Any]) -> None:
    """What the run, not the comparison with the truth, tells the report's reader: the noise levels riekf and
    batch used and why (the run's ``noise:`` notes), what the estimator said of its own run (its notes,
    ``<estimator>: ...``: e.g. batch's evidence-scaled levels and the detections' correlation it weighed, a
    doubtful first solution, riekf's recoveries), the velocity gaps that split the run into segments, and the
    time window it kept, what the run's own status says beside the convergence (``convergence.own_status``:
    :func:`own_status`), and what to try next (``hints``: :func:`run_hints`); a note of the truth's body frame
    turned reads as the camera's when the run's notes name the camera's extrinsic
    (:func:`.sections.camera_named_notes`), else its ``mend`` is what the run's frames say removes it
    (:func:`.sections.turn_mend`); where the truth was carried from its own frame to the body
    (``options.truth_in_body``), the run's note saying so (``alignment.truth_body_note``). The same whether the
    report is made by ``slamobs run`` or again by ``slamobs report``."""
    from slamobs.pipeline.evaluation.sections import body_frame_notes, camera_named_notes, turn_mend

    own = f"{(metadata.get('observer') or {}).get('name')}: "
    run_notes = with_verdict_warnings(run_notes, report, metadata)
    if report.get("notes"):
        report["notes"] = camera_named_notes(report, metadata)
        report["notes"] += body_frame_notes(report, metadata.get("input") or {})
    turn = (report.get("ape") or {}).get("truth_frame_turn")
    if turn and not turn.get("camera_named"):  # what removes the turn, from the run's frames (one sentence's words)
        turn["mend"] = turn_mend(metadata.get("input") or {})
    if report.get("ape") and (report.get("options") or {}).get("truth_in_body"):  # the truth carried to the body
        from slamobs.pipeline.alignment import truth_body_note

        run_input = metadata.get("input") or {}
        turned = bool(report["ape"].get("truth_frame_turn"))
        report.setdefault("notes", []).extend(truth_body_note(run_input["body_frame"], run_input["truth_body"], turned))
    if said := [n for n in run_notes if n.startswith(("noise: ", "warning: noise: ", own, f"warning: {own}"))]:
        report.setdefault("notes", []).extend(said)
    segments = metadata.get("segments") or []
    if len(segments) > 1:
        report.setdefault("notes", []).append(
            f"the run has {len(segments)} segments (velocity gaps longer than limits.max_gap, or a split "
            "recording's missing files): nothing was "
            "integrated across a gap and the pose was re-anchored to the map after it where a frame allowed "
            "(run.json notes say where); errors just after a gap show how well that worked"
        )
        report["segments"] = segments
    if metadata.get("time_window"):
        report["time_window"] = metadata["time_window"]
    if report.get("convergence"):  # the truth's verdict with the run's own beside it
        report["convergence"]["own_status"] = own_status(metadata)
    report["hints"] = run_hints(report, metadata)


def write_report(
    report: dict[str, Any],
    out_dir: Path | str,
    poses: Table | None,
    biases: Table | None,
    landmarks: Table | None,
    truth: PoseStream,
    landmark_truth: dict[int, np.ndarray] | None = None,
    *,
    evaluation: TrajectoryEvaluation | None = None,
    plots: bool | str = "all",
    metadata: dict[str, Any] | None = None,
    exports: tuple[str, ...] = (),
    plot_workers=None,
    more_figures: list = (),
    aligned=None,
) -> list[Path]:
    """Write report.json, report.md, the PNG plots (``plots``: ``"all"``, the main ones with True, none with False:
    they are most of the report's time on short logs; :func:`.figure_jobs.chosen`), the estimate aligned into the
    truth's frame (``poses_aligned.parquet``, ``landmarks_aligned.parquet``, with the run ``metadata``) and, as
    ``exports`` asks, the TUM files ("tum") and the evo result zip ("evo") into ``out_dir``; returns the written
    paths. The plots and the zip re-use the association window, clock offset and alignment recorded in the report,
    so they show exactly the numbers of the report; ``evaluation`` is the one :func:`evaluate_report` returned with
    this report (same pairs and alignment; ``poses`` may then be None), else it is computed again from ``poses``.
    With ``plot_workers`` (started :class:`~.plot_worker.PlotWorkers`) the figures are drawn by those helper
    processes while the aligned tables are written; ``more_figures`` (the run's own, :mod:`.figure_jobs`) are drawn
    with the report's, and report.json lists every figure (``figures``). ``aligned``: the aligned tables' rows
    already written (:func:`aligned_rows`), finished here. The writes are plain: callers that replace an existing
    report write into a temporary directory first (see :mod:`.run_dir`).
    """
    from slamobs.pipeline.evaluation.evo_zip import save_result_zip
    from slamobs.pipeline.readers.trajectory_files import write_tum

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    options = _options_of(report)  # the applied offset is fixed there: no need to estimate it again
    if evaluation is None and poses is None:
        raise ValueError("write_report needs the poses table or the report's evaluation")
    ev = evaluation or evaluate_trajectory(poses, truth, options, estimate_offset=False)
    submitted = plot_workers is not None and plot_workers.submitted  # by evaluate_tables, as it went
    jobs = [*more_figures, *plot_jobs(report, ev, biases, landmarks, landmark_truth)] if plots and not submitted else []
    jobs = chosen(jobs, plots)
    if plots or submitted:  # the figures the report's directory holds, listed in the report
        report["figures"] = [name for _, name, _ in (plot_workers.jobs if submitted else jobs)]
    written = []
    json_path = out / "report.json"
    json_path.write_text(json.dumps(report, indent=2, sort_keys=True, allow_nan=False) + "\n", encoding="utf-8")
    written.append(json_path)
    md_path = out / "report.md"
    md_path.write_text(render_markdown(report), encoding="utf-8")
    written.append(md_path)

    if "evo" in exports:
        written.append(save_result_zip(out / EVO_ZIP, ev.translation))
    if "tum" in exports:
        written.append(write_tum(out / ESTIMATE_TUM, ev.estimate))
        written.append(write_tum(out / TRUTH_TUM, ev.truth))
    if jobs and plot_workers is not None:
        plot_workers.submit(jobs)  # drawn by the helper processes while the aligned tables are written
    if aligned is not None:
        written += close_aligned(aligned, report, metadata or {})
    else:
        written += write_aligned_tables(out, report, ev, landmarks, metadata or {})
    if plot_workers is not None and plot_workers.submitted:
        written += plot_workers.collect(out)
    elif jobs:
        from slamobs.pipeline.evaluation.plot_worker import draw

        written += draw(jobs, lambda name: out / name)
    return written


def write_aligned_tables(
    out: Path, report: dict[str, Any], ev: TrajectoryEvaluation, landmarks: Table | None, metadata: dict[str, Any]
) -> list[Path]:
    """``poses_aligned.parquet`` and ``landmarks_aligned.parquet``: every pose and the map moved by the report's
    alignment into the truth's frame (a stretch of poses at a time), with the run metadata and the alignment."""
    return close_aligned(aligned_rows(out, ev, landmarks, metadata), report, metadata)


def aligned_rows(out: Path, ev: TrajectoryEvaluation, landmarks: Table | None, metadata: dict[str, Any]):
    """The rows of the aligned tables written into ``out`` (a :class:`~pipeline.writers.TableWriter` whose footer
    :func:`close_aligned` adds): all they need is the alignment, so a run writes them while its report's threads
    still compute (the footer's report and metadata come at the end)."""
    from slamobs.pipeline.writers import FLOAT_BITS, TableWriter

    al = ev.alignment
    bits = int((metadata.get("output") or {}).get("float_bits", FLOAT_BITS))
    sink = TableWriter(out, bits)
    try:
        est = ev.estimate
        for rows in row_blocks(len(est)):
            pos = al.positions(np.asarray(est.position[rows], dtype=np.float64))
            rot = rotated(al.rot, quats_to_rots(np.ascontiguousarray(est.quat_xyzw[rows], dtype=np.float64)))
            q = rots_to_quats(np.ascontiguousarray(rot))
            sink.write(
                {
                    "poses_aligned": {
                        "t_ns": np.asarray(est.t_ns[rows]),
                        "x": pos[:, 0],
                        "y": pos[:, 1],
                        "z": pos[:, 2],
                        "qx": q[:, 0],
                        "qy": q[:, 1],
                        "qz": q[:, 2],
                        "qw": q[:, 3],
                    }
                }
            )
        if landmarks is not None:
            xyz = al.positions(columns(landmarks, ["x", "y", "z"], np.float64))
            sink.write(
                {
                    "landmarks_aligned": {
                        **{c: column(landmarks, c) for c in column_names(landmarks)},
                        "x": xyz[:, 0],
                        "y": xyz[:, 1],
                        "z": xyz[:, 2],
                    }
                }
            )
    except BaseException:
        sink.abort()
        raise
    return sink


def close_aligned(sink, report: dict[str, Any], metadata: dict[str, Any]) -> list[Path]:
    """The aligned tables of :func:`aligned_rows` finished with the run ``metadata`` and the report's alignment."""
    meta = {
        **metadata,
        "aligned": {
            "frame": "ground truth",
            "alignment": report["method"]["alignment"],
            "truth_source": report.get("truth_source"),
        },
    }
    try:
        return sink.close(meta)
    except BaseException:
        sink.abort()
        raise
