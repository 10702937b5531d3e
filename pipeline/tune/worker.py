"""What a batch worker does for a tune: score one gain set on one log, in memory (nothing is written).

A tune runs the same few logs hundreds of times with different gains, so each worker process keeps the logs it
has read and aligned (:data:`PREPARED`, keyed by the log's identity and the config that shapes its reading):
every log is read once per worker process, not once per trial (``benchmarks/tune_read_once.py`` measures it).
The task is the batch's own :class:`~slamobs.pipeline.batch.executor.Task` (plain data, checked against the
worker's slamobs version and code), run by the batch pools (local processes or Dask).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections import OrderedDict
from dataclasses import replace
from pathlib import Path

from slamobs.pipeline.batch.executor import Task, base_row, check_environment, failure_text

#: Logs a worker process keeps prepared (least recently used dropped first).
CACHE_LOGS = 32
#: Public: benchmarks/tune_read_once.py clears it to time a tune that re-read its logs.
PREPARED: OrderedDict = OrderedDict()
#: What a tune can minimise: the run's headline metric it reads (``RunSummary.headline`` names).
OBJECTIVES = {"ape": "ape_trans_rmse_m", "rotation": "ape_rot_rmse_deg", "landmarks": "landmark_rmse_m"}
#: What a trial is measured against: the log's ground truth, or the batch smoother's solution on the same log
#: (logs without truth can then be tuned). The task's config carries it under :data:`TARGET_KEY` (a tune's own
#: key, taken out before the config is read).
TARGETS = ("truth", "batch")
TARGET_KEY = "_tune_target"
#: Batch solutions a worker process keeps (one per prepared log and noise/batch settings).
_REFERENCES: OrderedDict = OrderedDict()
#: The time offset's decision on each prepared log's stream, kept per worker process (:func:`decided_offset`).
_OFFSETS: OrderedDict = OrderedDict()


def _reading_key(log: str, config: dict, directions: bool) -> str:
    st = os.stat(log)
    # what shapes the prepared log: not the estimator, its settings, the outputs or whether figures are drawn
    shaping = {k: v for k, v in config.items() if k not in ("observer", "gains", "output", "noise", "batch")}
    shaping["evaluation"] = {k: v for k, v in shaping.get("evaluation", {}).items() if k != "plots"}
    return json.dumps(
        [os.path.realpath(log), st.st_size, st.st_mtime_ns, directions, shaping], sort_keys=True, default=list
    )


def prepared_log(log: str, config, directions: bool, need_truth: bool = True):
    """The log read and aligned, from this process's cache; (PreparedLog, read seconds or 0.0 when cached)."""
    from slamobs.pipeline.run import prepare_log

    key = _reading_key(log, config.to_dict(), directions)
    if key in PREPARED:
        PREPARED.move_to_end(key)
        return PREPARED[key], 0.0
    t = time.perf_counter()
    prepared = prepare_log(Path(log), config, directions=directions, estimator=config.observer)
    if need_truth and (prepared.streams.truth is None or not len(prepared.streams.truth)):
        from slamobs.pipeline.errors import InputError

        raise InputError(
            log,
            "no ground truth (a truth topic, evaluation.truth_file or a TF edge in topics.truth): a tuning log "
            "needs it unless the tune is --target batch (scored against the batch smoother's solution); "
            "a --holdout log always does",
        )
    PREPARED[key] = prepared
    while len(PREPARED) > CACHE_LOGS:
        PREPARED.popitem(last=False)
    return prepared, time.perf_counter() - t


def decided_offset(prepared, est) -> dict | None:
    """The time offset's decision on ``prepared``'s stream (``time_offset.decide``), made once per prepared log and
    kept with it for every trial's observer (``ObserverOptions.time_offset``; 0.06-0.15 CPU s each otherwise);
    None for an estimator that decides its own (riekf, batch)."""
    if est.spec.own_time_offset:
        return None
    from slamobs.pipeline.observers import time_offset

    stream = prepared.aligned
    key = id(stream)
    if key in _OFFSETS and _OFFSETS[key][0] is stream:  # held here, so its id is not reused meanwhile
        _OFFSETS.move_to_end(key)
        return _OFFSETS[key][1]
    _OFFSETS[key] = (stream, time_offset.decide(stream))
    while len(_OFFSETS) > CACHE_LOGS:
        _OFFSETS.popitem(last=False)
    return _OFFSETS[key][1]


def batch_reference(prepared, config):
    """The batch smoother's solution on ``prepared`` (its seed and noise as ``config`` says, every gain at its
    default) as ``(truth, landmark truth)`` for :func:`score`, kept per worker process."""
    import numpy as np

    from slamobs.pipeline.lie import rots_to_quats
    from slamobs.pipeline.run import estimator_input
    from slamobs.pipeline.streams import PoseStream

    cfg = replace(config, observer="batch", gains={})
    key = json.dumps(
        [id(prepared), cfg.to_dict().get("noise"), cfg.to_dict().get("batch")], sort_keys=True, default=str
    )
    if key in _REFERENCES and _REFERENCES[key][0] is prepared:  # held here, so its id is not reused meanwhile
        _REFERENCES.move_to_end(key)
        return _REFERENCES[key][1:]
    est = estimator_input(prepared, cfg)
    res = est.spec.run(prepared.aligned, est.gains, replace(est.options, out_every=1))
    ok = np.isfinite(res.position).all(axis=1)
    t = res.t_ns[ok]
    truth = PoseStream(
        "batch", "batch", "base_link", t, t, res.position[ok], rots_to_quats(np.ascontiguousarray(res.rotation[ok]))
    )
    marks = {int(i): np.asarray(p, float) for i, p in zip(res.landmark_ids, res.landmark_xyz) if np.isfinite(p).all()}
    _REFERENCES[key] = (prepared, truth, marks)
    while len(_REFERENCES) > CACHE_LOGS:
        _REFERENCES.popitem(last=False)
    return truth, marks


def score(prepared, config, target: str = "truth") -> dict[str, float | None]:
    """Run ``config``'s observer on a prepared log and measure it as the run's report does (APE after the SE(3)
    alignment, map error after the same alignment), without writing anything; against the log's truth, or with
    ``target="batch"`` against the batch smoother's trajectory and map on the same log.

    Raises:
        ObserverDiverged: the estimate became non-finite.
        InputError: the observer cannot run on this log (e.g. it needs IMU directions the log lacks).

    """
    import numpy as np
    import pandas as pd

    from slamobs.pipeline.evaluation.metrics import landmark_errors
    from slamobs.pipeline.evaluation.trajectory_evaluation import ReportOptions, evaluate_trajectory, truth_in_body
    from slamobs.pipeline.observers.base import ObserverDiverged, lost_evidence
    from slamobs.pipeline.run import estimator_input, truth_on_run_clock
    from slamobs.pipeline.writers import stretch_tables

    est = estimator_input(prepared, config)
    # every sample, as the run's report sees before output.rate_hz thins the output
    options = replace(est.options, out_every=1, time_offset=decided_offset(prepared, est))
    res = est.spec.run(prepared.aligned, est.gains, options)
    if not np.isfinite(res.position).all():
        raise ObserverDiverged(int(res.t_ns[np.argmax(~np.isfinite(res.position).all(axis=1))]), res.stats)
    poses = pd.DataFrame(stretch_tables(res)["poses"])
    carried = None  # batch's solution is of the body; the log's truth carried to the body where it is another frame's
    if target == "batch":
        truth, landmark_truth = batch_reference(prepared, config)
    else:
        truth, landmark_truth = truth_on_run_clock(prepared.streams, config), prepared.streams.landmark_truth
        carried = truth_in_body(prepared.aligned.truth_body)
    ev = evaluate_trajectory(
        poses,
        truth,
        ReportOptions(t_max_diff_s=config.evaluation.t_max_diff, truth_in_body=carried),
        estimate_offset=False,
    )
    checks = res.stats.get("metadata", {})
    lm_rmse = None
    if landmark_truth:
        al = ev.alignment
        lm = landmark_errors(res.landmark_ids, res.landmark_xyz, landmark_truth, al.rot, al.trans, al.scale)
        lm_rmse = float(np.sqrt(np.mean(lm.errors**2))) if lm.errors.size else None
    return {
        "ape_trans_rmse_m": float(ev.translation.stats["rmse"]),
        "ape_rot_rmse_deg": float(ev.rotation.stats["rmse"]),
        "landmark_rmse_m": lm_rmse,
        "substeps": int(res.stats.get("substeps", 0)),
        "capped_intervals": int(res.stats.get("capped_intervals", 0)),
        # the run's own check (its "likely lost" warning), whatever the objective says
        "likely_lost": (lost_evidence(checks.get("resightings"), checks.get("velocity_bias")) or (None, None))[1],
    }


def run_trial_log(task: Task) -> dict:
    """One (trial, log) pair: the row the tune records. Never raises for the log or the gains: a diverged
    observer is ``status == "diverged"`` (the gains are bad), a log that cannot be tuned on is ``"failed"``
    with ``fatal`` set (the tune stops with its one-line error)."""
    from slamobs.pipeline.config import RunConfig
    from slamobs.pipeline.errors import GainError, InputError
    from slamobs.pipeline.observers.base import ObserverDiverged

    check_environment(task.version, task.code)
    t0 = time.perf_counter()
    row = {**base_row(task), "status": "ok", "error": None, "fatal": False, "read_s": 0.0}
    raw = dict(task.config)
    target = raw.pop(TARGET_KEY, "truth")
    config = RunConfig.from_dict(raw)
    try:
        from slamobs.pipeline.estimators import get_estimator

        directions = get_estimator(config.observer).min_directions > 0
        prepared, row["read_s"] = prepared_log(task.log, config, directions, need_truth=target == "truth")
        t = time.perf_counter()
        row.update(score(prepared, config, target))
        row["observer_s"] = time.perf_counter() - t
    except ObserverDiverged as err:
        row.update(status="diverged", error=f"{task.log}: observer diverged (non-finite state) at t_ns={err.t_ns}")
    except (InputError, GainError, OSError, ValueError) as err:
        row.update(status="failed", error=failure_text(err, task.log), fatal=True)
    except Exception as err:  # noqa: BLE001 - reported as the trial's failure, the tune decides
        row.update(status="failed", error=failure_text(err, task.log))
    row["total_s"] = time.perf_counter() - t0
    return row


def objective_value(rows: list[dict], objective: str) -> float:
    """The median of the objective's metric over a trial's logs; infinite when any log diverged or lacks it (the
    gains are unusable there), NaN when a log failed for another reason."""
    import numpy as np

    key = OBJECTIVES[objective]
    values = []
    for row in rows:
        if row["status"] == "diverged":
            return math.inf
        if row["status"] != "ok":
            return math.nan
        v = row.get(key)
        values.append(math.inf if v is None or not math.isfinite(v) else float(v))
    return float(np.median(values)) if values else math.nan
