"""Statistics across runs, as pure functions over the runs table (:mod:`inputs`): per estimator and log the
mean, median, min, max and standard deviation of every metric, and which estimator wins how often.

The standard deviation is the population one (``ddof=0``, NumPy's default, as evo and
rpg_trajectory_evaluation compute it), so one run has std 0. A metric a run does not have (no truth, no map)
is left out of that cell's statistics; a cell with no value at all stays missing (NaN), never zero.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from slamobs.pipeline.batch.ledger import FAILED, finished
from slamobs.pipeline.stats.inputs import METRICS

#: The statistics of a cell, in table order (``n``: runs with a value of the metric).
STATS = ("n", "mean", "median", "min", "max", "std")
#: The log label of the rows over every log of an estimator.
ALL_LOGS = "all logs"
KEYS = ["metric", "estimator", "log"]
#: A repeated group's runs named in its note (:func:`repeat_words`), the rest counted.
REPEAT_SOURCES = 3


def ok_runs(runs: pd.DataFrame) -> pd.DataFrame:
    """The finished runs: ``ok``, or off by their estimator's own status (``likely_lost``, ``lost``,
    ``gated_at_end``: :func:`.batch.ledger.finished`); their metrics are measured all the same."""
    return runs[runs["status"].map(finished).astype(bool)]


def repeats(runs: pd.DataFrame) -> list[dict]:
    """Finished runs of one estimator on one log with the same value of every metric but run time (missing ones
    alike, at least one present): the same log and settings run twice (a batch and a compare of one log, the same
    batch given under two names), each counted in ``n`` and the ``all logs`` rows. Per such group its
    ``estimator``, ``log``, ``runs`` and their ``sources``; a group whose metrics differ (another config) is none."""
    compared = [m for m in METRICS if m != "run_time_s"]
    ok = ok_runs(runs)
    values = ok[compared].to_numpy(dtype=np.float64)
    present = np.isfinite(values).any(axis=1)
    key = [tuple(np.where(np.isfinite(row), row, np.inf).tolist()) for row in values]  # NaN as one value
    ok = ok.assign(_key=key)[present]
    out = []
    for (est, log, _), group in ok.groupby(["estimator", "log", "_key"], sort=True):
        if len(group) > 1:
            out.append({"estimator": est, "log": log, "runs": len(group), "sources": group["source"].tolist()})
    return out


def repeat_words(rep: dict) -> str:
    """One group of :func:`repeats` as a sentence."""
    named = ", ".join(map(str, rep["sources"][:REPEAT_SOURCES]))
    more = f" and {rep['runs'] - REPEAT_SOURCES} more" if rep["runs"] > REPEAT_SOURCES else ""
    return (
        f"{rep['estimator']} on {rep['log']}: {rep['runs']} runs with the same value of every metric but run time "
        f"(the same log and settings run {rep['runs']} times: {named}{more}); each counts in n and in the "
        "`all logs` rows"
    )


def _long(runs: pd.DataFrame) -> pd.DataFrame:
    """The metric values of the finished runs, one row per (run, metric) with a value."""
    long = ok_runs(runs).melt(id_vars=["estimator", "log"], value_vars=list(METRICS), var_name="metric")
    return long[np.isfinite(long["value"].to_numpy(dtype=np.float64))]


def _cells(runs: pd.DataFrame) -> pd.DataFrame:
    """Every (metric, estimator, log) of the inputs, and ``ALL_LOGS`` per estimator: the rows of the table."""
    pairs = runs[["estimator", "log"]].drop_duplicates()
    pairs = pd.concat([pairs, pd.DataFrame({"estimator": pairs["estimator"].unique(), "log": ALL_LOGS})])
    metrics = pd.DataFrame({"metric": list(METRICS)})
    return metrics.merge(pairs, how="cross")[KEYS]


def _aggregate(values: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    grouped = values.groupby(by, sort=False)["value"]
    out = grouped.agg(["count", "mean", "median", "min", "max"]).rename(columns={"count": "n"})
    out["std"] = grouped.std(ddof=0)
    return out.reset_index()


def _run_counts(runs: pd.DataFrame) -> pd.DataFrame:
    """Runs and failed runs per (estimator, log) and per estimator over all logs."""
    failed = runs["status"] == FAILED
    per = runs.assign(failed=failed).groupby(["estimator", "log"], sort=False)["failed"].agg(["size", "sum"])
    per = per.reset_index()
    total = per.groupby("estimator", sort=False)[["size", "sum"]].sum().reset_index().assign(log=ALL_LOGS)
    both = pd.concat([per, total], ignore_index=True)
    return both.rename(columns={"size": "runs", "sum": "failed"})


def cell_stats(runs: pd.DataFrame) -> pd.DataFrame:
    """Columns metric, estimator, log, runs, failed and :data:`STATS`: a row per metric, estimator and log (and
    per metric and estimator over ``ALL_LOGS``), in :data:`METRICS` order, estimators and logs sorted."""
    values = _long(runs)
    stats = pd.concat([_aggregate(values, KEYS), _aggregate(values, KEYS[:2]).assign(log=ALL_LOGS)], ignore_index=True)
    table = _cells(runs).merge(stats, on=KEYS, how="left").merge(_run_counts(runs), on=["estimator", "log"])
    table["n"] = table["n"].fillna(0).astype(np.int64)
    order = {m: i for i, m in enumerate(METRICS)}
    table = table.assign(_m=table["metric"].map(order), _all=table["log"] == ALL_LOGS).sort_values(
        ["_m", "_all", "log", "estimator"], kind="stable"
    )
    return table.drop(columns=["_m", "_all"]).reset_index(drop=True)[[*KEYS, "runs", "failed", *STATS]]


def winners(stats: pd.DataFrame) -> pd.DataFrame:
    """Per metric and log (not ``ALL_LOGS``) the estimators with the lowest mean (ties: each one wins);
    columns metric, log, estimator. A log where fewer than two estimators have the metric has no winner."""
    per_log = stats[(stats["log"] != ALL_LOGS) & stats["mean"].notna()]
    contested = per_log.groupby(["metric", "log"])["estimator"].transform("size") >= 2
    per_log = per_log[contested]
    best = per_log.groupby(["metric", "log"])["mean"].transform("min")
    return per_log.loc[per_log["mean"] == best, ["metric", "log", "estimator"]].reset_index(drop=True)


def ranking(stats: pd.DataFrame) -> pd.DataFrame:
    """Estimators (rows, most wins first) × metrics (columns): on how many logs each estimator had the lowest
    mean; ``total`` sums them, ``contested`` (a row of its own) is the number of logs compared per metric."""
    won = winners(stats)
    estimators = sorted(stats["estimator"].unique())
    table = pd.crosstab(won["estimator"], won["metric"]).reindex(index=estimators, columns=list(METRICS))
    table = table.fillna(0).astype(np.int64)
    table["total"] = table.sum(axis=1)
    table = table.sort_values("total", ascending=False, kind="stable")
    contested = won.drop_duplicates(["metric", "log"]).groupby("metric").size()
    table.loc["contested"] = contested.reindex(list(METRICS)).fillna(0).astype(np.int64).tolist() + [
        int(contested.sum())
    ]
    table.index.name = "estimator"
    return table
