"""How many digits :func:`pipeline.lie.se3_exp_into` keeps on the small twists of an integration step, against an
exact reference (issue 27, session 19).

    .venv/bin/python benchmarks/se3_exp_precision.py [--per-decade 200]

For rotation angles θ from 1e-9 to 1 rad (random axes and translations, a fixed seed), the exponential
``R = I + a K + b K²``, ``p = v + b w×v + c w×(w×v)`` is computed by ``se3_exp_into`` (and by the closed form it
used before session 19: ``b = (1 − cos θ)/θ²``, ``c = (θ − sin θ)/θ³``) and, from the same double inputs, in 50-digit
decimal arithmetic with ``a``, ``b``, ``c`` from their Taylor series (no cancellation). Per decade of θ, the
largest errors in units of the double's ε (2.2e-16): of ``b`` and ``c`` (relative), of ``R`` (its largest entry's,
absolute: rounding alone leaves up to ~0.5) and of ``p`` (over ``|v|``: rounding alone leaves ~0.5-1). The closed
form's ``1 − cos θ`` and ``θ − sin θ`` cancel: ``b`` is off by ~ε/θ² relative, and ``b (w × v)`` (of size θ|v|) puts
~ε/(2θ) relative into ``p``. An integration adds these errors once per step: a 1 h log at 200 Hz has 720,000.
"""

from __future__ import annotations

import argparse
import math
from decimal import Decimal, getcontext

import numpy as np

getcontext().prec = 50
EPS = float(np.finfo(float).eps)


def _closed(w0, w1, w2, v0, v1, v2):
    """The closed form as ``se3_exp_into`` computed it before session 19 (numba-free copy, same operations)."""
    t2 = w0 * w0 + w1 * w1 + w2 * w2
    theta = math.sqrt(t2)
    st = math.sin(theta)
    a, b, c = st / theta, (1.0 - math.cos(theta)) / t2, (theta - st) / (t2 * theta)
    if theta < 1e-8:  # its limits below lie.SMALL_ANGLE
        a, b, c = 1.0, 0.5, 1.0 / 6.0
    return _compose(float, a, b, c, t2, (w0, w1, w2), (v0, v1, v2)), (b, c)


def _compose(num, a, b, c, t2, w, v):
    """``R`` (row-major, 9) and ``p`` (3) from the coefficients, in the number type ``num``."""
    w0, w1, w2 = w
    v0, v1, v2 = v
    one = num(1)
    r = [
        one + b * (w0 * w0 - t2),
        -a * w2 + b * w0 * w1,
        a * w1 + b * w0 * w2,
        a * w2 + b * w0 * w1,
        one + b * (w1 * w1 - t2),
        -a * w0 + b * w1 * w2,
        -a * w1 + b * w0 * w2,
        a * w0 + b * w1 * w2,
        one + b * (w2 * w2 - t2),
    ]
    x = (w1 * v2 - w2 * v1, w2 * v0 - w0 * v2, w0 * v1 - w1 * v0)
    xx = (w1 * x[2] - w2 * x[1], w2 * x[0] - w0 * x[2], w0 * x[1] - w1 * x[0])
    p = [v[i] + b * x[i] + c * xx[i] for i in range(3)]
    return r, p


def _exact(w, v):
    """``(R, p)`` and ``(b, c)`` in 50-digit decimals from the same doubles (the series summed to convergence)."""
    wd, vd = [Decimal(x) for x in w], [Decimal(x) for x in v]
    t2 = sum(x * x for x in wd)
    coef = []
    for first in (1, 2, 3):  # a: 1/(2k+1)!, b: 1/(2k+2)!, c: 1/(2k+3)!, alternating in θ²
        s, term, k = Decimal(0), Decimal(1) / math.factorial(first), 0
        while term != 0 and abs(term) > Decimal(10) ** -60:
            s += term
            k += 1
            term = term * (-t2) / ((first + 2 * k - 1) * (first + 2 * k))
        coef.append(s)
    r, p = _compose(Decimal, *coef, t2, wd, vd)
    return r, p, coef[1], coef[2]


def main() -> None:
    from slamobs.pipeline import lie

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-decade", type=int, default=200)
    args = ap.parse_args()
    rng = np.random.default_rng(27)
    r_out, p_out = np.empty((3, 3)), np.empty(3)
    print("| θ (rad) | closed form: b | c | R | p | se3_exp_into: R | p |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for lo in range(-9, 0):
        worst = np.zeros(6)
        for _ in range(args.per_decade):
            theta = 10 ** rng.uniform(lo, lo + 1)
            axis = rng.normal(size=3)
            w = theta * axis / np.linalg.norm(axis)
            v = rng.normal(size=3) * 10 ** rng.uniform(-4, 0)
            r_ref, p_ref, b_ref, c_ref = _exact(w, v)
            (r_c, p_c), (b_c, c_c) = _closed(*w, *v)
            lie.se3_exp_into(*w, *v, r_out, p_out)
            vn = float(np.linalg.norm(v))

            def rel_r(r):
                return max(abs(float(Decimal(x) - y)) for x, y in zip(r, r_ref)) / EPS

            def rel_p(p):
                return math.sqrt(sum(float(Decimal(x) - y) ** 2 for x, y in zip(p, p_ref))) / vn / EPS

            errs = (
                abs(float((Decimal(b_c) - b_ref) / b_ref)) / EPS,
                abs(float((Decimal(c_c) - c_ref) / c_ref)) / EPS,
                rel_r(r_c),
                rel_p(p_c),
                rel_r(list(r_out.ravel())),
                rel_p(list(p_out)),
            )
            worst = np.maximum(worst, errs)
        print(
            f"| 1e{lo}..1e{lo + 1} | {worst[0]:.3g} | {worst[1]:.3g} | {worst[2]:.3g} | {worst[3]:.3g} | "
            f"{worst[4]:.3g} | {worst[5]:.3g} |"
        )
    print("(errors in units of ε = 2.2e-16: b, c relative; R its largest entry's, absolute; p over |v|)")


if __name__ == "__main__":
    main()
