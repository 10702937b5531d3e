"""Compiled normal equations of the batch smoother and their solution over the graph's structure.

The unknowns are the keyframe poses (6 each, tangent ``[θ; ρ]``: ``R ← R Exp(θ)``, ``P ← P + Rρ``, GTSAM's
convention, :mod:`pipeline.smoother.preintegration`), the landmarks (3 each) and the segment biases (6 each).
Relative motion couples consecutive keyframes only, a detection one keyframe and one landmark; so the
information matrix is block tridiagonal in the poses (``A``) with a border of ``n_b = 3L + 6S`` columns (``B``,
``C``):

    [A  B] [x_a]   [r_a]        W = L⁻¹B,  z = L⁻¹r_a  (A = L Lᵀ, L block lower bidiagonal),
    [Bᵀ C] [x_b] = [r_b]        (C − WᵀW) x_b = r_b − Wᵀz,   A x_a = r_a − B x_b.

One forward sweep factors ``A`` block by block and accumulates the border's Schur complement (the rows of ``W``
of 32 keyframes at a time, in register tiles); a second forward and backward sweep gives the poses. Nothing of
size ``K × n_b`` is held: ``W``'s rows are recomputed where needed. The marginal covariances come from the same
factors: the poses' diagonal blocks of ``A⁻¹`` by the block tridiagonal recursion
``Z_ii = (D_i D_iᵀ)⁻¹ + F_iᵀ Z_{i+1,i+1} F_i`` (``F_i = E_{i+1} D_i⁻¹``), plus ``V_i S⁻¹ V_iᵀ`` with ``V = A⁻¹B``
(``Lᵀ V = W``, backward), and the border's marginals from ``S⁻¹``. Cost per sweep: ``O(K n_b²)`` flops.

The landmark factor is the body-frame point ``Rᵀ(ℓ − P) − y`` with an isotropic standard deviation ``σ`` per
axis and a Huber kernel on the norm of the whitened residual (GTSAM's ``Robust`` model: the residual and
Jacobian scaled by the square root of the weight), the model the χ² gate and the candidates' detection cost
use.
"""

from __future__ import annotations

import math

import numpy as np

from slamobs.pipeline.kernel_cache import njit
from slamobs.pipeline.lie import so3_exp, so3_log
from slamobs.pipeline.smoother.preintegration import motion_residual

#: Keyframes whose rows of ``W`` enter the Schur complement together (:func:`_schur_update`).
BATCH = 32
#: Keyframes between the stored rows of ``W`` from which the covariance sweep recomputes the others.
CHECKPOINT = 512


@njit(cache=True)
def detection_terms(rot, pos, lms, kf_of_det, det_idx, det_y, det_sigma, shape, huber, weight):
    """Huber-robust cost of every detection at the point, and each detection's ``weight / σ²`` (into
    ``weight``) for the normal equations. ``shape`` (M, 3, 3): each detection's information matrix in the body
    frame relative to ``1/σ²`` (range and bearing weighed apart, :mod:`pipeline.smoother.anisotropy`), or
    empty (0, 3, 3): the identity, every axis alike."""
    total = 0.0
    d = np.empty(3)
    shaped = shape.shape[0] > 0
    for m in range(kf_of_det.shape[0]):
        i, lm = kf_of_det[m], det_idx[m]
        e2 = 0.0
        for c in range(3):
            q = (
                rot[i, 0, c] * (lms[lm, 0] - pos[i, 0])
                + rot[i, 1, c] * (lms[lm, 1] - pos[i, 1])
                + rot[i, 2, c] * (lms[lm, 2] - pos[i, 2])
            )
            d[c] = q - det_y[m, c]
            e2 += d[c] ** 2
        if shaped:
            e2 = 0.0
            for c in range(3):
                for k in range(3):
                    e2 += d[c] * shape[m, c, k] * d[k]
        s2 = max(det_sigma[m], 1e-12) ** 2
        e = math.sqrt(max(e2, 0.0) / s2)
        if e <= huber:
            total += 0.5 * e * e
            weight[m] = 1.0 / s2
        else:
            total += huber * (e - 0.5 * huber)
            weight[m] = huber / e / s2
    return total


@njit(cache=True)
def motion_terms(data, b_bar, rot, pos, bias, seg_of, ad, ao, mb, ga, c, gb, bias0):
    """The relative-motion factors' part of the normal equations (added into ``ad``, ``ao``, ``mb``, ``ga`` and
    the bias blocks of ``c``, ``gb``, whose bias columns start at ``bias0``)."""
    ti = np.eye(4)
    tj = np.eye(4)
    rw = np.empty(6)
    hh = np.empty((3, 6, 6))
    for j in range(data.shape[0]):
        ti[:3, :3] = rot[j]
        ti[:3, 3] = pos[j]
        tj[:3, :3] = rot[j + 1]
        tj[:3, 3] = pos[j + 1]
        s = seg_of[j]
        motion_residual(data, j, b_bar, ti, tj, bias[s], rw, hh, True)
        b0 = bias0 + 6 * s
        for p in range(6):
            for q in range(6):
                a00 = a01 = a11 = a0b = a1b = abb = 0.0
                for m in range(6):
                    a00 += hh[0, m, p] * hh[0, m, q]
                    a01 += hh[0, m, p] * hh[1, m, q]
                    a11 += hh[1, m, p] * hh[1, m, q]
                    a0b += hh[0, m, p] * hh[2, m, q]
                    a1b += hh[1, m, p] * hh[2, m, q]
                    abb += hh[2, m, p] * hh[2, m, q]
                ad[j, p, q] += a00
                ao[j, p, q] += a01
                ad[j + 1, p, q] += a11
                mb[j, 0, p, q] = a0b
                mb[j, 1, p, q] = a1b
                c[b0 + p, b0 + q] += abb
            g0 = g1 = gbb = 0.0
            for m in range(6):
                g0 += hh[0, m, p] * rw[m]
                g1 += hh[1, m, p] * rw[m]
                gbb += hh[2, m, p] * rw[m]
            ga[j, p] += g0
            ga[j + 1, p] += g1
            gb[b0 + p] += gbb


@njit(cache=True)
def detection_normal(rot, pos, lms, kf_of_det, det_idx, det_y, weight, shape, ad, ga, c, gb):
    """The detections' part of the normal equations: pose and landmark diagonal blocks and gradients (the
    pose-landmark blocks are recomputed by :func:`border_row` where needed); ``shape`` as in
    :func:`detection_terms`."""
    if shape.shape[0] > 0:
        _shaped_normal(rot, pos, lms, kf_of_det, det_idx, det_y, weight, shape, ad, ga, c, gb)
        return
    for m in range(kf_of_det.shape[0]):
        i, lm, a = kf_of_det[m], det_idx[m], weight[m]
        r = rot[i]
        e0, e1, e2 = lms[lm, 0] - pos[i, 0], lms[lm, 1] - pos[i, 1], lms[lm, 2] - pos[i, 2]
        q0 = r[0, 0] * e0 + r[1, 0] * e1 + r[2, 0] * e2
        q1 = r[0, 1] * e0 + r[1, 1] * e1 + r[2, 1] * e2
        q2 = r[0, 2] * e0 + r[1, 2] * e1 + r[2, 2] * e2
        d0, d1, d2 = q0 - det_y[m, 0], q1 - det_y[m, 1], q2 - det_y[m, 2]
        # J_pose = [[q]×, −I], J_ℓ = Rᵀ (times √a); [q]×ᵀ[q]× = |q|² I − q qᵀ
        qq = q0 * q0 + q1 * q1 + q2 * q2
        h = ad[i]
        h[0, 0] += a * (qq - q0 * q0)
        h[1, 1] += a * (qq - q1 * q1)
        h[2, 2] += a * (qq - q2 * q2)
        h[0, 1] -= a * q0 * q1
        h[1, 0] -= a * q0 * q1
        h[0, 2] -= a * q0 * q2
        h[2, 0] -= a * q0 * q2
        h[1, 2] -= a * q1 * q2
        h[2, 1] -= a * q1 * q2
        # −[q]×ᵀ = [q]× (top right), −[q]× (bottom left)
        h[0, 4] -= a * q2
        h[0, 5] += a * q1
        h[1, 3] += a * q2
        h[1, 5] -= a * q0
        h[2, 3] -= a * q1
        h[2, 4] += a * q0
        h[4, 0] -= a * q2
        h[5, 0] += a * q1
        h[3, 1] += a * q2
        h[5, 1] -= a * q0
        h[3, 2] -= a * q1
        h[4, 2] += a * q0
        for p in range(3):
            h[3 + p, 3 + p] += a
            c[3 * lm + p, 3 * lm + p] += a
        # [q]×ᵀ d = d × q
        ga[i, 0] += a * (d1 * q2 - d2 * q1)
        ga[i, 1] += a * (d2 * q0 - d0 * q2)
        ga[i, 2] += a * (d0 * q1 - d1 * q0)
        ga[i, 3] -= a * d0
        ga[i, 4] -= a * d1
        ga[i, 5] -= a * d2
        for p in range(3):
            gb[3 * lm + p] += a * (r[p, 0] * d0 + r[p, 1] * d1 + r[p, 2] * d2)


@njit(cache=True)
def _skew_t_times(q, m, out):
    """``out = [q]×ᵀ m`` for a (3, n) ``m`` (``[q]×ᵀ = −[q]×``: row p is ``(m × q)`` taken column-wise)."""
    for col in range(m.shape[1]):
        out[0, col] = q[2] * m[1, col] - q[1] * m[2, col]
        out[1, col] = q[0] * m[2, col] - q[2] * m[0, col]
        out[2, col] = q[1] * m[0, col] - q[0] * m[1, col]


@njit(cache=True)
def _shaped_normal(rot, pos, lms, kf_of_det, det_idx, det_y, weight, shape, ad, ga, c, gb):
    """:func:`detection_normal` with each detection's information ``a·S`` (``J_pose = [[q]×, −I]``,
    ``J_ℓ = Rᵀ``): ``[[q]×ᵀS[q]×, −[q]×ᵀS; −S[q]×, S]``, ``R S Rᵀ``, gradients ``[[q]×ᵀSd; −Sd]``, ``R S d``."""
    q = np.empty(3)
    d = np.empty((3, 1))
    sq = np.empty((3, 3))  # S [q]×
    qsq = np.empty((3, 3))
    sd = np.empty((3, 1))
    qsd = np.empty((3, 1))
    qx = np.empty((3, 3))
    for m in range(kf_of_det.shape[0]):
        i, lm, a = kf_of_det[m], det_idx[m], weight[m]
        r, sm = rot[i], shape[m]
        e0, e1, e2 = lms[lm, 0] - pos[i, 0], lms[lm, 1] - pos[i, 1], lms[lm, 2] - pos[i, 2]
        for p in range(3):
            q[p] = r[0, p] * e0 + r[1, p] * e1 + r[2, p] * e2
            d[p, 0] = q[p] - det_y[m, p]
        qx[0, 0], qx[0, 1], qx[0, 2] = 0.0, -q[2], q[1]
        qx[1, 0], qx[1, 1], qx[1, 2] = q[2], 0.0, -q[0]
        qx[2, 0], qx[2, 1], qx[2, 2] = -q[1], q[0], 0.0
        for p in range(3):
            for k in range(3):
                sq[p, k] = sm[p, 0] * qx[0, k] + sm[p, 1] * qx[1, k] + sm[p, 2] * qx[2, k]
            sd[p, 0] = sm[p, 0] * d[0, 0] + sm[p, 1] * d[1, 0] + sm[p, 2] * d[2, 0]
        _skew_t_times(q, sq, qsq)
        _skew_t_times(q, sd, qsd)
        h = ad[i]
        for p in range(3):
            for k in range(3):
                h[p, k] += a * qsq[p, k]
                h[3 + p, 3 + k] += a * sm[p, k]
                h[3 + p, k] -= a * sq[p, k]  # −S[q]×
                h[k, 3 + p] -= a * sq[p, k]  # its transpose
            ga[i, p] += a * qsd[p, 0]
            ga[i, 3 + p] -= a * sd[p, 0]
        for p in range(3):  # R S Rᵀ and R S d
            v = 0.0
            for u in range(3):
                v += r[p, u] * sd[u, 0]
            gb[3 * lm + p] += a * v
            for k in range(3):
                v = 0.0
                for u in range(3):
                    for w in range(3):
                        v += r[p, u] * sm[u, w] * r[k, w]
                c[3 * lm + p, 3 * lm + k] += a * v


@njit(cache=True)
def border_row(i, rot, pos, lms, det_lo, det_hi, det_idx, weight, shape, mb, seg_of, bias0, out):
    """Row block ``i`` of ``B`` (6 × n_b): the pose's coupling to the landmarks it sees and to its biases
    (``shape`` as in :func:`detection_terms`)."""
    out[:] = 0.0
    r = rot[i]
    shaped = shape.shape[0] > 0
    q = np.empty(3)
    srt = np.empty((3, 3))  # S Rᵀ
    qsrt = np.empty((3, 3))
    for m in range(det_lo, det_hi):
        if shaped:  # J_poseᵀ a S J_ℓ = a [[q]×ᵀ S Rᵀ; −S Rᵀ]
            lm, a, sm = det_idx[m], weight[m], shape[m]
            d0, d1, d2 = lms[lm, 0] - pos[i, 0], lms[lm, 1] - pos[i, 1], lms[lm, 2] - pos[i, 2]
            for p in range(3):
                q[p] = r[0, p] * d0 + r[1, p] * d1 + r[2, p] * d2
                for k in range(3):
                    srt[p, k] = sm[p, 0] * r[k, 0] + sm[p, 1] * r[k, 1] + sm[p, 2] * r[k, 2]
            _skew_t_times(q, srt, qsrt)
            for k in range(3):
                col = 3 * lm + k
                for p in range(3):
                    out[p, col] += a * qsrt[p, k]
                    out[3 + p, col] -= a * srt[p, k]
            continue
        lm, a = det_idx[m], weight[m]
        d0, d1, d2 = lms[lm, 0] - pos[i, 0], lms[lm, 1] - pos[i, 1], lms[lm, 2] - pos[i, 2]
        q0 = r[0, 0] * d0 + r[1, 0] * d1 + r[2, 0] * d2
        q1 = r[0, 1] * d0 + r[1, 1] * d1 + r[2, 1] * d2
        q2 = r[0, 2] * d0 + r[1, 2] * d1 + r[2, 2] * d2
        for c in range(3):  # J_poseᵀ J_ℓ = a [[q]×ᵀ Rᵀ; −Rᵀ], [q]×ᵀ = −[q]×
            col = 3 * lm + c
            out[0, col] += a * (q2 * r[c, 1] - q1 * r[c, 2])
            out[1, col] += a * (q0 * r[c, 2] - q2 * r[c, 0])
            out[2, col] += a * (q1 * r[c, 0] - q0 * r[c, 1])
            out[3, col] -= a * r[c, 0]
            out[4, col] -= a * r[c, 1]
            out[5, col] -= a * r[c, 2]
    n = seg_of.shape[0]
    if i < n:
        b0 = bias0 + 6 * seg_of[i]
        for p in range(6):
            for q in range(6):
                out[p, b0 + q] += mb[i, 0, p, q]
    if i > 0:
        b0 = bias0 + 6 * seg_of[i - 1]
        for p in range(6):
            for q in range(6):
                out[p, b0 + q] += mb[i - 1, 1, p, q]


@njit(cache=True)
def _lower_solve(d, b, out):
    """``out = d⁻¹ b`` for a lower triangular (6, 6) ``d`` and a (6, n) ``b`` (row by row: contiguous)."""
    n = b.shape[1]
    for p in range(6):
        op, bp = out[p], b[p]
        for col in range(n):
            op[col] = bp[col]
        for k in range(p):
            x, ok = d[p, k], out[k]
            for col in range(n):
                op[col] -= x * ok[col]
        inv = 1.0 / d[p, p]
        for col in range(n):
            op[col] *= inv


@njit(cache=True)
def _upper_solve(d, b, out):
    """``out = d⁻ᵀ b`` for a lower triangular (6, 6) ``d`` and a (6, n) ``b``."""
    n = b.shape[1]
    for p in range(5, -1, -1):
        op, bp = out[p], b[p]
        for col in range(n):
            op[col] = bp[col]
        for k in range(p + 1, 6):
            x, ok = d[k, p], out[k]
            for col in range(n):
                op[col] -= x * ok[col]
        inv = 1.0 / d[p, p]
        for col in range(n):
            op[col] *= inv


@njit(cache=True)
def _cholesky6(m, out):
    """Lower Cholesky factor of a (6, 6) ``m`` into ``out``; False unless positive definite."""
    out[:] = 0.0
    for j in range(6):
        x = m[j, j]
        for k in range(j):
            x -= out[j, k] * out[j, k]
        if not x > 0.0:
            return False
        out[j, j] = math.sqrt(x)
        for i in range(j + 1, 6):
            y = m[i, j]
            for k in range(j):
                y -= out[i, k] * out[j, k]
            out[i, j] = y / out[j, j]
    return True


@njit(cache=True)
def _sub_product(a, b, out, transpose):
    """``out −= a b`` (or ``aᵀ b``) for a (6, 6) ``a`` and a (6, n) ``b``."""
    for p in range(6):
        for k in range(6):
            x = a[k, p] if transpose else a[p, k]
            if x != 0.0:
                for col in range(b.shape[1]):
                    out[p, col] -= x * b[k, col]


@njit(cache=True)
def _w_row(i, dd, ee, brow, w_prev, out):
    """``W_i = D_i⁻¹(B_i − E_i W_{i−1})``."""
    if i > 0:
        _sub_product(ee[i], w_prev, brow, False)
    _lower_solve(dd[i], brow, out)


@njit(cache=True, fastmath=True)
def _schur_update(wt, zt, used, s, rb):
    """``S −= W_Rᵀ W_R`` (2 × 2 tiles of the upper triangle, ``n_b`` even) and ``r_b −= W_Rᵀ z_R`` for the first
    ``used`` columns of ``wt`` (n_b, 6R), the rows of ``W`` of up to ``R`` keyframes side by side: the products
    over ``6R`` rows at once, which keeps the operands in registers."""
    nb = wt.shape[0]
    for a in range(0, nb, 2):
        wa0, wa1 = wt[a], wt[a + 1]
        y0 = y1 = 0.0
        for r in range(used):
            y0 += wa0[r] * zt[r]
            y1 += wa1[r] * zt[r]
        rb[a] -= y0
        rb[a + 1] -= y1
        for b in range(a, nb, 2):
            wb0, wb1 = wt[b], wt[b + 1]
            x00 = x01 = x10 = x11 = 0.0
            for r in range(used):
                x00 += wa0[r] * wb0[r]
                x01 += wa0[r] * wb1[r]
                x10 += wa1[r] * wb0[r]
                x11 += wa1[r] * wb1[r]
            s[a, b] -= x00
            s[a, b + 1] -= x01
            s[a + 1, b] -= x10
            s[a + 1, b + 1] -= x11


@njit(cache=True)
def factor(ad, ao, lam, ra, geo, dd, ee, s, rb):
    """Factor ``A + λI`` (``dd``: diagonal Cholesky blocks, ``ee``: the blocks of ``L`` below them), ``ra``
    overwritten by ``z = L⁻¹ r_a``, and the Schur complement ``S −= WᵀW`` (upper triangle of ``s``) with its
    right side ``rb −= Wᵀz``. ``geo``: the detections and biases for :func:`border_row`. False if ``A + λI``
    is not positive definite."""
    rot, pos, lms, det_start, det_idx, weight, shape, mb, seg_of, bias0 = geo
    nb = s.shape[0]
    pad = nb + nb % 2
    w_prev = np.zeros((6, nb))
    w = np.zeros((6, nb))
    wt = np.zeros((pad, 6 * BATCH))
    zt = np.zeros(6 * BATCH)
    acc = np.zeros((pad, pad))
    rba = np.zeros(pad)
    used = 0
    m = np.empty((6, 6))
    et = np.empty((6, 6))
    brow = np.empty((6, nb))
    rhs = np.empty((6, 1))
    z = np.empty((6, 1))
    for i in range(ad.shape[0]):
        m[:] = ad[i]
        for p in range(6):
            m[p, p] += lam
        if i > 0:
            _lower_solve(dd[i - 1], ao[i - 1], et)  # E_iᵀ = D_{i−1}⁻¹ A_{i−1,i}
            ee[i] = et.T
            _sub_product(et, et, m, True)  # − E_i E_iᵀ
        if not _cholesky6(m, dd[i]):
            return False
        border_row(i, rot, pos, lms, det_start[i], det_start[i + 1], det_idx, weight, shape, mb, seg_of, bias0, brow)
        _w_row(i, dd, ee, brow, w_prev, w)
        rhs[:, 0] = ra[i]
        if i > 0:
            _sub_product(ee[i], ra[i - 1].reshape(6, 1), rhs, False)
        _lower_solve(dd[i], rhs, z)
        ra[i] = z[:, 0]
        for p in range(6):
            wt[:nb, used + p] = w[p]
            zt[used + p] = z[p, 0]
        used += 6
        if used == 6 * BATCH or i == ad.shape[0] - 1:
            _schur_update(wt, zt, used, acc, rba)
            used = 0
        w_prev[:] = w
    s += acc[:nb, :nb]
    rb += rba[:nb]
    return True


@njit(cache=True)
def back_substitute(z, xb, geo, dd, ee, x):
    """The poses' step ``x`` (K, 6) from ``A x_a = r_a − B x_b``, given ``z = L⁻¹ r_a`` and the border's step."""
    rot, pos, lms, det_start, det_idx, weight, shape, mb, seg_of, bias0 = geo
    k, nb = z.shape[0], xb.shape[0]
    brow = np.empty((6, nb))
    rhs = np.empty((6, 1))
    bx = np.empty((6, 1))
    y = np.empty((k, 6))
    prev = np.zeros((6, 1))
    for i in range(k):  # y = z + L⁻¹(−B x_b): y_i = z_i + D_i⁻¹(−B_i x_b − E_i (y − z)_{i−1})
        border_row(i, rot, pos, lms, det_start[i], det_start[i + 1], det_idx, weight, shape, mb, seg_of, bias0, brow)
        for p in range(6):
            v = 0.0
            for col in range(nb):
                v -= brow[p, col] * xb[col]
            rhs[p, 0] = v
        if i > 0:
            _sub_product(ee[i], prev, rhs, False)
        _lower_solve(dd[i], rhs, bx)
        prev[:] = bx
        y[i] = bx[:, 0] + z[i]
    nxt = np.zeros((6, 1))
    for i in range(k - 1, -1, -1):  # Lᵀ x = y
        rhs[:, 0] = y[i]
        if i < k - 1:
            _sub_product(ee[i + 1], nxt, rhs, True)
        _upper_solve(dd[i], rhs, bx)
        nxt[:] = bx
        x[i] = bx[:, 0]


@njit(cache=True)
def _marginal(z, v, s_inv, out):
    """``Z_ii + V_i S⁻¹ V_iᵀ``."""
    nb = v.shape[1]
    vs = np.zeros((6, nb))
    for p in range(6):
        for k in range(nb):
            x = v[p, k]
            if x != 0.0:
                for col in range(nb):
                    vs[p, col] += x * s_inv[k, col]
    for p in range(6):
        for q in range(6):
            x = z[p, q]
            for col in range(nb):
                x += vs[p, col] * v[q, col]
            out[p, q] = x


@njit(cache=True)
def pose_marginals(geo, dd, ee, s_inv, wanted, out):
    """Marginal covariances (body twist) of the keyframes ``wanted`` (sorted) into ``out``: ``Z_ii + V_i S⁻¹ V_iᵀ``
    (module docstring), with ``W``'s rows recomputed a ``CHECKPOINT`` at a time from stored ones."""
    rot, pos, lms, det_start, det_idx, weight, shape, mb, seg_of, bias0 = geo
    k, nb = dd.shape[0], s_inv.shape[0]
    n_cp = (k + CHECKPOINT - 1) // CHECKPOINT
    cps = np.zeros((n_cp, 6, nb))  # W at the row before each stretch
    brow = np.empty((6, nb))
    w = np.zeros((6, nb))
    w_prev = np.zeros((6, nb))
    for i in range(k):
        if i % CHECKPOINT == 0:
            cps[i // CHECKPOINT] = w_prev
        border_row(i, rot, pos, lms, det_start[i], det_start[i + 1], det_idx, weight, shape, mb, seg_of, bias0, brow)
        _w_row(i, dd, ee, brow, w_prev, w)
        w_prev[:] = w
    seg = np.empty((CHECKPOINT, 6, nb))
    v_next = np.zeros((6, nb))
    v = np.empty((6, nb))
    z_next = np.zeros((6, 6))
    z = np.empty((6, 6))
    inv_d = np.empty((6, 6))
    f = np.empty((6, 6))
    fz = np.empty((6, 6))
    j = wanted.shape[0] - 1
    for s in range(n_cp - 1, -1, -1):
        lo, hi = s * CHECKPOINT, min(k, (s + 1) * CHECKPOINT)
        w_prev[:] = cps[s]
        for i in range(lo, hi):
            border_row(
                i, rot, pos, lms, det_start[i], det_start[i + 1], det_idx, weight, shape, mb, seg_of, bias0, brow
            )
            _w_row(i, dd, ee, brow, w_prev, seg[i - lo])
            w_prev[:] = seg[i - lo]
        for i in range(hi - 1, lo - 1, -1):
            _lower_solve(dd[i], np.eye(6), inv_d)  # D_i⁻¹
            z[:] = 0.0
            _sub_product(inv_d, inv_d, z, True)  # −D_i⁻ᵀ D_i⁻¹
            z *= -1.0
            brow[:] = seg[i - lo]
            if i < k - 1:
                _sub_product(ee[i + 1], v_next, brow, True)
                f[:] = 0.0
                _sub_product(ee[i + 1].T.copy(), inv_d, f, True)  # −F_i = −E_{i+1} D_i⁻¹
                fz[:] = 0.0
                _sub_product(f, z_next, fz, True)  # F_iᵀ Z_{i+1}
                _sub_product(fz.T.copy(), f, z, True)  # + F_iᵀ Z_{i+1} F_i (two signs)
            _upper_solve(dd[i], brow, v)
            v_next[:] = v
            z_next[:] = z
            if j >= 0 and wanted[j] == i:
                _marginal(z, v, s_inv, out[j])
                j -= 1


@njit(cache=True)
def retract(rot, pos, lms, bias, x, xb, n_lm, out_rot, out_pos, out_lms, out_bias):
    """The point moved by the step: ``R Exp(θ)``, ``P + Rρ``, landmarks and biases added."""
    for i in range(rot.shape[0]):
        e = so3_exp(x[i, :3].copy())
        for p in range(3):
            for q in range(3):
                out_rot[i, p, q] = rot[i, p, 0] * e[0, q] + rot[i, p, 1] * e[1, q] + rot[i, p, 2] * e[2, q]
            out_pos[i, p] = pos[i, p] + rot[i, p, 0] * x[i, 3] + rot[i, p, 1] * x[i, 4] + rot[i, p, 2] * x[i, 5]
    for lm in range(n_lm):
        out_lms[lm] = lms[lm] + xb[3 * lm : 3 * lm + 3]
    for s in range(bias.shape[0]):
        out_bias[s] = bias[s] + xb[3 * n_lm + 6 * s : 3 * n_lm + 6 * s + 6]


@njit(cache=True)
def pose_deviation(r0, p0, rot, pos):
    """``[Log(R₀ᵀR); R₀ᵀ(P − P₀)]``: how far a pose moved from ``(r0, p0)`` (the gauge prior's residual)."""
    out = np.empty(6)
    rel = np.empty((3, 3))
    for p in range(3):
        for q in range(3):
            rel[p, q] = r0[0, p] * rot[0, q] + r0[1, p] * rot[1, q] + r0[2, p] * rot[2, q]
        out[3 + p] = r0[0, p] * (pos[0] - p0[0]) + r0[1, p] * (pos[1] - p0[1]) + r0[2, p] * (pos[2] - p0[2])
    out[:3] = so3_log(rel)
    return out
