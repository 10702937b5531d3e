"""Tag corners and camera images -> landmarks: camera models, corner order, PnP and its rejections, image
detection accuracy against rendered truth, several cameras in one stream, and corner and image logs end to end."""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

pytest.importorskip("cv2")  # the vision extra; `.[test]` installs it, so CI runs these

from slamobs.pipeline.config import parse_config
from slamobs.pipeline.errors import InputError
from slamobs.pipeline.lie import quat_to_rot, so3_exp
from slamobs.pipeline.readers import read_log
from slamobs.pipeline.readers.cameradecode import to_opencv_order
from slamobs.pipeline.run import run_log
from slamobs.pipeline.simulate import simulation, write_log
from slamobs.pipeline.simulate.camera import CameraSim, TagRenderer, tag_views
from slamobs.pipeline.simulate.scenarios import get_scenario
from slamobs.pipeline.streams import CornerStream, LogStreams, Transform, Vec3Stream
from slamobs.pipeline.vision.cameras import CameraModel, distortion_model, read_camera_files
from slamobs.pipeline.vision.detector import TagDetector, family_constant
from slamobs.pipeline.vision.landmarks import TagOptions, tag_landmarks
from slamobs.pipeline.vision.tagpose import (
    AMBIGUOUS,
    GRAZING,
    OK,
    REPROJECTION,
    TOO_SMALL,
    TagQuality,
    solve_tags,
    winding,
)

FACING = np.diag([1.0, -1.0, -1.0])  # tag x right, y up, z towards a camera looking along +z


# --------------------------------------------------------------------------- camera models


KALIBR = """\
cam0:
  camera_model: pinhole
  intrinsics: [603.9, 603.2, 665.0, 554.3]
  distortion_model: equidistant
  distortion_coeffs: [-0.0123, -0.0100, 0.0075, -0.0025]
  resolution: [1280, 1024]
  rostopic: /left/image_raw
  T_cam_imu:
  - [0, -1, 0, 0.01]
  - [0, 0, -1, 0.02]
  - [1, 0, 0, 0.03]
  - [0, 0, 0, 1]
cam1:
  camera_model: pinhole
  intrinsics: [604.5, 604.0, 648.5, 440.3]
  distortion_model: radtan
  distortion_coeffs: [-0.28, 0.07, 0.0002, 0.0001]
  resolution: [1280, 1024]
  rostopic: /right/image_raw
  T_cn_cnm1:
  - [1, 0, 0, -0.2]
  - [0, 1, 0, 0]
  - [0, 0, 1, 0]
  - [0, 0, 0, 1]
"""

ROS_YAML = """\
image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix: {rows: 3, cols: 3, data: [500.0, 0, 320.5, 0, 501.0, 240.5, 0, 0, 1]}
distortion_model: plumb_bob
distortion_coefficients: {rows: 1, cols: 5, data: [-0.1, 0.02, 0.001, -0.001, 0.0]}
projection_matrix: {rows: 3, cols: 4, data: [480.0, 0, 322.0, 0, 0, 481.0, 241.0, 0, 0, 0, 1, 0]}
"""

POSES = """\
cam0:
  pose:
    position: {x: 0.1, y: 0, z: 0}
    rotation: {x: 0, y: 0, z: 1.5707963}
"""

TAGSLAM = """\
bodies:
 - world:
     is_static: true
     pose: {position: {x: 0, y: 0, z: 1}, rotation: {x: 0, y: 0, z: 0}}
     tags:
       - {id: 4, size: 0.2, pose: {position: {x: 1, y: 2, z: 3}, rotation: {x: 0, y: 0, z: 0}}}
       - {id: 9, size: 0.2}
 - rig:
     is_static: false
     odom_frame_id: odom
     T_body_odom: {position: {x: 0.5, y: 0, z: 0}, rotation: {x: 0, y: 0, z: 3.14159265}}
"""


def test_camera_files(tmp_path):
    (tmp_path / "kalibr.yaml").write_text(KALIBR)
    (tmp_path / "info.yaml").write_text(ROS_YAML)
    (tmp_path / "poses.yaml").write_text(POSES)
    (tmp_path / "tagslam.yaml").write_text(TAGSLAM)
    files = read_camera_files([tmp_path / n for n in ("kalibr.yaml", "info.yaml", "poses.yaml", "tagslam.yaml")])
    models = {m.name: m for m in files.models}
    assert [models["cam0"].model, models["cam1"].model, models["narrow_stereo"].model] == [
        "equidistant",
        "radtan",
        "radtan",
    ]
    assert models["cam0"].topics == ("/left/image_raw",) and models["cam1"].size == (1280, 1024)
    assert models["narrow_stereo"].k[1, 1] == 501.0 and models["narrow_stereo"].rectified().k[0, 0] == 480.0
    # the run's note and run.json give the model with units (was 'f=(283.9, 285.0) c=(421.1, 400.5)')
    assert models["cam1"].describe().startswith("radtan 1280x1024 px, f=(")
    assert " px, c=(" in models["cam1"].describe() and models["cam1"].describe().endswith(
        " px, from kalibr.yaml (cam1)"
    )
    ends = {(t.parent, t.child): t for t in files.transforms}
    chain = ends[("camera", "cam0"), ("camera", "cam1")]  # x_cam0 = T_c1_c0^-1 x_cam1
    np.testing.assert_allclose(chain.trans, [0.2, 0, 0])
    imu = ends[("imu", ""), ("camera", "cam0")]  # x_imu = T_cam_imu^-1 x_cam: the optical axis is imu x
    np.testing.assert_allclose(imu.rot @ [0, 0, 1.0], [1, 0, 0], atol=1e-12)
    pose = ends[("frame", "rig"), ("camera", "cam0")]  # TagSLAM camera pose in the rig (rotation vector)
    np.testing.assert_allclose(pose.rot @ [1.0, 0, 0], [0, 1, 0], atol=1e-7)
    odom = ends[("frame", "rig"), ("frame", "odom")]  # T_body_odom: x_rig = T x_odom
    np.testing.assert_allclose(odom.trans, [0.5, 0, 0])
    # undistort inverts project for both lens models
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-0.8, 0.8, (50, 2)), np.ones(50)]) * rng.uniform(1, 5, (50, 1))
    for model in (models["cam0"], models["cam1"]):
        px = model.project(pts)
        ideal = pts[:, :2] / pts[:, 2:] * model.k[[0, 1], [0, 1]] + model.k[[0, 1], [2, 2]]
        np.testing.assert_allclose(model.undistort(px), ideal, atol=1e-6)


def test_zero_coefficients_are_the_ideal_lens_of_their_model(tmp_path):
    """All-zero coefficients: a radtan (plumb_bob) lens is the pinhole r = f tan θ, an equidistant (fisheye) one
    the ideal fisheye r = f θ (OpenCV's cv2.fisheye with zeros), not a pinhole; 60 deg off the axis they are
    0.55 f apart."""
    (tmp_path / "c.yaml").write_text(
        "cam0: {intrinsics: [500, 500, 320, 240], distortion_model: equidistant, distortion_coeffs: [0, 0, 0, 0]}\n"
        "cam1: {intrinsics: [500, 500, 320, 240], distortion_model: radtan, distortion_coeffs: [0, 0, 0, 0]}\n"
    )
    fisheye, pinhole = read_camera_files([tmp_path / "c.yaml"]).models
    assert (fisheye.model, pinhole.model) == ("equidistant", "none")
    # a CameraInfo's plumb_bob with an empty D is no distortion (image_geometry's reading), not refused
    assert distortion_model("plumb_bob", np.zeros(0), "CameraInfo on /cam/camera_info", "x.bag") == "none"
    ray = np.array([[np.sin(np.radians(60.0)), 0.0, np.cos(np.radians(60.0))]])
    np.testing.assert_allclose(fisheye.project(ray)[0] - [320, 240], [500 * np.radians(60.0), 0], atol=1e-6)
    np.testing.assert_allclose(pinhole.project(ray)[0] - [320, 240], [500 * np.tan(np.radians(60.0)), 0], atol=1e-6)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("cam0: {camera_model: omni, intrinsics: [1, 1, 1, 1]}", "camera model 'omni' is not supported"),
        (
            "cam0: {intrinsics: [500, 500, 1, 1], distortion_model: equidistant, distortion_coeffs: [0.1, 0.2]}",
            "equidistant distortion needs 4 coefficients, got 2",
        ),
        (
            "cam0: {intrinsics: [500, 500, 1, 1], distortion_model: fov, distortion_coeffs: [0.1]}",
            "distortion model 'fov' is not supported",
        ),
        ("cam0: {intrinsics: [0, 0, 1, 1]}", "no usable focal length"),
        ("something: else", "not a camera file"),
    ],
)
def test_bad_camera_files(tmp_path, text, match):
    (tmp_path / "c.yaml").write_text(text)
    with pytest.raises(InputError, match=match) as err:
        read_camera_files([tmp_path / "c.yaml"])
    assert str(tmp_path / "c.yaml") in str(err.value) and "\n" not in str(err.value)


def test_missing_opencv_names_the_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "cv2", None)  # import cv2 raises ImportError
    with pytest.raises(InputError, match=r"pip install 'slamobs\[vision\]'"):
        TagDetector("36h11", path="log.bag")


def test_config_tags_cameras_and_map(tmp_path):
    cfg = tmp_path / "run.yaml"
    cfg.write_text(
        "cameras: cams/kalibr.yaml\ntags: {size: 0.15, sizes: {7: 0.1}, family: tag25h9}\n"
        "map: maps/m.csv\ntopics: {detections: [/a/tags, /b/tags]}\n"
    )
    from slamobs.pipeline.config import load_config

    c = load_config(cfg)
    assert c.cameras == (str((tmp_path / "cams/kalibr.yaml").resolve()),)
    assert c.map.file == str((tmp_path / "maps/m.csv").resolve()) and c.map.mode == "fixed"
    assert c.tags.options().sizes == {7: 0.1} and c.topics["detections"] == ["/a/tags", "/b/tags"]
    assert family_constant(c.tags.family) == "DICT_APRILTAG_25h9"
    with pytest.raises(InputError, match="unknown tag family 'tag99h1'"):
        family_constant("tag99h1")
    with pytest.raises(InputError, match="invalid config at map.mode"):
        parse_config({"map": {"file": "m.csv", "mode": "loose"}})


# --------------------------------------------------------------------------- corners and PnP


def test_corner_order_and_mirrored_detections():
    square = np.array([[[10.0, 10.0], [20.0, 10.0], [20.0, 20.0], [10.0, 20.0]]])  # OpenCV order: clockwise
    assert winding(square)[0] > 0
    apriltag = square[:, [3, 2, 1, 0]]  # bottom-left first, counter-clockwise in the image
    out, mirrored = to_opencv_order(apriltag, (3, 2, 1, 0))
    np.testing.assert_array_equal(out, square) and mirrored == 0
    out, mirrored = to_opencv_order(square, (3, 2, 1, 0))  # the wrong convention: wound the other way
    assert mirrored == 1 and winding(out)[0] > 0


def _project(model: CameraModel, size: float, rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    from slamobs.pipeline.vision.tagpose import model_corners

    return model.project(model_corners(size) @ rot.T + trans)


def test_pnp_and_rejections():
    model = CameraSim().model()
    quality = TagQuality(min_view_angle_deg=30.0)
    cases = {  # name -> (rotation, position, corner perturbation)
        "good": (FACING @ so3_exp(np.array([0.3, 0.2, 0.1])), np.array([0.4, -0.2, 3.0]), 0.0),
        "turned": (FACING @ so3_exp(np.array([0.0, 0.6, 0.0])), np.array([0.1, 0.0, 3.0]), 0.0),  # IPPE fails
        "grazing": (FACING @ so3_exp(np.array([0.0, 1.2, 0.0])), np.array([0.0, 0.0, 3.0]), 0.0),  # 21 deg
        "bent": (FACING, np.array([0.0, 0.3, 3.0]), 12.0),
        "small": (FACING, np.array([0.0, 0.0, 30.0]), 0.0),
    }
    corners = []
    for rot, trans, bend in cases.values():
        px = _project(model, 0.5, rot, trans)
        px[0] += bend
        corners.append(model.undistort(px))
    poses = solve_tags(np.array(corners), np.full(5, 0.5), model.k, quality)
    assert poses.status.tolist() == [OK, OK, GRAZING, REPROJECTION, TOO_SMALL]
    for k, name in enumerate(("good", "turned")):  # exact corners: the exact pose
        np.testing.assert_allclose(poses.xyz[k], cases[name][1], atol=1e-6)
        np.testing.assert_allclose(quat_to_rot(poses.quat_xyzw[k]), cases[name][0], atol=1e-6)
    # a tag far away and seen face-on has two poses that explain its (noisy) corners almost equally well
    noise = np.random.default_rng(1).normal(0.0, 0.5, (4, 2))
    far = model.undistort(
        _project(model, 0.5, FACING @ so3_exp(np.array([0.05, 0, 0])), np.array([0, 0, 12.0])) + noise
    )
    strict = TagQuality(max_ambiguity=0.3, max_centre_spread=0.0, min_side_px=0)
    assert solve_tags(far[None], np.array([0.5]), model.k, strict).status[0] == AMBIGUOUS
    assert solve_tags(far[None], np.array([0.5]), model.k, TagQuality(min_side_px=0)).status[0] == OK


def test_image_detection_and_pnp_accuracy():
    """Clean 640x480 images, tags about 5 m away: the landmark point within 2 cm (RMS), corners unbiased."""
    cam = CameraSim(output="images", image_noise=0.0, jpeg_quality=None)
    model = cam.model()
    detector = TagDetector("36h11")
    rng = np.random.default_rng(3)
    errors, corner_err, normal_err = [], [], []
    for _ in range(12):
        lms = np.array([[-1.6, -0.8, 5.0], [1.6, -0.8, 5.0], [0.0, 0.9, 5.0]]) + rng.uniform(-0.3, 0.3, (3, 3))
        rots = np.array([FACING @ so3_exp(rng.normal(0, 0.35, 3)) for _ in range(3)])
        ids = np.array([3, 17, 42])
        img = TagRenderer(cam, lms, rots, ids).render(np.eye(3), np.zeros(3), rng)
        views = tag_views(cam, np.eye(3)[None], np.zeros((1, 3)), lms, rots, None)
        found, corners = detector.detect(img)
        assert set(found.tolist()) == set(ids[views.lm_idx].tolist())  # every tag in view, nothing else
        for k, ident in enumerate(found):
            li = int(np.flatnonzero(ids == ident)[0])
            corner_err.append(corners[k] - views.corners[int(np.flatnonzero(views.lm_idx == li)[0])])
            pose = solve_tags(model.undistort(corners[k])[None], np.array([cam.tag_size]), model.k, TagQuality())
            assert pose.status[0] == OK
            errors.append(np.linalg.norm(pose.xyz[0] - lms[li]))
            normal_err.append(np.degrees(np.arccos(quat_to_rot(pose.quat_xyzw[0])[:, 2] @ rots[li][:, 2])))
    assert len(errors) >= 30
    assert np.sqrt(np.mean(np.square(errors))) <= 0.02
    corner_err = np.array(corner_err)
    assert np.sqrt(np.mean(corner_err**2)) < 0.15 and np.abs(corner_err.mean(axis=(0, 1))).max() < 0.03
    assert np.median(normal_err) < 3.0


# --------------------------------------------------------------------------- several cameras


def _corner_stream(
    topic: str, frame: str, t_ns: np.ndarray, model: CameraModel, points: list[np.ndarray], size: float
) -> CornerStream:
    """Tag 5 at camera-frame ``points[f]`` in frame ``f``."""
    corners = np.array([_project(model, size, FACING, p) for p in points])
    n = len(points)
    return CornerStream(topic, frame, t_ns, t_ns, np.arange(n + 1), np.full(n, 5), corners)


def test_several_cameras_one_stream():
    """Two cameras of a rig see one tag: their frames 3 ms apart become one frame, the larger sighting is kept,
    each in its own camera frame, and the alignment stage puts either at the same body-frame point."""
    from slamobs.pipeline.alignment import align

    model = CameraSim().model()
    rot_lc = so3_exp(np.array([0.0, 0.4, 0.0]))  # right camera in the left (body) frame: turned, 1 m closer
    t_lc = np.array([0.2, 0.1, 1.0])
    tag_left = np.array([0.2, 0.1, 2.0])
    tag_right = rot_lc.T @ (tag_left - t_lc)
    t_ns = np.arange(6, dtype=np.int64) * 100_000_000
    left = _corner_stream("/left/tags", "left", t_ns, model, [tag_left] * 6, 0.3)
    right = _corner_stream("/right/tags", "right", t_ns[:3] + 3_000_000, model, [tag_right] * 3, 0.3)
    info = [
        CameraModel(f"/{f}/camera_info", model.k, model.dist, model.model, model.size, "CameraInfo", frame=f)
        for f in ("left", "right")
    ]
    quat = np.array([0.0, np.sin(0.2), 0.0, np.cos(0.2)])
    t = np.arange(0, 700_000_000, 10_000_000, dtype=np.int64)
    streams = LogStreams(
        "rig.bag",
        angular_velocity=Vec3Stream("/imu", "left", t, t, np.zeros((t.size, 3))),
        linear_velocity=Vec3Stream("/odom", "left", t, t, np.zeros((t.size, 3))),
        static_tf=[Transform("left", "right", t_lc, quat)],
        tag_corners=[left, right],
        camera_info=info,
    )
    tags = tag_landmarks(streams, TagOptions(size=0.3))
    det = tags.detections
    assert det.cameras == ("left", "right") and len(det) == 6 and np.diff(det.offsets).tolist() == [1] * 6
    assert det.t_ns[0] == 1_500_000  # the mean stamp of the two merged frames
    assert det.camera_of.tolist() == [1, 1, 1, 0, 0, 0]  # the nearer camera's (larger) sighting where both saw it
    assert any("3 frames of 2 cameras taken together" in n for n in tags.notes)
    assert any("3 sightings of a tag by several cameras" in n for n in tags.notes)
    streams.detections = det
    aligned = align(streams)
    np.testing.assert_allclose(aligned.det_y, np.tile(tag_left, (6, 1)), atol=1e-6)
    table = pd.DataFrame(tags.table)
    assert sorted(table["camera"]) == ["/left/tags"] * 6 + ["/right/tags"] * 3


def _two_cameras(**fields) -> LogStreams:
    """A log of two cameras (cam_a, cam_b) with intrinsics, each seeing one tag 2 m ahead in three frames, odometry in
    'base' and no transform unless ``fields`` give one."""
    model = CameraSim().model()
    t_ns = np.arange(3, dtype=np.int64) * 100_000_000
    return LogStreams(
        "rig.bag",
        linear_velocity=Vec3Stream("/odom", "base", t_ns, t_ns, np.zeros((3, 3))),
        tag_corners=[
            _corner_stream("/a/tags", "cam_a", t_ns, model, [np.array([0, 0, 2.0])] * 3, 0.3),
            _corner_stream("/b/tags", "cam_b", t_ns, model, [np.array([0, 0, 2.0])] * 3, 0.3),
        ],
        camera_info=[
            CameraModel("/cam/camera_info", model.k, model.dist, model.model, None, "x", frame=f)
            for f in ("cam_a", "cam_b")
        ],
        **fields,
    )


def test_camera_without_extrinsic_is_dropped():
    streams = _two_cameras()
    tags = tag_landmarks(streams, TagOptions(size=0.3), identity_frames=("cam_a",))
    assert tags.detections.topic == "/a/tags"
    dropped = next(n for n in tags.notes if n.startswith("warning: /b/tags: no transform from camera frame 'cam_b'"))
    assert "its 3 detections (50 % of the cameras') dropped" in dropped  # a user told what the run goes without
    assert "in the config's cameras: files" in dropped  # where the extrinsic goes (TagSLAM test_21's cameras)
    with pytest.raises(InputError, match="need the tag size"):
        tag_landmarks(streams, TagOptions(), identity_frames=("cam_a",))
    streams.camera_info = []
    with pytest.raises(InputError, match=r"no camera intrinsics for /a/tags, /b/tags .*cameras: FILE\)$"):
        tag_landmarks(streams, TagOptions(size=0.3))
    # without the tag size either: both in one error (TagSLAM test_22 asked for the cameras, then for the size)
    with pytest.raises(InputError, match=r"cameras: FILE\); and tags.size \(edge, m\)$"):
        tag_landmarks(streams, TagOptions())


def test_a_camera_info_for_another_resolution_is_scaled_to_the_images():
    """Tags found in images twice the size the CameraInfo gives, its principal point at the centre of its own size (a
    calibration of the binned camera): its intrinsics are scaled to the images and the tag sits at its true range
    (taken as read: at half of it). Where the principal point sits at the images' centre, only the size fields are
    wrong: taken as read, with a note."""
    model = CameraSim().model()
    t_ns = np.arange(3, dtype=np.int64) * 100_000_000
    tag = np.array([0.1, -0.05, 2.0])
    seen = _corner_stream("/cam/image_raw", "cam", t_ns, model, [tag] * 3, 0.3)
    seen = dataclasses.replace(seen, source="images", image_size=model.size)
    half = (model.size[0] // 2, model.size[1] // 2)
    binned = dataclasses.replace(model, k=np.diag([0.5, 0.5, 1.0]) @ model.k, size=half, frame="cam")
    resized = dataclasses.replace(model, size=half, frame="cam")  # its size fields alone wrong
    for info in (binned, resized):
        streams = LogStreams(
            "cam.bag",
            linear_velocity=Vec3Stream("/odom", "cam", t_ns, t_ns, np.zeros((3, 3))),
            tag_corners=[seen],
            camera_info=[info],
        )
        tags = tag_landmarks(streams, TagOptions(size=0.3))
        np.testing.assert_allclose(tags.detections.xyz, np.tile(tag, (3, 1)), atol=1e-3)
    said = [n for n in tags.notes if "its images are" in n]
    assert said and "near the images' centre: its intrinsics taken as the images'" in said[0]
    streams.camera_info = [binned]
    said = [n for n in tag_landmarks(streams, TagOptions(size=0.3)).notes if "its images are" in n]
    assert said[0].startswith("warning: /cam/image_raw: its images are 640x480 px where ")
    assert "scaled by 2 to the images'" in said[0] and "every tag's range would be 0.5 times the true one" in said[0]


def test_a_detectors_corners_outside_the_image_of_their_calibration_are_named():
    """A detector's corner messages (no image size) of a 640x480 camera under the calibration of its 2x binned
    images (320x240): the tags' corners reach past that image, every range comes out halved; named with a warning
    (the ranges used as read). Under the right calibration, or corners a few px past the edge, nothing is said."""
    model = CameraSim().model()
    t_ns = np.arange(6, dtype=np.int64) * 100_000_000
    tags = [np.array([0.8, 0.5, 2.0])] * 6  # off the centre of the full image: past the edge of the binned one
    stream = _corner_stream("/cam/tags", "cam", t_ns, model, tags, 0.3)
    binned = dataclasses.replace(model, k=np.diag([0.5, 0.5, 1.0]) @ model.k, size=(320, 240), frame="cam")

    def said(info):
        streams = LogStreams(
            "cam.bag",
            linear_velocity=Vec3Stream("/odom", "cam", t_ns, t_ns, np.zeros((6, 3))),
            tag_corners=[stream],
            camera_info=[info],
        )
        return [n for n in tag_landmarks(streams, TagOptions(size=0.3)).notes if "corners outside" in n]

    assert not said(dataclasses.replace(model, frame="cam"))
    got = said(binned)
    assert len(got) == 1 and got[0].startswith("warning: /cam/tags: 6 of its 6 tag detections have corners outside")
    assert "320x240 px image" in got[0] and "every tag's range comes out scaled" in got[0]


def test_a_fisheye_read_without_its_distortion_is_named_by_the_distances_between_its_tags(tmp_path):
    """figure8 seen by a 70 deg equidistant (fisheye) camera as tag corners (0.3 px noise), written and read back:
    as written the distances between two tags in one image vary 1.4 % and no ray correction improves them (1.0x);
    with its CameraInfo's coefficients zeroed (read as a pinhole, as an all-zero D is) the same correction takes the
    spread from ~3 % back to ~1.2 % (2.6x): named once, with the topic, the camera frame and the CameraInfo's D."""
    sim = simulation(
        "figure8",
        duration=20.0,
        seed=5,
        detection_rate=10.0,
        camera=CameraSim(output="corners", distortion="equidistant"),
    )
    streams = read_log(write_log(sim, tmp_path / "fisheye.bag"))

    def check(s):
        tags = tag_landmarks(s, TagOptions(size=0.5))
        return tags.distortion["/camera/tags"], [n for n in tags.notes if "distances between two tags" in n]

    fit, said = check(streams)
    assert fit["gain"] < 1.1 and not fit["wrong"] and not said
    zeroed = [dataclasses.replace(m, model="none", dist=np.zeros(0)) for m in streams.camera_info]
    fit, said = check(dataclasses.replace(streams, camera_info=zeroed))
    assert fit["gain"] > 2.0 and fit["wrong"] and len(said) == 1, fit
    assert said[0].startswith("warning: /camera/tags (camera frame '") and "its lens distortion (none)" in said[0]
    assert said[0].endswith(
        "check the CameraInfo's distortion_model and D (at the camera's driver), or a calibration file (cameras: FILE)"
    )


def test_a_rig_with_no_camera_placed_names_its_frames_and_where_the_extrinsics_go():
    """TagSLAM test_21 (four cameras) with its intrinsics file, then its camera poses too: twice "no camera has a
    transform to the body frame ...; (TF, Kalibr chain, TagSLAM camera poses)", no frame named, no config key,
    nothing of the placed camera's rig left unconnected to the odometry's frame."""
    streams = _two_cameras(static_tf=[Transform("rig", "cam_b", np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))])
    with pytest.raises(InputError) as err:
        tag_landmarks(streams, TagOptions(size=0.3))
    msg = str(err.value.problem)
    assert msg.startswith("no camera has a transform to the body frame 'base' ('cam_b' connects to rig; 'base' ")
    assert "in the config's cameras: files" in msg and msg.endswith("frames.assume_identity: [cam_a, cam_b]")


# --------------------------------------------------------------------------- logs end to end


@pytest.fixture(scope="module")
def camera_logs(tmp_path_factory):
    """figure8 seen as tag corners (ROS1 bag) and as 320x240 JPEG images (MCAP, rosbag2), 20 s at 10 Hz."""
    base = tmp_path_factory.mktemp("camera_logs")
    corners = simulation("figure8", duration=20.0, seed=5, detection_rate=10.0, camera=CameraSim(output="corners"))
    images = simulation(
        "figure8",
        duration=20.0,
        seed=5,
        detection_rate=10.0,
        camera=CameraSim(output="images", width=320, height=240, fov_h_deg=60.0, tag_size=0.8),
    )
    return {
        "corners": write_log(corners, base / "corners.bag"),
        "images": write_log(images, base / "images.mcap"),
        "images_ros2": write_log(images, base / "images_ros2"),
        "sim": images,
    }


def _truth_map_error(out: Path) -> tuple[float, float]:
    report = json.loads((out / "report.json").read_text())
    return report["ape"]["translation_m"]["rmse"], report["landmarks"]["map_aligned"]["error_m"]["rmse"]


def test_corner_and_image_logs_end_to_end(camera_logs, tmp_path):
    results = {}
    for kind, size in (("corners", 0.5), ("images", 0.8)):
        cfg = parse_config({"tags": {"size": size}, "evaluation": {"plots": False}})
        summary = run_log(camera_logs[kind], tmp_path / kind, cfg)
        out = tmp_path / kind
        table = pd.read_parquet(out / "tag_detections.parquet")
        assert (table["status"] == "ok").mean() > 0.6 and set(table["camera"]) == {table["camera"].iloc[0]}
        assert summary.metadata["input"]["cameras"]  # which model, from where
        results[kind] = _truth_map_error(out)
    ape_c, map_c = results["corners"]
    ape_i, map_i = results["images"]
    # 20 s from a cold start (a 320x240 camera for the images): the observer is within decimetres
    assert ape_c < 0.5 and map_c < 0.5 and ape_i < 0.8 and map_i < 0.8


def test_an_ideal_fisheye_log_with_zero_coefficients_matches_the_truth(tmp_path):
    """figure8 seen as tag corners by a 100 deg ideal fisheye (r = f θ), its CameraInfo equidistant with D all zero:
    read as that lens the run is within decimetres (APE 0.18 m, map 0.26 m) and its distortion check says nothing;
    read as a pinhole, as all-zero coefficients were whatever the model, every tag off the centre was placed at the
    wrong bearing and range (APE 2.3 m, map 2.8 m) and the check named a correct D (docs/benchmarks.md, session 29)."""
    cam = CameraSim(output="corners", distortion="equidistant", fov_h_deg=100.0, coefficients=(0.0,) * 4)
    sim = simulation("figure8", duration=20.0, seed=5, detection_rate=10.0, camera=cam)
    out = tmp_path / "out"
    summary = run_log(
        write_log(sim, tmp_path / "fisheye.bag"),
        out,
        parse_config({"tags": {"size": 0.5}, "evaluation": {"plots": False}}),
    )
    assert summary.metadata["input"]["cameras"]["/camera/tags"].startswith("equidistant 640x480 px")
    assert not summary.metadata["input"]["distortion_check"]["/camera/tags"]["wrong"]
    ape, map_error = _truth_map_error(out)
    assert ape < 0.5 and map_error < 0.5, (ape, map_error)


def test_image_containers_agree(camera_logs):
    """The same rendered images through ROS2 MCAP and rosbag2 sqlite give the same tags, the tags the simulated
    camera shows."""
    a = read_log(camera_logs["images"]).tag_corners
    b = read_log(camera_logs["images_ros2"]).tag_corners
    assert len(a) == len(b) == 1 and a[0].source == "images"
    np.testing.assert_array_equal(a[0].ids, b[0].ids)
    np.testing.assert_allclose(a[0].corners, b[0].corners)
    cam = camera_logs["sim"].whole().camera

    def pairs(t_ns, offsets, ids):
        return {(int(t), int(i)) for t, o0, o1 in zip(t_ns, offsets[:-1], offsets[1:]) for i in ids[o0:o1]}

    shown, found = pairs(cam.t_ns, cam.offsets, cam.ids), pairs(a[0].t_ns, a[0].offsets, a[0].ids)
    assert {i for _, i in found} <= set(get_scenario("figure8").landmark_ids.tolist())
    assert len(found & shown) >= 0.8 * len(shown)


def test_foxglove_images_with_a_ros_camera_file(tmp_path):
    """Foxglove's CompressedImage (ros2msg schema in MCAP) has no header: stamp and frame are its own fields. Its
    camera comes from a ROS camera_info YAML whose camera_name is the image's frame id."""
    from rosbags.typesys import get_types_from_msg

    from slamobs.pipeline.simulate import make_typestore
    from slamobs.pipeline.simulate.logwriter import write_raw_log
    from slamobs.pipeline.vision import opencv

    cv2 = opencv()
    ts = make_typestore(ros1=False)
    ts.register(
        get_types_from_msg(
            "builtin_interfaces/Time timestamp\nstring frame_id\nuint8[] data\nstring format\n",
            "foxglove_msgs/msg/CompressedImage",
        )
    )
    cam = CameraSim(output="images", distortion="none")
    where = np.array([0.3, -0.2, 4.0])
    img = TagRenderer(cam, where[None], FACING[None], np.array([7])).render(
        np.eye(3), np.zeros(3), np.random.default_rng(0)
    )
    jpeg = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].ravel()
    types = ts.types
    msgs = []
    for k in range(3):
        ns = 1_700_000_000_000_000_000 + k * 100_000_000
        msg = types["foxglove_msgs/msg/CompressedImage"](
            timestamp=types["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
            frame_id="front",
            data=jpeg,
            format="jpeg",
        )
        msgs.append((ns, bytes(ts.serialize_cdr(msg, "foxglove_msgs/msg/CompressedImage"))))
    log = write_raw_log(tmp_path / "fox.mcap", "mcap", {"/front/image": msgs}, "foxglove_msgs/msg/CompressedImage", ts)
    k = cam.k
    (tmp_path / "front.yaml").write_text(
        f"camera_name: front\nimage_width: {cam.width}\nimage_height: {cam.height}\n"
        f"camera_matrix: {{rows: 3, cols: 3, data: [{k[0, 0]}, 0, {k[0, 2]}, 0, {k[1, 1]}, {k[1, 2]}, 0, 0, 1]}}\n"
        "distortion_model: plumb_bob\ndistortion_coefficients: {rows: 1, cols: 5, data: [0, 0, 0, 0, 0]}\n"
    )
    streams = read_log(log)
    (corners,) = streams.tag_corners
    assert corners.frame_id == "front" and corners.ids.tolist() == [7, 7, 7]
    assert corners.t_ns.tolist() == [m[0] for m in msgs]
    tags = tag_landmarks(
        streams, TagOptions(size=cam.tag_size), camera_files=[tmp_path / "front.yaml"], identity_frames=("front",)
    )
    np.testing.assert_allclose(tags.detections.xyz, np.tile(where, (3, 1)), atol=0.02)


def test_camera_sample_log_runs_with_its_config(tmp_path):
    from click.testing import CliRunner

    from slamobs.cli.main import main

    samples = Path(__file__).resolve().parents[1] / "sample_logs"
    out = tmp_path / "out"
    res = CliRunner().invoke(
        main,
        [
            "run",
            str(samples / "figure8_camera.mcap"),
            "-o",
            str(out),
            "--config",
            str(samples / "figure8_camera.yaml"),
            "-q",
        ],
        catch_exceptions=False,
    )
    assert res.exit_code == 0, res.output
    report = json.loads((out / "report.json").read_text())
    assert report["ape"]["translation_m"]["rmse"] < 0.6
    assert len(pd.read_parquet(out / "tag_detections.parquet")) > 100


def test_raw_image_encodings_and_a_raw_image_bag(tmp_path):
    from slamobs.pipeline.vision import opencv
    from slamobs.pipeline.vision.detector import ImageError, is_depth, raw_to_gray

    cv2 = opencv()
    gray = np.random.default_rng(2).integers(0, 256, (6, 8)).astype(np.uint8)
    bgr = cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR)
    padded = np.zeros((6, 10), np.uint8)  # rows padded to a step of 10 bytes
    padded[:, :8] = gray
    cases = {
        "mono8": (padded, 10),
        "bgr8": (bgr, 24),
        "rgb8": (bgr[..., ::-1].copy(), 24),
        "bgra8": (cv2.cvtColor(gray, cv2.COLOR_GRAY2BGRA), 32),
    }
    for encoding, (data, step) in cases.items():
        np.testing.assert_array_equal(raw_to_gray(6, 8, encoding, step, False, data.tobytes()), gray)
    mono16 = (gray.astype(np.uint16) * 257).astype(">u2")
    np.testing.assert_allclose(raw_to_gray(6, 8, "mono16", 16, True, mono16.tobytes()), gray, atol=1)
    with pytest.raises(ImageError, match="too short"):
        raw_to_gray(6, 8, "mono8", 8, False, gray.tobytes()[:-1])
    with pytest.raises(ImageError, match="'32SC4' is not supported"):
        raw_to_gray(6, 8, "32SC4", 128, False, bytes(6 * 128))
    assert is_depth("16UC1", "/camera/depth/image_raw") and not is_depth("mono16", "/ir/image")
    # raw mono8 sensor_msgs/Image in a ROS1 bag
    sim = simulation(
        "figure8",
        duration=1.0,
        detection_rate=5.0,
        camera=CameraSim(output="images", width=320, height=240, fov_h_deg=60.0, tag_size=0.8, jpeg_quality=None),
    )
    (stream,) = read_log(write_log(sim, tmp_path / "raw.bag")).tag_corners
    cam = sim.whole().camera
    assert stream.topic == "/camera/image_raw" and len(stream) == 5
    assert set(stream.ids.tolist()) >= set(cam.ids.tolist())


@pytest.mark.parametrize(
    ("settings", "problem"),
    [
        (
            {"adaptiveThreshWinSizeMin": -5},
            "OpenCV rejects the settings {'adaptiveThreshWinSizeMin': -5}: params.adaptiveThreshWinSizeMin >= 3",
        ),
        ({"perspectiveRemovePixelPerCell": 0}, "OpenCV rejects the settings"),  # only seen once a tag is found
        ({"minMarkerPerimeterRate": float("nan")}, "minMarkerPerimeterRate = nan: must be finite"),
        ({"adaptiveThreshWinSizeMin": float("inf")}, "adaptiveThreshWinSizeMin = inf: must be finite"),
        ({"adaptiveThreshWinSizeMin": 3.5}, "adaptiveThreshWinSizeMin = 3.5: must be an integer"),
        ({"detectInvertedMarker": "false"}, "detectInvertedMarker = 'false': must be true or false"),
        ({"cornerRefinementMethod": 7}, "cornerRefinementMethod = 7: must be 0 (none), 1 (subpix)"),
        ({"readDetectorParameters": 1}, "'readDetectorParameters' is not a cv2.aruco.DetectorParameters field"),
    ],
)
def test_detector_settings_opencv_rejects_are_one_line(settings, problem):
    with pytest.raises(InputError) as err:
        TagDetector("36h11", settings, path="run.yaml")
    assert str(err.value).startswith("run.yaml: tags.detector: ") and problem in str(err.value)
    assert "\n" not in str(err.value)
    TagDetector("36h11", {"adaptiveThreshWinSizeMin": 5, "adaptiveThreshConstant": 7})  # valid ones still work


ROS_INFO = (
    "camera_name: camera\ncamera_matrix: {rows: 3, cols: 3, data: [457, 0, 319.5, 0, 457, 239.5, 0, 0, 1]}\n"
    "distortion_model: plumb_bob\n"
)


def test_ros_camera_file_with_plain_lists(tmp_path):
    path = tmp_path / "cam.yaml"
    path.write_text(
        "camera_name: camera\ncamera_matrix: [457, 0, 319.5, 0, 457, 239.5, 0, 0, 1]\n"
        "distortion_model: plumb_bob\ndistortion_coefficients: [0.1, 0, 0, 0, 0]\nimage_width: 640\n"
        "image_height: 480\n"
    )
    (model,) = read_camera_files([path]).models
    assert model.model == "radtan" and model.dist.tolist() == [0.1, 0, 0, 0, 0] and model.size == (640, 480)
    assert model.k[0, 0] == 457.0


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        (
            ROS_INFO + "distortion_coefficients: [0, 0, 0, 0, 0]\nimage_width: big\n",
            "image_width must be a whole number of pixels, got 'big'",
        ),
        (
            ROS_INFO + "distortion_coefficients: [0, 0, 0, 0, 0]\nimage_height: .inf\n",
            "image_height must be a whole number of pixels, got inf",
        ),
        (ROS_INFO + "distortion_coefficients: [a, b]\n", "distortion_coefficients.data must be a list of numbers"),
        (
            "cam0: {intrinsics: [500, 500, 1, 1], resolution: [640.5, 480]}",
            "cam0.resolution must be a whole number of pixels, got 640.5",
        ),
        ("bodies: 5\n", "bodies must be a list of {name: body} entries"),
        (b"\xff\xfe\x00", "not UTF-8 text (byte 0xff at offset 0): save the camera file as UTF-8"),
    ],
)
def test_bad_camera_file_values_are_one_line(tmp_path, text, problem):
    path = tmp_path / "cam.yaml"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(InputError) as err:
        read_camera_files([path])
    assert str(err.value) == f"{path}: {problem}"


def test_missing_camera_file_is_an_error_even_when_unused(tmp_path):
    from slamobs.pipeline.vision.cameras import check_camera_files

    check_camera_files(())
    with pytest.raises(InputError) as err:
        check_camera_files([tmp_path / "nonexistent.yaml"])
    assert str(err.value) == f"{tmp_path / 'nonexistent.yaml'}: camera file not found"


def test_detector_settings_checked_with_the_config_path():
    from slamobs.pipeline.vision.detector import check_detector_settings

    check_detector_settings("36h11", None, "run.yaml")
    check_detector_settings("36h11", {"adaptiveThreshWinSizeMin": 5}, "run.yaml")
    with pytest.raises(InputError, match=r"^run.yaml: tags.detector: OpenCV rejects the settings .*>= 3"):
        check_detector_settings("36h11", {"adaptiveThreshWinSizeMin": -5}, "run.yaml")


def test_missing_camera_file_fails_a_run_without_camera_topics(tmp_path):
    """A ``cameras:`` file that does not exist was dropped without a word on a log without camera topics."""
    from click.testing import CliRunner

    from slamobs.cli.main import main

    cfg = tmp_path / "cm.yaml"
    cfg.write_text(f"cameras: {tmp_path / 'nonexistent.yaml'}\n")
    log = Path(__file__).resolve().parents[1] / "sample_logs" / "circle.bag"
    res = CliRunner().invoke(main, ["run", str(log), "-o", str(tmp_path / "out"), "--config", str(cfg), "-q"])
    assert res.exit_code == 2 and "Traceback" not in res.output
    assert res.output.strip() == f"error: {tmp_path / 'nonexistent.yaml'}: camera file not found"
    assert not (tmp_path / "out").exists()


def test_a_missing_tag_size_names_the_sizes_a_tagslam_file_states(tmp_path):
    """TagSLAM test_22 run with cameras: [cameras.yaml, camera_poses.yaml, tagslam.yaml] and no tags: section: the
    error said only "set tags.size", though the tagslam.yaml given beside the calibration states
    default_tag_size 0.42 (test_21: 0.16, and 0.1 for tags 100-108). It names what the file states; the run still
    takes no size the config does not give."""
    streams = _two_cameras()
    stated = TAGSLAM.replace("     is_static: true\n", "     is_static: true\n     default_tag_size: 0.3\n", 1)
    (tmp_path / "tagslam.yaml").write_text(stated)
    with pytest.raises(InputError, match="need the tag size") as err:
        tag_landmarks(streams, TagOptions(), camera_files=[tmp_path / "tagslam.yaml"], identity_frames=("cam_a",))
    assert str(err.value).endswith(
        "the cameras: files say: tagslam.yaml states default_tag_size 0.3 m (body 'world'); 0.2 m for tags 4, 9 "
        "(set them if they are this log's tags)"
    )
    (tmp_path / "tagslam.yaml").write_text(
        TAGSLAM.replace("size: 0.2, ", "").replace(", size: 0.2", "")
    )  # no size: the old words
    with pytest.raises(InputError) as err:
        tag_landmarks(streams, TagOptions(), camera_files=[tmp_path / "tagslam.yaml"], identity_frames=("cam_a",))
    assert str(err.value).endswith("set tags.size (or tags.sizes per id) in the config")


def test_a_tag_size_other_than_the_one_a_tagslam_file_states_is_said(tmp_path):
    """TagSLAM test_21 run as its tagslam.yaml's default_tag_size says (``tags.size: 0.16``, the file in cameras:):
    its tags 100-107, 0.1 m by the same file, were solved at 0.16 m (ranges 1.6x) without a word. The run now
    names the tags, the two sizes, the factor and the tags.sizes line; with that line given, or for a tag the file
    does not list, nothing is said, and the size used stays the config's."""
    streams = _two_cameras()  # tag 5, 3 detections in each camera; cam_b has no extrinsic (dropped)
    listed = TAGSLAM.replace(
        "       - {id: 9, size: 0.2}\n", "       - {id: 9, size: 0.2}\n       - {id: 5, size: 0.1}\n"
    )
    (tmp_path / "tagslam.yaml").write_text(listed)
    files = [tmp_path / "tagslam.yaml"]
    tags = tag_landmarks(streams, TagOptions(size=0.3), camera_files=files, identity_frames=("cam_a",))
    said = [n for n in tags.notes if "states 0.1 m" in n]
    assert said == [
        "warning: tagslam.yaml states 0.1 m for tag 5 (3 detections), the run gave them 0.3 m (tags.size): each of "
        "their ranges is 3x what 0.1 m gives, and the map and poses that use them follow; if tagslam.yaml is this "
        "log's, set tags.sizes: {5: 0.1}"
    ]
    assert np.linalg.norm(tags.detections.xyz[0]) == pytest.approx(2.0, rel=1e-3)  # solved at the config's 0.3 m
    options = TagOptions(size=0.3, sizes={5: 0.1})
    assert not [
        n
        for n in tag_landmarks(streams, options, camera_files=files, identity_frames=("cam_a",)).notes
        if "states 0.1 m" in n
    ]
    (tmp_path / "tagslam.yaml").write_text(TAGSLAM)  # tag 5 not listed: nothing to hold it against
    tags = tag_landmarks(streams, TagOptions(size=0.3), camera_files=files, identity_frames=("cam_a",))
    assert not [n for n in tags.notes if " states " in n]
