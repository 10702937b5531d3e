"""What a tune writes into OUT, each file replaced atomically: ``trials.parquet`` (schema ``schemas/tune_trials.json``),
``gains.yaml`` (a config ``--config`` takes), ``objective.png``, ``tune.json`` and ``tune.md`` (best gains, the
defaults for comparison, the leave-one-log-out validation and the holdout logs).

Holdout logs (``--holdout``) are the honest check: the sampler never sees them, and the defaults and the best
gains are scored on each at the end. On short simulated logs tuned gains often do not transfer (the error's
spread from one noise realisation to the next exceeds what the gains change), and only logs the tune never saw
show it.

Leave-one-log-out: for each log, the trial with the lowest median over the *other* logs is picked among the tune's
trials and its error on the held-out log is reported beside the defaults' error there. Selection uses only the other
logs; the trials themselves were proposed by a sampler that saw every log (a nested tune per held-out log would
cost as many tunes as there are logs), so this measures whether the chosen gains transfer, not a sampler that
never saw the log.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from slamobs.pipeline.tune.worker import OBJECTIVES
from slamobs.pipeline.errors import plural

UNITS = {"ape": "m", "rotation": "deg", "landmarks": "m"}
#: What the objective was measured against, by tune target other than the truth (worker.TARGETS).
AGAINST = {
    "batch": "the batch smoother's trajectory and map on each log (no ground truth needed; "
    "--holdout logs: their truth)",
}


def _replace(path: Path, write) -> None:
    """``write(tmp)`` then rename onto ``path``: a reader sees the old or the new file, never half of one."""
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _trials(study) -> list:
    import optuna

    states = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.FAIL)
    return [t for t in study.get_trials(deepcopy=False, states=states) if "logs" in t.user_attrs]


def trial_rows(study, spec, logs: list[str]) -> list[dict]:
    rows = []
    for t in _trials(study):
        gains = t.user_attrs["gains"]
        for i, r in enumerate(t.user_attrs["logs"]):
            rows.append(
                {
                    "trial": t.number,
                    "state": t.state.name,
                    "is_default": bool(t.user_attrs.get("default")),
                    "objective": t.value if t.value is not None else math.nan,
                    "log_index": i,
                    "log": logs[i],
                    **{
                        k: r.get(k)
                        for k in (
                            "status",
                            "ape_trans_rmse_m",
                            "ape_rot_rmse_deg",
                            "landmark_rmse_m",
                            "read_s",
                            "observer_s",
                            "worker",
                            "error",
                        )
                    },
                    **{f"gain_{g.name}": float(gains[g.name]) for g in spec.gains},
                }
            )
    return rows


def write_trials(path: Path, rows: list[dict], spec) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    from slamobs.schemas import table_spec

    doc = table_spec("tune_trials")
    fields = [
        pa.field(f["name"], getattr(pa, f["type"])(), metadata={"unit": f["unit"], "description": f["description"]})
        for f in doc["fields"]
    ]
    fields += [
        pa.field(f"gain_{g.name}", pa.float64(), nullable=False, metadata={"unit": "", "description": g.description})
        for g in spec.gains
    ]
    schema = pa.schema(fields, metadata={"description": doc["description"]})
    table = pa.Table.from_pylist(rows, schema=schema)
    _replace(path, lambda tmp: pq.write_table(table, tmp, compression="zstd"))


def _per_log(trial, key: str) -> list[float]:
    out = []
    for r in trial.user_attrs["logs"]:
        v = r.get(key) if r.get("status") == "ok" else None
        out.append(math.inf if r.get("status") == "diverged" else math.nan if v is None else float(v))
    return out


def validation(complete: list, default, key: str, logs: list[str]) -> dict:
    """Leave-one-log-out (module doc): per held-out log the trial chosen on the others and its error there."""
    if len(logs) < 2:
        return {"method": "leave-one-log-out", "rows": [], "note": "needs two or more logs"}
    values = np.array([_per_log(t, key) for t in complete])  # trials x logs
    rows = []
    for i, log in enumerate(logs):
        others = np.delete(values, i, axis=1)
        with np.errstate(invalid="ignore"):
            train = np.median(others, axis=1)
        train = np.where(np.isnan(train), np.inf, train)
        k = int(np.argmin(train))
        held = float(values[k, i])
        base = float(_per_log(default, key)[i]) if default is not None else None
        rows.append(
            {
                "log": log,
                "chosen_trial": complete[k].number,
                "train_median": float(train[k]),
                "held_out": held,
                "default": base,
                "improvement": None
                if base is None or not math.isfinite(base) or not math.isfinite(held)
                else 1.0 - held / base,
                "gains": complete[k].user_attrs["gains"],
            }
        )
    better = sum(1 for r in rows if r["default"] is not None and r["held_out"] < r["default"])
    return {
        "method": (
            "leave-one-log-out: for each log, the trial with the lowest median over the other logs is "
            "chosen among the tune's trials and measured on the held-out log; the trials were proposed "
            "by a sampler that saw every log"
        ),
        "rows": rows,
        "held_out_better_than_default": better,
        "logs": len(logs),
    }


def holdout_summary(rows: list[dict], key: str) -> dict:
    """Per holdout log the defaults' and the tuned gains' error; how often and by how much the tuned ones win."""
    out = []
    for r in rows:
        d, t = (_value(r.get(name), key) for name in ("defaults", "tuned"))
        out.append(
            {
                "log": r["log"],
                "best_trial": r["best_trial"],
                "defaults": d,
                "tuned": t,
                "improvement": 1.0 - t / d if math.isfinite(d) and math.isfinite(t) and d > 0 else None,
            }
        )
    d = np.array([r["defaults"] for r in out], dtype=float)
    t = np.array([r["tuned"] for r in out], dtype=float)
    with np.errstate(invalid="ignore"):
        return {
            "method": "logs the sampler never saw, scored at the end with the defaults and the best gains",
            "rows": out,
            "tuned_better": int(np.sum(t < d)),
            "logs": len(out),
            "median_defaults": float(np.median(d)) if len(d) else None,
            "median_tuned": float(np.median(t)) if len(t) else None,
        }


def _value(row: dict | None, key: str) -> float:
    if not row:
        return math.nan
    if row.get("status") == "diverged":
        return math.inf
    v = row.get(key) if row.get("status") == "ok" else None
    return math.nan if v is None else float(v)


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if isinstance(v, float) and math.isinf(v):
        return "diverged"
    return f"{v:.4g}"


def write_gains(path: Path, spec, gains: dict, header: list[str]) -> None:
    lines = [f"# {h}" for h in header]
    lines += [f"observer: {spec.name}", "gains:", f"  {spec.name}:"]
    lines += [f"    {name}: {float(v)!r}" for name, v in gains.items()]
    _replace(path, lambda tmp: tmp.write_text("\n".join(lines) + "\n"))


def plot_objective(path: Path, complete: list, default, objective: str) -> None:
    from slamobs.pipeline.evaluation.plots import import_matplotlib, plain_log_axis

    import_matplotlib()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    fig = Figure(figsize=(8.0, 4.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    n = np.array([t.number for t in complete])
    v = np.array([t.value for t in complete], dtype=float)
    finite = np.isfinite(v)
    ax.plot(n[finite], v[finite], "o", ms=4, color="C0", label="trial (median over the logs)")
    if (~finite).any() and finite.any():
        top = np.nanmax(v[finite]) * 1.5
        ax.plot(n[~finite], np.full((~finite).sum(), top), "x", color="C3", label="diverged on a log")
    if finite.any():
        best = np.minimum.accumulate(np.where(finite, v, np.inf))
        ax.step(n, np.where(np.isfinite(best), best, np.nan), where="post", color="C1", label="best so far")
    if default is not None and default.value is not None and math.isfinite(default.value):
        ax.axhline(default.value, ls="--", color="0.4", label="defaults")
    ax.set_yscale("log")
    plain_log_axis(ax.yaxis)  # not 5×10⁻², 6×10⁻², ...
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # trials are counted: no trial 0.25
    ax.set_xlabel("trial")
    ax.set_ylabel(f"median {OBJECTIVES[objective]} [{UNITS[objective]}]")
    ax.set_title("slamobs tune: objective per trial")
    ax.grid(True, alpha=0.3, which="both")
    ax.legend(fontsize=8)
    _replace(path, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))


def write_results(out: Path, study, spec, setup: dict, options, holdout: list[dict] = ()) -> dict:
    """Every result file from the study as it is; returns tune.json's content."""
    import optuna

    logs = setup["logs"]
    key = OBJECTIVES[options.objective]
    complete = [t for t in _trials(study) if t.state == optuna.trial.TrialState.COMPLETE]
    default = next((t for t in complete if t.user_attrs.get("default")), None)
    finite = [t for t in complete if math.isfinite(t.value)]
    best = min(finite, key=lambda t: (t.value, t.number)) if finite else None
    write_trials(out / "trials.parquet", trial_rows(study, spec, logs), spec)
    val = validation(complete, default, key, logs) if complete else {"rows": []}
    unit = UNITS[options.objective]

    def trial_doc(t):
        if t is None:
            return None
        return {
            "trial": t.number,
            "objective": t.value,
            "gains": t.user_attrs["gains"],
            "per_log": dict(zip(logs, _per_log(t, key))),
            "likely_lost": {
                log: r["likely_lost"] for log, r in zip(logs, t.user_attrs["logs"]) if r.get("likely_lost")
            },
        }

    summary = {
        "observer": spec.name,
        "objective": {
            "name": options.objective,
            "metric": key,
            "unit": unit,
            "statistic": "median over the logs",
            **({"against": AGAINST[options.target]} if options.target != "truth" else {}),
        },
        "trials": {
            "complete": len(complete),
            "failed": len(_trials(study)) - len(complete),
            "requested": options.trials,
        },
        "best": trial_doc(best),
        "defaults": trial_doc(default),
        "validation": val,
        "holdout": holdout_summary(list(holdout), key) if holdout else None,
        "setup": setup,
        "files": {"gains": "gains.yaml", "trials": "trials.parquet", "plot": "objective.png"},
    }
    if best is not None:
        header = [
            f"slamobs tune: best of {plural(len(complete), 'trial')} on {plural(len(logs), 'log')} "
            f"(trial {best.number}), "
            f"median {key} {best.value:.4g} {unit}"
            + (f" (defaults {_fmt(default.value)})" if default is not None else ""),
            "use with: slamobs run LOG --config gains.yaml (or copy the gains section into your run.yaml)",
        ]
        write_gains(out / "gains.yaml", spec, best.user_attrs["gains"], header)
    if complete:
        plot_objective(out / "objective.png", complete, default, options.objective)
    _replace(out / "tune.md", lambda tmp: tmp.write_text(render_markdown(summary)))
    _replace(out / "tune.json", lambda tmp: tmp.write_text(json.dumps(_finite(summary), indent=2)))
    return summary


def _finite(o):
    """JSON has no inf or NaN: null (a diverged log or trial says so in tune.md and trials.parquet)."""
    if isinstance(o, float):
        return o if math.isfinite(o) else None
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    return o


def defaults_won(s: dict) -> str:
    """What the best trial is when it is the defaults' trial (no trial scored lower, so gains.yaml holds the
    defaults), said after its number by the command and tune.md; "" otherwise."""
    best, default = s.get("best"), s.get("defaults")
    if not best or not default or best["trial"] != default["trial"]:
        return ""
    return "the defaults: no other trial scored lower; gains.yaml holds them"


def lost_words(s: dict) -> str | None:
    """The best trial's logs on which its run's own check says the estimate is likely lost (the run's warning with
    these gains), and the defaults' count: tune.json's ``best.likely_lost``; None when there is none."""
    best, default = s.get("best"), s.get("defaults")
    lost = (best or {}).get("likely_lost") or {}
    if not lost:
        return None
    n_logs = len(s["setup"]["logs"])
    first, why = next(iter(lost.items()))
    more = f" and {plural(len(lost) - 1, 'other log')}" if len(lost) > 1 else ""
    before = (
        f"; with the defaults on {len((default or {}).get('likely_lost') or {})} of {n_logs}"
        if default and "likely_lost" in default
        else ""
    )
    return (
        f"with the best gains the run's own check says its estimate is likely lost on {len(lost)} of "
        f"{plural(n_logs, 'log')} ({Path(first).name}: {why}{more}){before}: a run with them warns so, whatever its "
        "score; check those logs' runs (`slamobs run LOG --config gains.yaml`), tune longer (a larger --trials) or "
        "keep the defaults"
    )


def render_markdown(s: dict) -> str:
    o = s["objective"]
    lines = [
        f"# slamobs tune: {s['observer']}",
        "",
        f"Objective: median over the logs of `{o['metric']}` [{o['unit']}]"
        + (f" against {o['against']}" if "against" in o else "")
        + f"; {s['trials']['complete']} complete "
        f"trials ({s['trials']['failed']} failed) of {s['trials']['requested']} requested.",
        "",
    ]
    if s["best"] and s["defaults"]:
        lines += ["| log | defaults | best (tuned on all logs) |", "|---|---:|---:|"]
        for log in s["setup"]["logs"]:
            lines.append(
                f"| {Path(log).name} | {_fmt(s['defaults']['per_log'][log])} | {_fmt(s['best']['per_log'][log])} |"
            )
        lines.append(f"| **median** | {_fmt(s['defaults']['objective'])} | {_fmt(s['best']['objective'])} |")
        lines += [
            "",
            "Best gains (trial %d%s): %s"
            % (
                s["best"]["trial"],
                f", {defaults_won(s)}" if defaults_won(s) else "",
                ", ".join(f"{k} {v:.4g}" for k, v in s["best"]["gains"].items()),
            ),
            "",
        ]
        if said := lost_words(s):
            lines += [f"Warning: {said}", ""]
    val = s["validation"]
    lines += ["## Leave-one-log-out validation", ""]
    if val.get("rows"):
        lines += [
            val["method"] + ".",
            "",
            "| held-out log | defaults | chosen on the other logs | change | chosen trial |",
            "|---|---:|---:|---:|---:|",
        ]
        for r in val["rows"]:
            change = "-" if r["improvement"] is None else f"{-100 * r['improvement'] + 0.0:+.0f} %"
            lines.append(
                f"| {Path(r['log']).name} | {_fmt(r['default'])} | {_fmt(r['held_out'])} | {change} | "
                f"{r['chosen_trial']} |"
            )
        lines += [
            "",
            f"Gains chosen without a log beat the defaults on it for {val['held_out_better_than_default']} "
            f"of {val['logs']} logs.",
        ]
    else:
        lines.append(val.get("note", "no complete trials"))
    held = s.get("holdout")
    lines += ["", "## Holdout logs", ""]
    if held:
        lines += [held["method"] + ".", "", "| holdout log | defaults | tuned | change |", "|---|---:|---:|---:|"]
        for r in held["rows"]:
            change = "-" if r["improvement"] is None else f"{-100 * r['improvement'] + 0.0:+.0f} %"
            lines.append(f"| {Path(r['log']).name} | {_fmt(r['defaults'])} | {_fmt(r['tuned'])} | {change} |")
        lines += [
            f"| **median** | {_fmt(held['median_defaults'])} | {_fmt(held['median_tuned'])} | |",
            "",
            f"The tuned gains beat the defaults on {held['tuned_better']} of {held['logs']} holdout logs."
            + (
                ""
                if 2 * held["tuned_better"] > held["logs"]
                else " They do not transfer: keep the defaults, or tune on more and longer logs."
            ),
        ]
    else:
        lines.append(
            "None given (`--holdout LOG`): without logs the tune never saw, nothing shows whether the "
            "gains transfer to your other logs."
        )
    return "\n".join(lines) + "\n"
