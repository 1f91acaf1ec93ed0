"""The GK assistance of GK-TransT (seed 000 §3.2), independent of the tracker in front of it.

``GKAssist`` composes the pixel Kalman filter (``pixel_kalman``), the HSV confidence gate
(``hsv_gate``), the geometric localisation of the auxiliary marker (``aux_locator``), the
pixel-scale EMA (``scale``) and the sub-pixel circle-fit centres of seed 004 §4 (``subpixel``);
``trust`` judges per frame whether the tracker, a colour fit or the prediction is believed, and
re-detects the marker in the whole frame.
Marker positions are full-sensor pixels; frames are RGB.
"""

from observer.gk.assist import GKAssist, GKConfig, GKResult
from observer.gk.aux_locator import AuxLocator, AuxLocatorConfig, AuxResult
from observer.gk.hsv_gate import HSVGate, HSVGateConfig, HSVRange
from observer.gk.pixel_kalman import PixelKalman, PixelKalmanConfig
from observer.gk.scale import PixelScaleEMA, ScaleEMAConfig, scale_from_camera
from observer.gk.subpixel import SubpixelConfig, SubpixelResult, refine_marker_centre
from observer.gk.trust import MarkerTrust, TrustConfig, TrustDecision

__all__ = [
    "AuxLocator",
    "AuxLocatorConfig",
    "AuxResult",
    "GKAssist",
    "GKConfig",
    "GKResult",
    "HSVGate",
    "HSVGateConfig",
    "HSVRange",
    "MarkerTrust",
    "PixelKalman",
    "PixelKalmanConfig",
    "PixelScaleEMA",
    "ScaleEMAConfig",
    "SubpixelConfig",
    "SubpixelResult",
    "TrustConfig",
    "TrustDecision",
    "refine_marker_centre",
    "scale_from_camera",
]
