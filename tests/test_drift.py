"""Drift detection: a pair tracker pushed off its marker is flagged (geometry, seed 000 §3.2.2, or
the attitude residual) and re-acquires the marker from colour."""

from __future__ import annotations

import numpy as np
import pytest

from observer.gk.drift import DriftConfig, DriftMonitor
from observer.gk.hsv_gate import box_sensor_to_image
from observer.trackers import make_pair_tracker
from observer.tracking import PairResult
from plant import attitude as A
from plant.camera import marker_pixels
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer

P = PlantParams()
N = 30
PUSH_AT = 8
#: The seed's tracking criterion (seed 000 §4.2), sensor px.
CLOSE_PX = 20.0


def cone(t):
    g = 1.0 * t
    return A.from_zyz(-g, np.deg2rad(8.0), g)


@pytest.fixture(scope="module")
def frames():
    renderer = AnalyticRenderer(P, seed=5)
    dt = 1.0 / P.camera.frame_rate_hz
    return [renderer.render(cone(k * dt), t_exposure=k * dt) for k in range(N)]


def _run(frames, drift, push=True, residual=None):
    """kcf_numpy on the frames; at ``PUSH_AT`` the yellow tracker is started again on an empty
    corner of the frame (the dark housing: static, so it stays there, confident). ``residual``
    maps frame -> the attitude residual the caller reports before that frame."""
    tr = make_pair_tracker("kcf_numpy", P, drift=drift)
    f0 = frames[0]
    tr.start(f0.image, f0.boxes_px, f0.binning)
    out = []
    for k in range(1, N):
        f = frames[k]
        if push and k == PUSH_AT:
            corner = np.array([20.0, 20.0, *box_sensor_to_image(f0.boxes_px[1],
                                                                 f.binning)[2:]])
            tr.trackers[1].initialize(f.image, corner)
        if residual is not None:
            tr.residual_hint_px = residual.get(k)
        out.append((k, tr.step(f.image)))
    return out


def _error(res: PairResult, frame, m: int) -> float:
    return float(np.hypot(*(res.marker_px[m] - frame.marker_px[m])))


def test_expected_distance_is_the_rigid_pairs_projection():
    """D_exp = L S cos β against the projected marker centres: exact at rest; at 15° tilt
    within 2.5 % (the markers' depth changes too, which D_exp ignores; measured 2.2 %, and
    5.5 % without the cos β)."""
    mon = DriftMonitor(P)
    errors = []
    for tilt_deg in (0.0, 8.0, 15.0):
        q = A.from_zyz(0.3, np.deg2rad(tilt_deg), 1.0)
        px = marker_pixels(P, q)
        errors.append(mon.distance_error(px[0], px[1], np.deg2rad(tilt_deg)))
    assert errors[0] < 1e-9 and max(errors) < 0.025, errors


def test_a_tracker_pushed_off_its_marker_is_flagged_and_reacquires(frames):
    without = _run(frames, None)
    off = [_error(r, frames[k], 1) for k, r in without if k >= PUSH_AT]
    # without drift detection the pushed tracker stays off, and says it measured the marker
    assert min(off) > 100.0 and all(r.yellow_measured for k, r in without if k >= PUSH_AT)

    got = _run(frames, DriftConfig())
    flagged = [k for k, r in got if "drift: markers" in r.reason]
    # flagged once, after DriftConfig.frames frames of a broken geometry
    assert flagged == [PUSH_AT + DriftConfig().frames - 1], flagged
    res = dict(got)[flagged[0]]
    assert res.yellow_lost and not res.yellow_measured and res.lost
    assert res.red_measured and not res.red_lost  # the red box is on its colour
    assert "yellow re-detected from colour" in res.reason
    # re-acquired: from the next frame on, measured and within 20 px of the true centre
    after = [(k, r) for k, r in got if k > flagged[0]]
    assert len(after) == N - 1 - flagged[0]
    assert all(r.yellow_measured and not r.yellow_lost for _, r in after)
    assert max(_error(r, frames[k], 1) for k, r in after) < CLOSE_PX
    # before the push nothing was flagged
    assert all(r.yellow_measured and r.reason == "" for k, r in got if k < PUSH_AT)


def test_a_residual_above_its_bound_for_a_few_frames_flags_and_redetects(frames):
    """A good track whose attitude residual is reported at 12 px (above the 5 px bound) for 3
    frames: both boxes are on their colours, so both markers are flagged lost, re-detected and
    measured again on the next frame."""
    bad = {10: 12.0, 11: 12.0, 12: 12.0}
    got = dict(_run(frames, DriftConfig(), push=False, residual=bad))
    res = got[12]
    assert "drift: attitude residual" in res.reason
    assert res.red_lost and res.yellow_lost and not (res.red_measured or res.yellow_measured)
    assert all("drift" not in got[k].reason for k in got if k != 12)
    for k in range(13, N):
        assert got[k].red_measured and got[k].yellow_measured, k
    assert max(_error(got[k], frames[k], m) for k in range(12, N) for m in (0, 1)) < CLOSE_PX
    # two bad frames in a row are not a drift
    got = dict(_run(frames, DriftConfig(), push=False, residual={10: 12.0, 11: 12.0}))
    assert not any("drift" in r.reason for r in got.values())
