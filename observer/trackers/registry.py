"""The tracker family: every marker-pair tracker by name, with what it is and how it is built
(``plant.registry``); ``observer.trackers.make_pair_tracker`` builds through it.

Names say what they are: ``kcf`` and ``csrt`` are OpenCV's trackers alone, one per marker;
``kcf_gk`` and ``csrt_gk`` are the same trackers on the red marker inside the GK assistance,
restarted on its Kalman prediction when it stands in (they cannot search at a given centre);
``gk_transt`` is the TransT network inside the GK assistance (seed 000 §3.2) and ``dual_transt``
two networks, one per marker. ``transt`` is the former scenario name of ``gk_transt``.

Every builder takes ``(params, refine, transt_factory, **kwargs)``: the plant, whether to refine
the centres by the sub-pixel circle fit (None: on for the GK trackers, off for the seed's
baselines, which report the box centre), the factory of the TransT single-object tracker (None:
the shipped network, ``TransTTracker.small``) and the tracker's own keyword arguments. The
implementations are imported when built: they import this package's base classes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from plant.params import PlantParams
from plant.registry import Registry


def _transt(factory: Callable[[], Any] | None) -> Callable[[], Any]:
    """``factory``, or the shipped network's tracker."""
    if factory is not None:
        return factory
    from observer.transt.tracker import TransTTracker

    return TransTTracker.small


#: GK-TransT's search crop (px of the network input) once the red marker has been measured on
#: the network's own box in this many frames in a row (``GKTransTPairTracker``'s
#: ``steady_search_size`` and ``steady_min_frames``). Our choice, on the development seeds
#: (docs/tracking.md): the network call costs 0.61 times the full 128 px crop's, and with five
#: steady frames required no case's precision moved.
STEADY_SEARCH_PX, STEADY_MIN_FRAMES = 96, 5

#: The dual TransT's lost threshold (``IndependentPairTracker.lost_score``) and the score at or
#: below which its ``hold_below_score`` variant keeps a network's box
#: (``TransTTracker.hold_below_score``): a frame the pair reports lost then does not move the
#: search region either. Not the default, which is TransT's own rule (docs/tracking.md: the
#: hold keeps a track through an occluder the markers do not move under, and loses a marker
#: that moved out of the held search region, where TransT's growing box found it again).
DUAL_LOST_SCORE = 0.2


def _gk_transt(params: PlantParams | None, refine: bool | None,
               transt_factory: Callable[[], Any] | None, **kwargs: Any) -> Any:
    """GK-TransT: one network on the red marker guided by the GK assistance; a TransT network
    searches the smaller crop in steady frames unless ``steady_search_size=None`` is given."""
    from observer.trackers.gk_transt import GKTransTPairTracker
    from observer.transt.tracker import TransTTracker

    tracker = _transt(transt_factory)()
    if isinstance(tracker, TransTTracker):
        kwargs = {"steady_search_size": STEADY_SEARCH_PX,
                  "steady_min_frames": STEADY_MIN_FRAMES} | kwargs
    return GKTransTPairTracker(tracker, params, refine=True if refine is None else refine,
                               **kwargs)


def _dual_transt(params: PlantParams | None, refine: bool | None,
                 transt_factory: Callable[[], Any] | None,
                 hold_below_score: float | None = None, **kwargs: Any) -> Any:
    """The dual TransT: two independent networks; with ``hold_below_score`` their trackers keep
    their box on frames scored at or below it (default None: TransT's own rule, always the
    network's box)."""
    from observer.transt.tracker import TransTTracker

    single = _transt(transt_factory)

    def held() -> Any:
        tracker = single()
        if isinstance(tracker, TransTTracker):
            tracker.hold_below_score = hold_below_score
        return tracker

    return _one_per_marker("dual_transt", lambda factory: held, lost_score=DUAL_LOST_SCORE)(
        params, refine, None, **kwargs)


def _gk_opencv(kind: str) -> Callable[..., Any]:
    """The builder of OpenCV's ``kind`` inside the GK assistance."""
    def build(params: PlantParams | None, refine: bool | None,
              transt_factory: Callable[[], Any] | None, **kwargs: Any) -> Any:
        from observer.opencv_trackers import OpenCVTracker
        from observer.trackers.gk_transt import GKTransTPairTracker

        return GKTransTPairTracker(OpenCVTracker(kind), params,  # type: ignore[arg-type]
                                   refine=True if refine is None else refine,
                                   guide_search=False, restart_on_prediction=True,
                                   name=f"{kind}_gk", **kwargs)
    return build


def _one_per_marker(name: str, single: Callable[[Callable[[], Any] | None], Callable[[], Any]],
                    **defaults: Any) -> Callable[..., Any]:
    """The builder of ``IndependentPairTracker`` with the single-object tracker factory
    ``single(transt_factory)`` on each marker, and ``defaults`` for its keyword arguments."""
    def build(params: PlantParams | None, refine: bool | None,
              transt_factory: Callable[[], Any] | None, **kwargs: Any) -> Any:
        from observer.trackers.dual import IndependentPairTracker

        return IndependentPairTracker(single(transt_factory), params,
                                      refine=False if refine is None else refine, name=name,
                                      **{**defaults, **kwargs})
    return build


def _opencv(kind: str) -> Callable[[Callable[[], Any] | None], Callable[[], Any]]:
    """The factory of OpenCV's ``kind`` (the TransT factory is not used)."""
    def single(transt_factory: Callable[[], Any] | None) -> Callable[[], Any]:
        from observer.opencv_trackers import OpenCVTracker

        return lambda: OpenCVTracker(kind)
    return single


def _numpy_kcf(transt_factory: Callable[[], Any] | None) -> Callable[[], Any]:
    """The numpy KCF's class."""
    from observer.trackers.kcf_numpy import NumpyKCF

    return NumpyKCF


def _k2cf(transt_factory: Callable[[], Any] | None) -> Callable[[], Any]:
    """K²CF's class."""
    from observer.trackers.k2cf import K2CF

    return K2CF


TRACKERS = Registry(
    "tracker",
    "the marker-pair tracker of image mode: frame in, both marker centres (sensor px) out",
    "(params, refine, transt_factory, **kwargs) -> MarkerPairTracker",
    "tracker: NAME (mode: image)",
)
TRACKERS.register("gk_transt", "GK-TransT: one TransT network on the red marker inside the GK "
                  "assistance (seed 000 §3.2)", _gk_transt)
TRACKERS.register("dual_transt", "two independent TransT networks, one per marker (the seed's "
                  "original TransT)", _dual_transt)
TRACKERS.register("kcf", "OpenCV KCF alone, one per marker", _one_per_marker("kcf", _opencv("kcf")))
TRACKERS.register("csrt", "OpenCV CSRT alone, one per marker",
                  _one_per_marker("csrt", _opencv("csrt")))
TRACKERS.register("kcf_numpy", "the numpy KCF alone, one per marker",
                  _one_per_marker("kcf_numpy", _numpy_kcf))
TRACKERS.register("k2cf", "K²CF, one per marker (seed 004 §3.2)",
                  _one_per_marker("k2cf", _k2cf, coast_on_bad_frames=True))
TRACKERS.register("kcf_gk", "OpenCV KCF on the red marker inside the GK assistance (no "
                  "network)", _gk_opencv("kcf"))
TRACKERS.register("csrt_gk", "OpenCV CSRT on the red marker inside the GK assistance (no "
                  "network)", _gk_opencv("csrt"))
TRACKERS.rename("transt", "gk_transt")
