"""What every landmark observer does when a detection frame arrives, as one compiled helper.

A frame replaces the visible set: its landmark indices and body-frame measurements become the observer's
``vis_idx``/``y``; a landmark seen for the first time is placed at ``P̂ + R̂y`` so that its innovation starts at
zero (spec §8); every detection's innovation ``p̂_i − R̂y_i − P̂`` and the landmark estimate it was compared
with are recorded.
"""

from __future__ import annotations

from numba import njit


@njit(cache=True)
def load_frame(a, nvis, det_idx, det_y, r_hat, p_hat, lm, lm_init, vis_idx, y, innov, trk_p, row):
    """Take detections ``a .. a + nvis - 1`` as the visible set; their output rows start at ``row``."""
    for j in range(nvis):
        i = det_idx[a + j]
        vis_idx[j] = i
        for c in range(3):
            y[j, c] = det_y[a + j, c]
        for c in range(3):  # R̂y, written out: no temporary per detection
            ry = r_hat[c, 0] * y[j, 0] + r_hat[c, 1] * y[j, 1] + r_hat[c, 2] * y[j, 2]
            if not lm_init[i]:
                lm[i, c] = p_hat[c] + ry
            innov[row + j, c] = lm[i, c] - ry - p_hat[c]
            trk_p[row + j, c] = lm[i, c]
        lm_init[i] = True
