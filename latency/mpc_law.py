"""The delay-aware MPC's linearised feedback law, and its margins against the vision delay.

The MPC (``controller.mpc``) has no fixed linear law, but about rest at the reference with its
constraints inactive it is a smooth map from its initial state to its first torque. To first order
``T_0 = −K x̂`` with ``K`` (3 × 6, over the body rotation vector δθ and the rate ω): this module
measures ``K`` by central differences of :meth:`controller.mpc.MPCController.first_torque` (the
real NLP and solver), then writes the whole law as the controller runs it on an attitude-only
estimate, per axis, at the frame period ``T`` with the delay τ (exposure to actuation):

    x_k  = (θ_k, (θ_k − θ_{k−1}) / T)          estimate at the exposure time kT; the rate is the
                                              backward difference of ``RateFromAttitude``
    x̂_k = Φ(τ_p) x_k + Σ_{i≥1} Γ_i u_{k−i}    delay compensation to kT + τ_p with the commands
                                              already sent (u_{k−i} acts on [τ − iT, τ − (i−1)T)
                                              relative to kT)
    u_k  = −K_i x̂_k

with ``Φ``, ``Γ_i`` the exact zero-order-hold integrals of the axis model ``θ' = ω``,
``J ω' = u − b ω`` over the pieces of ``[0, τ_p]``; ``τ_p = τ`` when the MPC knows its latency
(``predict_s`` sets a mismatch), and ``Φ = I``, ``Γ = 0`` without delay awareness. That is a
discrete LTI controller ``C(z)`` which :func:`latency.margins.sampled_margins` takes with the plant
``1/(J s² + b s)``, exactly as the PID's exact discrete law is analysed.

Friction: Coulomb friction is left out of the plant, of the MPC's model and of the prediction, as
in the PID's analysis. Linearised at ω = 0 the smooth Coulomb law would act as a stiff damper
(τ_c/ω_s = 0.3 N·m·s/rad for the plant's law), which describes sticking, not the moving rotor,
where the friction is a nearly constant torque. ``mpc_state_gain`` therefore measures ``K`` on an
MPC built from the same parameters with ``coulomb_Nm = 0``.
``tests/test_mpc_law.py`` checks the law against the real ``MPCController`` fed the same
small-signal estimates, and the margins against simulated instability.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import control as ct
import numpy as np
from numpy.typing import NDArray

from controller.base import Reference, RefSample
from controller.mpc import MPCController
from controller.mpc_config import MPCConfig
from latency.zoh import zoh_integrals
from plant import attitude
from plant.params import PlantParams

__all__ = ["mpc_discrete_law", "mpc_state_gain"]


@dataclass(frozen=True)
class _Hold(Reference):
    """A constant reference: rest at ``q``."""

    q: NDArray[np.float64]

    def sample(self, t: float) -> RefSample:
        return RefSample(q=self.q)


def frictionless(params: PlantParams) -> PlantParams:
    """``params`` with the Coulomb friction removed (module docstring)."""
    return params.model_copy(update={"rotor": params.rotor.model_copy(update={"coulomb_Nm": 0.0})})


def mpc_state_gain(
    config: MPCConfig | None = None, params: PlantParams | None = None, eps: float = 1e-3
) -> NDArray[np.float64]:
    """``K`` (3 × 6) with ``T_0 ≈ −K (δθ, ω)`` about rest at the identity, by central
    differences of the MPC's first torque (N·m per rad and per rad/s), Coulomb friction removed.

    ``eps`` is the perturbation (rad and rad/s); the torques it causes stay far inside the limits.
    """
    mpc = MPCController(config, frictionless(params or PlantParams()))
    ref = _Hold(np.array([1.0, 0.0, 0.0, 0.0]))
    K = np.zeros((3, 6))
    for j in range(6):
        cols = []
        for sgn in (1.0, -1.0):
            dx = np.zeros(6)
            dx[j] = sgn * eps
            x0 = np.r_[attitude.from_rotvec(dx[:3]), dx[3:]]
            cols.append(mpc.first_torque(x0, ref))
        K[:, j] = -(cols[0] - cols[1]) / (2.0 * eps)
    return K


def mpc_discrete_law(
    K_axis: NDArray[np.float64],
    *,
    inertia_kgm2: float,
    damping_Nms_per_rad: float,
    period_s: float,
    delay_s: float,
    predict_s: float | None = None,
    delay_aware: bool = True,
) -> ct.StateSpace:
    """One axis of the linearised MPC law as a discrete controller ``C(z)`` (``u = −C y``).

    Parameters
    ----------
    K_axis : (2,)
        The axis's gains on (θ, ω): ``(K[i, i], K[i, 3 + i])`` of :func:`mpc_state_gain`.
    inertia_kgm2, damping_Nms_per_rad : float
        The axis model ``J θ'' + b θ' = u`` of the prediction (kg·m², N·m·s/rad).
    period_s : float
        Frame period T (s) of the estimates (and of the commands).
    delay_s : float
        Exposure-to-actuation delay τ (s): command ``u_k`` acts from ``kT + τ``.
    predict_s : float, optional
        The delay the MPC compensates (s); default ``delay_s`` (it knows its latency).
    delay_aware : bool
        False: ``x̂_k = x_k`` (no prediction).

    Returns
    -------
    StateSpace
        Discrete (dt = T), input θ_k (rad), output ``−u_k`` (N·m), i.e. ``C(z)`` in the
        negative-feedback convention of :mod:`latency.margins`.
    """
    if not (period_s > 0 and delay_s >= 0 and inertia_kgm2 > 0 and damping_Nms_per_rad >= 0):
        raise ValueError("need period_s > 0, delay_s >= 0, inertia_kgm2 > 0, damping >= 0")
    T = float(period_s)
    tau_p = float(delay_s if predict_s is None else predict_s)
    if tau_p < 0:
        raise ValueError(f"predict_s must be >= 0, got {predict_s}")
    K = np.asarray(K_axis, dtype=float).reshape(1, 2)
    A = np.array([[0.0, 1.0], [0.0, -damping_Nms_per_rad / inertia_kgm2]])
    B = np.array([[0.0], [1.0 / inertia_kgm2]])
    M = max(1, math.ceil(delay_s / T - 1e-12) + 1)  # past commands u_{k-1} .. u_{k-M}
    Phi = np.eye(2)
    Gam = [np.zeros((2, 1)) for _ in range(M)]
    if delay_aware and tau_p > 0:
        Phi, _ = zoh_integrals(A, B, tau_p)
        for i in range(1, M + 1):
            # u_{k-i} acts on [τ - iT, τ - (i-1)T) relative to kT; the prediction spans [0, τ_p]
            lo = max(delay_s - i * T, 0.0)
            hi = min(delay_s - (i - 1) * T, tau_p)
            if hi > lo:
                _, G = zoh_integrals(A, B, hi - lo)
                Gam[i - 1] = zoh_integrals(A, B, tau_p - hi)[0] @ G
    # u_k = D y_k + Cz z_k, z_k = (θ_{k-1}, u_{k-1}, ..., u_{k-M})
    D = float(-(K @ Phi @ np.array([[1.0], [1.0 / T]]))[0, 0])
    Cz = np.zeros((1, M + 1))
    Cz[0, 0] = float((K @ Phi @ np.array([[0.0], [1.0 / T]]))[0, 0])
    for i in range(M):
        Cz[0, 1 + i] = float(-(K @ Gam[i])[0, 0])
    n = M + 1
    Ac = np.zeros((n, n))
    Bc = np.zeros((n, 1))
    Bc[0, 0] = 1.0  # θ_k -> θ_{(k+1)-1}
    Ac[1, :] = Cz[0]  # u_k -> u_{(k+1)-1}
    Bc[1, 0] = D
    for i in range(2, n):
        Ac[i, i - 1] = 1.0
    return ct.ss(Ac, Bc, -Cz, np.array([[-D]]), T)
