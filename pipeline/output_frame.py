"""The frame a run's tables are written in (``output.frame``): one rigid transform of the observer's map frame.

Observers estimate the pose only up to what their sensors observe (docs/observers.md §1.1), so the frame of
their output is a choice. Every choice here is a single rigid transform ``x_out = R x_map + t`` applied to every pose,
track, innovation and landmark of the run, so the written map and trajectory stay exactly as consistent as the
observer made them:

- ``map``: the observer's map frame itself; with a known map (``map:``) that map's frame, and then the default.
- ``start``: the first pose is the identity.
- ``gravity``: z up (against the configured gravity), origin at the first position. Observers that use IMU
  directions give it themselves: the mean orientation of their map frame in their inertial frame
  (:attr:`ObserverResult.map_frame`), whose x follows the horizontal magnetic reference; for the others the
  accelerometer's "up" (samples at rest when there are enough, else every sample the direction model
  trusts, body acceleration removed) in the estimate's frame, turned onto z by the smallest rotation.
- ``truth``: the first estimate pose with a ground-truth pose within ``t_max_diff`` is put on it. The
  observers without directions do not depend on their initial frame (tested), so this equals initialising
  them there; those with directions keep their inertial frame, so it is their output moved rigidly.
- an explicit initial pose ``{position: [x, y, z], orientation_xyzw: [x, y, z, w]}``: the first pose.

The transform is fixed from the first stretch of the run (the whole run below ~11 minutes), before anything is
written, so long runs are still written stretch by stretch.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from slamobs.pipeline.errors import InputError, plural
from slamobs.pipeline.kernel_cache import njit
from slamobs.pipeline.lie import quat_to_rot, rotate_covariance, rots_to_quats, so3_exp, so3_log
from slamobs.pipeline.observers.base import ObserverResult
from slamobs.pipeline.simd import fma

NAMES = ("map", "start", "gravity", "truth")
#: Velocity samples with ‖V_m‖ and ‖Ω_m‖ below these count as at rest for the accelerometer's "up".
REST_SPEED = 0.05  # m/s
REST_RATE = 0.05  # rad/s
#: Rest samples needed before only they are used.
MIN_REST_SAMPLES = 20


def default_frame(uses_directions: bool, known_map: bool = False) -> str:
    """``map`` with a known map (its frame is what the user gave), else ``gravity`` for observers that estimate it
    (IMU directions) and ``start`` for the others."""
    return "map" if known_map else ("gravity" if uses_directions else "start")


def parse_frame(value) -> str | dict:
    """Config value -> a frame name or an explicit pose ``{"position": (3,), "rotation": (3, 3)}``."""
    if value is None or isinstance(value, str):
        return value
    q = np.asarray(value["orientation_xyzw"], dtype=float)
    if not np.isfinite(q).all() or np.linalg.norm(q) < 1e-9:
        raise ValueError("output.frame orientation_xyzw must be a non-zero quaternion")
    return {"position": np.asarray(value["position"], dtype=float), "rotation": quat_to_rot(q / np.linalg.norm(q))}


@dataclass(frozen=True)
class OutputFrame:
    """``x_out = rot x_map + trans`` and how it was chosen."""

    name: str
    rot: np.ndarray
    trans: np.ndarray
    method: str

    def apply(self, part: ObserverResult) -> ObserverResult:
        """The stretch (and its map) in this frame; biases are body-frame and stay. The identity (``map``, or
        ``start`` from a first pose at the identity, as riekf's and fast-adaptation's) moves nothing: the
        stretch's rows as they are, the map copied (its live arrays move on)."""
        r, t = self.rot, self.trans
        if self.is_identity():
            return replace(
                part,
                landmark_xyz=np.array(part.landmark_xyz),
                landmark_cov=None if part.landmark_cov is None else np.array(part.landmark_cov),
            )
        return replace(
            part,
            rotation=turned(r, part.rotation),
            position=moved(part.position, r, t),
            track_xyz=moved(part.track_xyz, r, t),
            innovation=moved(part.innovation, r),
            landmark_xyz=part.landmark_xyz @ r.T + t,
            pose_cov=None if part.pose_cov is None else rotate_covariance(part.pose_cov, np.kron(np.eye(2), r)),
            landmark_cov=None if part.landmark_cov is None else rotate_covariance(part.landmark_cov, r),
        )

    def is_identity(self) -> bool:
        """``x_out = x_map``: rotation exactly the identity, no translation (the rows keep their bits)."""
        return bool(np.array_equal(self.rot, np.eye(3)) and not np.any(self.trans))

    def describe(self) -> dict:
        """For run.json and the Parquet metadata."""
        return {
            "name": self.name,
            "method": self.method,
            "from_map_frame": {
                "rotation_quat_xyzw": [float(v) for v in rots_to_quats(self.rot[None])[0]],
                "translation_m": [float(v) for v in self.trans],
            },
        }


#: Rows from which :func:`turned` and :func:`moved` take their compiled loops (an 11-minute stretch of the hour:
#: 131,072 poses, ~0.2 CPU s of ``einsum`` and BLAS calls on the writer's thread); shorter arrays take the array
#: code, so that a short log's first run does not compile them.
FRAME_KERNEL_ROWS = 65_536


def turned(r: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """``r @ R_k`` for each rotation matrix, as ``np.einsum("ij,kjl->kil", r, rotations)`` rounds it (each entry
    summed from 0.0 in the order of ``j``, no fused multiply-add): the same bits from a compiled loop for long
    stretches (``tests/test_output_frame.py``)."""
    m = np.asarray(rotations)
    if m.shape[0] < FRAME_KERNEL_ROWS or m.dtype != np.float64 or not m.flags.c_contiguous:
        return np.einsum("ij,kjl->kil", r, m)
    out = np.empty_like(m)
    _turned_rows(np.ascontiguousarray(r, dtype=np.float64), m, out)
    return out


def moved(points: np.ndarray, r: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
    """``points @ r.T (+ t)``, as NumPy's BLAS call rounds it on an FMA CPU (each entry ``fma`` of the three
    products in turn from 0.0, then ``+ t``): the same bits from a compiled loop for long C-contiguous arrays
    (``tests/test_output_frame.py``)."""
    p = np.asarray(points)
    if p.shape[0] < FRAME_KERNEL_ROWS or p.dtype != np.float64 or not p.flags.c_contiguous or p.shape[1:] != (3,):
        return p @ r.T if t is None else p @ r.T + t
    out = np.empty_like(p)
    shift = np.zeros(3) if t is None else np.ascontiguousarray(t, dtype=np.float64)
    _moved_rows(p, np.ascontiguousarray(r, dtype=np.float64), shift, out)
    return out


@njit(cache=True, nogil=True)
def _turned_rows(r, m, out):  # pragma: no cover - compiled
    """``out_k = r @ m_k``, every entry summed from 0.0 without fused multiply-adds (``einsum``'s rounding)."""
    for k in range(m.shape[0]):
        for i in range(3):
            for c in range(3):
                acc = 0.0
                for j in range(3):
                    acc += r[i, j] * m[k, j, c]
                out[k, i, c] = acc


@njit(cache=True, nogil=True)
def _moved_rows(p, r, t, out):  # pragma: no cover - compiled
    """``out_k = r p_k + t``, each entry ``fma(p₂, r₂, fma(p₁, r₁, fma(p₀, r₀, 0)))`` then ``+ t`` (OpenBLAS's
    dgemm kernels on an FMA CPU; ``+ 0.0`` changes nothing there: the sum from 0.0 is never -0.0)."""
    for k in range(p.shape[0]):
        for i in range(3):
            acc = fma(p[k, 0], r[i, 0], 0.0)
            acc = fma(p[k, 1], r[i, 1], acc)
            out[k, i] = fma(p[k, 2], r[i, 2], acc) + t[i]


def _first_pose_at(rot0: np.ndarray, pos0: np.ndarray, target_rot: np.ndarray, target_pos: np.ndarray):
    """The transform that moves pose ``(rot0, pos0)`` onto ``(target_rot, target_pos)``."""
    r = target_rot @ rot0.T
    return r, target_pos - r @ pos0


def _onto_z(up: np.ndarray) -> np.ndarray:
    """Smallest rotation taking the unit vector ``up`` onto +z."""
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, z)
    s, c = np.linalg.norm(axis), float(up @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return so3_exp(axis / s * np.arctan2(s, c))


def _accelerometer_up(part: ObserverResult, aligned, log) -> tuple[np.ndarray, str]:
    """Mean accelerometer "up" in the estimate's frame over the stretch's rows."""
    dirs = aligned.directions
    if dirs is None or "gravity" not in dirs.names:
        raise InputError(
            log,
            "output.frame gravity needs an accelerometer (sensor_msgs/Imu) for this observer; "
            "choose output.frame start",
        )
    j = dirs.names.index("gravity")
    k = np.searchsorted(aligned.vel_t_ns, part.t_ns)
    up_b, w = dirs.body[k, j], dirs.weight[k, j].copy()
    rest = (
        (np.linalg.norm(aligned.velocity[k], axis=1) < REST_SPEED)
        & (np.linalg.norm(aligned.omega[k], axis=1) < REST_RATE)
        & (w > 0)
    )
    if rest.sum() >= MIN_REST_SAMPLES:
        w = np.where(rest, 1.0, 0.0)
        how = f"{plural(int(rest.sum()), 'sample')} at rest"
    else:
        how = f"{plural(int((w > 0).sum()), 'sample')}, body acceleration from the odometry removed (too few at rest)"
    ok = (w > 0) & np.isfinite(up_b).all(axis=1)
    if not ok.any():
        raise InputError(log, "output.frame gravity: no usable accelerometer sample in the first stretch")
    up = np.einsum("kij,kj->i", part.rotation[ok] * w[ok, None, None], up_b[ok])
    return up / np.linalg.norm(up), how


def _truth_pose(part: ObserverResult, truth, t_max_diff: float):
    """The first estimate row inside the truth's span with truth samples within ``t_max_diff`` on both sides,
    and the truth pose interpolated at its time (linear position, geodesic rotation); None if there is none."""
    t = np.asarray(truth.t_ns, dtype=np.int64)
    order = np.argsort(t, kind="stable")
    t = t[order]
    j = np.searchsorted(t, part.t_ns, side="right")  # truth sample j - 1 <= estimate time < sample j
    inside = (j >= 1) & (j < t.size)
    jc = np.clip(j, 1, max(t.size - 1, 1))
    tol = t_max_diff * 1e9
    exact = (j >= 1) & (t[np.clip(j - 1, 0, None)] == part.t_ns)
    near = exact | (inside & (part.t_ns - t[jc - 1] <= tol) & (t[np.minimum(jc, t.size - 1)] - part.t_ns <= tol))
    if not near.any():
        return None
    k = int(np.argmax(near))
    a, b = order[jc[k] - 1], order[min(jc[k], t.size - 1)]
    r_a = quat_to_rot(np.asarray(truth.quat_xyzw[a], dtype=float))
    if exact[k] or a == b:
        return k, r_a, np.asarray(truth.position[a], dtype=float)
    s = float(part.t_ns[k] - t[jc[k] - 1]) / float(t[jc[k]] - t[jc[k] - 1])
    r_b = quat_to_rot(np.asarray(truth.quat_xyzw[b], dtype=float))
    pos = (1.0 - s) * np.asarray(truth.position[a], dtype=float) + s * np.asarray(truth.position[b], dtype=float)
    return k, r_a @ so3_exp(s * so3_log(np.ascontiguousarray(r_a.T @ r_b))), pos


def resolve(
    choice,
    first: ObserverResult,
    *,
    aligned,
    log,
    gravity,
    truth=None,
    t_max_diff: float = 0.01,
    uses_directions: bool = False,
    known_map: bool = False,
    notes: list[str] | None = None,
) -> OutputFrame:
    """The output frame for ``choice`` (None = the observer's default) from the run's first stretch."""
    notes = notes if notes is not None else []
    if choice is None:
        choice = default_frame(uses_directions, known_map)
    if choice == "map":
        return OutputFrame(
            "map",
            np.eye(3),
            np.zeros(3),
            "the observer's map frame as it is" + (" (the known map's frame)" if known_map else ""),
        )
    if not len(first.t_ns):
        return OutputFrame(choice if isinstance(choice, str) else "pose", np.eye(3), np.zeros(3), "no poses")
    rot0, pos0 = first.rotation[0], first.position[0]
    if isinstance(choice, dict):
        r, t = _first_pose_at(rot0, pos0, choice["rotation"], choice["position"])
        return OutputFrame("pose", r, t, "the first pose is the configured initial pose")
    if choice == "truth":
        found = None if truth is None or not len(truth) else _truth_pose(first, truth, t_max_diff)
        if found is not None:
            k, r_true, p_true = found
            r, t = _first_pose_at(first.rotation[k], first.position[k], r_true, p_true)
            return OutputFrame(
                "truth",
                r,
                t,
                f"the estimate pose at t_ns {int(first.t_ns[k])} is put on the truth "
                f"pose interpolated there (truth samples within {t_max_diff:g} s)",
            )
        fallback = default_frame(uses_directions, known_map)
        notes.append(
            f"output.frame truth: no ground-truth pose within {t_max_diff:g} s of the first stretch's "
            f"estimate; written in the {fallback} frame instead"
        )
        return resolve(
            fallback,
            first,
            aligned=aligned,
            log=log,
            gravity=gravity,
            uses_directions=uses_directions,
            known_map=known_map,
            notes=notes,
        )
    if choice == "start":
        r, t = _first_pose_at(rot0, pos0, np.eye(3), np.zeros(3))
        return OutputFrame("start", r, t, "the first pose is the identity")
    if choice != "gravity":
        raise ValueError(f"unknown output frame {choice!r} (choose {', '.join(NAMES)} or an initial pose)")
    g = np.asarray(gravity, dtype=float)
    to_z = _onto_z(-g / np.linalg.norm(g))  # the configured "up" of the inertial frame onto +z
    if first.map_frame is not None:
        r = to_z @ first.map_frame["mean_rotation"]
        method = (
            f"the observer's own estimate: mean orientation of its map frame in its inertial frame (gravity "
            f"and magnetic references) over {first.map_frame['samples']} samples after "
            f"{first.map_frame['estimated_s']:.1f} s of estimation"
        )
    else:
        up, how = _accelerometer_up(first, aligned, log)
        r = _onto_z(up)
        method = f"accelerometer 'up' in the estimate's frame turned onto z (yaw kept): {how}"
    return OutputFrame("gravity", r, -(r @ pos0), method + "; origin at the first position")
