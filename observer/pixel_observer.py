"""Marker pixels -> ``Estimate``: the attitude back end that every front end feeds.

A front end (the measurement model, or a renderer + tracker + GK assistance) produces the marker
pixels of a frame. A ``PixelObserver`` turns them into the ``Estimate`` a controller reads, in
two phases that match the timed loop:

* ``process(marker_px, t_exposure, ...)`` when the frame is taken (the pixels are fused at their
  exposure time);
* ``release(t_release)`` when the observer hands the result over; a delay-compensating observer
  predicts its state to ``t_release`` with the torque commands recorded up to then.

``FilterObserver`` does this with the quaternion EKF/AEKF of ``observer.aekf``; ``SolverObserver``
with a per-frame attitude solver and no filter.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.aekf import AEKFConfig, QuaternionAEKF
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.gk.pixel_kalman import PixelKalman, PixelKalmanConfig
from observer.types import AttitudeSolver
from plant import attitude
from plant.estimate import Estimate
from plant.params import PlantParams


class PixelObserver(Protocol):
    """Back end from marker pixels (sensor px) to attitude estimates."""

    def reset(self, q0: ArrayLike, t0: float) -> None:
        """Start from attitude ``q0`` (4,) at time ``t0`` (s), forgetting every earlier frame."""

    def record_torque(self, t: float, torque_stator: NDArray[np.float64]) -> None:
        """The torque (3,), N·m, stator frame, commanded from time ``t`` (s), for back ends that
        predict with the commands (the others ignore it)."""

    def process(
        self,
        marker_px: NDArray[np.float64],
        t_exposure: float,
        lost: bool = False,
        reason: str = "",
        compute_time_s: float = 0.0,
    ) -> None:
        """Take the marker pixels (N, 2), sensor px, of a frame exposed at ``t_exposure`` (s);
        ``lost`` True when the front end lost the markers, ``reason`` its explanation and
        ``compute_time_s`` the front end's compute time (s) to report in the estimate."""

    def release(self, t_release: float) -> Estimate:
        """The ``Estimate`` handed to the controller at ``t_release`` (s) for the last processed
        frame."""


class FilterObserver:
    """Quaternion EKF/AEKF on marker pixels, optionally predicting across the latency.

    Parameters
    ----------
    params : PlantParams
        The filter's model of the rotor and camera.
    config : AEKFConfig
        Filter settings (``adaptive=False`` for the plain EKF).
    compensate_delay : bool
        If True, ``release`` returns the state predicted to the release time (``t_state`` =
        ``t_available``); if False, the state at the frame's exposure time.
    max_coast_s : float
        After this long (s) without an accepted measurement the estimate is flagged invalid.
        Re-acquisition: a measurement the filter rejects after that long (its prediction has
        drifted outside the innovation gate) restarts the filter from the per-frame solve of
        the pixels (``solver``; ``restarts`` counts these), and the estimate is valid again
        once the restarted filter accepts a following measurement (so that a single outlier
        cannot restart it into a valid wrong attitude).
    solver : AttitudeSolver, optional
        The per-frame solve for the restart (default
        ``observer.cor_solver.CorSolver(CorModel.nominal(params))``).
    """

    def __init__(
        self,
        params: PlantParams,
        config: AEKFConfig | None = None,
        compensate_delay: bool = True,
        max_coast_s: float = 0.5,
        solver: AttitudeSolver | None = None,
    ) -> None:
        if max_coast_s <= 0:
            raise ValueError(f"max_coast_s must be positive, got {max_coast_s}")
        self.params = params
        self.config = config or AEKFConfig()
        self.compensate_delay = compensate_delay
        self.max_coast_s = max_coast_s
        self.solver = solver or CorSolver(CorModel.nominal(params))
        self.reset([1.0, 0.0, 0.0, 0.0], 0.0)

    def reset(self, q0: ArrayLike, t0: float) -> None:
        """Start from attitude ``q0`` at rest at time ``t0`` (s)."""
        self.filter = QuaternionAEKF(self.params, self.config, q0=q0, t0=t0)
        self._last_accepted = -np.inf
        self._last_torque = np.zeros(3)
        self._pending: tuple | None = None
        self.restarts = 0

    def record_torque(self, t: float, torque_stator: NDArray[np.float64]) -> None:
        """The torque (N·m, stator frame) commanded from time ``t`` (s)."""
        self.filter.set_torque(t, torque_stator)
        self._last_torque = np.asarray(torque_stator, dtype=float).reshape(3).copy()

    def _restart(self, z: NDArray[np.float64], t_exposure: float) -> bool:
        """Restart the filter at ``t_exposure`` (s) from the per-frame solve of the pixels
        ``z``, warm-started at the filter's attitude, at rest, with the latest torque.
        Returns whether the solve succeeded."""
        s = self.solver.solve(z, self.filter.q)
        if not s.valid:
            return False
        self.filter.restart(s.q, t_exposure)
        self.filter.set_torque(t_exposure, self._last_torque)
        self.restarts += 1
        return True

    def process(
        self,
        marker_px: NDArray[np.float64],
        t_exposure: float,
        lost: bool = False,
        reason: str = "",
        compute_time_s: float = 0.0,
    ) -> None:
        """Fuse the pixels (N, 2) of a frame exposed at ``t_exposure`` (s). A front end that
        has lost the markers passes ``lost=True`` (its pixels, if any, are then ignored)."""
        z = np.asarray(marker_px, dtype=float)
        if lost:
            result_reason = reason or "front end lost the markers"
            accepted = False
        else:
            r = self.filter.update(z, t_exposure)
            accepted, result_reason = r.accepted, r.reason
            stale = t_exposure - self._last_accepted > self.max_coast_s
            if not accepted and stale and self._restart(z, t_exposure):
                # Not yet accepted: one frame (maybe an outlier) is not a track; the next
                # measurement the restarted filter accepts makes the estimate valid again.
                result_reason = (f"filter restarted from the per-frame solve ({r.reason}); "
                                 "valid after its next accepted measurement")
        if accepted:
            self._last_accepted = t_exposure
        # A measurement the filter rejects (outside its innovation gate) is not fused: the
        # estimate is the filter's prediction, so it is flagged lost like a frame without
        # markers, and it turns invalid after ``max_coast_s`` without an accepted measurement.
        self._pending = (z, t_exposure, not accepted, result_reason, compute_time_s)

    def release(self, t_release: float) -> Estimate:
        """The estimate handed over at ``t_release`` (s) for the last processed frame."""
        if self._pending is None:
            raise RuntimeError("release() before process()")
        z, t_exposure, lost, reason, compute_time_s = self._pending
        t_state = t_release if self.compensate_delay else max(t_exposure, self.filter.t)
        q, omega, cov = self.filter.estimate_at(t_state)
        stale = t_release - self._last_accepted > self.max_coast_s
        valid = not stale
        if stale:
            reason = reason or "no accepted measurement"
            reason = f"{reason}; coasting for more than {self.max_coast_s} s"
        return Estimate(
            t_exposure=t_exposure,
            t_available=t_release,
            q=q,
            euler_zyz=np.array(attitude.to_zyz(q)),
            marker_px=z,
            covariance=cov,
            valid=valid,
            lost=lost,
            reason=reason,
            compute_time_s=compute_time_s,
            omega=omega,
            t_state=t_state,
        )


class SolverObserver:
    """A per-frame attitude solver (no filter): the estimate is the solution at the frame's
    exposure time, warm-started from the previous one; the rate is unknown (NaN).

    Parameters
    ----------
    solver : AttitudeSolver
        e.g. ``observer.cor_solver.CorSolver(CorModel.nominal(params))``.
    max_invalid_s : float
        After this long (s) without a valid solution the estimate is flagged invalid; until
        then the last valid solution is held (and its ``reason`` says so).
    """

    def __init__(self, solver: AttitudeSolver, max_invalid_s: float = 0.5) -> None:
        if max_invalid_s <= 0:
            raise ValueError(f"max_invalid_s must be positive, got {max_invalid_s}")
        self.solver = solver
        self.max_invalid_s = max_invalid_s
        self.reset([1.0, 0.0, 0.0, 0.0], 0.0)

    def reset(self, q0: ArrayLike, t0: float) -> None:
        """Start from attitude ``q0`` (4,) at time ``t0`` (s): that attitude is held (with an
        unknown covariance) until the first valid solution."""
        self._q = attitude.normalize(q0, "q0")
        self._cov = np.full((3, 3), np.nan)
        self._last_valid = t0
        self._pending: tuple | None = None

    def record_torque(self, t: float, torque_stator: NDArray[np.float64]) -> None:
        """A per-frame solver ignores the commands."""

    def process(
        self,
        marker_px: NDArray[np.float64],
        t_exposure: float,
        lost: bool = False,
        reason: str = "",
        compute_time_s: float = 0.0,
    ) -> None:
        """Solve the attitude from the marker pixels (N, 2), sensor px, of the frame exposed at
        ``t_exposure`` (s), starting from the last solution; a lost frame or a failed solve keeps
        the last valid solution. The estimate is made by ``release``."""
        z = np.asarray(marker_px, dtype=float)
        if lost:
            reason = reason or "front end lost the markers"
        else:
            r = self.solver.solve(z, self._q)
            if r.valid:
                self._q, self._cov, self._last_valid = r.q, r.covariance, t_exposure
            reason = r.reason
        self._pending = (z, t_exposure, lost, reason, compute_time_s)

    def release(self, t_release: float) -> Estimate:
        """The estimate at ``t_release`` (s): the last valid solution, whose ``t_state`` is its
        exposure time; invalid once no valid solution has come for more than ``max_invalid_s``.
        ``RuntimeError`` before the first ``process``."""
        if self._pending is None:
            raise RuntimeError("release() before process()")
        z, t_exposure, lost, reason, compute_time_s = self._pending
        held = self._last_valid < t_exposure
        if held:
            reason = f"{reason}; holding the solution from t = {self._last_valid:.4f} s"
        valid = t_exposure - self._last_valid <= self.max_invalid_s
        return Estimate(
            t_exposure=t_exposure,
            t_available=t_release,
            q=self._q.copy(),
            euler_zyz=np.array(attitude.to_zyz(self._q)),
            marker_px=z,
            covariance=self._cov,
            valid=valid,
            lost=lost,
            reason=reason,
            compute_time_s=compute_time_s,
            t_state=self._last_valid,
        )


class PixelKalmanObserver:
    """The seed's pixel Kalman filter (seed 000 §3.2.1: constant velocity, Δt = 1 frame) on
    each marker centre, then a per-frame solver on the filtered centres.

    This is the filter whose Q and R the closed-loop tuning (``experiments.tuning``) adjusts: a
    small Q/R smooths the pixels but lags them; a large Q/R passes the noise through.
    """

    def __init__(
        self,
        solver: AttitudeSolver,
        config: PixelKalmanConfig | None = None,
        max_invalid_s: float = 0.5,
    ) -> None:
        self.config = config or PixelKalmanConfig()
        self.inner = SolverObserver(solver, max_invalid_s)
        self.filters = [PixelKalman(self.config), PixelKalman(self.config)]
        self._lost = False

    def reset(self, q0: ArrayLike, t0: float) -> None:
        """Start the solver from attitude ``q0`` (4,) at time ``t0`` (s) and clear both pixel
        filters."""
        self.inner.reset(q0, t0)
        for f in self.filters:
            f.reset()

    def record_torque(self, t: float, torque_stator: NDArray[np.float64]) -> None:
        """The pixel filters ignore the commands."""

    def process(
        self,
        marker_px: NDArray[np.float64],
        t_exposure: float,
        lost: bool = False,
        reason: str = "",
        compute_time_s: float = 0.0,
    ) -> None:
        """Filter each marker centre of the frame exposed at ``t_exposure`` (s) (the pixels (N, 2),
        sensor px): predict, then update with a finite centre or coast without one, and pass the
        filtered centres to the solver. A lost frame is solved from the predicted centres (seed 000
        §3.2.1) but its estimate stays flagged lost. Mirrored in
        ``latency.compiled.observer._pixel_kalman``; keep both in step
        (tests/test_compiled_mirror.py checks them equal)."""
        z = np.asarray(marker_px, dtype=float).reshape(-1, 2)
        filtered = np.full_like(z, np.nan)
        for i, f in enumerate(self.filters):
            f.predict()
            if lost or not np.all(np.isfinite(z[i])):
                f.coast()
            else:
                f.update(z[i])
            filtered[i] = f.position
        # The Kalman prediction stands in for a lost observation (seed 000 §3.2.1); the
        # estimate is still flagged lost.
        self._lost = lost
        predicted = lost and bool(np.all(np.isfinite(filtered)))
        self.inner.process(filtered, t_exposure, lost and not predicted, reason, compute_time_s)

    def release(self, t_release: float) -> Estimate:
        """The solver's estimate at ``t_release`` (s), flagged lost when the last frame was."""
        return replace(self.inner.release(t_release), lost=self._lost)
