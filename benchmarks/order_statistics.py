"""The report's order statistics (median, p90/p95/p99 of an error vector): NumPy's partition at all their ranks
at once against :func:`slamobs.pipeline.evaluation.metrics.ranked` (one rank at a time), and ``np.median``
against ``metrics.median``; this thread's CPU.

    .venv/bin/python benchmarks/order_statistics.py [--repeat 20]

An hour's report takes ~40 such statistics of 10^5-10^6 errors (APE, APE by alignment, the segment errors'
6 kinds x 5 lengths, RPE). NumPy selects at a single rank with its vectorised code and at several with its
scalar introselect; the values at the ranks are the same either way (checked here too).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as `slamobs` runs (cli/main.py)

import numpy as np  # noqa: E402


def _cpu_ms(fn, repeat: int) -> float:
    fn()
    c = time.thread_time()
    for _ in range(repeat):
        fn()
    return (time.thread_time() - c) / repeat * 1e3


def main() -> None:
    from slamobs.pipeline.evaluation.metrics import PERCENTILES, median, ranked, statistics

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=20)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    print(f"# load {os.getloadavg()[0]:.2f}; numpy {np.__version__}; CPU ms per vector (fastest of 3 means)")
    print(
        f"{'n':>9s} {'np.partition(ranks)':>20s} {'ranked':>8s} {'statistics':>11s} {'np.median+percentile':>21s} "
        f"{'np.median':>10s} {'metrics.median':>15s}"
    )
    for n in (1_000, 10_000, 100_000, 360_000, 720_000):
        e = np.abs(rng.standard_normal(n))
        virtual = (n - 1) * np.asarray(PERCENTILES) / 100
        below = np.floor(virtual).astype(np.intp)
        ranks = np.unique(np.concatenate(([0, n - 1, n // 2 - 1 + n % 2, n // 2], below, below + 1)))
        ranks = ranks[ranks < n]
        assert ranked(e, ranks)[ranks].tobytes() == np.partition(e, ranks)[ranks].tobytes()
        assert np.float64(median(e)).tobytes() == np.float64(np.median(e)).tobytes()
        times = [
            min(_cpu_ms(fn, args.repeat) for _ in range(3))
            for fn in (
                lambda: np.partition(e, ranks),
                lambda: ranked(e, ranks),
                lambda: statistics(e),
                lambda: (np.median(e), np.percentile(e, PERCENTILES)),
                lambda: np.median(e),
                lambda: median(e),
            )
        ]
        widths = (20, 8, 11, 21, 10, 15)
        print(f"{n:9d} " + " ".join(f"{t:{w}.3f}" for t, w in zip(times, widths)))


if __name__ == "__main__":
    main()
