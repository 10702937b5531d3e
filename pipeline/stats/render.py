"""The statistics as text: Markdown, CSV and LaTeX, in two layouts.

``table`` (default): per metric a row per log and estimator with runs, n, mean, median, min, max and std.
``rpg``: per metric a row per log and a column per estimator, each cell ``mean, median (min, max)`` as
rpg_trajectory_evaluation's tables print it, the lowest mean of a row in bold. A missing value is ``–`` in
Markdown, ``--`` in LaTeX and an empty field in CSV: never a zero.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd

from slamobs.pipeline.stats.compute import STATS
from slamobs.pipeline.stats.inputs import METRICS

STYLES = ("table", "rpg")
MISSING = {"md": "–", "tex": "--"}
NUMBER = "{:.4g}"


TEX_SPECIAL = re.compile(r"[\\_%&#$]")
TEX_ESCAPES = {"\\": r"\textbackslash{}", "_": r"\_", "%": r"\%", "&": r"\&", "#": r"\#", "$": r"\$"}


def tex_escape(text: str) -> str:
    """LaTeX's special characters in a log or estimator name made literal."""
    return TEX_SPECIAL.sub(lambda m: TEX_ESCAPES[m.group(0)], text)


def cell_texts(stats: pd.DataFrame, fmt: str) -> pd.DataFrame:
    """``stats`` with every statistic as text and an ``rpg`` column ``mean, median (min, max)`` (one pass)."""
    texts = stats[["metric", "estimator", "log"]].copy()
    texts["runs"] = stats["runs"].astype(int).astype(str)
    texts["n"] = stats["n"].astype(int).astype(str)
    for s in STATS[1:]:
        values = stats[s].to_numpy(dtype=float)
        text = np.array([NUMBER.format(v) for v in values.tolist()], dtype=object)
        text[np.isnan(values)] = MISSING[fmt]
        texts[s] = text
    rpg = texts["mean"] + ", " + texts["median"] + " (" + texts["min"] + ", " + texts["max"] + ")"
    texts["rpg"] = rpg.where(stats["n"].to_numpy() > 0, MISSING[fmt])
    return texts


def metric_grid(stats: pd.DataFrame, texts: pd.DataFrame, metric: str, fmt: str) -> tuple[list[str], list[list[str]]]:
    """The header and rows of one metric's table in ``rpg`` layout: a row per log, a column per estimator, the
    lowest mean of a row (among two or more) in bold."""
    mine = (stats["metric"] == metric).to_numpy()
    part, text = stats[mine], texts[mine]
    best = part.groupby("log", sort=False)["mean"].transform("min")
    contested = part.groupby("log", sort=False)["mean"].transform("count") > 1
    bold = (part["mean"] == best) & contested
    mark = (lambda t: f"**{t}**") if fmt == "md" else (lambda t: rf"\textbf{{{t}}}")
    cells = text["rpg"].where(~bold, text["rpg"].map(mark))
    grid = pd.DataFrame({"log": part["log"], "estimator": part["estimator"], "cell": cells})
    logs = list(dict.fromkeys(part["log"]))
    estimators = sorted(part["estimator"].unique())
    table = grid.pivot(index="log", columns="estimator", values="cell").reindex(index=logs, columns=estimators)
    return ["log", *estimators], [[log, *row] for log, row in zip(logs, table.fillna("").to_numpy().tolist())]


def metric_rows(stats: pd.DataFrame, texts: pd.DataFrame, metric: str, fmt: str) -> tuple[list[str], list[list[str]]]:
    """The header and rows of one metric's table in ``table`` layout."""
    head = ["log", "estimator", "runs", *STATS]
    return head, texts.loc[(stats["metric"] == metric).to_numpy(), head].to_numpy().tolist()


def _layout(style: str):
    if style not in STYLES:
        raise ValueError(f"style {style!r}: one of {', '.join(STYLES)}")
    return metric_grid if style == "rpg" else metric_rows


def _md_table(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(c.replace("|", "\\|") for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def markdown(
    stats: pd.DataFrame, rank: pd.DataFrame, style: str, sources: list[str], notes: list[str] | None = None
) -> str:
    """The whole ``stats.md``: one table per metric with values, then the ranking; ``notes`` (the repeated runs,
    :func:`.compute.repeat_words`) under the key."""
    layout, texts = _layout(style), cell_texts(stats, "md")
    text = "# Statistics across runs\n\nInputs: " + ", ".join(f"`{s}`" for s in sources) + "\n\n"
    text += (
        "Per estimator and log over the finished runs: runs read (failed ones among them: stats.csv `failed`, "
        "runs.csv `status`), n finished runs with the metric, mean, median, min, max and population std (ddof 0); "
        "`all logs` pools every run of the estimator. – : no finished run has the metric (no truth, no map, or "
        "every run failed). Lower is better for every metric.\n"
    )
    if notes:
        text += "\n" + "".join(f"- note: {n}\n" for n in notes)
    for metric, label in METRICS.items():
        if not (stats["metric"] == metric).any():
            continue
        text += f"\n## {label}\n\n" + _md_table(*layout(stats, texts, metric, "md"))
    text += (
        "\n## Ranking\n\nOn how many logs each estimator had the lowest mean (ties count for each; "
        "`contested`: logs with at least two estimators).\n\n"
    )
    head = ["estimator", *rank.columns]
    rows = [[str(idx), *[str(int(v)) for v in rank.loc[idx]]] for idx in rank.index]
    return text + _md_table(head, rows)


def _tex_table(caption: str, head: list[str], rows: list[list[str]]) -> str:
    cols = "l" * 2 + "r" * (len(head) - 2) if head[1] == "estimator" else "l" + "r" * (len(head) - 1)
    lines = [r"\begin{table}[t]", r"\centering", rf"\caption{{{tex_escape(caption)}}}", rf"\begin{{tabular}}{{{cols}}}"]
    lines += [r"\toprule", " & ".join(tex_escape(h) for h in head) + r" \\", r"\midrule"]
    for row in rows:
        cells = [c if c.startswith(r"\textbf") else tex_escape(c) for c in row[:2]] + row[2:]  # names, then numbers
        lines.append(" & ".join(cells) + r" \\")
    return "\n".join([*lines, r"\bottomrule", r"\end{tabular}", r"\end{table}"]) + "\n"


def latex(stats: pd.DataFrame, rank: pd.DataFrame, style: str) -> str:
    """``stats.tex``: a booktabs table per metric and the ranking (needs ``\\usepackage{booktabs}``)."""
    layout, texts = _layout(style), cell_texts(stats, "tex")
    parts = ["% slamobs stats: tables need \\usepackage{booktabs}\n"]
    for metric, label in METRICS.items():
        if (stats["metric"] == metric).any():
            parts.append(_tex_table(label, *layout(stats, texts, metric, "tex")))
    head = ["estimator", *rank.columns]
    rows = [[str(idx), *[str(int(v)) for v in rank.loc[idx]]] for idx in rank.index]
    parts.append(_tex_table("Logs on which each estimator had the lowest mean", head, rows))
    return "\n".join(parts)


def csv_text(table: pd.DataFrame, index: bool = False) -> str:
    """CSV with missing values as empty fields."""
    return table.to_csv(index=index, na_rep="", float_format="%.10g")
