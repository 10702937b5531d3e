"""Known landmark maps: files, and what they do to a run (``map:`` and ``evaluation.map_truth`` in the config).

Files: a ``landmarks.parquet`` of an earlier run (``id, x, y, z``), a CSV ``id,x,y,z`` (header optional, ``#``
comments), or a TagSLAM ``tagslam.yaml`` (the tags of its static bodies with a pose, tag centres composed with
their body's pose; tags given only a size are not positions).

Modes:

* ``fixed``: localisation against the map. Its landmarks start at the map's positions and are never updated
  (their update weight is 0: :func:`pipeline.observers.shared_steps.landmark_weight`); detections of tags not
  in the map are dropped. A fixed map is an absolute frame, so observers that rotate the whole map with their
  inertial-direction correction (hashim-imu, hybrid) are refused: the rotation would move the map, and
  rotating the vehicle alone would change their law.
* ``prior``: the map is the initial estimate of its landmarks, updated like any other; tags not in it are
  initialised at first sighting.

Either way the map fixes the frame of the run, so the observer starts from the pose the map gives: the first
detection frame with three or more mapped, not collinear landmarks is fitted (SE(3), Umeyama) and carried back
to the first velocity sample with the measured odometry.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.paths import check_input, read_text, read_yaml

MODES = ("fixed", "prior")
#: A pose fit needs mapped landmarks spread this much (m, second principal extent) in one frame.
MIN_SPREAD_M = 0.05


@dataclass(frozen=True)
class KnownMap:
    """Landmark positions of a map file (ids sorted)."""

    ids: np.ndarray  # (L,) int64
    xyz: np.ndarray  # (L, 3)
    source: str
    mode: str = "fixed"

    def positions(self) -> dict[int, np.ndarray]:
        return {int(i): p.copy() for i, p in zip(self.ids, self.xyz)}

    @property
    def fixed(self) -> bool:
        return self.mode == "fixed"


def read_map(path: str | Path, mode: str = "fixed") -> KnownMap:
    """A map file (landmarks.parquet, CSV id,x,y,z or tagslam.yaml); a one-line InputError when it is unusable."""
    path = Path(path)
    if mode not in MODES:
        raise InputError(path, f"map mode {mode!r} is not one of {', '.join(MODES)}")
    if not path.exists() and not path.is_symlink():
        raise InputError(path, "map file not found")
    check_input(path, "map file", directory_ok=False)  # a directory, a FIFO, a dangling link: one line each
    suffix = path.suffix.lower()
    if suffix == ".parquet":
        ids, xyz = _parquet(path)
    elif suffix in (".yaml", ".yml"):
        ids, xyz = _tagslam(path)
    else:
        ids, xyz = _csv(path)
    if ids.size == 0:
        raise InputError(path, "map holds no landmark positions")
    if np.unique(ids).size != ids.size:
        dup = sorted({int(i) for i in ids[np.flatnonzero(np.diff(np.sort(ids)) == 0)]})
        raise InputError(path, f"map lists landmark id(s) {dup[:5]} more than once")
    if not np.isfinite(xyz).all():
        raise InputError(path, "map has non-finite positions")
    order = np.argsort(ids)
    return KnownMap(ids[order].astype(np.int64), np.ascontiguousarray(xyz[order], dtype=np.float64), str(path), mode)


def _parquet(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path, columns=["id", "x", "y", "z"])
    except (pa.ArrowException, OSError, KeyError) as err:
        raise InputError(path, f"not a landmarks table (id, x, y, z): {' '.join(str(err).split())[:160]}") from None
    try:
        ids = [_landmark_id(i) for i in table["id"].to_pylist()]
        xyz = np.column_stack([np.asarray(table[a].to_pylist(), dtype=np.float64) for a in "xyz"])
    except (TypeError, ValueError, OverflowError):
        raise InputError(path, "landmarks table: ids must be integers and x, y, z numbers") from None
    return np.asarray(ids, np.int64).reshape(-1), xyz.reshape(-1, 3)


def _landmark_id(value: object) -> int:
    """A landmark id: an integer (``7``, ``7.0``) within int64; ValueError saying what is wrong otherwise."""
    if isinstance(value, str):
        try:
            value = int(value.strip())
        except ValueError:
            try:
                value = float(value)
            except ValueError:
                raise ValueError("not an integer") from None
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError("not an integer")
    if not -(2**63) <= value < 2**63:
        raise ValueError("out of range (64-bit integers)")
    return value


def _csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    ids, rows = [], []
    for n, line in enumerate(read_text(path, "map", "replace").splitlines(), 1):
        text = line.split("#", 1)[0].strip()
        if not text:
            continue
        parts = [p.strip() for p in text.replace(";", ",").replace("\t", ",").split(",")]
        if len(parts) == 1:
            parts = text.split()
        if n == 1 and parts and parts[0].lower() == "id":
            continue  # header
        try:
            if len(parts) != 4:
                raise ValueError
            row = [float(p) for p in parts]
        except ValueError:
            raise InputError(path, f"line {n}: expected 'id,x,y,z', got {text[:60]!r}") from None
        try:
            ids.append(_landmark_id(parts[0]))
        except ValueError as err:
            raise InputError(path, f"line {n}: landmark id {parts[0][:30]} is {err}") from None
        rows.append(row[1:])
    return np.asarray(ids, np.int64), np.asarray(rows, np.float64).reshape(-1, 3)


def _tagslam(path: Path) -> tuple[np.ndarray, np.ndarray]:
    from slamobs.pipeline.lie import so3_exp

    doc = read_yaml(path, "map")
    if not isinstance(doc, dict) or not isinstance(doc.get("bodies"), list):
        raise InputError(path, "not a TagSLAM tagslam.yaml (no 'bodies' list)")

    def pose(node: dict, what: str) -> tuple[np.ndarray, np.ndarray]:
        try:
            p = node["position"]
            r = node.get("rotation", node.get("rotvec", {"x": 0, "y": 0, "z": 0}))
            t = np.array([float(p[a]) for a in "xyz"])
            rv = np.array([float(r[a]) for a in "xyz"])
        except (KeyError, TypeError, ValueError, OverflowError):
            raise InputError(path, f"{what}: pose needs position and rotation x, y, z") from None
        return so3_exp(rv), t

    ids, xyz = [], []
    for entry in doc["bodies"]:
        if entry is not None and not isinstance(entry, dict):
            raise InputError(path, f"bodies: expected {{name: body}} entries, got {entry!r:.60}")
        for name, body in (entry or {}).items():
            if not isinstance(body, dict) or not body.get("is_static"):
                continue
            rot_b, t_b = (
                pose(body["pose"], f"body {name}") if isinstance(body.get("pose"), dict) else (np.eye(3), np.zeros(3))
            )
            tags = body.get("tags") or []
            if not isinstance(tags, list):
                raise InputError(path, f"body {name}: tags must be a list of {{id, size, pose}}, got {tags!r:.60}")
            for tag in tags:
                if isinstance(tag, dict) and isinstance(tag.get("pose"), dict):
                    _, t_t = pose(tag["pose"], f"tag {tag.get('id')}")
                    try:
                        ids.append(_landmark_id(tag.get("id")))
                    except ValueError as err:
                        raise InputError(path, f"body {name}: tag id {tag.get('id')!r:.30} is {err}") from None
                    xyz.append(rot_b @ t_t + t_b)
    return np.asarray(ids, np.int64), np.asarray(xyz, np.float64).reshape(-1, 3)


# --------------------------------------------------------------------------- a run against a known map


def restrict_to_map(aligned, known: KnownMap):
    """The aligned stream with only the detections of mapped landmarks (``fixed`` mode), and a note."""
    keep = np.isin(aligned.det_ids, known.ids)
    dropped = int(keep.size - np.count_nonzero(keep))
    if not dropped:
        return aligned, None
    unknown = sorted({int(i) for i in aligned.det_ids[~keep]})
    counts = np.bincount(
        np.repeat(np.arange(aligned.det_t_ns.shape[0]), np.diff(aligned.det_offsets))[keep],
        minlength=aligned.det_t_ns.shape[0],
    )
    ids = aligned.det_ids[keep]
    landmark_ids, det_idx = np.unique(ids, return_inverse=True)
    shown = ", ".join(map(str, unknown[:10])) + (f", ... ({len(unknown)} ids)" if len(unknown) > 10 else "")
    note = f"map (fixed): {dropped} detections of {len(unknown)} tags not in the map dropped ({shown})"
    return replace(
        aligned,
        det_offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        det_idx=det_idx.astype(np.int64),
        det_y=np.ascontiguousarray(aligned.det_y[keep]),
        landmark_ids=landmark_ids.astype(np.int64),
    ), note


@dataclass(frozen=True)
class MapStart:
    """What a known map gives the observer: initial landmark positions, which are fixed, and the start pose."""

    lm: np.ndarray  # (L, 4): x, y, z and the update weight (1 estimated, 0 fixed)
    lm_init: np.ndarray  # (L,) bool: position known from the map
    pose: tuple[np.ndarray, np.ndarray] | None  # (R0, P0) at the first velocity sample, None if no fit
    note: str


def map_start(aligned, known: KnownMap) -> MapStart:
    """Initial map and pose of a run on ``aligned`` against ``known`` (see the module docstring)."""
    row = np.searchsorted(known.ids, aligned.landmark_ids)
    row = np.minimum(row, known.ids.size - 1)
    mapped = known.ids[row] == aligned.landmark_ids
    lm = np.zeros((aligned.landmark_ids.shape[0], 4))
    lm[:, 3] = 1.0
    lm[mapped, :3] = known.xyz[row[mapped]]
    if known.fixed:
        lm[mapped, 3] = 0.0
    pose, how = _start_pose(aligned, lm[:, :3], mapped)
    note = (
        f"map ({known.mode}) {Path(known.source).name}: {int(mapped.sum())} of its {known.ids.size} landmarks "
        f"detected; {how}"
    )
    return MapStart(lm, mapped.copy(), pose, note)


def _start_pose(aligned, xyz: np.ndarray, mapped: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray] | None, str]:
    from slamobs.pipeline.lie import integrate_body_twists, umeyama

    offsets, idx = aligned.det_offsets, aligned.det_idx
    for f in range(aligned.det_t_ns.shape[0]):
        rows = np.arange(offsets[f], offsets[f + 1])
        rows = rows[mapped[idx[rows]]]
        if rows.size < 3:
            continue
        y = aligned.det_y[rows]
        p = xyz[idx[rows]]
        spread = np.linalg.svd(p - p.mean(axis=0), compute_uv=False)
        if spread.size < 2 or spread[1] / np.sqrt(rows.size) < MIN_SPREAD_M:
            continue
        try:
            rot_f, p_f, _ = umeyama(y, p)
        except ValueError:
            continue
        # carry the pose back to the first velocity sample: T0 = T_f D^-1, D = odometry from t0 to the frame
        t_f = aligned.det_t_ns[f]
        k = int(np.searchsorted(aligned.vel_t_ns, t_f, side="right"))
        t = aligned.seconds(np.append(aligned.vel_t_ns[:k], t_f))
        dt = np.diff(t)
        rs, ps = integrate_body_twists(
            np.eye(3),
            np.zeros(3),
            np.ascontiguousarray(aligned.omega[: dt.size]),
            np.ascontiguousarray(aligned.velocity[: dt.size]),
            dt,
        )
        rot0 = rot_f @ rs[-1].T
        p0 = p_f - rot0 @ ps[-1]
        at = (t_f - aligned.vel_t_ns[0]) * 1e-9
        return (rot0, p0), (
            f"start pose fitted to {rows.size} mapped landmarks at +{at:.2f} s and carried back with the odometry"
        )
    return None, "no frame sees 3 mapped landmarks apart: the observer starts at the map origin"
