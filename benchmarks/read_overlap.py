"""What running the estimator while the log is read (issue 27) could gain on this machine, at most.

    .venv/bin/python benchmarks/read_overlap.py LOG [--observer fast-adaptation] [--repeat 2]

A run reads and aligns the log (``prepare_log``), then runs the observer a stretch at a time (``STRETCH_SAMPLES``
velocity samples, as ``slamobs run`` does; nothing is written here). Three lines, each timed as wall and CPU
seconds of this process (the VM is shared: the CPU time is the steadier figure, and the load is printed):

* ``read + align``: ``prepare_log`` alone; ``observer``: every stretch on the aligned stream alone.
* ``staged``: the two one after the other, as a run does them today.
* ``overlapped (bound)``: the same two pieces of work at once: the observer runs on a thread over a stream
  aligned beforehand while this thread reads and aligns the log again. No pipeline can do better on this
  machine: a streamed one does the same work and more (merging chunk by chunk, carrying state), and cannot start
  the observer before the first chunk is read. ``gain`` is staged wall minus this wall.

The reader already decodes on two threads (chunks loaded on one, topics decoded on the caller's and a helper),
so how much a second core adds depends on how busy the read keeps both cores: CPU / wall of ``read + align``.
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

# as `slamobs` (cli/main.py) runs: one BLAS thread. With OpenBLAS's threads the alignment's (N, 3) @ (3, 3)
# rotations cost ~20x the CPU (spinning threads) on the loaded 2-core VM, which a run never pays.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))
from end_to_end import load  # noqa: E402


def _timed(fn):
    """``fn()``, its wall and CPU seconds (CPU of every thread of this process)."""
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def main() -> None:
    from slamobs.pipeline.config import load_config
    from slamobs.pipeline.run import STRETCH_SAMPLES, estimator_input, prepare_log, resolve_estimator

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--observer", default="fast-adaptation")
    ap.add_argument("--repeat", type=int, default=2, help="timed rounds (the best of each line is printed)")
    args = ap.parse_args()
    config = replace(load_config(None), observer=args.observer)
    spec = resolve_estimator(config)
    needed = spec.directions_needed(config)
    directions = needed > 0 or config.output.frame == "gravity"

    def read():
        return prepare_log(args.log, config, directions=directions, needs_directions=needed, noise=spec.uses_noise)

    prepared = read()
    est = estimator_input(prepared, config)
    stream = prepared.aligned

    def observe():
        for _ in spec.chunks(stream, est.gains, est.options, STRETCH_SAMPLES):
            pass

    observe()  # numba's cache loaded

    def staged():
        read()
        observe()

    def overlapped():
        worker = threading.Thread(target=observe, name="bench-observer")
        worker.start()
        try:
            read()
        finally:
            worker.join()

    print(f"# {args.log} ({int(stream.vel_t_ns.shape[0])} velocity samples), {args.observer}; {load()}")
    best: dict[str, tuple[float, float]] = {}
    for _ in range(args.repeat):
        for name, fn in (("read + align", read), ("observer", observe), ("staged", staged), ("overlapped", overlapped)):
            _, wall, cpu = _timed(fn)
            best[name] = min(best.get(name, (wall, cpu)), (wall, cpu))
    print(f"{'what':20s} {'wall s':>8s} {'CPU s':>8s}")
    for name, (wall, cpu) in best.items():
        print(f"{name + (' (bound)' if name == 'overlapped' else ''):20s} {wall:8.2f} {cpu:8.2f}")
    gain = best["staged"][0] - best["overlapped"][0]
    print(
        f"gain {gain:.2f} s wall ({gain / best['staged'][0]:.0%} of staged); read + align keeps "
        f"{best['read + align'][1] / best['read + align'][0]:.2f} cores busy"
    )
    print(f"# {load()}")


if __name__ == "__main__":
    main()
