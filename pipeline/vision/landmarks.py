"""Tag corners of every camera -> one landmark detection stream (tag centres in the camera frames).

Per camera topic: its camera model, then the PnP of every detection (:mod:`.tagpose`) with the size of its
tag; poor solutions are dropped and counted. The cameras of a rig then feed one
:class:`~pipeline.streams.DetectionStream` whose detections each name their camera frame, so the alignment
stage moves each into the body frame with its own extrinsic:

* Camera models: a ``CameraInfo`` topic of the camera (same frame id, else same namespace) is preferred; else a
  camera of the ``cameras:`` files declared for the topic (Kalibr ``rostopic``/``tagtopic``, the topic's
  namespace, or a ROS YAML ``camera_name`` equal to the frame id); a single remaining camera and topic are paired.
  Image topics named ``*rect*`` use the rectified model of a CameraInfo. A topic without a model is dropped
  (noted); none at all is an error.
* Extrinsics: TF, else the rig transforms of the files (Kalibr ``T_cn_cnm1``/``T_cam_imu``, TagSLAM camera
  poses and ``T_body_odom``), which are added as static transforms only where TF does not already connect the
  two frames; else ``frames.assume_identity``. A camera still not connected to the body frame is dropped (noted).
* Frames of different cameras closer in time than ``sync_s`` (default: a quarter of the fastest camera's frame
  period) become one frame at their mean stamp, so no camera's view replaces another's; a tag seen by several
  cameras in one frame keeps the sighting with the largest image area.

The tag orientation (tag -> camera) and the quality numbers of every detection go to the ``tag_detections``
table.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slamobs.pipeline.errors import InputError
from slamobs.pipeline.streams import CornerStream, DetectionStream, LogStreams, Transform
from slamobs.pipeline.vision.cameras import NAMED_IDS, CameraFiles, CameraModel, read_camera_files
from slamobs.pipeline.vision.distortion import distortion_fit, distortion_warning
from slamobs.pipeline.vision.tagpose import REASONS, TagQuality, solve_tags, winding


@dataclass(frozen=True)
class TagOptions:
    """The ``tags`` section of the config that concerns tag poses."""

    size: float | None = None  # m, edge of the black square; the default for every id
    sizes: dict[int, float] = field(default_factory=dict)  # per id
    quality: TagQuality = TagQuality()
    ignore: frozenset[int] = frozenset()
    sync_s: float | None = None  # None: a quarter of the fastest camera's frame period


@dataclass
class TagLandmarks:
    """The detection stream made of tag corners, the per-detection table, added transforms and notes."""

    detections: DetectionStream
    table: dict[str, np.ndarray]
    transforms: list[Transform]
    notes: list[str]
    cameras: dict[str, str]  # topic -> camera model and extrinsic, for run.json
    #: topic -> the distortion check's record (:mod:`.distortion`; run.json ``input.distortion_check``)
    distortion: dict[str, dict] = field(default_factory=dict)


def _namespace(topic: str) -> str:
    return topic.rstrip("/").rsplit("/", 1)[0]


def _in_namespace(topic: str, ns: str) -> bool:
    return bool(ns) and ns != "/" and topic.startswith(ns.rstrip("/") + "/")


def _match_models(
    streams: list[CornerStream], infos: list[CameraModel], files: CameraFiles, notes: list[str]
) -> dict[str, CameraModel]:
    """Camera model of each corner stream topic (see the module docstring for the order of the rules)."""
    found: dict[str, CameraModel] = {}
    used_files: set[str] = set()
    for s in streams:
        frame = s.frame_id.lstrip("/")
        cands = [m for m in infos if frame and m.frame == frame] or [
            m for m in infos if _in_namespace(s.topic, _namespace(m.name))
        ]
        if cands:
            cands.sort(key=lambda m: (not _in_namespace(s.topic, _namespace(m.name)), m.name))
            found[s.topic] = cands[0]
            continue
        decl = [
            m
            for m in files.models
            if any(
                s.topic == t or s.topic.startswith(t.rstrip("/") + "/") or _namespace(s.topic) == _namespace(t)
                for t in m.topics
            )
        ]
        decl = decl or [m for m in files.models if m.frame and m.frame == frame]
        if decl:
            found[s.topic] = decl[0]
            used_files.add(decl[0].name)
    rest = [s for s in streams if s.topic not in found]
    free = [m for m in files.models if m.name not in used_files]
    if len(rest) == 1 and len(free) == 1:
        found[rest[0].topic] = free[0]
        notes.append(
            f"{rest[0].topic}: the only camera without a model, paired with {free[0].source}, the only "
            "camera file entry left"
        )
    for s in streams:  # tags found in rectified images: the rectified model (P, no distortion)
        model = found.get(s.topic)
        if model is not None and s.source == "images" and "rect" in s.topic:
            found[s.topic] = model.rectified()
    return found


def _frame_of_end(end: tuple[str, str], camera_frames: dict[str, str], imu_frame: str) -> str:
    kind, name = end
    if kind == "camera":
        return camera_frames.get(name, name)
    if kind == "imu":
        return imu_frame
    return name.lstrip("/")


def _rig_transforms(
    files: CameraFiles, camera_frames: dict[str, str], imu_frame: str, tf, notes: list[str]
) -> list[Transform]:
    """The files' rig transforms as static transforms, where TF does not connect the two frames already."""
    from slamobs.pipeline.lie import rots_to_quats

    out = []
    for rt in files.transforms:
        parent = _frame_of_end(rt.parent, camera_frames, imu_frame)
        child = _frame_of_end(rt.child, camera_frames, imu_frame)
        if not parent or not child:
            notes.append(f"{rt.source}: no IMU frame in the log (angular velocity from an Imu), not used")
            continue
        if parent == child:
            continue
        if tf.chain(parent, child) is not None:
            notes.append(f"{rt.source}: {parent} -> {child} taken from TF, not from the file")
            continue
        quat = rots_to_quats(np.ascontiguousarray(rt.rot[None]))[0]
        out.append(Transform(parent, child, np.asarray(rt.trans, dtype=np.float64), quat))
        notes.append(f"extrinsic {parent} -> {child} from {rt.source}")
    return out


def _sizes(ids: np.ndarray, options: TagOptions, topic: str, path: str, stated: Sequence[str] = ()) -> np.ndarray:
    """Each detection's tag edge (m; NaN for an id without one); an InputError when no id has one, naming what
    the ``cameras:`` files state (``stated``: a tagslam.yaml's sizes, :attr:`.CameraFiles.stated_tag_sizes`)."""
    sizes = np.array([options.sizes.get(int(i), options.size or np.nan) for i in ids], dtype=np.float64)
    if ids.size and np.isnan(sizes).all() and options.size is None:
        said = f"; the cameras: files say: {'; '.join(stated)} (set them if they are this log's tags)" if stated else ""
        raise InputError(
            path,
            "tag corners need the tag size (edge of the black square, m): set tags.size "
            f"(or tags.sizes per id) in the config{said}",
            topic,
        )
    return sizes


def _area(corners: np.ndarray) -> np.ndarray:
    return 0.5 * np.abs(winding(corners))


def _groups(t_ns: np.ndarray, cam: np.ndarray, sync_ns: int) -> np.ndarray:
    """Group index of each frame (sorted by stamp): frames of different cameras within ``sync_ns`` of the first
    frame of a group join it."""
    group = np.empty(t_ns.shape[0], np.int64)
    g = -1
    start = 0
    members: set[int] = set()
    for k in range(t_ns.shape[0]):
        if g < 0 or t_ns[k] - start > sync_ns or int(cam[k]) in members:
            g += 1
            start = int(t_ns[k])
            members = set()
        members.add(int(cam[k]))
        group[k] = g
    return group


def tag_landmarks(
    streams: LogStreams,
    options: TagOptions,
    *,
    camera_files: list[str | Path] = (),
    identity_frames: tuple[str, ...] = (),
    body_frame: str | None = None,
) -> TagLandmarks:
    """The landmark detections of the tag corner streams of ``streams`` (see the module docstring).

    Raises:
        InputError: No camera model or no extrinsic for any camera, no tag size, or no detection left.

    """
    path = streams.path
    notes: list[str] = []
    files = read_camera_files(list(camera_files)) if camera_files else CameraFiles()
    notes += files.notes
    unsized = options.size is None and not options.sizes  # said with the intrinsics: one round trip, not two
    models, corner_streams = _with_intrinsics(streams, files, notes, "; and tags.size (edge, m)" if unsized else "")
    kept, added = _with_extrinsics(streams, corner_streams, models, files, identity_frames, body_frame, notes)
    rows = []  # per camera: frame stamps, record times, offsets, ids, xyz, quat, quality, status, area
    cameras_meta, checks, warnings = {}, {}, []
    reject = np.zeros(len(REASONS), np.int64)
    ignored = unsized = 0
    for c, s in enumerate(kept):
        model = models[s.topic]
        row, n_ignored, n_unsized, fit = _camera_poses(c, s, model, options, path, files.stated_tag_sizes)
        rows.append(row)
        reject += np.bincount(row[4].status, minlength=len(REASONS))  # row[4]: the tag poses
        ignored, unsized = ignored + n_ignored, unsized + n_unsized
        cameras_meta[s.topic] = f"{model.describe()}; frame '{s.frame_id}'"
        notes.append(f"{s.topic}: camera {model.describe()}")
        if fit is not None:
            checks[s.topic] = fit.record()
            warnings += [distortion_warning(s.topic, s.frame_id, model, fit)] if fit.wrong else []
    notes += _pose_notes(reject, ignored, unsized, options)
    notes += _size_against_stated(
        np.concatenate([s.ids for s in kept]) if kept else np.empty(0, np.int64), options, files
    )
    table = _table(rows)
    stream, merge_notes = _merge(rows, options.sync_s)
    notes += merge_notes + warnings
    return TagLandmarks(stream, table, added, notes, cameras_meta, checks)


def _with_intrinsics(streams: LogStreams, files: CameraFiles, notes: list[str], also: str = ""):
    """The camera model of each corner stream and the streams that have one (the others noted as dropped).

    Raises:
        InputError: No stream has a camera model.

    """
    corner_streams = list(streams.tag_corners)
    models = _match_models(corner_streams, streams.camera_info, files, notes)
    missing = [s.topic for s in corner_streams if s.topic not in models]
    if missing and len(missing) == len(corner_streams):
        have = ", ".join(m.source for m in streams.camera_info) or "no CameraInfo topic"
        raise InputError(
            streams.path,
            f"no camera intrinsics for {', '.join(missing)} (the log has {have}); name a "
            f"Kalibr or ROS camera_info YAML file in the config (cameras: FILE){also}",
            missing[0],
        )
    for topic in missing:
        notes.append(f"{topic}: no camera intrinsics (CameraInfo or cameras: file), its detections dropped")
    for s in corner_streams:
        if s.topic in models:
            models[s.topic] = _fit_to_images(s, models[s.topic], notes)
    return models, [s for s in corner_streams if s.topic in models]


#: A principal point is "near the centre" of an image when it lies within this share of the width and of the height
#: of the centre (calibrated lenses: a few per cent; one for an image twice or half as large sits at a quarter or
#: on the edge, a share of 0.25 or 0.5 off).
CENTRE_SHARE = 0.15


#: Tag corners of a detector's messages are "outside" the image a camera model gives when they lie more than this
#: share of its width or height beyond its edge (TagSLAM's detectors: up to 0.026 of 1024 px in test_11, 0.047 of 171
#: px in test_21's ToF cameras: corners of tags cut by the edge); named when ``OUTSIDE_MIN`` detections and
#: ``OUTSIDE_SHARE`` of them have one (a calibration for 2x binned images under full-size ones: every corner off the
#: middle half of the image).
OUTSIDE_MARGIN = 0.1
OUTSIDE_MIN = 5
OUTSIDE_SHARE = 0.01


def _corners_outside(stream: CornerStream, model: CameraModel) -> list[str]:
    """The warning of tag corners (a detector's messages) outside the image ``model`` gives (``OUTSIDE_MARGIN``):
    the calibration of another resolution than the detector's images; none where they fit or no size is given."""
    if model.size is None or not stream.ids.shape[0]:
        return []
    size = np.asarray(model.size, dtype=np.float64)
    out = np.any(
        (stream.corners < -OUTSIDE_MARGIN * size) | (stream.corners > (1.0 + OUTSIDE_MARGIN) * size), axis=(1, 2)
    )
    n = int(np.count_nonzero(out))
    if n < max(OUTSIDE_MIN, OUTSIDE_SHARE * out.shape[0]):
        return []
    reach = np.max(stream.corners.reshape(-1, 2), axis=0)
    return [
        f"warning: {stream.topic}: {n} of its {out.shape[0]} tag detections have corners outside the "
        f"{model.size[0]}x{model.size[1]} px image {model.source} gives (reaching ({reach[0]:.0f}, {reach[1]:.0f}) "
        "px): a calibration of smaller images than the detector's (a binned or scaled camera), so every tag's range "
        "comes out scaled by the ratio; used as read: give the calibration of the detector's images (cameras: FILE, "
        "with topics.camera_info: '' where the log's CameraInfo gives this one)"
    ]


def _fit_to_images(stream: CornerStream, model: CameraModel, notes: list[str]) -> CameraModel:
    """``model`` for the images the tags of ``stream`` were found in, where its image size is not theirs: scaled
    to them when its principal point is near the centre of its own size and not of theirs, both sides scaled alike
    (a camera calibrated at another resolution: K for 2x binned images under full-size ones put every tag at twice
    its range, riekf 8.3 m off on the camera sample, with only a velocity-scale warning); said in ``notes``. A
    detector's corners (no image size) are held against the model's size instead (:func:`_corners_outside`)."""
    if stream.image_size is None:
        notes += _corners_outside(stream, model)
        return model
    if model.size is None or tuple(stream.image_size) == tuple(model.size):
        return model
    (w, h), (mw, mh) = stream.image_size, model.size
    cx, cy = float(model.k[0, 2]), float(model.k[1, 2])

    def central(width: int, height: int) -> bool:
        return abs(cx / width - 0.5) <= CENTRE_SHARE and abs(cy / height - 0.5) <= CENTRE_SHARE

    said = (
        f"{stream.topic}: its images are {w}x{h} px where {model.source} gives {mw}x{mh} px, with its principal "
        f"point at ({cx:.1f}, {cy:.1f}) px"
    )
    if central(w, h):
        notes.append(f"{said}, near the images' centre: its intrinsics taken as the images' (its size fields wrong)")
        return model
    sx, sy = w / mw, h / mh
    if central(mw, mh) and abs(sx / sy - 1.0) <= 0.01:
        notes.append(
            f"warning: {said}, near the centre of its own size, not of the images': a calibration of the camera at "
            f"another resolution; its focal lengths and principal point scaled by {sx:.4g} to the images' (taken "
            f"as read, every tag's range would be {1 / sx:.4g} times the true one); if the images are cropped, not "
            "scaled, give their calibration (topics.camera_info: '' and cameras: FILE)"
        )
        return model.resized(w, h)
    notes.append(
        f"warning: {said}, near the centre of neither: its intrinsics used as read, so the tags' ranges and "
        "bearings may be off; give the calibration of these images (topics.camera_info: '' and cameras: FILE)"
    )
    return model


#: the camera files that place cameras on the rig, as the errors and notes about a missing extrinsic name them
EXTRINSIC_FILES = (
    "a Kalibr chain's T_cn_cnm1 and T_cam_imu, TagSLAM's camera_poses.yaml and tagslam.yaml with its T_body_odom"
)


def _with_extrinsics(
    streams: LogStreams,
    corner_streams: list[CornerStream],
    models: dict[str, CameraModel],
    files: CameraFiles,
    identity_frames: tuple[str, ...],
    body_frame: str | None,
    notes: list[str],
):
    """The corner streams with a camera-to-body transform and the rig transforms added from the camera files.

    Extrinsics come from TF, else the files' rig transforms, else ``frames.assume_identity``; with one camera
    the stream is kept regardless (the alignment stage reports the missing transform).

    Raises:
        InputError: No camera has a transform to the body frame.

    """
    from slamobs.pipeline.alignment import body_frame_name
    from slamobs.pipeline.frames import TfBuffer

    path = streams.path
    camera_frames = {m.name: s.frame_id.lstrip("/") for s in corner_streams if (m := models[s.topic]) in files.models}
    imu = (
        streams.angular_velocity.frame_id
        if streams.angular_velocity is not None
        and streams.accel is not None
        and streams.accel.topic == streams.angular_velocity.topic
        else ""
    )
    tf = TfBuffer(streams.static_tf, streams.tf, path=path)
    added = _rig_transforms(files, camera_frames, imu.lstrip("/"), tf, notes)
    tf = TfBuffer([*streams.static_tf, *added], streams.tf, path=path)
    body = body_frame_name(streams.linear_velocity, body_frame)
    ident = {f.lstrip("/") for f in identity_frames}
    kept = []
    for s in corner_streams:
        frame = s.frame_id.lstrip("/")
        if frame == body or frame in ident or tf.chain(body, frame) is not None:
            kept.append(s)
        elif len(corner_streams) > 1:
            share = 100.0 * s.ids.shape[0] / max(sum(c.ids.shape[0] for c in corner_streams), 1)
            notes.append(
                f"warning: {s.topic}: no transform from camera frame '{frame}' to body frame '{body}' "
                f"({tf.explain(body, frame)}), its {s.ids.shape[0]} detections ({share:.0f} % of the cameras') "
                "dropped; give its extrinsic on /tf or in the "
                f"config's cameras: files ({EXTRINSIC_FILES}), or list '{frame}' in frames.assume_identity"
            )
        else:
            kept.append(s)  # one camera: the alignment stage reports the missing transform
    if not kept:
        raise InputError(path, _no_extrinsics(corner_streams, body, tf))
    return kept, added


def _no_extrinsics(corner_streams: list[CornerStream], body: str, tf) -> str:
    """The error of a rig none of whose cameras has a transform to the body: the frames, why (the first camera's
    chain), and where each way of giving them goes (TagSLAM test_21 with ``cameras: cameras.yaml`` and then with
    ``camera_poses.yaml`` too said only "(TF, Kalibr chain, TagSLAM camera poses)", twice)."""
    frames = [s.frame_id.lstrip("/") for s in corner_streams]
    reasons = [tf.explain(body, f) for f in frames]  # a placed camera's, when one is: it shows what is left
    why = next((r for f, r in zip(frames, reasons) if not r.startswith(f"'{f}' is in no transform")), reasons[0])
    return (
        f"no camera has a transform to the body frame '{body}' ({why}); give the "
        f"extrinsics on /tf or in the config's cameras: files ({EXTRINSIC_FILES}), or list the camera frames in "
        f"frames.assume_identity: [{', '.join(frames)}]"
    )


def _camera_poses(
    c: int, s: CornerStream, model: CameraModel, options: TagOptions, path: str, stated: Sequence[str] = ()
) -> tuple:
    """Camera ``c``'s row for ``_table``/``_merge`` (its tag poses), the counts of ignored and unsized
    detections, which are left out before solving, and its distortion check (:func:`.distortion.distortion_fit`,
    on the detections kept; None with too few pairs of tags in one image)."""
    keep = np.ones(s.ids.shape[0], bool)
    ignored = 0
    if options.ignore:
        drop = np.isin(s.ids, list(options.ignore))
        ignored = int(np.count_nonzero(drop))
        keep &= ~drop
    sizes = _sizes(s.ids, options, s.topic, path, stated)
    no_size = ~np.isfinite(sizes) & keep
    unsized = int(np.count_nonzero(no_size))
    keep &= ~no_size
    ideal = model.undistort(s.corners.reshape(-1, 2)).reshape(-1, 4, 2)
    poses = solve_tags(ideal[keep], sizes[keep], model.k, options.quality)
    frame_of = np.repeat(np.arange(len(s)), np.diff(s.offsets))[keep]
    ok = poses.ok
    fit = distortion_fit(ideal[keep][ok], model.k, sizes[keep][ok], frame_of[ok], s.ids[keep][ok])
    return (c, s, frame_of, s.ids[keep], poses, _area(s.corners[keep])), ignored, unsized, fit


def _size_against_stated(ids: np.ndarray, options: TagOptions, files: CameraFiles) -> list[str]:
    """The warning where the edge a run gives detected tags (``tags.sizes``, else ``tags.size``) is not the one a
    tagslam.yaml in ``cameras:`` states for them (:attr:`.CameraFiles.tag_sizes`; test_21's ``tags.size: 0.16``
    over its tags 100-108 of 0.1 m): a PnP range scales with the edge, so each of their ranges comes out
    given/stated times the true one, silently; the file's sizes are said, not taken (they may be another
    recording's). Ignored tags and tags without a size are left out (they are not solved)."""
    ids, counts = np.unique(ids[~np.isin(ids, list(options.ignore))], return_counts=True)
    off: dict[tuple[float, float, str, str], list[tuple[int, int]]] = {}
    for i, n in zip(ids.tolist(), counts.tolist()):
        given, key = (options.sizes[i], "tags.sizes") if i in options.sizes else (options.size, "tags.size")
        stated = files.tag_sizes.get(i)
        if given is not None and stated is not None and not np.isclose(given, stated[0], rtol=1e-6, atol=0.0):
            off.setdefault((stated[0], given, key, stated[1]), []).append((i, n))
    out = []
    for (stated, given, key, name), tags in sorted(off.items()):
        listed = ", ".join(str(i) for i, _ in tags[:NAMED_IDS])
        more = f" and {len(tags) - NAMED_IDS} more" if len(tags) > NAMED_IDS else ""
        setting = ", ".join(f"{i}: {stated:g}" for i, _ in tags[:NAMED_IDS]) + (", ..." if more else "")
        out.append(
            f"warning: {name} states {stated:g} m for tag{'s' if len(tags) > 1 else ''} {listed}{more} "
            f"({sum(n for _, n in tags)} detections), the run gave them {given:g} m ({key}): each of "
            f"their ranges is {given / stated:.3g}x what {stated:g} m gives, and the map and poses that use them "
            f"follow; if {name} is this log's, set tags.sizes: {{{setting}}}"
        )
    return out


def _pose_notes(reject: np.ndarray, ignored: int, unsized: int, options: TagOptions) -> list[str]:
    """What the tag-pose stage kept and why it dropped the rest, counted over every camera."""
    total = int(reject.sum())
    text = f"tag poses: {total - int(reject[1:].sum())} of {total} detections kept"
    if reject[1:].any():
        text += "; rejected: " + ", ".join(
            f"{options.quality.describe(r)} {int(reject[r])}" for r in range(1, len(REASONS)) if reject[r]
        )
    notes = [text]
    if ignored:
        notes.append(f"{ignored} detections of ignored tags (tags.ignore) dropped")
    if unsized:
        notes.append(f"{unsized} detections of tags without a size (tags.sizes, no tags.size) dropped")
    return notes


def _table(rows) -> dict[str, np.ndarray]:
    """The ``tag_detections`` table: every detection with its pose in the camera frame and its verdict."""
    cols: dict[str, list[np.ndarray]] = {
        k: []
        for k in (
            "t_ns",
            "camera",
            "id",
            "x",
            "y",
            "z",
            "qx",
            "qy",
            "qz",
            "qw",
            "reprojection_px",
            "ambiguity",
            "view_angle_deg",
            "status",
        )
    }
    for _, s, frame_of, ids, poses, _ in rows:
        cols["t_ns"].append(s.t_ns[frame_of])
        cols["camera"].append(np.full(ids.shape[0], s.topic, dtype=object))
        cols["id"].append(ids)
        for a, name in enumerate("xyz"):
            cols[name].append(poses.xyz[:, a])
        for a, name in enumerate(("qx", "qy", "qz", "qw")):
            cols[name].append(poses.quat_xyzw[:, a])
        cols["reprojection_px"].append(poses.reprojection_px)
        cols["ambiguity"].append(poses.ambiguity)
        cols["view_angle_deg"].append(poses.view_angle_deg)
        cols["status"].append(np.array(REASONS, dtype=object)[poses.status])
    out = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
    order = np.argsort(out["t_ns"], kind="stable")
    return {k: v[order] for k, v in out.items()}


def _merge(rows, sync_s: float | None) -> tuple[DetectionStream, list[str]]:
    """One detection stream of every camera's kept detections (see the module docstring)."""
    notes = []
    streams = [s for _, s, *_ in rows]
    topic = ", ".join(s.topic for s in streams)
    cams = tuple(s.frame_id.lstrip("/") for s in streams)
    f_t = np.concatenate([s.t_ns for s in streams])
    f_rec = np.concatenate([s.rec_ns for s in streams])
    f_cam = np.concatenate([np.full(len(s), c) for c, s in enumerate(streams)])
    f_base = np.cumsum([0] + [len(s) for s in streams])
    det_frame = np.concatenate([f_base[c] + frame_of[p.ok] for c, (_, _, frame_of, _, p, _) in enumerate(rows)])
    det_cam = np.concatenate([np.full(int(np.count_nonzero(p.ok)), c) for c, (_, _, _, _, p, _) in enumerate(rows)])
    det_id = np.concatenate([ids[p.ok] for _, _, _, ids, p, _ in rows])
    det_xyz = np.concatenate([p.xyz[p.ok] for *_, p, _ in rows]).reshape(-1, 3)
    det_area = np.concatenate([area[p.ok] for *_, p, area in rows])
    order = np.argsort(f_t, kind="stable")
    if len(streams) > 1:
        periods = [np.median(np.diff(s.t_ns)) for s in streams if len(s) > 1]
        sync = sync_s if sync_s is not None else (0.25e-9 * min(periods) if periods else 0.0)
        group_sorted = _groups(f_t[order], f_cam[order], int(round(sync * 1e9)))
    else:
        sync = 0.0
        group_sorted = np.arange(order.shape[0])
    group = np.empty_like(group_sorted)
    group[order] = group_sorted
    n_groups = int(group_sorted[-1]) + 1 if group_sorted.size else 0
    g_count = np.bincount(group, minlength=n_groups)
    g_t = (np.bincount(group, weights=f_t - f_t.min(), minlength=n_groups) / np.maximum(g_count, 1)).round()
    g_t = (g_t + (f_t.min() if f_t.size else 0)).astype(np.int64)
    g_rec = np.full(n_groups, np.iinfo(np.int64).min, np.int64)
    np.maximum.at(g_rec, group, f_rec)
    if len(streams) > 1 and (merged := int(np.count_nonzero(g_count > 1))):
        notes.append(
            f"{merged} frames of {len(streams)} cameras taken together (stamps within {1e3 * sync:.1f} ms; tags.sync_s)"
        )
    # detections: by group, then id; one sighting per id and group (the largest image area)
    det_group = group[det_frame]
    order_det = np.lexsort((-det_area, det_id, det_group))
    first = np.ones(order_det.shape[0], bool)
    first[1:] = (det_group[order_det][1:] != det_group[order_det][:-1]) | (
        det_id[order_det][1:] != det_id[order_det][:-1]
    )
    if n_dup := int(np.count_nonzero(~first)):
        notes.append(f"{n_dup} sightings of a tag by several cameras in one frame: the largest in the image kept")
    sel = order_det[first]
    counts = np.bincount(det_group[sel], minlength=n_groups)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    multi = len(streams) > 1
    stream = DetectionStream(
        topic,
        cams[0],
        g_t,
        g_rec,
        offsets,
        det_id[sel].astype(np.int64),
        np.ascontiguousarray(det_xyz[sel]),
        cams if multi else (),
        det_cam[sel].astype(np.int64) if multi else None,
    )
    return stream, notes
