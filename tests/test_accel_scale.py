"""The velocity's own scale from the IMU's accelerometer (``observers.accel_scale``): the detection pairs'
velocity-scale warning names the one cause the accelerometer points at (session 29)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from slamobs.pipeline.alignment import align
from slamobs.pipeline.observers import accel_scale, time_offset
from slamobs.pipeline.simulate import expected_streams, simulate


@pytest.fixture(scope="module")
def figure8():
    return align(expected_streams(simulate("figure8", seed=2, duration=40.0)))


def _scale_warnings(stream) -> list[str]:
    notes = time_offset.note(None, time_offset.estimate(stream))
    return [n for n in notes if "the detections say the body moved" in n]


def test_a_velocity_in_another_unit_is_told_from_a_tag_size_off(figure8):
    # main named both causes for both (time_offset.SCALE_CAUSES): the pairs cannot tell them apart
    assert _scale_warnings(figure8) == []  # as recorded: nothing
    slow = _scale_warnings(replace(figure8, velocity=figure8.velocity * 0.5))  # the velocity half its size
    assert slow and all("the velocity is off" in n and "cannot tell which" not in n for n in slow), slow
    assert all("IMU's accelerometer says so too (1.8" in n for n in slow), slow
    tags = _scale_warnings(replace(figure8, det_y=figure8.det_y * 2.0))  # tags.size twice the tags'
    assert tags and all("the detections' scale is off (tags.size" in n for n in tags), tags
    assert all("says the velocity reads right (0.9" in n and "cannot tell which" not in n for n in tags), tags


def test_a_constant_motion_leaves_both_causes_named():
    # a circle at one speed: an accelerometer bias and a tilt take the centripetal acceleration, the velocity's
    # noise left pulls the fitted scale to 0 (rho2 ~0); said as the pairs say it, not as the detections' scale
    stream = align(expected_streams(simulate("circle", seed=2, duration=40.0)))
    accel = accel_scale.velocity_scale_by_accel(stream)
    assert accel is not None and accel["rho2"] < accel_scale.MIN_RHO2 and abs(accel["scale"]) < 0.1, accel
    assert accel_scale.scale_cause(2.0, accel, time_offset.SCALE_CAUSES) == time_offset.SCALE_CAUSES
    assert accel_scale.scale_cause(2.0, None, time_offset.SCALE_CAUSES) == time_offset.SCALE_CAUSES
