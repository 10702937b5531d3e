"""A simulated camera that reports tags as a real one does: corner pixels, or rendered images, with CameraInfo.

The pinhole camera (``fx = fy`` from the horizontal field of view, optional radtan or equidistant distortion)
sits where the scenario's camera is. A tag is seen when it is in front of the camera, faces it (view angle above
``MIN_VIEW_DEG``), lies within the scenario camera's range and all four corners project into the image with a
side of at least ``MIN_SIDE_PX``.

* ``corners``: the true corner pixels plus Gaussian noise, written as ``apriltag_msgs/ApriltagArrayStamped``
  (corners in the AprilTag order).
* ``images``: OpenCV marker images of the tag family warped into the image by the true camera pose, rendered
  at ``SUPERSAMPLE`` x the resolution and area-averaged (anti-aliased edges), distorted by a remap, then blurred,
  noised and JPEG-encoded as asked; far tags first so near ones occlude them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from slamobs.pipeline.vision.tagpose import model_corners

#: Sub-pixels per pixel and axis when rendering; texture pixels per marker cell.
SUPERSAMPLE = 3
CELL_PX = 24
#: A tag is reported only when seen at least this steeply (deg between the line of sight and its plane) ...
MIN_VIEW_DEG = 20.0
#: ... and with every side at least this long in the image (px).
MIN_SIDE_PX = 10.0
#: Distortion coefficients of the simulated lenses.
DISTORTIONS = {
    "none": np.zeros(0),
    "radtan": np.array([-0.12, 0.05, 0.0005, -0.0003, 0.0]),
    "equidistant": np.array([-0.01, 0.02, -0.01, 0.002]),
}
OUTPUTS = ("fiducials", "corners", "images")


@dataclass(frozen=True)
class CameraSim:
    """How the simulated camera reports tags: ``fiducials`` (3D poses, the default), ``corners`` or ``images``."""

    output: str = "fiducials"
    width: int = 640
    height: int = 480
    fov_h_deg: float = 70.0
    distortion: str = "radtan"
    tag_size: float = 0.5  # m, black square
    family: str = "36h11"
    pixel_noise: float = 0.3  # px, corners
    image_noise: float = 2.0  # grey levels, images
    blur: float = 0.0  # Gaussian sigma, px
    jpeg_quality: int | None = 90  # None: raw sensor_msgs/Image (mono8)
    #: The lens's coefficients instead of ``DISTORTIONS[distortion]`` (all zero for equidistant: the ideal fisheye
    #: ``r = f θ``, written as an equidistant CameraInfo with a zero ``D``).
    coefficients: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.output not in OUTPUTS:
            raise ValueError(f"camera output must be one of {', '.join(OUTPUTS)}, got {self.output!r}")
        if self.distortion not in DISTORTIONS:
            raise ValueError(f"distortion must be one of {', '.join(DISTORTIONS)}, got {self.distortion!r}")
        if self.width < 16 or self.height < 16 or not 10.0 <= self.fov_h_deg < 170.0 or self.tag_size <= 0:
            raise ValueError("camera: image at least 16x16 px, field of view 10..170 deg, positive tag size")
        if self.coefficients is not None and len(self.coefficients) != DISTORTIONS[self.distortion].shape[0]:
            raise ValueError(f"{self.distortion} distortion takes {DISTORTIONS[self.distortion].shape[0]} coefficients")

    @property
    def k(self) -> np.ndarray:
        f = 0.5 * self.width / np.tan(np.radians(0.5 * self.fov_h_deg))
        return np.array([[f, 0.0, 0.5 * (self.width - 1)], [0.0, f, 0.5 * (self.height - 1)], [0.0, 0.0, 1.0]])

    def model(self):
        """The camera as a :class:`pipeline.vision.cameras.CameraModel` (what its CameraInfo says)."""
        from slamobs.pipeline.vision.cameras import CameraModel

        return CameraModel(
            "camera",
            self.k,
            self.coeffs.copy(),
            self.distortion,
            (self.width, self.height),
            "simulation",
        )

    @property
    def ros_distortion(self) -> str:
        return {"none": "plumb_bob", "radtan": "plumb_bob", "equidistant": "equidistant"}[self.distortion]

    @property
    def coeffs(self) -> np.ndarray:
        """The lens's distortion coefficients (``coefficients`` where given)."""
        return DISTORTIONS[self.distortion] if self.coefficients is None else np.asarray(self.coefficients, float)

    @property
    def ros_coeffs(self) -> np.ndarray:
        return self.coeffs if self.distortion != "none" else np.zeros(5)


@dataclass(frozen=True)
class TagViews:
    """Per frame the camera pose, and the tags it sees with their true corner pixels (CSR over frames)."""

    r_wc: np.ndarray  # (F, 3, 3) camera -> world
    t_wc: np.ndarray  # (F, 3)
    offsets: np.ndarray  # (F + 1,)
    lm_idx: np.ndarray  # (M,) index into the scenario's landmarks
    corners: np.ndarray  # (M, 4, 2) OpenCV order, distorted pixels, noise-free


def tag_views(
    cam: CameraSim, r_wc: np.ndarray, t_wc: np.ndarray, landmarks: np.ndarray, rots: np.ndarray, max_range: float | None
) -> TagViews:
    """Which tags each camera pose sees (module docstring) and where their corners are in the image."""
    model = cam.model()
    obj = model_corners(cam.tag_size)  # (4, 3) tag frame, OpenCV order
    world = landmarks[:, None, :] + np.einsum("lij,kj->lki", rots, obj)  # (L, 4, 3)
    f_n = r_wc.shape[0]
    rel = world[None] - t_wc[:, None, None, :]  # (F, L, 4, 3)
    pc = np.einsum("fji,flkj->flki", r_wc, rel)  # camera frame
    centre = np.einsum("fji,flj->fli", r_wc, landmarks[None] - t_wc[:, None, :])
    normal = np.einsum("fji,lj->fli", r_wc, rots[:, :, 2])
    rng = np.linalg.norm(centre, axis=2)
    view = np.degrees(np.arcsin(np.clip(-np.einsum("fli,fli->fl", normal, centre) / np.maximum(rng, 1e-9), -1, 1)))
    ok = (pc[..., 2] > 0.05).all(axis=2) & (view > MIN_VIEW_DEG)
    if max_range is not None:
        ok &= rng <= max_range
    frame_idx, lm_idx = np.nonzero(ok)
    px = (
        model.project(pc[frame_idx, lm_idx].reshape(-1, 3)).reshape(-1, 4, 2) if frame_idx.size else np.zeros((0, 4, 2))
    )
    side = np.linalg.norm(px - np.roll(px, -1, axis=1), axis=2).min(axis=1) if px.size else np.zeros(0)
    inside = (
        (px[..., 0] >= 1) & (px[..., 0] <= cam.width - 2) & (px[..., 1] >= 1) & (px[..., 1] <= cam.height - 2)
    ).all(axis=1) & (side >= MIN_SIDE_PX)
    frame_idx, lm_idx, px = frame_idx[inside], lm_idx[inside], px[inside]
    offsets = np.concatenate([[0], np.cumsum(np.bincount(frame_idx, minlength=f_n))]).astype(np.int64)
    return TagViews(r_wc, t_wc, offsets, lm_idx.astype(np.int64), px)


@dataclass
class TagRenderer:
    """Grey images of the tags a camera pose sees (module docstring)."""

    cam: CameraSim
    landmarks: np.ndarray  # (L, 3)
    rots: np.ndarray  # (L, 3, 3) tag -> world
    ids: np.ndarray  # (L,)
    background: int = 150
    _textures: dict[int, np.ndarray] = field(default_factory=dict)

    @cached_property
    def cv2(self):
        """OpenCV, imported when the first image is drawn (an optional dependency)."""
        from slamobs.pipeline.vision import opencv

        return opencv("", "simulated camera images")

    @cached_property
    def _distortion_map(self) -> tuple[np.ndarray, np.ndarray] | None:
        """For each supersampled pixel of the distorted image: where it is in the ideal (pinhole) canvas. Computed
        at the pixel centres and resized (resize puts a sub-pixel at the same image coordinate as the canvas)."""
        if self.cam.distortion == "none":
            return None
        s, w, h = SUPERSAMPLE, self.cam.width, self.cam.height
        jj, ii = np.mgrid[0:h, 0:w].astype(np.float64)
        ideal = self.cam.model().undistort(np.stack([ii.ravel(), jj.ravel()], axis=1))
        canvas = (s * (ideal + 0.5) - 0.5).astype(np.float32)
        return tuple(
            self.cv2.resize(canvas[:, a].reshape(h, w), (s * w, s * h), interpolation=self.cv2.INTER_LINEAR)
            for a in range(2)
        )

    def render(self, r_wc: np.ndarray, t_wc: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The 8-bit grey image at camera pose ``(r_wc, t_wc)``: tags, then distortion, blur and noise."""
        cv2 = self.cv2
        s, w, h = SUPERSAMPLE, self.cam.width, self.cam.height
        canvas = np.full((s * h, s * w), float(self.background), np.float32)
        a_s = np.array([[s, 0.0, 0.5 * (s - 1)], [0.0, s, 0.5 * (s - 1)], [0.0, 0.0, 1.0]])
        k = self.cam.k
        centre = (self.landmarks - t_wc) @ r_wc  # camera frame, (L, 3)
        for li in np.argsort(-np.linalg.norm(centre, axis=1)):
            r_ct = r_wc.T @ self.rots[li]
            t_ct = centre[li]
            if t_ct[2] <= 0.05 or r_ct[:, 2] @ t_ct >= 0:  # behind the camera, or its back to it
                continue
            tex, margin = self._marker(int(self.ids[li]))
            n_tex = tex.shape[0]
            n = n_tex - 2 * margin
            size = self.cam.tag_size
            # texture pixel (x, y) -> tag plane (a, b): black square edges at x = margin - 0.5 and margin + n - 0.5
            tex_to_tag = np.array(
                [
                    [size / n, 0.0, size * (0.5 - margin - 0.5 * n) / n],
                    [0.0, -size / n, -size * (0.5 - margin - 0.5 * n) / n],
                    [0.0, 0.0, 1.0],
                ]
            )
            h_mat = a_s @ k @ np.column_stack([r_ct[:, 0], r_ct[:, 1], t_ct]) @ tex_to_tag
            quad = cv2.perspectiveTransform(
                np.array([[[0, 0], [n_tex - 1, 0], [n_tex - 1, n_tex - 1], [0, n_tex - 1]]], np.float64), h_mat
            )[0]
            x0, y0 = np.floor(quad.min(axis=0)).astype(int) - 2
            x1, y1 = np.ceil(quad.max(axis=0)).astype(int) + 2
            x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, s * w), min(y1, s * h)
            if x1 <= x0 or y1 <= y0:
                continue
            shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
            roi = canvas[y0:y1, x0:x1]
            cv2.warpPerspective(
                tex,
                shift @ h_mat,
                (x1 - x0, y1 - y0),
                dst=roi,
                flags=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_TRANSPARENT,
            )
        if (maps := self._distortion_map) is not None:
            canvas = cv2.remap(canvas, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        img = cv2.resize(canvas, (w, h), interpolation=cv2.INTER_AREA)
        if self.cam.blur > 0:
            img = cv2.GaussianBlur(img, (0, 0), self.cam.blur)
        if self.cam.image_noise > 0:
            img = img + rng.normal(0.0, self.cam.image_noise, img.shape).astype(np.float32)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)

    @cached_property
    def _dictionary(self):
        from slamobs.pipeline.vision.detector import family_constant

        return self.cv2.aruco.getPredefinedDictionary(getattr(self.cv2.aruco, family_constant(self.cam.family)))

    def _marker(self, ident: int) -> tuple[np.ndarray, int]:
        """Marker image (black square of ``cells`` cells of ``CELL_PX``) in a white margin of one cell, float32,
        and the margin in px."""
        if ident not in self._textures:
            cells = self._dictionary.markerSize + 2
            marker = self.cv2.aruco.generateImageMarker(self._dictionary, ident, cells * CELL_PX, borderBits=1)
            self._textures[ident] = np.pad(marker, CELL_PX, constant_values=255).astype(np.float32)
        return self._textures[ident], CELL_PX
