"""Statistics across runs (``slamobs stats``): batch datasets, compare outputs and run directories gathered into
one runs table (:mod:`inputs`), summarised per estimator and log with a ranking (:mod:`compute`), written as
Markdown, CSV and LaTeX (:mod:`render`) with box and violin plots (``pipeline.evaluation.plots``).

Layout of ``OUT/``::

    stats.md, stats.tex     one table per metric and the ranking (layout ``table`` or ``rpg``)
    stats.csv               metric, estimator, log, runs, failed, n, mean, median, min, max, std
    ranking.csv             per estimator and metric: logs won (lowest mean), total; row ``contested``
    runs.csv                every run read: estimator, log, status, source, the metrics
    figures/<metric>_box.png, figures/<metric>_violin.png
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from slamobs.pipeline.stats.compute import cell_stats, ok_runs, ranking, repeat_words, repeats
from slamobs.pipeline.stats.inputs import METRICS, gather_runs
from slamobs.pipeline.stats.render import STYLES, csv_text, latex, markdown

FIGURES = "figures"
KINDS = ("box", "violin")


@dataclass
class StatsResult:
    out: Path
    runs: pd.DataFrame
    stats: pd.DataFrame
    ranking: pd.DataFrame
    figures: list[Path]
    #: The runs counted more than once (:func:`.compute.repeats`), as sentences.
    notes: list[str]


def metric_values(runs: pd.DataFrame, metric: str) -> dict[str, dict[str, np.ndarray]]:
    """``values[estimator][log]``: the finished runs' finite values of ``metric`` (estimators and logs sorted)."""
    ok = ok_runs(runs)
    ok = ok[np.isfinite(ok[metric].to_numpy(dtype=np.float64))]
    values: dict[str, dict[str, np.ndarray]] = {}
    for (est, log), group in ok.groupby(["estimator", "log"], sort=True):
        values.setdefault(est, {})[log] = group[metric].to_numpy(dtype=np.float64)
    return values


def figure_jobs(runs: pd.DataFrame) -> list[tuple[str, str, dict]]:
    """A box and a violin figure per metric that any run has, as jobs of ``plot_worker`` (``plots`` function,
    file name, arguments)."""
    jobs = []
    for metric, label in METRICS.items():
        values = metric_values(runs, metric)
        if values:
            args = {"values": values, "ylabel": label, "title": label.split(" [")[0]}
            jobs += [
                ("plot_distributions", f"{metric}_{kind}.png", {**args, "kind": kind}) for kind in ("box", "violin")
            ]
    return jobs


def write_figures(runs: pd.DataFrame, folder: Path) -> list[Path]:
    """Draw :func:`figure_jobs` into ``folder``: in helper processes on the cores nothing else uses (the report's
    figure helpers), in this process when there are none."""
    from slamobs.pipeline.evaluation.plot_worker import PlotWorkers, draw, free_cores

    jobs = figure_jobs(runs)
    if not jobs:
        return []
    folder.mkdir(exist_ok=True)
    helpers = min(free_cores(), len(jobs))
    if helpers <= 1:
        return draw(jobs, lambda name: folder / name)
    with PlotWorkers(helpers) as workers:
        workers.submit(jobs)
        return workers.collect(folder)


def write_stats(
    inputs: list[Path], out: Path, *, style: str = STYLES[0], figures: bool = True, force: bool = False
) -> StatsResult:
    """Gather the runs of ``inputs``, summarise them and write ``out`` (atomically: all of it or nothing)."""
    from slamobs.pipeline.writers import atomic_directory

    inputs = [Path(p) for p in inputs]
    runs = gather_runs(inputs)
    stats = cell_stats(runs)
    rank = ranking(stats)
    sources = [str(p) for p in inputs]
    notes = [repeat_words(r) for r in repeats(runs)]
    drawn: list[Path] = []
    with atomic_directory(out, force=force, inputs=inputs) as tmp:
        (tmp / "stats.md").write_text(markdown(stats, rank, style, sources, notes))
        (tmp / "stats.tex").write_text(latex(stats, rank, style))
        (tmp / "stats.csv").write_text(csv_text(stats))
        (tmp / "ranking.csv").write_text(csv_text(rank, index=True))
        (tmp / "runs.csv").write_text(csv_text(runs))
        if figures:
            drawn = [Path(out) / FIGURES / p.name for p in write_figures(runs, tmp / FIGURES)]
    return StatsResult(Path(out), runs, stats, rank, drawn, notes)


__all__ = ["METRICS", "STYLES", "StatsResult", "cell_stats", "gather_runs", "ranking", "write_stats"]
