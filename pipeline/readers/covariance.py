"""The noise levels a log states about itself: the covariance fields of its velocity messages.

The reference estimators (``batch``, ``riekf``) weight odometry by its noise; ``sensor_msgs/Imu``
(``angular_velocity_covariance``), ``nav_msgs/Odometry`` and ``TwistWithCovarianceStamped``
(``twist.covariance``) carry it. Drivers fill these fields with a constant, but not always the same one all
along: after a reset a driver may switch to REP 145's -1 or a placeholder, or the reverse. So every message's
diagonal is judged: the readers decode it with the velocities (``rows.STATED_COLUMNS``, kept as runs of equal rows:
``Rows.stated``), and the stamps of the first messages give the sample period that turns a per-sample variance
into a noise density.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slamobs.pipeline.blocks import equal_rows, finite_rows
from slamobs.pipeline.errors import InputError

from .container import open_log
from .decode import decode_rows
from .msgdefs import complete_definitions
from .roles import topics_of
from .rows import LAYOUTS, STATED_COLUMNS, Rows, stated_start

#: Messages whose stamps give the sample period (the stated variances are judged in every message).
SAMPLE_MESSAGES = 25


@dataclass(frozen=True)
class StatedNoise:
    """Per-axis standard deviation of one sample (body frame of the message) and the sample period."""

    topic: str
    sigma: np.ndarray  # (3,); NaN where ``problem`` says why the stated values are not believed
    period_s: float
    problem: str | None = None
    #: how many messages stated implausible values, what and from when (None: every message was plausible)
    rejected: str | None = None

    @property
    def density(self) -> np.ndarray:
        """White-noise density ``sigma * sqrt(period)`` (units per sqrt(Hz))."""
        return self.sigma * np.sqrt(self.period_s)


#: Diagonal variances drivers write when they know nothing: a value this large or this small that is an exact
#: power of ten is a placeholder, not a measurement.
PLACEHOLDER_ABOVE, PLACEHOLDER_BELOW = 1e2, 1e-8


def implausible(diag: np.ndarray) -> str | None:
    """Why three stated variances are not a measurement (None: plausible): REP 145's -1 ("no estimate"),
    zeros ("unknown"), negative or non-finite values, placeholders such as 1e-9, 1e3 or 1e6."""
    diag = np.asarray(diag, dtype=float)
    if not np.all(np.isfinite(diag)):
        return "not finite"
    if diag[0] == -1:
        return "-1 (REP 145: no estimate)"
    if np.any(diag < 0):
        return "negative"
    if np.any(diag == 0):
        return "zero (unknown)"
    exact = np.isclose(np.log10(diag), np.round(np.log10(diag)), rtol=0, atol=1e-9)
    if np.any(exact & ((diag >= PLACEHOLDER_ABOVE) | (diag <= PLACEHOLDER_BELOW))):
        return f"placeholder ({', '.join(f'{d:g}' for d in diag)})"
    return None


#: Why a row of stated variances is not a measurement, by the code :func:`implausible_rows` gives (0: plausible).
_WHY = ("", "not finite", "-1 (REP 145: no estimate)", "negative", "zero (unknown)", "placeholder")


def implausible_rows(diag: np.ndarray) -> np.ndarray:
    """:func:`implausible` of every row of ``diag`` (N, 3) at once, as codes into the reasons (0: plausible); a
    column at a time (``blocks.finite_rows``), logarithms only of the values a placeholder can be."""
    diag = np.asarray(diag, dtype=float)
    cols = [diag[:, k] for k in range(diag.shape[1])]
    finite, zero, negative, extreme = finite_rows(diag), cols[0] == 0, cols[0] < 0, np.zeros(diag.shape[0], bool)
    for c in cols[1:]:
        zero |= c == 0
        negative |= c < 0
    for c in cols:
        extreme |= (c >= PLACEHOLDER_ABOVE) | ((c <= PLACEHOLDER_BELOW) & (c > 0))
    placeholder = np.zeros(diag.shape[0], bool)
    if (where := np.flatnonzero(extreme & finite & ~zero & ~negative)).size:
        sub = diag[where]
        exp = np.log10(sub)
        exact = np.abs(exp - np.round(exp)) <= 1e-9  # as implausible() judges exact powers of ten
        placeholder[where] = (exact & ((sub >= PLACEHOLDER_ABOVE) | (sub <= PLACEHOLDER_BELOW))).any(axis=1)
    code = np.zeros(diag.shape[0], np.int8)
    for value, rows in ((5, placeholder), (4, zero), (3, negative), (2, cols[0] == -1), (1, ~finite)):
        code[rows] = value  # the first reason of implausible() wins: written last
    return code


def stated_from_rows(rows: Rows, role: str) -> StatedNoise | None:
    """The noise ``rows`` (one decoded velocity topic) state for ``role``, every message's diagonal judged: the
    median of the plausible ones, with a note of how many were not and from when; None when the type states none.
    A topic with more implausible messages than plausible ones is given with its ``problem`` (the values it
    states cannot be believed for the whole log). The diagonals come as runs of equal rows (``Rows.stated``): each
    run is judged once, and only a changing stream's plausible rows are laid out for their median."""
    column = STATED_COLUMNS.get((role, rows.msgtype))
    steps = np.diff(np.sort(rows.t_ns[:SAMPLE_MESSAGES])) * 1e-9
    steps = steps[steps > 0]
    if column is None or steps.size == 0 or rows.stated is None:
        return None
    period = float(np.median(steps))
    first_column = stated_start(rows.msgtype) or 0
    at = LAYOUTS[rows.msgtype].columns[column]
    diag = rows.stated.values[:, at.start - first_column : at.stop - first_column]  # one row per run
    if equal_rows(diag, np.broadcast_to(diag[0], diag.shape)).all():  # drivers state one constant: judged once
        why = implausible(diag[0])
        sigma = np.sqrt(diag[0]) if why is None else np.full(3, np.nan)
        return StatedNoise(rows.topic, sigma, period, why and f"{why} (all {rows.stated.n} messages)")
    lengths = rows.stated.lengths
    code = implausible_rows(diag)
    bad = np.flatnonzero(code)  # runs
    if bad.size == 0:
        return StatedNoise(rows.topic, np.sqrt(np.median(np.repeat(diag, lengths, axis=0), axis=0)), period)
    n, nbad = rows.stated.n, int(lengths[bad].sum())
    first = bad[0]
    why = implausible(diag[first]) or _WHY[code[first]]
    ends = rows.stated.starts[[bad[0], bad[-1]]] + [0, lengths[bad[-1]] - 1]  # the first and last bad rows
    span = (rows.t_ns[ends] - rows.t_ns.min()) * 1e-9
    rejected = (
        f"{nbad} of {n} messages state {why}"
        + (" and other implausible values" if np.unique(code[bad]).size > 1 else "")
        + f" (between {span[0]:.4g} and {span[1]:.4g} s of the topic)"
    )
    if 2 * nbad > n:
        return StatedNoise(
            rows.topic, np.full(3, np.nan), period, rejected if nbad < n else f"{why} (all {n} messages)", rejected
        )
    good = code == 0
    sigma = np.sqrt(np.median(np.repeat(diag[good], lengths[good], axis=0), axis=0))
    return StatedNoise(rows.topic, sigma, period, rejected=f"{rejected}; the median of the other {n - nbad} used")


def stated_noise(
    path: str | Path, topics: dict[str, str], roles: tuple[str, ...] = ("angular_velocity", "linear_velocity")
) -> dict[str, StatedNoise]:
    """Role -> the noise stated by every message of that role's topic (:func:`stated_from_rows`; roles without one
    are left out). A run takes them from its read (``LogStreams.stated_covariance``); this reads the topics again.

    A topic whose messages cannot be read here is treated as stating nothing (the run reads it properly and
    reports any damage itself).
    """
    found: dict[str, StatedNoise] = {}
    wanted = {role: topics[role] for role in roles if topics.get(role)}
    if not wanted:
        return found
    try:
        with open_log(path) as reader:
            complete_definitions(reader)
            table = topics_of(reader)
            for role, topic in wanted.items():
                if topic in table and (role, table[topic][0].msgtype) in STATED_COLUMNS:
                    stated = stated_from_rows(decode_rows(reader, path, topic, table[topic][1]), role)
                    if stated is not None:
                        found[role] = stated
    except (InputError, AttributeError, KeyError, TypeError, ValueError):
        return found
    return found
