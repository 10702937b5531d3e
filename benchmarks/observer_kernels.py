"""Internal steps per second of the compiled observer kernels vs. a straightforward NumPy step.

    .venv/bin/python benchmarks/observer_kernels.py [--seconds 60] [--repeat 5]

For 4, 30 and 300 visible landmarks, runs the numba kernel of each observer over a synthetic stream
(all landmarks visible at 20 Hz, velocity at 200 Hz) and counts its internal (sub-)steps per second; the
NumPy column runs the same fast-adaptation sub-step (docs/observers.md §4 + §6.1) vectorised
over landmarks with NumPy, in the same process. Compilation happens before timing; each rate is the best
of ``--repeat`` runs (a shared machine only ever slows a run down). "us/event" is the time per velocity
sample or landmark frame: with the default gains there are only ~5 sub-steps per event at 4 landmarks, so
the per-event work matters as much as the sub-step. The cost per sub-step is fitted as ``a + b n`` over the
landmark counts (linear growth with the visible landmarks), and the fast-adaptation floors are checked.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from slamobs.pipeline.alignment import AlignedStream
from slamobs.pipeline.lie import se3_exp
from slamobs.pipeline.observers import ObserverOptions
from slamobs.pipeline.estimators import ESTIMATORS


def synthetic_stream(
    n_landmarks: int, seconds: float, rate: float = 200.0, det_rate: float = 20.0, seed: int = 0
) -> AlignedStream:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 1.0 / rate)
    omega = np.tile([0.01, -0.02, 0.3], (t.size, 1))
    vel = np.tile([1.5, 0.0, 0.05], (t.size, 1))
    landmarks = rng.uniform(-8, 8, size=(n_landmarks, 3))
    td = np.arange(0.0, seconds, 1.0 / det_rate)
    y = np.empty((td.size, n_landmarks, 3))
    for k, tk in enumerate(td):
        r, p = se3_exp(np.array([0.0, 0.0, 0.3]) * tk, np.array([1.5, 0.0, 0.0]) * tk)
        y[k] = (landmarks - p) @ r
    ns = (t * 1e9).astype(np.int64)
    n_dir = 2
    from slamobs.pipeline.directions import DirectionSet

    dirs = DirectionSet(
        ("gravity", "magnetic"),
        np.array([[0, 0, 1.0], [0.4, 0, -0.9]]) / np.linalg.norm([[0, 0, 1.0], [0.4, 0, -0.9]], axis=1, keepdims=True),
        np.tile(np.array([[0, 0, 1.0], [0.406, 0, -0.914]]), (t.size, 1, 1)),
        np.ones((t.size, n_dir)),
    )
    return AlignedStream(
        t0_ns=0,
        vel_t_ns=ns,
        omega=omega,
        velocity=vel,
        det_t_ns=(td * 1e9).astype(np.int64),
        det_offsets=np.arange(0, n_landmarks * td.size + 1, n_landmarks, dtype=np.int64),
        det_idx=np.tile(np.arange(n_landmarks), td.size).astype(np.int64),
        det_y=y.reshape(-1, 3),
        landmark_ids=np.arange(n_landmarks, dtype=np.int64),
        body_frame="base_link",
        directions=dirs,
    )


def numpy_steps_per_s(n_landmarks: int, steps: int, gains=dict(k_p=1.0, k_w=1.0, alpha=1.0, gamma=1.0)) -> float:
    """The fast-adaptation sub-step written plainly with NumPy arrays (vectorised over landmarks)."""
    rng = np.random.default_rng(1)
    lm = rng.normal(size=(n_landmarks, 3)) * 5
    y = rng.normal(size=(n_landmarks, 3)) * 5
    r_hat, p_hat = np.eye(3), np.zeros(3)
    b_om, b_v = np.zeros(3), np.zeros(3)
    om_m, v_m = np.array([0.01, -0.02, 0.3]), np.array([1.5, 0.0, 0.05])
    h = 1e-4
    kwa, ga = gains["k_w"] / gains["alpha"], gains["gamma"] / gains["alpha"]
    t0 = time.perf_counter()
    for _ in range(steps):
        e = lm - y @ r_hat.T - p_hat
        rte = e @ r_hat
        w_om = np.cross(y, rte).sum(axis=0)
        w_v = rte.sum(axis=0)
        psi = gains["k_p"] * (1.0 + np.einsum("ij,ij->i", e, e)) / 4.0
        lm = lm - np.minimum(h * psi, 1.0)[:, None] * e
        om_odo, v_odo = om_m - b_om, v_m - b_v
        b_om = b_om - h * ga * w_om
        b_v = b_v - h * ga * w_v
        d_r, d_p = se3_exp(h * (om_odo + kwa * w_om), h * (v_odo + kwa * w_v))
        p_hat = p_hat + r_hat @ d_p
        r_hat = r_hat @ d_r
        o_r, o_p = se3_exp(h * om_odo, h * v_odo)
        y = (y - o_p) @ o_r
    return steps / (time.perf_counter() - t0)


def kernel_steps_per_s(name: str, stream: AlignedStream, repeat: int) -> tuple[float, int, float]:
    """Best sub-steps per second over ``repeat`` runs, the sub-step count, and the best seconds per event."""
    spec = ESTIMATORS[name]
    gains = spec.resolve_gains(None)
    res = spec.run(stream, gains, ObserverOptions())  # compile / warm
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = spec.run(stream, gains, ObserverOptions())
        best = min(best, time.perf_counter() - t0)
    steps = int(res.stats.get("substeps", 0))
    events = stream.vel_t_ns.shape[0] + stream.det_t_ns.shape[0]
    return steps / best, steps, best / events


def cpu_model() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


#: Floors of the fast-adaptation kernel (issue "Speed and memory").
FLOOR_STEPS_PER_S = 2_000_000
FLOOR_SPEEDUP = 100.0
LANDMARKS = (4, 30, 300)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--seconds",
        type=float,
        default=60.0,
        help="simulated seconds at 4 landmarks (shorter streams for more landmarks)",
    )
    ap.add_argument("--repeat", type=int, default=5, help="runs per measurement (the best counts)")
    args = ap.parse_args()
    print(
        f"# observer kernels, {cpu_model()}, python {platform.python_version()}, "
        f"one core; stream: velocity 200 Hz, detections 20 Hz, all landmarks visible, default gains"
    )
    print(
        f"{'observer':<16} {'landmarks':>9} {'steps':>10} {'kernel steps/s':>15} {'numpy steps/s':>14} "
        f"{'speed-up':>9} {'us/step':>8} {'us/event':>9} {'us/step/landmark':>17}"
    )
    rates: dict[tuple[str, int], float] = {}
    np_rates: dict[int, float] = {}
    for n in LANDMARKS:
        stream = synthetic_stream(n, max(4.0, args.seconds * LANDMARKS[0] / n))  # about the same steps for each n
        np_rates[n] = np_rate = max(numpy_steps_per_s(n, 3000 if n < 100 else 1000) for _ in range(3))
        for name in ESTIMATORS:
            rate, steps, per_event = kernel_steps_per_s(name, stream, args.repeat)
            rates[name, n] = rate
            fa = name == "fast-adaptation"
            ratio = f"{rate / np_rate:8.0f}x" if fa else f"{'':>9}"
            np_col = f"{np_rate:>14,.0f}" if fa else f"{'':>14}"
            print(
                f"{name:<16} {n:>9} {steps:>10} {rate:>15,.0f} {np_col} {ratio} {1e6 / rate:>8.3f} "
                f"{1e6 * per_event:>9.3f} {1e6 / rate / n:>17.4f}"
            )
    print("# cost per internal step fitted as a + b * landmarks (least squares over 4, 30, 300)")
    for name in ESTIMATORS:
        us = np.array([1e6 / rates[name, n] for n in LANDMARKS])
        b, a = np.polyfit(np.array(LANDMARKS, float), us, 1)
        worst = float(np.max(np.abs(a + b * np.array(LANDMARKS) - us) / us))
        print(f"{name:<16} a = {a:.3f} us, b = {1e3 * b:.2f} ns per landmark (fit within {100 * worst:.0f} %)")
    fa4 = rates["fast-adaptation", 4]
    ok = fa4 >= FLOOR_STEPS_PER_S and fa4 / np_rates[4] >= FLOOR_SPEEDUP
    print(
        f"# floor fast-adaptation at 4 landmarks: {fa4:,.0f} steps/s (>= {FLOOR_STEPS_PER_S:,}), "
        f"{fa4 / np_rates[4]:.0f}x NumPy (>= {FLOOR_SPEEDUP:.0f}x): {'ok' if ok else 'MISSED'}"
    )


if __name__ == "__main__":
    main()
