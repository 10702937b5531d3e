"""The velocity's own scale from the IMU's accelerometer: what the detection pairs cannot tell (a velocity in another
unit reads to them as tags of another size, ``time_offset.SCALE_CAUSES``), the specific force can.

The accelerometer measures ``f = Rᵀ(a − g) + b_a``; the body velocity ``V`` as read is ``V_true / c`` when it is in
another unit. Over a window of ``WINDOW_S`` seconds, in the attitude of the window's start (the gyro's rotation
``R_k`` from there), ``Σ R_j f_j Δt = c (R_k V_k − V_0) − g₀ t_k + (Σ R_j Δt) b_a``: gravity in the window's start
frame ``g₀`` is one unknown vector per window, and the accelerometer's bias one for the log. Each window's part along
``1, t, t²`` is taken off every column (``g₀ t``, the constants, and the gravity a gyro's bias leaks in, quadratic in
t), and ``c`` and ``b_a`` are fitted by least squares over all windows; its standard error is the windows' own scatter
(a sandwich over windows: the integrated noise is correlated within one). Windows whose residual is over
``OUTLIER_RMS`` times the median are dropped once (slip, impacts). Means over ``alignment.ACCEL_BLOCK_S`` blocks keep
it cheap (36,000 blocks an hour) and average the odometry's noise and the IMU's vibration.

Not modelled: the accelerometer's lever arm from the body origin (``ω × (ω × r)``, small on a ground robot with the
IMU near its centre) and the gyro's scale. Run only where the detection pairs say the velocity's scale is off
(:func:`time_offset.estimate`): a clean log pays nothing but the block means of the alignment.
"""

from __future__ import annotations

import numpy as np

from slamobs.pipeline.alignment import ACCEL_BLOCK_S, accel_block_index, block_means
from slamobs.pipeline.lie import so3_exps

#: Window length (s): the body's acceleration changes within it (a figure 8's, a robot's stops and starts), the gyro's
#: attitude holds over it.
WINDOW_S = 3.0
#: Windows fewer than this give no scale (the camera sample, 15 s: 5 windows, its tags.size doubled told as the tags').
MIN_WINDOWS = 4
#: A window whose RMS residual exceeds this times the median window's is dropped (once).
OUTLIER_RMS = 3.0
#: The scale is said only where the velocity's and the accelerometer's parts the other unknowns leave correlate at
#: least this much (squared): where the body's acceleration hardly changes (a constant circle, a ground robot at one
#: speed) an accelerometer's bias and a tilt take all of it, and the velocity's noise left pulls the scale to 0
#: (generated ground, circle and loop logs: rho2 0.000-0.28, scale 0.001-0.54; figure 8s: 0.86-0.89, 0.93-0.99).
MIN_RHO2 = 0.7
#: The scale agrees with a factor when ``[scale - 3 sigma, scale / rho2 + 3 sigma]`` (the noise in the velocity pulls
#: it toward 0 by at most ``rho2``) meets that factor ``÷×`` this: a real MAV with its velocity from Vicon (ETH MSF
#: dataset) reads 0.83 ± 0.009 (rho2 0.94; its lever arm and the IMU's own scale not modelled), within 1.3 of 1.
AGREE = 1.3


def _block_means(t_ns: np.ndarray, t0_ns: int, x: np.ndarray, nb: int) -> tuple[np.ndarray, np.ndarray]:
    """Means of ``x`` (N, 3) over the accelerometer's blocks (NaN where a block has no sample), and the counts."""
    k = accel_block_index(t_ns, t0_ns)
    inside = (k >= 0) & (k < nb)
    return block_means(k[inside], x[inside], nb)


def _windows(stream) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The accelerometer's, the gyro's and the velocity's block means as ``(W, per, 3)`` windows of ``WINDOW_S``,
    only windows whose every block has samples of all three (none across a gap); None without an accelerometer."""
    if stream.accel_blocks is None or stream.vel_t_ns.shape[0] < 2:
        return None
    t0, f = stream.accel_blocks
    nb = f.shape[0]
    w, count = _block_means(stream.vel_t_ns, t0, stream.omega, nb)
    v, _ = _block_means(stream.vel_t_ns, t0, stream.velocity, nb)
    ok = (count > 0) & np.isfinite(f).all(axis=1) & np.isfinite(w).all(axis=1) & np.isfinite(v).all(axis=1)
    per = int(round(WINDOW_S / ACCEL_BLOCK_S))
    nw = nb // per
    full = ok[: nw * per].reshape(nw, per).all(axis=1)
    return tuple(a[: nw * per].reshape(nw, per, 3)[full] for a in (f, w, v))


def _trapezoid(x: np.ndarray, dt: float) -> np.ndarray:
    """The running trapezoid integral of ``x`` (W, per, ...) along its blocks, 0 at each window's first."""
    head = np.zeros((x.shape[0], 1, *x.shape[2:]))
    return np.concatenate([head, np.cumsum(0.5 * (x[:, 1:] + x[:, :-1]) * dt, axis=1)], axis=1)


def _columns(f: np.ndarray, w: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per window: the accelerometer's velocity change ``y`` (W, per, 3) and the regressors (W, per, 3, 7) of the
    velocity's scale (its change ``x``), the accelerometer's bias and the gyro's (the attitude's first-order change
    with it: ``[R f]× Σ R Δt``), all in the window's start attitude, each's part along ``1, t`` taken off."""
    nw, per, _ = f.shape
    dt = ACCEL_BLOCK_S
    steps = so3_exps(np.ascontiguousarray(w.reshape(-1, 3) * dt)).reshape(nw, per, 3, 3)
    r = np.empty((nw, per, 3, 3))
    r[:, 0] = np.eye(3)
    for j in range(1, per):  # the attitude at each block's middle, from the window's first
        r[:, j] = r[:, j - 1] @ steps[:, j - 1]
    rf = np.einsum("wjab,wjb->wja", r, f)
    b = _trapezoid(r, dt)
    skew = np.zeros((nw, per, 3, 3))
    skew[..., 0, 1], skew[..., 0, 2], skew[..., 1, 2] = -rf[..., 2], rf[..., 1], -rf[..., 0]
    skew -= np.swapaxes(skew, -1, -2)
    x = np.einsum("wjab,wjb->wja", r, v) - v[:, :1]
    a = np.concatenate([x[..., None], b, _trapezoid(skew @ b, dt)], axis=3)
    t = np.arange(per) * dt
    q = np.linalg.qr(np.column_stack([np.ones(per), t]))[0]
    proj = np.eye(per) - q @ q.T
    return np.einsum("ij,wj...->wi...", proj, _trapezoid(rf, dt)), np.einsum("ij,wj...->wi...", proj, a)


def _fit(y: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Least squares of ``y`` (W, m) on ``a`` (W, m, 7) over all windows: the unknowns, their covariance by the
    windows' scatter (sandwich), each window's RMS residual and the squared correlation ``rho2`` (``MIN_RHO2``). A bias
    the windows cannot see (the accelerometer's along a gravity that stays put, taken off with ``g₀ t``) is left at 0
    (pseudo-inverse)."""
    ata = np.einsum("wmi,wmj->ij", a, a)
    inv = np.linalg.pinv(ata, rcond=1e-9)
    theta = inv @ np.einsum("wmi,wm->i", a, y)
    res = y - a @ theta
    score = np.einsum("wmi,wm->wi", a, res) * np.sqrt(y.shape[0] / max(y.shape[0] - 1, 1))  # few windows: CR1
    # the velocity's and the accelerometer's parts the other unknowns leave (Frisch-Waugh): their correlation
    nuis = np.linalg.pinv(ata[1:, 1:], rcond=1e-9)
    xt = a[..., 0] - a[..., 1:] @ (nuis @ ata[1:, 0])
    yt = y - a[..., 1:] @ (nuis @ np.einsum("wmi,wm->i", a[..., 1:], y))
    rho2 = float(np.sum(xt * yt) ** 2 / max(float(np.sum(xt * xt) * np.sum(yt * yt)), 1e-300))
    return theta, inv @ (score.T @ score) @ inv, np.sqrt(np.mean(res * res, axis=1)), rho2


def velocity_scale_by_accel(stream) -> dict | None:
    """``{"scale", "sigma", "windows", "bias"}``: the factor the velocity as read must be multiplied by for the
    accelerometer's specific force (module docstring), its standard error, the windows fitted and the
    accelerometer's bias (m/s², body frame); None without an accelerometer or with under ``MIN_WINDOWS`` windows."""
    blocks = _windows(stream)
    if blocks is None or blocks[0].shape[0] < MIN_WINDOWS:
        return None
    y, a = _columns(*blocks)
    nw = y.shape[0]
    yy, a = y.reshape(nw, -1), a.reshape(nw, -1, a.shape[-1])  # rows: block then axis
    theta, cov, rms, rho2 = _fit(yy, a)
    keep = rms <= OUTLIER_RMS * np.median(rms)
    if MIN_WINDOWS <= int(keep.sum()) < nw:
        theta, cov, _, rho2 = _fit(yy[keep], a[keep])
    return {
        "scale": round(float(theta[0]), 4),
        "sigma": round(float(np.sqrt(max(cov[0, 0], 0.0))), 4),
        "rho2": round(float(rho2), 3),
        "windows": int(keep.sum()) if int(keep.sum()) >= MIN_WINDOWS else nw,
        "bias": [round(float(e), 4) for e in theta[1:4]],
        "gyro_bias": [round(float(e), 5) for e in theta[4:]],
    }


def agrees(accel: dict, factor: float) -> bool:
    """Whether the accelerometer's scale (:func:`velocity_scale_by_accel`) agrees with ``factor`` (``AGREE``)."""
    c, e = accel["scale"], accel["sigma"]
    lo, hi = c - 3.0 * e, c / max(accel["rho2"], 1e-9) + 3.0 * e
    return lo <= factor * AGREE and hi >= factor / AGREE


#: What the velocity-scale warning says when the accelerometer agrees with the detections (``{}``: its numbers).
VELOCITY_CAUSE = (
    "the IMU's accelerometer says so too ({}): the velocity is off, its unit or axes (at the odometry's driver), not "
    "the detections' scale"
)
#: What scales the detections, which both sentences that name them say (``time_offset.SCALE_CAUSES`` too).
DETECTION_SCALES = (
    "tags.size, or tags.sizes per id: the black square's edge in m where the run finds the tags' poses from corners or "
    "images, the tags' own scale then; the detector's tag size, or a depth camera's depth scale, where the log gives "
    "their positions; or their unit"
)
#: ... when it says the velocity reads right.
DETECTIONS_CAUSE = (
    f"the IMU's accelerometer says the velocity reads right ({{}}): the detections' scale is off ({DETECTION_SCALES}), "
    "or their frame's extrinsic: a camera turned or given as the inverse transform reads this way"
)


def scale_cause(factor: float, accel: dict | None, both: str) -> str:
    """Which cause of a velocity axis ``factor`` times off the accelerometer names: the velocity's
    (``VELOCITY_CAUSE``) when its scale agrees with ``factor`` and not with 1, the detections' (``DETECTIONS_CAUSE``)
    when it agrees with 1 and not with ``factor``; ``both`` (the detection pairs' sentence naming both) when there
    is no accelerometer, its scale is unsaid (``MIN_RHO2``) or agrees with both or neither."""
    if accel is None or accel["rho2"] < MIN_RHO2:
        return both
    said = f"{accel['scale']:.3g}x ± {accel['sigma']:.2g}, its specific force against the velocity's change over "
    said += f"{accel['windows']} windows of {WINDOW_S:g} s"
    one, other = agrees(accel, 1.0), agrees(accel, factor)
    if other and not one:
        return VELOCITY_CAUSE.format(said)
    if one and not other:
        return DETECTIONS_CAUSE.format(said)
    return both
