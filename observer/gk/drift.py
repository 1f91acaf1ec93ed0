"""Drift detection for any pair tracker: a tracker that has left its marker is flagged and the
marker re-detected from colour.

A single-object tracker can lock onto the background next to its marker and keep reporting a
confident box there (a drifting TransT: 60-120 px off on a clean recording, never flagged). The
two markers are a rigid pair, so such a drift shows up in the pixels (seed 000 §3.2.2) or in the
attitude solved from them:

* **geometry**: with both markers measured, their distance D_det must match
  D_exp = L·S·cos β (S the pixel scale ``scale_from_camera``, β the latest tilt estimate, 0 when
  unknown): E = |D_det − D_exp| / D_exp < ``E_max`` (the seed's 0.3);
* **residual**: the attitude solver's RMS reprojection residual must stay below
  ``max_residual_px`` (the least-squares solve's own bound, 5 px).

When either fails for ``frames`` frames in a row, the markers concerned are flagged lost (and
not measured) in that frame: each marker whose box holds less than the seed's 5 % of its colour
(the HSV gate, seed 000 §3.2.1), or both when both boxes pass the gate. They are then searched
for in the whole frame (``DriftMonitor.redetect``): marker-coloured blobs of about the marker's
size (``observer.gk.trust.colour_blobs``), paired with the other marker (its blobs if it is
concerned too, else its current centre) and kept when the pair passes the distance check; the
pair with the smallest E wins and the tracker restarts there
(``observer.trackers.MarkerPairTracker``).

Units: marker positions in full-sensor px, frames RGB binned by ``binning``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from observer.gk.hsv_gate import HSVGate, HSVGateConfig, box_sensor_to_image
from observer.gk.scale import scale_from_camera
from observer.gk.trust import TrustConfig, colour_blobs
from observer.tracking import PairResult
from plant.camera import image_to_sensor
from plant.params import PlantParams

MARKERS = ("red", "yellow")


class DriftConfig(BaseModel):
    """When a pair tracker counts as drifting (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    E_max: float = Field(0.3, gt=0.0, lt=1.0,
                         description="Seed 000 §3.2.2: a pair is consistent when E < 0.3.")
    max_residual_px: float = Field(
        5.0, gt=0.0, description="Our choice: the least-squares solve's own bound "
        "(``CorSolverConfig.max_residual_rms_px``), sensor px RMS.")
    frames: int = Field(3, ge=1, description="Our choice: frames in a row with the geometry or "
                        "the residual failing before the markers are flagged and re-detected "
                        "(one bad frame, e.g. blur, is not a drift).")


class DriftMonitor:
    """Counts the frames that fail the geometry or the residual check, decides which markers
    have drifted and re-detects them from colour (module docstring).

    Parameters
    ----------
    params : PlantParams
        Camera (the pixel scale) and VFC (L, marker diameter).
    config : DriftConfig, optional
    gate : HSVGateConfig, optional
        The marker colours and the 5 % gate (seed 000 §3.2.1).
    """

    def __init__(self, params: PlantParams, config: DriftConfig | None = None,
                 gate: HSVGateConfig | None = None) -> None:
        self.params = params
        self.config = config or DriftConfig()
        self.gate = HSVGate(gate)
        self.scale_px_per_m = scale_from_camera(params.camera)
        self.reset()

    def reset(self) -> None:
        """Forget the counts."""
        self.geometry_failures = 0
        self.residual_failures = 0

    def expected_distance_px(self, tilt_rad: float | None) -> float:
        """D_exp = L·S·cos β, sensor px (β = 0 when unknown)."""
        beta = 0.0 if tilt_rad is None or not math.isfinite(tilt_rad) else tilt_rad
        return self.params.vfc.L_m * self.scale_px_per_m * math.cos(beta)

    def distance_error(self, red_px: NDArray, yellow_px: NDArray,
                       tilt_rad: float | None) -> float:
        """E = |D_det − D_exp| / D_exp of a red and a yellow centre (sensor px)."""
        d_exp = self.expected_distance_px(tilt_rad)
        return abs(float(np.hypot(*(np.asarray(yellow_px) - red_px))) - d_exp) / d_exp

    def check(self, image: NDArray[np.uint8], binning: int, res: PairResult,
              tilt_rad: float | None, residual_px: float | None
              ) -> tuple[NDArray[np.bool_], str]:
        """Count this frame and return (the markers concerned (2,), why); none concerned
        (all False, "") until a check has failed for ``config.frames`` frames in a row.

        ``residual_px`` is the attitude solver's RMS residual of the previous frame (None or
        NaN: not solved; the count is kept)."""
        c = self.config
        if res.red_measured and res.yellow_measured:
            E = self.distance_error(res.red_px, res.yellow_px, tilt_rad)
            self.geometry_failures = self.geometry_failures + 1 if E >= c.E_max else 0
        if residual_px is not None and math.isfinite(residual_px):
            self.residual_failures = \
                self.residual_failures + 1 if residual_px > c.max_residual_px else 0
        if self.geometry_failures >= c.frames:
            d = float(np.hypot(*(res.yellow_px - res.red_px)))
            why = (f"drift: markers {d:.0f} px apart, expected "
                   f"{self.expected_distance_px(tilt_rad):.0f} px (E >= {c.E_max}) for "
                   f"{self.geometry_failures} frames")
        elif self.residual_failures >= c.frames:
            why = (f"drift: attitude residual above {c.max_residual_px} px for "
                   f"{self.residual_failures} frames")
        else:
            return np.zeros(2, bool), ""
        self.reset()
        off = np.array([not self._on_colour(image, binning, box, colour)
                        for box, colour in zip(res.boxes_px, MARKERS, strict=True)])
        return (off if off.any() else np.ones(2, bool)), why

    def _on_colour(self, image: NDArray[np.uint8], binning: int, box_px: NDArray,
                   colour: str) -> bool:
        """The box (sensor px) holds more than the gate's share of the marker's colour."""
        if not np.all(np.isfinite(box_px)):
            return False
        return self.gate.ratio(image, box_sensor_to_image(box_px, binning),
                               colour).confident  # type: ignore[arg-type]

    def redetect(self, image: NDArray[np.uint8], binning: int, concerned: NDArray[np.bool_],
                 marker_px: NDArray[np.float64], tilt_rad: float | None
                 ) -> NDArray[np.float64] | None:
        """Both centres (2, 2), sensor px, after searching the whole frame for the concerned
        markers (module docstring); None when no pair passes the distance check."""
        radius_img = 0.5 * self.params.vfc.marker_diameter_mm / 1000.0 \
            * self.scale_px_per_m / binning
        trust = TrustConfig()
        options = []
        for k, colour in enumerate(MARKERS):
            if concerned[k]:
                blobs = colour_blobs(image, self.gate.config.range_of(colour),  # type: ignore
                                     radius_img, trust)
                options.append([image_to_sensor(c, binning) for c, _ in blobs])
            else:
                options.append([np.asarray(marker_px[k], dtype=float)])
        best, best_E = None, self.config.E_max
        for red in options[0]:
            for yellow in options[1]:
                E = self.distance_error(red, yellow, tilt_rad)
                if E < best_E:
                    best, best_E = np.vstack([red, yellow]), E
        return best
