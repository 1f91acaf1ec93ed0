"""Bad input on the Python API, as a user's script could pass it: a clear ``ValueError``
naming the argument, or (``track``, which never raises) a failed result with the reason."""

from __future__ import annotations

import math

import numpy as np
import pytest

from experiments import cvat
from latency.models import Constant, Gamma, Normal, Uniform
from observer.aekf import AEKFConfig
from observer.gk.pixel_kalman import PixelKalmanConfig
from observer.trackers.k2cf import K2CF

NOT_IMAGES = {
    "None": None,
    "a string": "frame.png",
    "a list": [[[0, 0, 0]]],
    "NaN floats": np.full((60, 80, 3), np.nan),
    "a 0x0 array": np.zeros((0, 0, 3), np.uint8),
}


def _textured_frame(shift: int = 0) -> np.ndarray:
    """A 120 x 160 RGB frame with a bright square at (60 + shift, 40)."""
    img = np.random.default_rng(0).integers(0, 40, (120, 160, 3)).astype(np.uint8)
    img[40:60, 60 + shift : 80 + shift] = (230, 40, 40)
    return img


@pytest.mark.parametrize("what", list(NOT_IMAGES))
def test_k2cf_track_on_a_non_image_fails_with_the_reason(what):
    """``track`` never raises: a frame that is no image gives a failed result (no box, not
    valid, not measured) saying why, and the track goes on from where it was."""
    k2 = K2CF()
    k2.initialize(_textured_frame(), (60, 40, 20, 20))
    assert k2.track(_textured_frame(1)).valid
    res = k2.track(NOT_IMAGES[what])
    assert not res.valid and not res.measured and res.score == 0.0
    assert np.all(np.isnan(res.box_image_px))
    assert "frame" in res.reason
    after = k2.track(_textured_frame(2))
    assert after.valid and after.measured
    assert after.centre_image_px == pytest.approx([72.0, 50.0], abs=1.0)


@pytest.mark.parametrize("what", list(NOT_IMAGES))
def test_k2cf_initialize_on_a_non_image_raises(what):
    with pytest.raises(ValueError, match="frame"):
        K2CF().initialize(NOT_IMAGES[what], (60, 40, 20, 20))


@pytest.mark.parametrize("scale", [1e-300, 1e-20, 0.0, -1.0, math.inf])
def test_pixel_kalman_refuses_a_measurement_noise_without_meaning(scale):
    with pytest.raises(ValueError, match="R"):
        PixelKalmanConfig(R=np.diag([scale, scale]).tolist())


def test_a_scenario_refuses_a_pixel_noise_without_meaning():
    from latency import Scenario

    with pytest.raises(ValueError, match="pixel_r_scale"):
        Scenario.model_validate({"observer": {"kind": "pixel_kalman", "pixel_r_scale": 1e-300}})


def test_pixel_kalman_accepts_the_seeds_and_a_tiny_but_meaningful_noise():
    assert PixelKalmanConfig(R=(0.1 * np.eye(2)).tolist()).R[0][0] == 0.1  # seed 000 §3.2.1
    assert PixelKalmanConfig(R=(1e-10 * np.eye(2)).tolist()).R[0][0] == 1e-10


@pytest.mark.parametrize("field", ["sigma_px", "max_step_s", "theta", "q_omega_rad2_per_s3",
                                   "history_s"])
@pytest.mark.parametrize("value", [math.inf, math.nan])
def test_aekf_config_refuses_numbers_that_are_not_finite(field, value):
    with pytest.raises(ValueError, match=field):
        AEKFConfig(**{field: value})


@pytest.mark.parametrize(
    ("model", "kwargs", "field"),
    [
        (Constant, {"value_s": math.inf}, "value_s"),
        (Normal, {"mean_value_s": math.inf, "std_s": 0.001}, "mean_value_s"),
        (Normal, {"mean_value_s": 0.01, "std_s": math.inf}, "std_s"),
        (Gamma, {"shape_k": 2.0, "scale_theta_s": math.inf}, "scale_theta_s"),
        (Gamma, {"shape_k": 2.0, "scale_theta_s": 0.01, "offset_s": math.nan}, "offset_s"),
        (Uniform, {"low_s": 0.0, "high_s": math.inf}, "high_s"),
    ],
)
def test_latency_models_refuse_numbers_that_are_not_finite(model, kwargs, field):
    with pytest.raises(ValueError, match=field):
        model(**kwargs)


CVAT = """<?xml version="1.0" encoding="utf-8"?>
<annotations>
  <version>1.1</version>
  <meta><task>{meta}</task></meta>
  <track id="0" label="red" source="manual">
    <box frame="0" outside="0" occluded="0" xtl="10.5" ytl="20.5" xbr="30.5" ybr="40.5"/>
  </track>
  <track id="1" label="yellow" source="manual">
    <box frame="0" outside="0" occluded="0" xtl="50.5" ytl="20.5" xbr="70.5" ybr="40.5"/>
  </track>
</annotations>
"""
SIZE = "<original_size><width>{w}</width><height>{h}</height></original_size>"


@pytest.mark.parametrize(
    ("meta", "words"),
    [
        ("<size>14</size>" + SIZE.format(w="wide", h=512),
         "line 4: <original_size/width> is 'wide', not an integer"),
        ("<size>14</size>" + SIZE.format(w=612, h="1e12"),
         "<original_size/height> is '1e12', not an integer"),
        ("<size>14</size>" + SIZE.format(w=612, h=10**12),
         "<original_size/height> is 1000000000000"),
        ("<size>14</size>" + SIZE.format(w=0, h=512), "<original_size/width> is 0, outside"),
        ("<size>1000000000000</size>", "<size> is 1000000000000, outside [0, 10000000]"),
        ("<size>many</size>", "<size> is 'many', not an integer"),
        ("<start_frame>-3</start_frame>", "<start_frame> is -3"),
        ("<stop_frame>99999999999</stop_frame>", "<stop_frame> is 99999999999"),
        ("<start_frame>0</start_frame><stop_frame>19999999</stop_frame>",
         "declares 20000000 frames"),
    ],
)
def test_cvat_refuses_a_bad_declared_size_naming_the_element(tmp_path, meta, words):
    """A non-numeric or absurd image or task size is refused (``CvatError``, a ValueError)
    naming the file, the line and the element, before anything of that size is allocated."""
    xml = tmp_path / "a.xml"
    xml.write_text(CVAT.format(meta=meta))
    with pytest.raises(cvat.CvatError) as err:
        cvat.read_cvat_xml(xml)
    assert isinstance(err.value, ValueError)
    assert str(err.value).startswith(str(xml)) and words in str(err.value), str(err.value)


def test_cvat_reads_a_good_declared_size(tmp_path):
    xml = tmp_path / "a.xml"
    xml.write_text(CVAT.format(meta="<size>14</size>" + SIZE.format(w=612, h=512)))
    tr = cvat.read_cvat_xml(xml)
    assert (tr.width, tr.height, tr.n_frames) == (612, 512, 14)
