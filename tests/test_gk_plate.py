"""The VFC plate as the hidden marker's stand-in (observer.gk.plate) against drawn truth.

Synthetic frames draw the plate (a dark square on a grey rotor) with the two markers on its
diagonal's axis, exactly where the plate's geometry puts them, turn and move it from frame to
frame and hide the red marker under a finger; the tracker must map the red centre it last saw
to where it is drawn now. The rendered hard case with the shipped network is in
tests/test_gk_trust.py.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from observer.gk.plate import PlateConfig, PlateTracker
from plant.camera import image_to_sensor, sensor_to_image
from plant.params import PlantParams

P = PlantParams()
BINNING = 4
SHIFT = 8  # cv2's fixed-point bits: sub-pixel drawing
SIZE = (512, 612)


def _draw(centre, angle, half_side, finger: bool = False):
    """A frame with the plate of half side ``half_side`` (image px) turned by ``angle`` (rad)
    about ``centre``, the red and yellow markers at -/+ L/2 along its x axis, and optionally a
    brown finger over the red one. Returns the image and the marker centres (2, 2), image px."""
    img = np.full((*SIZE, 3), 128, np.uint8)
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s], [s, c]])
    corners = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * half_side @ R.T + centre
    fixed = lambda p: np.rint(np.asarray(p) * (1 << SHIFT)).astype(np.int32)  # noqa: E731
    cv2.fillPoly(img, [fixed(corners)], (20, 20, 22), cv2.LINE_AA, SHIFT)
    r_marker = half_side * P.vfc.marker_diameter_mm / P.vfc.plate_size_mm
    L_img = half_side * 2.0 * P.vfc.L_m * 1000.0 / P.vfc.plate_size_mm
    markers = np.array([[-0.5 * L_img, 0.0], [0.5 * L_img, 0.0]]) @ R.T + centre
    for m, rgb in zip(markers, ((210, 25, 20), (225, 190, 25)), strict=True):
        cv2.circle(img, tuple(fixed(m)), int(round(r_marker * (1 << SHIFT))), rgb, -1,
                   cv2.LINE_AA, SHIFT)
    if finger:
        tip = markers[0] + [r_marker, 0.3 * r_marker]
        cv2.line(img, tuple(fixed(tip)), tuple(fixed(tip + [-400.0, 250.0])), (150, 90, 70),
                 int(3.2 * r_marker), cv2.LINE_AA)
        cv2.circle(img, tuple(np.rint(tip).astype(int)), int(1.6 * r_marker), (150, 90, 70), -1,
                   cv2.LINE_AA)
    return img, markers


def test_the_plate_maps_the_hidden_marker_while_the_rotor_turns():
    """Start on a clean frame, then 30 frames turning 2°/frame and moving 3 px/frame with the
    red marker under the finger from frame 5 on: the mapped red centre stays within 0.5 image
    px (2 sensor px) of where it is drawn, and the mapped yellow within the same of the drawn
    yellow, which ``check`` accepts."""
    tracker = PlateTracker(P)
    centre, angle, half = np.array([300.0, 250.0]), 0.3, 110.0
    img, markers = _draw(centre, angle, half)
    assert tracker.start(img, BINNING, *image_to_sensor(markers, BINNING))
    errors = []
    for k in range(1, 31):
        img, markers = _draw(centre + [3.0 * k, -1.5 * k], angle + np.deg2rad(2.0 * k), half,
                             finger=k >= 5)
        assert tracker.update(img), k
        if k < 5:  # both markers seen: the tracker keeps them as its reference
            tracker.remember(*image_to_sensor(markers, BINNING), BINNING)
            continue
        mapped = tracker.locate(BINNING)
        assert mapped is not None
        errors.append(np.hypot(*(sensor_to_image(mapped, BINNING) - markers).T))
        assert tracker.check(mapped[1], image_to_sensor(markers[1], BINNING))
    errors = np.array(errors)
    assert errors.max() < 0.5, errors.max(axis=0)
    # the finger is there: a constant-velocity guess from the last two seen frames would be
    # off by the turn, 2°/frame x 26 frames at the marker's arm of ~65 image px
    assert np.deg2rad(2.0) * 26 * 0.5 * np.hypot(*(markers[1] - markers[0])) > 30.0


def test_no_plate_no_start_and_a_wrong_yellow_loses_it():
    tracker = PlateTracker(P)
    grey = np.full((*SIZE, 3), 128, np.uint8)
    red, yellow = image_to_sensor(np.array([[250.0, 250.0], [350.0, 250.0]]), BINNING)
    assert not tracker.start(grey, BINNING, red, yellow)
    assert not tracker.tracked and tracker.locate(BINNING) is None
    assert not tracker.update(grey)  # lost stays lost, without raising

    img, markers = _draw(np.array([300.0, 250.0]), 0.1, 110.0)
    assert tracker.start(img, BINNING, *image_to_sensor(markers, BINNING))
    mapped = tracker.locate(BINNING)
    tolerance = PlateConfig().yellow_tolerance_px
    assert tracker.check(mapped[1] + 0.5 * tolerance, mapped[1])
    assert not tracker.check(mapped[1] + [tolerance + 1.0, 0.0], mapped[1])
    assert not tracker.tracked  # a plate the yellow marker contradicts is not believed


@pytest.mark.parametrize("jump_px", [60.0])
def test_a_jump_past_the_search_band_loses_the_plate(jump_px):
    """A plate that moves farther than the edge search reaches is lost, not refitted to
    something else."""
    tracker = PlateTracker(P)
    img, markers = _draw(np.array([300.0, 250.0]), 0.2, 110.0)
    assert tracker.start(img, BINNING, *image_to_sensor(markers, BINNING))
    far, _ = _draw(np.array([300.0 + jump_px, 250.0 + jump_px]), 0.9, 110.0)
    assert not tracker.update(far)
    assert tracker.locate(BINNING) is None
