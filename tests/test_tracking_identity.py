"""The loop's GK-TransT is the benchmark's GK-TransT: same centres on the same rendered frames.

The closed loop's image front end (``latency.frontends.ImageFrontEnd``, built the way a scenario
with ``tracker: transt`` builds it) and the tracking benchmark (``experiments.tracking_bench``)
run on the frames of one rendered sequence; their marker centres must be equal, frame by frame
after the annotated first frame,
on a clean sequence and through the seed's occlusion. The numpy KCF stands in for the TransT
network in both (the same stand-in as ``tests/test_trackers.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from experiments.sequences import OCCLUSION_FRAMES, SequenceSpec, development_seeds, render_sequence
from experiments.tracking_bench import tracker_factories
from experiments.tracking_runs import run_tracker
from latency.frontends import ImageFrontEnd
from observer.trackers import make_pair_tracker
from observer.trackers.kcf_numpy import NumpyKCF


@dataclass
class _Replay:
    """A renderer that returns the sequence's frames in order (the loop's attitude is unused)."""

    seq: object
    k: int = 0

    def render(self, q, t_exposure, omega=None):  # noqa: ANN001, ANN201 - renderer interface
        s, k = self.seq, self.k
        self.k += 1
        return _Frame(s.images[k], s.binning, s.marker_px[k], s.boxes_px[k])


@dataclass
class _Frame:
    image: np.ndarray
    binning: int
    marker_px: np.ndarray
    boxes_px: np.ndarray


@pytest.mark.parametrize("case,n_frames",
                         [("clean", 40), ("occlusion", OCCLUSION_FRAMES.stop + 6)])
def test_loop_and_benchmark_give_identical_centres(case, n_frames):
    seq = render_sequence(SequenceSpec(seed=development_seeds(1)[0], case=case,
                                       n_frames=n_frames))
    factories, _ = tracker_factories(["gk_transt"], stand_in=True)
    bench = run_tracker(factories["gk_standin"](), seq)

    locator = make_pair_tracker("gk_transt", seq.params, transt_factory=NumpyKCF)
    front = ImageFrontEnd(seq.params, _Replay(seq), locator)
    q, w = np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3)
    caps = [front.capture(q, w, k / seq.fps) for k in range(seq.n_frames)]
    loop_px = np.array([c.marker_px for c in caps])

    # frame 0 is the annotation in both (box centres here, the true centres there)
    assert np.array_equal(loop_px[1:], bench.marker_px[1:], equal_nan=True)
    # and the comparison is not vacuous: both tracked the markers (within 20 px of the truth,
    # the seed's criterion) outside the occlusion, and coasted through it
    err = np.linalg.norm(loop_px - seq.marker_px, axis=2)
    visible = ~seq.occluded
    assert np.all(err[visible] < 20.0)
    if case == "occlusion":
        occ = list(OCCLUSION_FRAMES)
        assert not bench.measured[occ, 0].any()
        # the boundary rule: the red marker is not measured; a frame with no marker measured
        # is lost for the observer, one with the yellow marker measured is not
        assert not any(caps[k].measured[0] for k in occ)
        assert all(caps[k].lost == (not caps[k].measured.any()) for k in occ[:5])
        assert any(caps[k].lost for k in occ[:5])
