"""ORB-AEKF: attitude of a textured rotor from ORB matches and the adaptive EKF (seed 001).

``OrbObserver`` chains the ORB front end of ``observer.orb`` (keypoints matched to a reference
view, their rotor-frame points known) with one of three back ends, the three methods of seed
001 Table 2:

* ``"orb"``: ORB alone, the per-frame least-squares solve ``observer.orb_pose.solve_attitude``;
* ``"ekf"``: the quaternion EKF of ``observer.aekf`` on the matched points
  (``QuaternionAEKF.update_points``), driven by the plant model and the recorded torque;
* ``"aekf"``: the same with covariance matching (seed 001 App. C.3: window N,
  λ = max(1, tr C_e / tr C), ϑ = 0.8).

It has the two-phase seam of ``observer.pixel_observer`` that the timed loop uses:
``reset(q0, t0)``, ``record_torque(t, torque)``, ``process(measurement, t_exposure, ...)`` when
the frame is taken and ``release(t_release) -> Estimate`` when the result is handed over; the
measurement is an ``observer.orb.OrbMeasurement`` (from ``measure(frame)``) instead of marker
pixels. ``update(frame, t_exposure)`` does all of it at once and releases after the measured
compute time (the frame observer's interface, ``observer.frame_observer``).

Bad input: a frame with too few matches (textureless, heavily blurred, empty or NaN) gives a
measurement with ``valid=False`` and a reason. The filters then predict through it: the released
estimate is the model's prediction, flagged ``lost`` with that reason, and stays ``valid`` until
``max_coast_s`` has passed without an accepted measurement. ORB alone has nothing to predict
with: its estimate for such a frame is invalid (q is NaN) and carries the reason.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.aekf import AEKFConfig, QuaternionAEKF
from observer.orb import OrbConfig, OrbFrontEnd, OrbMeasurement, OrbReference
from observer.orb_pose import solve_attitude
from plant import attitude
from plant.camera import Camera
from plant.estimate import Estimate
from plant.params import PlantParams

Method = Literal["orb", "ekf", "aekf"]


def orb_filter_config(adaptive: bool = True) -> AEKFConfig:
    """Filter settings for ORB points: the seed's ϑ = 0.8 and window (001 App. C, Table 1),
    our N = 10 and Q; ``sigma_px`` is a fallback (the front end gives each point its own)."""
    return AEKFConfig(adaptive=adaptive, sigma_px=2.0, theta=0.8, window_N=10)


class OrbObserver:
    """Frames of the textured rotor -> ``Estimate`` (ORB alone, ORB-EKF or ORB-AEKF).

    Parameters
    ----------
    params : PlantParams
        The model of rotor, camera and dynamics.
    reference : OrbReference
        The reference view (``OrbReference.capture``).
    method : "orb", "ekf" or "aekf"
        Back end (see the module docstring).
    orb_config : OrbConfig, optional
        Front-end settings.
    filter_config : AEKFConfig, optional
        Filter settings (default ``orb_filter_config``); its ``adaptive`` is set by ``method``.
    compensate_delay : bool
        Filters only: release the state predicted to the release time (True) or the state at
        the frame's exposure time (False).
    max_coast_s : float
        After this long (s) without an accepted measurement the estimate is invalid; a filter
        that has rejected measurements for this long is restarted from the per-frame solve.
    clock : callable returning seconds, default ``time.perf_counter``
        Times the front end and the back end (``compute_time_s``); tests inject a stand-in so
        that the latency does not depend on machine load.
    """

    def __init__(
        self,
        params: PlantParams,
        reference: OrbReference,
        method: Method = "aekf",
        orb_config: OrbConfig | None = None,
        filter_config: AEKFConfig | None = None,
        compensate_delay: bool = True,
        max_coast_s: float = 0.5,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        if method not in ("orb", "ekf", "aekf"):
            raise ValueError(f"method must be 'orb', 'ekf' or 'aekf', got {method!r}")
        if not max_coast_s > 0:
            raise ValueError(f"max_coast_s must be positive, got {max_coast_s}")
        self.params = params
        self.method: Method = method
        self.clock = clock
        self.front_end = OrbFrontEnd(params, reference, orb_config, clock)
        cfg = filter_config or orb_filter_config()
        self.filter_config = cfg.model_copy(update={"adaptive": method == "aekf"})
        self.compensate_delay = compensate_delay
        self.max_coast_s = float(max_coast_s)
        self.camera = Camera.from_plant(params)
        # Built once here (CasADi, about 0.25 s) so that no frame's latency pays for it.
        self._filter_model = None if method == "orb" else QuaternionAEKF(params, self.filter_config)
        self.reset(None, 0.0)

    # --- the seam ------------------------------------------------------------------------
    def reset(self, q0: ArrayLike | None = None, t0: float = 0.0) -> None:
        """Start at time ``t0`` (s) from attitude ``q0`` at rest, or, with ``q0=None``, from
        the first frame's per-frame solve."""
        self.filter: QuaternionAEKF | None = None
        self._q = np.full(4, np.nan)
        self._cov = np.full((3, 3), np.nan)
        self._last_accepted = float(t0) if q0 is not None else -np.inf
        self._last_torque: tuple[float, NDArray[np.float64]] = (float(t0), np.zeros(3))
        self._pending: tuple | None = None
        self.last_compute_time_s = float("nan")
        self.restarts = 0
        if q0 is not None:
            q0 = attitude.normalize(q0, "q0")
            self._q = q0
            if self.method != "orb":
                self._start_filter(q0, float(t0))

    def _start_filter(self, q0: NDArray[np.float64], t0: float) -> None:
        self._filter_model.restart(q0, t0)
        self.filter = self._filter_model
        _, T = self._last_torque  # the latest command acts from the start on
        self.filter.set_torque(t0, T)
        self._filter_torque_t = t0

    def record_torque(self, t: float, torque_stator: NDArray[np.float64]) -> None:
        """The torque (N·m, stator frame) commanded from time ``t`` (s)."""
        T = attitude.check_finite("torque_stator", torque_stator).reshape(3)
        self._last_torque = (float(t), T.copy())
        if self.filter is not None and t >= self._filter_torque_t:
            self.filter.set_torque(t, T)
            self._filter_torque_t = float(t)

    def measure(self, frame) -> OrbMeasurement:
        """The front end on a ``plant.scene.Frame`` (or any object with ``image`` and
        ``binning``)."""
        return self.front_end.measure(frame.image, frame.binning)

    def process(
        self,
        measurement: OrbMeasurement,
        t_exposure: float,
        lost: bool = False,
        reason: str = "",
        compute_time_s: float | None = None,
    ) -> None:
        """Fuse a frame's measurement taken at mid-exposure ``t_exposure`` (s).
        ``compute_time_s`` defaults to the front end's time plus this back end's."""
        t0 = self.clock()
        m = measurement
        lost = bool(lost or not m.valid)
        reason = reason or m.reason
        solved = None
        if not lost and (self.method == "orb" or self.filter is None):
            s = solve_attitude(self.camera, m.points_rotor_m, m.pixels_px, m.sigma_px)
            if s.valid:
                solved = s
            else:
                lost, reason = True, f"per-frame solve failed: {s.reason}"
        if self.method == "orb":
            if solved is not None:
                self._q, self._cov, self._last_accepted = solved.q, solved.covariance, t_exposure
        elif not lost:
            if self.filter is None:
                self._start_filter(solved.q, float(t_exposure))
                self._last_accepted = t_exposure
            else:
                r = self.filter.update_points(
                    m.points_rotor_m, m.pixels_px, t_exposure, sigma_px=m.sigma_px
                )
                if r.accepted:
                    self._last_accepted = t_exposure
                else:
                    reason = f"filter rejected the measurement: {r.reason}"
                    if t_exposure - self._last_accepted > self.max_coast_s:
                        self._restart(m, t_exposure)
        own = self.clock() - t0
        ct = m.compute_time_s + own if compute_time_s is None else compute_time_s
        #: Compute time (s) of the last processed frame: front end + back end, or as given.
        self.last_compute_time_s = float(ct)
        self._pending = (m, t_exposure, lost, reason, ct)

    def _restart(self, m: OrbMeasurement, t_exposure: float) -> None:
        """Restart a filter that has rejected everything for ``max_coast_s`` from the solve."""
        s = solve_attitude(self.camera, m.points_rotor_m, m.pixels_px, m.sigma_px)
        if s.valid:
            self._start_filter(s.q, float(t_exposure))
            self._last_accepted = t_exposure
            self.restarts += 1

    def release(self, t_release: float) -> Estimate:
        """The estimate handed over at ``t_release`` (s) for the last processed frame."""
        if self._pending is None:
            raise RuntimeError("release() before process()")
        m, t_exposure, lost, reason, ct = self._pending
        omega = np.full(3, np.nan)
        if self.method == "orb":
            fresh = self._last_accepted == t_exposure
            q, cov, t_state = self._q.copy(), self._cov.copy(), t_exposure
            valid = fresh
            if not fresh:
                q, cov = np.full(4, np.nan), np.full((3, 3), np.nan)
        elif self.filter is None:
            q, cov, t_state, valid = np.full(4, np.nan), np.full((3, 3), np.nan), t_exposure, False
            reason = reason or "no valid frame yet"
        else:
            t_state = t_release if self.compensate_delay else max(t_exposure, self.filter.t)
            q, omega, cov = self.filter.estimate_at(t_state)
            valid = t_release - self._last_accepted <= self.max_coast_s
            if lost:
                reason = f"{reason}; predicted through by the model"
            if not valid:
                reason = f"{reason or 'no accepted measurement'}; coasting for more than "
                reason += f"{self.max_coast_s} s"
        euler = np.array(attitude.to_zyz(q)) if np.all(np.isfinite(q)) else np.full(3, np.nan)
        return Estimate(
            t_exposure=t_exposure,
            t_available=t_release,
            q=q,
            euler_zyz=euler,
            marker_px=m.pixels_px,
            covariance=cov,
            valid=bool(valid),
            lost=lost,
            reason=reason,
            compute_time_s=ct,
            omega=omega,
            t_state=t_state,
        )

    def update(self, frame, t_exposure: float) -> Estimate:
        """Estimate from one frame taken at mid-exposure ``t_exposure`` (s), released after the
        measured compute time (``t_available = t_exposure + compute time``, the front end's
        and the back end's, ``last_compute_time_s``)."""
        self.process(self.measure(frame), t_exposure)
        return self.release(t_exposure + self.last_compute_time_s)
