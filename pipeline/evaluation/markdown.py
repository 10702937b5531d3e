"""report.md: the report's JSON document rendered as Markdown tables, one function per section.

Rendering reads the finished ``report.json`` dict only (a report read back from a run directory renders the
same page), so nothing here computes a number.
"""

from __future__ import annotations

from typing import Any

from slamobs.pipeline.evaluation.sync import halves_agree, halves_owner


def convergence_definition(conv: dict[str, Any]) -> str:
    """The convergence figure's definition, with its numbers (report.md): those of the frame that decided it, the
    whole run's alignment or (``tail_frame``) the one fitted on the run's end."""
    if tf := conv.get("tail_frame"):
        tail = f"{100 * conv['tail_fraction']:g} %"
        return (
            f"first time after which the error level (median position error over a {conv['window_s']:.3g} s "
            f"window, {100 * conv['window_fraction']:g} % of the log), in the frame of the log's last {tail} "
            f"(the alignment fitted on those pairs only), stays within max(threshold {conv['threshold_m']:g} m, "
            f"{conv['band_factor']:g} × {tf['steady_level_m']:.4g} m, the highest level there over the last "
            f"{tail}) = {tf['band_m']:.4g} m; under the whole-run alignment that band is {conv['band_m']:.4g} m"
        )
    return (
        f"first time after which the error level (median aligned position error over a {conv['window_s']:.3g} s "
        f"window, {100 * conv['window_fraction']:g} % of the log) stays within max(threshold "
        f"{conv['threshold_m']:g} m, {conv['band_factor']:g} × {conv['steady_level_m']:.4g} m, the highest level "
        f"over the last {100 * conv['tail_fraction']:g} % of the log) = {conv['band_m']:.4g} m"
    )


def convergence_line(conv: dict[str, Any]) -> str | None:
    """The convergence figure for a one-line summary: what stays within the band is the error *level* (a running
    median), not every error, which may still exceed the band now and then. A converged figure leads with what
    qualifies it: ``coarse`` (its level a sizeable share of the motion) and the run's own status where that says
    the estimate is off (``own_status``: :func:`.report.own_status`); a verdict of no gets the latter after it."""
    if not conv:
        return None
    own = conv.get("own_status")
    if conv.get("t_since_start_s") is None:
        said = f"; {own_words(own)}" if own else ""
        return "no: " + _not_converged(conv).removeprefix("not converged (").removesuffix(")") + said
    band = (conv.get("tail_frame") or conv)["band_m"]
    frame = f" in the frame of its last {round(100 * conv['tail_fraction'])} %" if conv.get("tail_frame") else ""
    return (
        f"{_qualified(conv)}{conv['t_since_start_s']:.2f} s after start (median position error{frame} over "
        f"{conv['window_s']:.3g} s within {band:.3g} m from then on{_tail_frame(conv)}{_coarse(conv)})"
    )


def _qualified(conv: dict[str, Any]) -> str:
    """What a converged figure leads with: ``coarse``, and "by the truth only" with the run's own status where that
    says the estimate is off (``own_status``)."""
    qualified = ["coarse"] if conv.get("coarse") else []
    qualified += [f"by the truth only ({own_words(own)})"] if (own := conv.get("own_status")) else []
    return ", ".join(qualified) + ": " if qualified else ""


def own_words(own: dict[str, str]) -> str:
    """The run's own status (report.json ``convergence.own_status``) in a few words: the status, in the word
    ``compare``'s and a batch's ``status`` column shows, and its run.json field."""
    return f"its own status is {own['status']} in run.json {own['field']}"


def own_said(own: dict[str, str]) -> str:
    """The run's own status and what its record said: report.md's own-record line, and each table of runs' note
    beside its ``status`` (``compare``'s, a batch's warnings: :meth:`.run.RunSummary.status_caveats`)."""
    return f"{own_words(own)}: {own['said']}"


def headline_caveats(report: dict[str, Any]) -> list[str]:
    """What a table of headline numbers (``slamobs compare``) must say beside them from this report: no convergence
    time and why, a coarse one or one the run's own status contradicts (``own_status``), the report's note of an
    alignment that tilts a run with a gravity axis (upside down: its rotation APE is meaningless) and its note of a
    truth recorded in a body frame turned against the estimate's (a rotation APE of 160-179 deg beside centimetres on
    TagSLAM test_21, with the key that removes it, or with the camera's extrinsic named instead)."""
    from slamobs.pipeline.evaluation.sections import tilt_note, truth_frame_words

    conv, ape = report.get("convergence") or {}, report.get("ape") or {}
    out = []
    if conv and (conv.get("t_since_start_s") is None or conv.get("coarse") or conv.get("own_status")):
        out.append(f"convergence: {convergence_line(conv)}")
    # the notes' words again, from the flags their sections set (ape.gravity_tilt_deg, ape.truth_frame_turn): a
    # reworded note cannot drop its caveat
    align = ((report.get("method") or {}).get("alignment") or {}).get("type")
    out += tilt_note(align, ape.get("gravity_tilt_deg"), report.get("ape_by_alignment") or {})
    if turn := ape.get("truth_frame_turn"):
        out.append(truth_frame_words(turn, ape["rotation_deg"]["rmse"], ape["translation_m"]["rmse"]))
    return out


def _tail_frame(conv: dict[str, Any]) -> str:
    """What a convergence judged in the frame of the run's end adds (``tail_frame``: the error grew under the
    whole-run alignment only)."""
    if not (tf := conv.get("tail_frame")):
        return ""
    tail = round(100 * conv["tail_fraction"])
    return (
        f", in the frame of its last {tail} % (the alignment fitted on those pairs only; level at most "
        f"{tf['steady_level_m']:.3g} m there, band {tf['band_m']:.3g} m); under the whole-run alignment its level "
        f"grows ({conv['tail_level_m']:.3g} m over the last {tail} % against {conv['earlier_level_m']:.3g} m before): "
        "that fit is pulled toward a worse stretch before"
    )


def extent_words(conv: dict[str, Any]) -> tuple[float | None, str, str]:
    """``(extent_m, name, how)``: the scale the convergence section judged lost and coarse by, its short name and
    how it is measured: the trajectory's own extent, or, for a truth that does not translate (``scene_extent_m``),
    the scene's."""
    scene = conv.get("scene_extent_m")
    if scene is None:
        return conv.get("trajectory_extent_m"), "path's extent", "RMS about its centre"
    rest = f"{conv['trajectory_extent_m']:.2g} m RMS about its centre"
    how = f"RMS from the rig's position to the landmarks; the truth does not translate: {rest}"
    return scene, "scene's extent", how


def _extent_phrase(conv: dict[str, Any]) -> tuple[float | None, str, str]:
    """:func:`extent_words` as report.md's sentences say it: the extent, whose ("trajectory's own extent" for the
    path's) and how it is measured."""
    extent, name, how = extent_words(conv)
    return extent, "trajectory's own extent" if name == "path's extent" else name, how


def _coarse(conv: dict[str, Any]) -> str:
    """What a converged (or recurring) figure adds when its level is a sizeable share of the motion itself."""
    if not conv.get("coarse"):
        return ""
    settled = (conv.get("tail_frame") or conv)["steady_level_m"]
    extent, whose, how = _extent_phrase(conv)
    return (
        f"; but that level, {settled:.3g} m, is {100 * conv['steady_level_share']:.0f} % of the "
        f"{whose} ({extent:.3g} m {how}): a coarse estimate"
    )


def _not_converged(conv: dict[str, Any]) -> str:
    if conv.get("lost"):
        extent, whose, how = _extent_phrase(conv)
        return (
            f"not converged (the error level, {conv['steady_level_m']:.3g} m at most over the last "
            f"{round(100 * conv['tail_fraction'])} % of the log, is above the {whose}, "
            f"{extent:.3g} m {how}: the estimate never locked on to the motion)"
        )
    if conv.get("growing"):
        tail = round(100 * conv["tail_fraction"])
        earlier, before_tail = conv.get("earlier_level_m"), conv.get("before_tail_level_m")
        if before_tail is not None and (earlier is None or before_tail < earlier):
            against = f"{before_tail:.3g} m over the {100 - tail} % before"
        else:
            against = f"{earlier:.3g} m over the {tail} % before"
        return (
            f"not converged (the error level keeps growing: a median of {conv['tail_level_m']:.3g} m over the last "
            f"{tail} % of the log against {against})"
        )
    if conv.get("recurring_s"):
        a, b = conv["recurring_s"]
        return (
            f"not converged (the error level recurs: it was within the band {conv['band_m']:.3g} m for {b - a:.3g} s, "
            f"{a:.3g}-{b:.3g} s after the start, and left it again; its last stretch within it, no longer, may be "
            f"one more such{_coarse(conv)})"
        )
    return "not converged (the last aligned position error is above the band)"


def _fmt(v: Any, digits: int = 6) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


STAT_KEYS = ("rmse", "mean", "median", "std", "min", "max", "sse", "n", "p95")


def _stats_table(rows: list[tuple[str, dict[str, Any] | None]]) -> list[str]:
    out = ["| quantity | " + " | ".join(STAT_KEYS) + " |", "|---|" + "---|" * len(STAT_KEYS)]
    for name, st in rows:
        cells = [_fmt(st.get(k)) if st is not None else "–" for k in STAT_KEYS]
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    return out


def _vec_str(v: list[float] | None) -> str:
    return "–" if v is None else "[" + ", ".join(_fmt(x) for x in v) + "]"


def _md_trajectory(report: dict[str, Any]) -> list[str]:
    ape, conv = report["ape"], report["convergence"]
    lines = ["## Absolute pose error (after alignment)", ""]
    lines += _stats_table([("translation [m]", ape["translation_m"]), ("rotation [deg]", ape["rotation_deg"])])
    conv_txt = (
        f"{_qualified(conv)}{conv['t_since_start_s']:.3f} s after the estimate start{_tail_frame(conv)}{_coarse(conv)}"
        if conv["t_ns"] is not None
        else _not_converged(conv)
    )
    lines += ["", f"Convergence: {conv_txt}; defined as the {convergence_definition(conv)}.", ""]
    if own := conv.get("own_status"):  # checked against truth above; the run's own record here
        lines += [f"The run's own record: {own_said(own)}.", ""]
    lines += [line for hint in report.get("hints") or [] for line in (f"Hint: {hint}.", "")]
    if report["evo"].get("ape"):
        departs = f" Not this report's number: {report['evo']['departs']}." if report["evo"].get("departs") else ""
        lines += [f"Reproduce with evo (TUM files written with `--export tum`): `{report['evo']['ape']}`.{departs}", ""]
    by = report.get("ape_by_alignment") or {}
    if by:
        lines += ["### APE under each alignment (same pairs)", ""]
        lines += _stats_table(
            [(f"{k}: translation [m]", v["translation_m"]) for k, v in by.items()]
            + [(f"{k}: rotation [deg]", v["rotation_deg"]) for k, v in by.items()]
        )
        lines.append("")
    return lines + _md_relative(report)


def _md_relative(report: dict[str, Any]) -> list[str]:
    """RPE, drift and the clock offset."""
    rpe_s, drift, off = report.get("rpe"), report.get("drift"), report["time_offset"]
    from slamobs.pipeline.evaluation.sections import relative_errors_turned

    lines = ["## Relative error and drift", ""]
    turned = relative_errors_turned((report.get("ape") or {}).get("truth_frame_turn"))
    if turned and (rpe_s or drift or _md_segment_errors(report.get("segment_errors"))):
        lines += [*turned, ""]
    if rpe_s:
        lines += [f"RPE, delta {rpe_s['delta']:g} {rpe_s['delta_unit']} ({rpe_s['n_pairs']} pairs):", ""]
        lines += _stats_table([("translation [m]", rpe_s["translation_m"]), ("rotation [deg]", rpe_s["rotation_deg"])])
        lines.append("")
    if drift:  # the table said neither what it is nor how it differs from the segment errors below
        lines += [
            "KITTI-style drift: mean relative error over the path segments of each length, translation in % of the "
            "length, rotation per metre (definition under Method):",
            "",
            "| segment [m] | segments | translation [%] | rotation [deg/m] |",
            "|---|---|---|---|",
        ]
        for row in drift["per_length"]:
            lines.append(
                f"| {row['length_m']:g} | {row['n_segments']} | {_fmt(row['translation_pct'], 4)} | "
                f"{_fmt(row['rotation_deg_per_m'], 4)} |"
            )
        lines += [
            f"| all | {drift['n_segments']} | {_fmt(drift['translation_pct'], 4)} | "
            f"{_fmt(drift['rotation_deg_per_m'], 4)} |",
            "",
        ]
    if not rpe_s and not drift:
        lines += ["Path too short for RPE and drift.", ""]
    lines += _md_segment_errors(report.get("segment_errors"))
    of_log = off.get("searched_against") == "velocity samples"
    caveat = LOG_CAVEAT if of_log else LAG_CAVEAT
    est = (
        "not estimated"
        if off["estimated_s"] is None
        else (
            f"{off['estimated_s']:.4f} s (peak correlation {off['peak_correlation']:.2f}, "
            f"{'reliable' + caveat if off['reliable'] else 'NOT reliable' + offset_doubts(off)})"
        )
    )
    whose = "the log (its velocity samples) against the truth" if of_log else "the estimate"
    lines += [f"Clock offset of {whose}: {est}; applied: {off['applied_s']:g} s ({off['applied_from']}).", ""]
    return lines


def _md_segment_errors(seg: dict[str, Any] | None) -> list[str]:
    """rpg's relative error per sub-trajectory length: "mean, median (min, max)" per length, rpg's table style."""
    if not seg or not any(row["translation_pct"] for row in seg["per_length"]):
        return []
    lines = [
        f"Segment errors (rpg_trajectory_evaluation; truth path {seg['path_length_m']:.4g} m, scale "
        f"{seg['scale']:.6g}: the alignment's), mean, median (min, max) (definition under Method):",
        "",
        "| length [m] | segments | translation [%] | rotation [deg/m] | yaw [deg] |",
        "|---|---|---|---|---|",
    ]
    for row in seg["per_length"]:
        cells = [
            "–"
            if row[k] is None
            else f"{_fmt(row[k]['mean'], 3)}, {_fmt(row[k]['median'], 3)} "
            f"({_fmt(row[k]['min'], 3)}, {_fmt(row[k]['max'], 3)})"
            for k in ("translation_pct", "rotation_deg_per_m", "yaw_deg")
        ]
        lines.append(f"| {row['length_m']:g} | {row['n_segments']} | " + " | ".join(cells) + " |")
    return lines + [""]


#: What a reliable offset is and is not: the estimate's lag behind the truth (a filter's delay) looks the same.
LAG_CAVEAT = (
    ": the estimate matches the truth best when shifted by this much, from the clocks or from the "
    "estimate lagging behind the motion; the trajectories cannot tell the two apart"
)
#: A run's offset is searched against its log's own velocity samples, on whose clock the estimate's stamps are.
LOG_CAVEAT = (
    ": the log's velocity samples match the truth's motion best when shifted by this much, whatever the estimate "
    "does; the estimate's stamps are on the log's clock"
)


def offset_doubts(off: dict[str, Any]) -> str:
    """Why a clock offset of the report's ``time_offset`` section is not reliable, as ``": reason; reason"``."""
    why = []
    if off["peak_correlation"] < 0.5:
        why.append("correlation below 0.5")
    if abs(off["estimated_s"]) >= off["search_window_s"] - off["grid_step_s"]:
        why.append("at the search limit")
    spread = off.get("uncertainty_s")
    if not halves_agree(spread, off["grid_step_s"], off["estimated_s"]):
        why.append(f"{halves_owner(off.get('searched_against'))} find offsets {2 * spread:.3g} s apart")
    with_m, without_m = off.get("ape_rmse_with_m"), off.get("ape_rmse_without_m")
    if with_m is not None and without_m is not None and with_m > without_m:
        why.append(f"applied, it raises the APE rmse from {without_m:.4g} to {with_m:.4g} m")
    return ": " + "; ".join(why) if why else ""


#: Where a map error's truth comes from, said wherever a map error is blank for the want of it (report.md, compare).
MAP_TRUTH_HINT = (
    "evaluation.map_truth in the run's config names a surveyed map (landmarks.parquet, CSV id,x,y,z or a TagSLAM "
    "tagslam.yaml) for the map error"
)


def _md_landmarks(lm: dict[str, Any]) -> list[str]:
    lines = ["## Landmark map error", ""]
    if not lm["truth_available"]:
        return lines + [
            f"{lm['n_estimated']} landmarks estimated; no landmark ground truth available: {MAP_TRUTH_HINT}.",
            "",
        ]
    lines += [
        f"{lm['n_matched']} of {lm['n_estimated']} estimated landmarks have ground truth "
        f"({lm['n_truth']} true landmarks).",
        "",
    ]
    rows = [("after trajectory alignment [m]", lm["error_m"])]
    turn = lm.get("alignment_turn")
    if turn:
        rows.append((f"after its loose turn, {turn['best_turn_deg']:.3g} deg [m]", turn["error_turned_m"]))
    if lm.get("map_aligned"):
        rows.append(("after map-only alignment [m]", lm["map_aligned"]["error_m"]))
    lines += _stats_table(rows)
    lines += [
        "",
        "| id | error [m] | error, loose turn [m] | slack of the alignment [m] | stated σ [m] | error, map-only "
        "alignment [m] | estimate (aligned) [m] | truth [m] | n_obs |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in lm["per_landmark"]:
        lines.append(
            f"| {row['id']} | {row['error_m']:.6g} | {_fmt(row.get('error_turned_m'))} | "
            f"{_fmt(row.get('alignment_slack_m'))} | {_fmt(row.get('sigma_m'))} | "
            f"{_fmt(row.get('error_map_aligned_m'))} | "
            f"{_vec_str(row['estimate_aligned'])} | {_vec_str(row['truth'])} | {_fmt(row['n_obs'])} |"
        )
    lines += ["", *_md_sigma_check(lm.get("sigma_check"))] if lm.get("sigma_check") else []
    return lines + [
        "",
        f"Estimated without truth: {lm['estimated_without_truth'] or 'none'}. "
        f"True landmarks never estimated: {lm['truth_never_estimated'] or 'none'}.",
        "",
    ]


def _md_sigma_check(check: dict[str, Any]) -> list[str]:
    """The map's stated σ against its error, in one line (report.json landmarks.sigma_check)."""
    lo, hi = check["bounds"]
    verdict = check["verdict"] + (f" (σ × {check['sigma_factor']:.2g})" if check["verdict"] != "within" else "")
    verdict += f": {check['verdict_why']}" if check.get("verdict_why") else ""
    dof = f" ({check['dof']} DoF: {', '.join(check['axes'])})" if check.get("axes") else ""
    return [
        f"Map σ against its error: mean landmark NEES {check['mean_nees']:.3g} over {check['n']} landmarks{dof} "
        f"(95 % bounds of independent landmarks {lo:.3g}-{hi:.3g}; overconfident above "
        f"{check['bound_any_correlation']:.3g} however correlated), median error/σ "
        f"{check['error_over_sigma_median']:.3g}, stated σ {check['sigma_m'][0]:.3g}-{check['sigma_m'][1]:.3g} m: "
        f"{verdict} (Method: map σ check)."
    ]


def _md_biases(bi: dict[str, Any]) -> list[str]:
    lines = ["## Biases (body frame)", ""]
    if bi["final"] is None:
        return lines + ["No bias estimates.", ""]
    lines += [
        "| bias | final estimate | truth | error (truth − estimate) | ‖error‖ | ‖error‖ of window mean | drift [/s] |",
        "|---|---|---|---|---|---|---|",
    ]
    for key, label in (("gyro", "gyro [rad/s]"), ("velocity", "velocity [m/s]")):
        truth = bi["truth"][key] if bi["truth"] else None
        err = bi["error"][key] if bi["error"] else None
        norm = bi["error_norm"][key] if bi["error_norm"] else None
        wnorm = bi["window_error_norm"][key] if bi.get("window_error_norm") else None
        drift = bi["stability"][key]["drift_norm_per_s"] if bi.get("stability") else None
        lines.append(
            f"| {label} | {_vec_str(bi['final'][key])} | {_vec_str(truth)} | {_vec_str(err)} | "
            f"{_fmt(norm)} | {_fmt(wnorm)} | {_fmt(drift)} |"
        )
    st = bi.get("stability") or {}
    frac = st.get("window_fraction")
    return lines + [
        "",
        f"Final estimate at t_ns = {bi['final']['t_ns']}; stability window: last {_fmt(frac)} of the bias time span.",
        "",
    ]


def _window_text(win: dict[str, Any]) -> str:
    """A time window as seconds from the log's start."""
    ends = [
        "start" if win["start_s"] is None else f"{win['start_s']:.3f} s",
        "end" if win["end_s"] is None else f"{win['end_s']:.3f} s",
    ]
    return f"{ends[0]} to {ends[1]} from the log's start"


def render_markdown(report: dict[str, Any]) -> str:
    """Human-readable version of the report (tables for APE, RPE/drift, landmarks, biases and the method)."""
    lines = ["# slamobs error report", ""]
    if win := report.get("time_window"):
        lines += [f"Time window: {_window_text(win)} (the run used this part of its log; the truth was cut to it).", ""]
    lines += _md_trajectory(report)
    lines += _md_landmarks(report["landmarks"])
    lines += _md_biases(report["biases"])
    if report.get("uncertainty"):
        lines += md_uncertainty(report["uncertainty"])
    if report.get("notes"):
        lines += ["## Notes", ""] + [f"- {n}" for n in report["notes"]] + [""]
    if report.get("figures"):
        lines += ["## Figures", ""] + [f"![{name}]({name})" for name in report["figures"]] + [""]
    lines += _md_method(report)
    return "\n".join(lines)


def md_uncertainty(u: dict[str, Any]) -> list[str]:
    """The estimator's covariance against its error: NEES with its bounds, errors within 3σ.
    Public: tests/test_uncertainty.py renders it alone."""
    lines = [
        "## Uncertainty (NEES)",
        "",
        f"Error (δθ, δp) in the {u['frame']}.",
        "",
        "| part | DoF | pairs | mean NEES | 95 % bounds of the mean | bound whatever the correlation "
        "| verdict (σ × to cover) | median | share of instants within χ²(DoF) "
        f"bounds | share of {u['window_s']:g} s windows within bounds | share within ±3σ (x, y, z; – not measured) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for part in ("position", "attitude"):
        r = u[part]
        if not r["n"]:
            lines.append(f"| {part} | | 0 | | | | | | | | |")
            continue
        wide_text = _fmt(r.get("bound_any_correlation"), 4)
        verdict = f"{r['verdict']} ({_fmt(r['sigma_factor'], 2)})" if r.get("verdict") else ""
        lines.append(
            f"| {part} | {r.get('dof', 3)}{' (' + ', '.join(r['axes']) + ')' if r.get('axes') else ''} | {r['n']} | "
            f"{_fmt(r['mean'], 4)} | {_fmt(r['bounds'][0], 4)} – {_fmt(r['bounds'][1], 4)} | {wide_text} | "
            f"{verdict} | {_fmt(r['median'], 4)} | {_fmt(r['share_instants_within'], 3)} | "
            f"{_fmt(r['share_windows_within'], 3)} | {_vec_str(r['within_3sigma'])} |"
        )
    return lines + [""]


def _md_method(report: dict[str, Any]) -> list[str]:
    """How every number was obtained, one table row per definition."""
    m = report["method"]
    assoc, al = m["association"], m["alignment"]
    lines = [
        "## Method",
        "",
        "| item | value |",
        "|---|---|",
        f"| tool | {m['tool']} |",
        f"| association | {assoc['rule']} |",
        f"| t_max_diff | {assoc['t_max_diff_s']:g} s |",
        f"| t_offset | {assoc['t_offset_s']:g} s |",
        f"| pairs | {assoc['n_pairs']} (estimate {assoc['n_estimate']} poses, truth {assoc['n_truth']} poses, "
        f"driven by the {assoc['driving_series']}) |",
        f"| alignment | {al['description']} |",
        f"| alignment rotation (quaternion x, y, z, w) | {_vec_str(al['rotation_quat_xyzw'])} |",
        f"| alignment translation [m] | {_vec_str(al['translation_m'])} |",
        f"| alignment scale | {al['scale']:.9g} |",
        f"| APE translation | {m['ape_translation']} |",
        f"| APE rotation | {m['ape_rotation']} |",
        f"| APE by alignment | {m['ape_by_alignment']} |",
        f"| statistics | {m['statistics']} |",
    ]
    if report.get("rpe"):
        lines.append(f"| RPE | {report['rpe']['method']} |")
    if report.get("drift"):
        lines.append(f"| drift | {report['drift']['method']} |")
    if _md_segment_errors(report.get("segment_errors")):  # the table is shown: its definition with it
        lines.append(f"| segment errors | {m['segment_errors']} |")
    lines += [
        f"| clock offset | {report['time_offset']['method']} |",
        f"| landmarks | {m['landmarks']} |",
    ]
    if report["landmarks"].get("map_aligned"):
        lines.append(f"| map-only alignment | {report['landmarks']['map_aligned']['method']} |")
    if report["landmarks"].get("alignment_turn"):
        lines.append(f"| loose turn of the alignment | {report['landmarks']['alignment_turn']['method']} |")
    if report["landmarks"].get("sigma_check"):
        lines.append(f"| map σ check | {report['landmarks']['sigma_check']['method']} |")
    lines += [f"| biases | {m['biases']} |", f"| convergence | {m['convergence']} |"]
    if report.get("uncertainty"):
        lines.append(f"| uncertainty | {m['uncertainty']} |")
    lines.append("")
    return lines
