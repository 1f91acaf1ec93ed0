"""Front ends of the timed loop: from the rotor's true motion to measured marker pixels.

* ``MeasurementFrontEnd`` (measurement-model mode): the true marker pixels at mid-exposure plus
  Gaussian noise, frame dropouts and outliers. Fast, for sweeps.
* ``ImageFrontEnd`` (image-in-the-loop mode): a rendered frame (with motion blur over the
  exposure), a real tracker on the red marker and the GK assistance of seed 000 §3.2 for both
  centres. Its compute time is measured.

Both return a ``Capture`` in full-sensor pixels, with the truth beside the measurement so that the
loop can flag tracking loss by the seed's 20 px criterion (seed 000 §4.2).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from observer.frame_observer import MarkerLocator
from plant.camera import marker_pixels
from plant.params import PlantParams


@dataclass(frozen=True)
class Capture:
    """One frame's measured and true marker centres (2, 2), sensor px (red, yellow)."""

    marker_px: NDArray[np.float64]
    true_px: NDArray[np.float64]
    lost: bool = False
    reason: str = ""
    compute_time_s: float = 0.0


class FrontEnd(Protocol):
    def reset(self) -> None: ...

    def capture(
        self, q: NDArray[np.float64], omega: NDArray[np.float64], t_exposure: float
    ) -> Capture: ...


class MeasurementConfig(BaseModel):
    """Noise of the measurement model, sensor px."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    sigma_px: float = Field(
        0.5, ge=0.0, description="Our choice: per-coordinate noise; the GK sub-pixel stage "
        "measured 0.15 px median, 0.3 px p95 on rendered frames (benchmarks/RESULTS.md)."
    )
    dropout_prob: float = Field(0.0, ge=0.0, le=1.0, description="Frames with no markers.")
    outlier_prob: float = Field(0.0, ge=0.0, le=1.0, description="Frames with a jumped centre.")
    outlier_px: float = Field(60.0, ge=0.0, description="Size of an outlier jump, sensor px.")


class MeasurementFrontEnd:
    """True marker pixels plus noise, dropout and outliers (measurement-model mode)."""

    def __init__(
        self, params: PlantParams, config: MeasurementConfig, rng: np.random.Generator
    ) -> None:
        self.params, self.config, self.rng = params, config, rng

    def reset(self) -> None:
        """Nothing to reset: the model has no memory."""

    def capture(
        self, q: NDArray[np.float64], omega: NDArray[np.float64], t_exposure: float
    ) -> Capture:
        c = self.config
        truth = marker_pixels(self.params, q)
        if self.rng.random() < c.dropout_prob:
            return Capture(np.full((2, 2), np.nan), truth, True, "dropout (measurement model)")
        z = truth + self.rng.normal(scale=c.sigma_px, size=(2, 2))
        if self.rng.random() < c.outlier_prob:
            angle = self.rng.uniform(0, 2 * np.pi)
            z[self.rng.integers(2)] += c.outlier_px * np.array([np.cos(angle), np.sin(angle)])
        return Capture(z, truth)


class ImageFrontEnd:
    """Render a frame (with motion blur), then locate both markers with a tracker and the GK
    assistance (``observer.frame_observer.MarkerLocator``).

    Parameters
    ----------
    params : PlantParams
    renderer : object with ``render(q, t_exposure, omega=...) -> plant.scene.Frame``
        (``AnalyticRenderer`` or ``MujocoRenderer``).
    locator : MarkerLocator, optional (default: OpenCV KCF + GK assistance)

    The tracker starts on the true box of the first frame, as a user's first-frame annotation
    would. ``tilt_hint_rad`` (set by the loop from the latest estimate) feeds the GK geometry.
    """

    def __init__(self, params: PlantParams, renderer, locator: MarkerLocator | None = None):
        self.params = params
        self.renderer = renderer
        self.locator = locator or MarkerLocator(params)

    @property
    def tilt_hint_rad(self) -> float | None:
        return self.locator.tilt_hint_rad

    @tilt_hint_rad.setter
    def tilt_hint_rad(self, value: float | None) -> None:
        self.locator.tilt_hint_rad = value

    def reset(self) -> None:
        self.locator.reset()

    def capture(
        self, q: NDArray[np.float64], omega: NDArray[np.float64], t_exposure: float
    ) -> Capture:
        frame = self.renderer.render(q, t_exposure=t_exposure, omega=omega)
        if not self.locator.started:
            self.locator.start(frame.image, frame.binning, frame.boxes_px[0])
        loc = self.locator.locate(frame.image, frame.binning)
        return Capture(loc.marker_px, frame.marker_px, loc.lost, loc.reason, loc.compute_time_s)
