"""Whether a camera's lens distortion fits its tags: the distances between two tags seen in one image.

Two static tags are the same distance apart in every image that shows both, wherever in the image they are. A
wrong distortion model or wrong coefficients place a tag off the image's centre at the wrong bearing and range, so
the distance of a pair seen near the centre and near the edge differs. The check (one per camera, truth-free,
before any estimate): every pair's distance in each image against that pair's median, the robust spread (MAD) of
those ratios as read, and again after the one radial correction ``θ' = θ (1 + a θ² + b θ⁴)`` of the rays (the
angle ``θ`` from the optical axis: an equidistant lens's own form) that makes the spread least. A correct
calibration leaves the correction nothing to take (gain ~1); a wrong one leaves a spread the correction takes away.

Each correction moves every corner's ray and solves the tags again (IPPE square, ~10 µs a tag): the tag's pose
takes up a wrong lens as a tilt and a range, which no cheaper stand-in follows (the tag moved as a point with its
angular size gave 1.0-1.6x on wrong lenses). At most ``MAX_DETECTIONS`` tags, about 40 corrections: 0.17-0.27 CPU s a
camera, paid only where a log has tag corners (:mod:`.landmarks`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: A pair of tags is used once it is seen together in this many images (its median distance is the reference).
MIN_SIGHTINGS = 5
#: The check needs this many pair sightings of a camera (fewer: no verdict, nothing said).
MIN_PAIRS = 100
#: Named when the correction cuts the spread by this factor or more: TagSLAM test_11 / test_21 as calibrated and
#: generated cameras read with their own distortion 1.00-1.03x; test_11 with its distortion zeroed or read as radtan
#: 2.96-4.39x, generated lenses read with no distortion or the other model 1.78-3.45x (but a radtan k1 of -0.12 read
#: without it: 1.22-1.35x, not named; docs/benchmarks.md, "A wrong camera distortion named by the distances between
#: tags, session 29").
GAIN = 1.5
#: ... and the spread as read is at least this share of the pair distance (TagSLAM's calibrated cameras 0.22-0.30 %,
#: test_11 misread 0.80-1.12 %): under it the tags agree to within a few mm a metre, whatever the lens.
MIN_SPREAD = 0.004
#: The correction's coefficients searched: ``a`` then ``b`` on the coarse grid, then each again on the fine grid
#: around the best so far.
COARSE = np.linspace(-0.5, 0.5, 11)
FINE = np.linspace(-0.08, 0.08, 9)
#: The correction keeps a ray inside this angle from the axis, rad (a pinhole image ends at 90 deg).
MAX_ANGLE = 1.45
#: At most this many detections are solved again per correction (~10 µs each, ~40 corrections; TagSLAM test_11
#: as calibrated 1.00x, misread 2.96-4.10x with 600 of them and 3.22-4.39x with 300: 0.33-0.37 or 0.17-0.23 CPU s
#: a camera).
MAX_DETECTIONS = 300


@dataclass(frozen=True)
class DistortionFit:
    """One camera's check: pair sightings used, the spread as read and corrected, the correction's coefficients."""

    pairs: int
    spread: float  # MAD of (distance / the pair's median − 1) as read
    corrected: float  # the same after the best correction
    a: float
    b: float

    @property
    def gain(self) -> float:
        return self.spread / self.corrected if self.corrected > 0 else 1.0

    @property
    def wrong(self) -> bool:
        return self.gain >= GAIN and self.spread >= MIN_SPREAD

    def record(self) -> dict:
        """run.json's ``input.distortion_check`` entry of the camera."""
        return {
            "pairs": self.pairs,
            "spread": round(self.spread, 6),
            "corrected": round(self.corrected, 6),
            "gain": round(self.gain, 3),
            "a": round(self.a, 4),
            "b": round(self.b, 4),
            "wrong": self.wrong,
        }


def _pairs(frame_of: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Index pairs ``(i, j)`` of detections in one image, and the group (tag pair) of each, for pairs seen
    ``MIN_SIGHTINGS`` times or more."""
    order = np.lexsort((ids, frame_of))
    f, d = frame_of[order], order
    starts = np.flatnonzero(np.r_[True, f[1:] != f[:-1]])
    ends = np.r_[starts[1:], f.shape[0]]
    ii, jj = [], []
    for a, b in zip(starts, ends):
        if b - a > 1:
            i, j = np.triu_indices(b - a, 1)
            ii.append(d[a + i])
            jj.append(d[a + j])
    if not ii:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0, int)
    i, j = np.concatenate(ii), np.concatenate(jj)
    lo, hi = np.minimum(ids[i], ids[j]), np.maximum(ids[i], ids[j])
    _, group, counts = np.unique(np.stack([lo, hi], 1), axis=0, return_inverse=True, return_counts=True)
    group = group.ravel()
    keep = counts[group] >= MIN_SIGHTINGS
    _, group = np.unique(group[keep], return_inverse=True)
    return i[keep], j[keep], group.ravel()


def _corrected_px(xn: np.ndarray, k: np.ndarray, a: float, b: float) -> np.ndarray:
    """Pixels of the ideal pinhole camera ``k`` of normalised points ``xn`` (..., 2) whose ray angle ``θ`` is
    corrected to ``θ (1 + a θ² + b θ⁴)`` (kept under ``MAX_ANGLE``)."""
    r = np.linalg.norm(xn, axis=-1)
    theta = np.arctan(r)
    new = np.clip(theta * (1.0 + a * theta**2 + b * theta**4), 0.0, MAX_ANGLE)
    scale = np.where(r > 0, np.tan(new) / np.maximum(r, 1e-300), 1.0)
    return xn * scale[..., None] * np.array([k[0, 0], k[1, 1]]) + k[:2, 2]


def _positions(px: np.ndarray, sizes: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The tags' positions (M, 3) from their ideal corners (IPPE square, as :func:`.tagpose.solve_tags` first
    tries); NaN where it finds none."""
    from slamobs.pipeline.vision import opencv
    from slamobs.pipeline.vision.tagpose import model_corners

    cv2 = opencv()
    out = np.full((px.shape[0], 3), np.nan)
    for m in range(px.shape[0]):
        try:
            ok, _, t = cv2.solvePnP(model_corners(float(sizes[m])), px[m], k, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
        except cv2.error:
            ok = False
        if ok:
            out[m] = np.ravel(t)
    return out


def _spread(xyz: np.ndarray, i: np.ndarray, j: np.ndarray, group: np.ndarray) -> float:
    """MAD of every pair sighting's distance over its pair's median distance, minus one (inf where a tag has no
    position)."""
    d = np.linalg.norm(xyz[i] - xyz[j], axis=1)
    if not np.isfinite(d).all():
        return np.inf
    order = np.lexsort((d, group))
    g, ds = group[order], d[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    counts = np.diff(np.r_[starts, g.shape[0]])
    med = 0.5 * (ds[starts + (counts - 1) // 2] + ds[starts + counts // 2])
    q = ds / med[g] - 1.0
    return float(1.4826 * np.median(np.abs(q - np.median(q))))


def distortion_fit(ideal_px: np.ndarray, k: np.ndarray, sizes: np.ndarray, frame_of: np.ndarray, ids: np.ndarray):
    """The check of one camera (module docstring) from its kept detections: corners of the ideal pinhole camera
    ``k`` (M, 4, 2), tag sizes (M,), image index and tag id of each; None with fewer than ``MIN_PAIRS`` pair
    sightings. At most ``MAX_DETECTIONS`` detections are used (whole images, spread over the log)."""
    i, j, group = _pairs(frame_of, ids)
    if i.shape[0] < MIN_PAIRS:
        return None
    used = np.unique(np.r_[i, j])
    if used.shape[0] > MAX_DETECTIONS:  # whole images, evenly over the log
        frames = np.unique(frame_of[used])
        frames = frames[np.linspace(0, frames.shape[0] - 1, MAX_DETECTIONS // 2).astype(int)]
        used = used[np.isin(frame_of[used], frames)]
    i, j, group = _pairs(frame_of[used], ids[used])  # indices into ``used``
    if i.shape[0] < MIN_PAIRS:
        return None
    kk = np.ascontiguousarray(k, np.float64)
    xn = (ideal_px[used] - kk[:2, 2]) / np.array([kk[0, 0], kk[1, 1]])

    def spread(a: float, b: float) -> float:
        return _spread(_positions(_corrected_px(xn, kk, a, b), sizes[used], kk), i, j, group)

    as_read = best = spread(0.0, 0.0)
    a = b = 0.0
    for step, grid in (("a", COARSE), ("b", COARSE), ("a", FINE), ("b", FINE)):
        centre = a if step == "a" else b
        for v in centre + grid:
            s = spread(v, b) if step == "a" else spread(a, v)
            if s < best:
                best, a, b = (s, v, b) if step == "a" else (s, a, v)
    return DistortionFit(int(i.shape[0]), as_read, best, float(a), float(b))


def distortion_warning(topic: str, frame: str, model, fit: DistortionFit) -> str:
    """The warning of a camera whose distortion does not fit its tags (``fit.wrong``): its topic and frame, the
    evidence, and where its distortion was read from (``model``: a :class:`.cameras.CameraModel`)."""
    where = (
        "the CameraInfo's distortion_model and D (at the camera's driver), or a calibration file (cameras: FILE)"
        if model.source.startswith("CameraInfo")
        else f"distortion_model and distortion_coeffs of {model.source}"
    )
    return (
        f"warning: {topic} (camera frame '{frame}'): the distances between two tags seen in one image vary "
        f"{100 * fit.spread:.2f} % (MAD over {fit.pairs} pair sightings) and {100 * fit.corrected:.2f} % once the "
        f"rays are corrected by θ (1 {fit.a:+.3f} θ² {fit.b:+.3f} θ⁴) ({fit.gain:.1f}x; a calibration that fits "
        f"leaves the correction nothing to take): its lens distortion ({model.model}) looks wrong, the tags off the "
        f"image's centre placed at the wrong bearing and range: check {where}"
    )
