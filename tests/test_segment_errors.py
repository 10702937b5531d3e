"""rpg_trajectory_evaluation's alignments and segment errors (issue 26 §4): ``posyaw`` is the 4-DoF alignment,
and the relative error per sub-trajectory length matches rpg's own definitions."""

from __future__ import annotations

import numpy as np
import pytest

from slamobs.pipeline.evaluation import ReportOptions, build_report
from slamobs.pipeline.evaluation.align import fit_alignment
from slamobs.pipeline.lie import quats_to_rots, rots_to_quats, so3_exp
from slamobs.pipeline.streams import PoseStream

T0_NS = 1_700_000_000_000_000_000


def _rz(th: float) -> np.ndarray:
    return so3_exp(np.array([0.0, 0.0, th]))


def make_truth(n: int = 1200, dt_ns: int = 20_000_000) -> PoseStream:
    """A tilted loop with turning attitude."""
    t = np.arange(n, dtype=np.int64) * dt_ns + T0_NS
    s = (t - T0_NS) / 1e9
    pos = np.stack([4.0 * np.sin(0.3 * s), 3.0 * np.sin(0.6 * s), 1.0 + 0.4 * np.cos(0.2 * s)], axis=1)
    rots = np.array([so3_exp(np.array([0.1 * np.sin(0.5 * x), 0.2 * np.cos(0.3 * x), 0.3 * x])) for x in s])
    return PoseStream("/truth", "world", "body", t, t.copy(), pos, rots_to_quats(rots))


def poses_of(t_ns, pos, rots):
    import pandas as pd

    q = rots_to_quats(np.ascontiguousarray(rots))
    return pd.DataFrame({"t_ns": t_ns, **dict(zip("xyz", pos.T)), **dict(zip(("qx", "qy", "qz", "qw"), q.T))})


@pytest.fixture(scope="module")
def truth() -> PoseStream:
    return make_truth()


def test_posyaw_is_the_4dof_alignment(truth):
    rng = np.random.default_rng(3)
    yaw, shift = _rz(0.9), np.array([1.0, -2.0, 0.5])
    est = (truth.position - shift) @ yaw  # truth = yaw · est + shift
    est += 0.001 * rng.standard_normal(est.shape)
    ref_r = quats_to_rots(truth.quat_xyzw)
    est_r = np.einsum("ji,njk->nik", yaw, ref_r)
    al = fit_alignment("posyaw", truth.position, est)
    assert al.kind == "yaw" and np.allclose(al.rot, yaw, atol=1e-3) and np.allclose(al.trans, shift, atol=5e-3)
    # one frame (rpg align_num_frames: 1): the yaw of the first pose pair, the first positions put together
    one = fit_alignment("posyaw", truth.position, est, ref_r, est_r, n=1)
    assert one.n_points == 1 and np.allclose(one.rot, yaw, atol=1e-9)
    assert np.allclose(one.positions(est[:1]), truth.position[:1], atol=1e-12)
    with pytest.raises(ValueError, match="posyaw"):
        ReportOptions(align="posyaws")


def test_report_with_posyaw(truth):
    yaw, shift = _rz(-0.4), np.array([0.3, 0.2, -0.1])
    rots = np.einsum("ij,njk->nik", yaw, quats_to_rots(truth.quat_xyzw))
    rep = build_report(poses_of(truth.t_ns, truth.position @ yaw.T + shift, rots), None, None, truth, align="posyaw")
    assert rep["method"]["alignment"]["type"] == "yaw"
    assert rep["ape"]["translation_m"]["rmse"] < 1e-9
