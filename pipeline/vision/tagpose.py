"""Square tags from their four corner pixels: OpenCV's ``solvePnP`` with ``SOLVEPNP_IPPE_SQUARE``.

Corners come in OpenCV's marker order (top-left, top-right, bottom-right, bottom-left of the tag seen from
the front); the tag frame is OpenCV's (x right, y up, z out of the tag face, origin at the centre), which is
also TagSLAM's. The corners are undistorted to the ideal pinhole camera first, so reprojection errors are in
pixels. IPPE returns the two poses a planar square allows; the better one is kept and the pair says how
trustworthy it is:

* ``reprojection_px``: RMS distance of the projected model corners to the measured ones (best pose);
* ``ambiguity``: best over second-best reprojection error (near 1: both poses explain the corners, the
  orientation is a coin toss);
* ``centre_spread``: distance between the two poses' centres over the range: the landmark point of an
  ambiguous pose is still good when the two centres agree (they do, nearly, for all but close tags);
* ``view_angle_deg``: angle between the line of sight and the tag plane (0 = grazing).

A detection is rejected for a reprojection error above ``max_reprojection_px``, a view angle below
``min_view_angle_deg``, an ambiguous pose (``ambiguity > max_ambiguity``) whose two centres disagree by more
than ``max_centre_spread`` of the range, or a range above ``max_range_m`` (if set: the range error of a PnP
grows with the square of the range).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Rejection reasons, in the order they are tested (``status`` of a detection; 0 = kept).
REASONS = ("ok", "no PnP solution", "reprojection error", "grazing view", "ambiguous pose", "too far", "too small")
OK, NO_SOLUTION, REPROJECTION, GRAZING, AMBIGUOUS, TOO_FAR, TOO_SMALL = range(7)


@dataclass(frozen=True)
class TagQuality:
    """Limits a tag pose must meet to become a landmark measurement."""

    max_reprojection_px: float = 2.0
    min_view_angle_deg: float = 12.0  # TagSLAM's minimum_viewing_angle
    max_ambiguity: float = 0.6
    max_centre_spread: float = 0.01  # of the range
    max_range_m: float | None = None  # farther tags are dropped (their range error grows with its square)
    min_side_px: float = 15.0  # shortest side in the (undistorted) image

    def describe(self, reason: int) -> str:
        if reason == NO_SOLUTION:
            return "no PnP solution"
        if reason == REPROJECTION:
            return f"reprojection error above {self.max_reprojection_px:g} px"
        if reason == GRAZING:
            return f"view angle below {self.min_view_angle_deg:g} deg"
        if reason == AMBIGUOUS:
            return (
                f"ambiguous pose (error ratio above {self.max_ambiguity:g}) with centres "
                f"{100 * self.max_centre_spread:g} % of the range apart"
            )
        if reason == TOO_FAR:
            return f"farther than {self.max_range_m:g} m"
        return f"shortest side below {self.min_side_px:g} px"


@dataclass(frozen=True)
class TagPoses:
    """Per detection: centre and orientation in the camera frame, quality and the verdict."""

    xyz: np.ndarray  # (M, 3) tag centre, camera frame
    quat_xyzw: np.ndarray  # (M, 4) tag -> camera rotation
    reprojection_px: np.ndarray  # (M,)
    ambiguity: np.ndarray  # (M,)
    view_angle_deg: np.ndarray  # (M,)
    status: np.ndarray  # (M,) int8, index into REASONS

    @property
    def ok(self) -> np.ndarray:
        return self.status == OK


def winding(corners: np.ndarray) -> np.ndarray:
    """Twice the signed area of each quadrilateral (M, 4, 2): positive for OpenCV's order in image coordinates."""
    x, y = corners[..., 0], corners[..., 1]
    return np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)


def model_corners(size: float) -> np.ndarray:
    """The tag's corners in its own frame, in the order ``SOLVEPNP_IPPE_SQUARE`` requires."""
    h = 0.5 * size
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


def _reprojection(k: np.ndarray, rot: np.ndarray, trans: np.ndarray, obj: np.ndarray, px: np.ndarray) -> float:
    """RMS pixel distance of the model corners projected by the pinhole ``k`` at pose ``(rot, trans)``."""
    cam = obj @ rot.T + trans
    if np.any(cam[:, 2] <= 0):
        return np.inf
    proj = (cam @ k.T)[:, :2] / cam[:, 2:3]
    return float(np.sqrt(np.mean(np.sum((proj - px) ** 2, axis=1))))


def solve_tags(ideal_px: np.ndarray, sizes: np.ndarray, k: np.ndarray, quality: TagQuality) -> TagPoses:
    """Poses of square tags from undistorted corners ``ideal_px`` (M, 4, 2) seen by the pinhole camera ``k``
    (sizes (M,) in metres: the black square's edge)."""
    from slamobs.pipeline.lie import rots_to_quats
    from slamobs.pipeline.vision import opencv

    cv2 = opencv()
    m = ideal_px.shape[0]
    xyz = np.full((m, 3), np.nan)
    rots = np.tile(np.eye(3), (m, 1, 1))
    reproj = np.full(m, np.inf)
    ambiguity = np.ones(m)
    spread = np.zeros(m)
    status = np.zeros(m, np.int8)
    kk = np.ascontiguousarray(k, dtype=np.float64)
    for j in range(m):
        obj = model_corners(float(sizes[j]))
        try:
            n, rvecs, tvecs, _ = cv2.solvePnPGeneric(
                obj, np.ascontiguousarray(ideal_px[j], np.float64), kk, None, flags=cv2.SOLVEPNP_IPPE_SQUARE
            )
        except cv2.error:
            n = 0
        if not n:
            status[j] = NO_SOLUTION
            continue
        # reprojection errors computed here: solvePnPGeneric's own are wrong for some views (OpenCV 5.0 reports
        # 50 px for an exact tag seen at 20 deg)
        sol_r = [cv2.Rodrigues(np.asarray(rv, dtype=np.float64))[0] for rv in rvecs[:n]]
        sol_t = [np.asarray(tv, dtype=np.float64).ravel() for tv in tvecs[:n]]
        errs = np.array([_reprojection(kk, r, t, obj, ideal_px[j]) for r, t in zip(sol_r, sol_t)])
        order = np.argsort(errs)
        best = order[0]
        if errs[best] > 0.25 * quality.max_reprojection_px:
            # IPPE's decomposition fails on exactly symmetric views (a tag turned only about its own y axis gives
            # 60+ px in OpenCV 5.0): the iterative solver (homography start, Levenberg-Marquardt) is the fallback,
            # kept if it fits better
            ok, rv, tv = cv2.solvePnP(
                obj, np.ascontiguousarray(ideal_px[j], np.float64), kk, None, flags=cv2.SOLVEPNP_ITERATIVE
            )
            if ok:
                r_lm, t_lm = cv2.Rodrigues(rv)[0], np.asarray(tv, dtype=np.float64).ravel()
                e_lm = _reprojection(kk, r_lm, t_lm, obj, ideal_px[j])
                if e_lm < errs[best]:
                    sol_r[best], sol_t[best], errs[best] = r_lm, t_lm, e_lm
                    order = np.argsort(errs)
                    best = order[0]
        t = sol_t[best]
        if not (np.isfinite(t).all() and t[2] > 0 and np.isfinite(errs[best])):
            status[j] = NO_SOLUTION
            continue
        xyz[j] = t
        rots[j] = sol_r[best]
        reproj[j] = errs[best]
        if n > 1:
            other = order[1]
            ambiguity[j] = errs[best] / errs[other] if errs[other] > 0 else 1.0
            spread[j] = np.linalg.norm(sol_t[other] - t) / np.linalg.norm(t)
    rng = np.linalg.norm(xyz, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        # angle between the line of sight and the tag plane: 90 deg minus the angle to the tag normal
        cos_normal = np.abs(np.einsum("mi,mi->m", rots[:, :, 2], xyz)) / rng
        view = np.degrees(np.arcsin(np.clip(cos_normal, 0.0, 1.0)))
    solved = status == OK
    status[solved & ~(reproj <= quality.max_reprojection_px)] = REPROJECTION
    status[(status == OK) & ~(view >= quality.min_view_angle_deg)] = GRAZING
    status[(status == OK) & (ambiguity > quality.max_ambiguity) & (spread > quality.max_centre_spread)] = AMBIGUOUS
    if quality.max_range_m is not None:
        status[(status == OK) & (rng > quality.max_range_m)] = TOO_FAR
    if quality.min_side_px > 0 and m:
        side = np.linalg.norm(ideal_px - np.roll(ideal_px, -1, axis=1), axis=2).min(axis=1)
        status[(status == OK) & (side < quality.min_side_px)] = TOO_SMALL
    quats = rots_to_quats(np.ascontiguousarray(rots)) if m else np.zeros((0, 4))
    return TagPoses(xyz, quats, reproj, ambiguity, np.where(np.isfinite(view), view, 0.0), status)
