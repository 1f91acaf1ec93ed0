"""Frequency-domain margins of a vision-in-the-loop control loop with an exact time delay.

The loop is broken at the plant input. With negative feedback ``u = -C F y`` the loop transfer is

    L(s) = C(s) F(s) H_T(s) P(s) e^{-s tau}

where

- ``P`` is the plant (continuous LTI, input torque N·m, output angle rad),
- ``F`` an optional observer/filter (continuous, or discrete at the sampling period),
- ``C`` the controller (continuous, or discrete with sampling period ``T``); a discrete factor
  ``G(z)`` is evaluated at ``z = e^{sT}``,
- ``H_T(s) = (1 - e^{-sT}) / (sT)`` the sample-and-hold at period ``T`` (omitted when the loop is
  not sampled). It is the ``k = 0`` term of the impulse-modulation (Poisson) sum that gives the
  exact sampled loop, ``L_d(e^{jwT}) = C(e^{jwT}) F(e^{jwT}) sum_k H_T(jw_k) P(jw_k)
  e^{-jw_k tau}``, ``w_k = w + 2 pi k / T``: the *hybrid* formulation below neglects the aliasing
  terms ``k != 0``. They are small when ``|P(j(w - 2pi/T))| << |P(jw)|``, i.e. well below the
  Nyquist frequency ``pi/T`` for a low-pass plant. For a double integrator at ``wT = 0.5`` the
  neglected terms are about 0.1 % of ``|L|``.
- ``e^{-s tau}`` the *exact* sensor-to-actuator delay ``tau`` (s), never a Padé approximation
  (Padé is offered only as a comparison, :func:`loop_pade`, :func:`pade_margins`).

Two formulations are offered:

``hybrid`` (:func:`loop_model`, :func:`loop_margins`)
    The formula above evaluated at ``s = jw``. Stability is decided by the Nyquist criterion
    applied to the exact-delay response (encirclement count of -1 along a D-contour indented to
    the right of poles at the origin). Gives the jitter margin.
``sampled`` (:func:`sampled_loop`, :func:`sampled_margins`)
    The exact discrete-time loop at the sample instants for a discrete controller: the plant is
    discretised with a zero-order hold and the fractional delay ``tau = m T + tau'`` by the
    modified z-transform (Åström & Wittenmark, *Computer-Controlled Systems*, 3rd ed., §2.3):
    ``x[k+1] = Phi x[k] + Gamma_0 u[k-m] + Gamma_1 u[k-m-1]``. Stability is decided by the
    closed-loop eigenvalues; the delay margin by scanning the delay with eigenvalues. Valid for
    frequencies in ``(0, pi/T]``; exact at the sample instants for the timing model "sample at
    ``kT``, actuate at ``kT + tau``, hold for ``T``".

Conventions: frequencies in rad/s, times in s, phases in rad inside; the phase margin is reported
in degrees as ``phase_margin_deg``; gain margins are plain ratios (not dB).

Every margin is accompanied by a stability verdict that does not rely on the phase (python-control's
``stability_margins`` wraps the phase and can report a large positive phase margin for an unstable
loop). When the closed loop is unstable, the headline margins are ``nan`` and
:meth:`Margins.summary` says "unstable".

References
----------
C.-Y. Kao and B. Lincoln, "Simple stability criteria for systems with time-varying delays",
Automatica 40(8), 1429-1434, 2004 (the jitter margin).
K. J. Åström and B. Wittenmark, *Computer-Controlled Systems*, 3rd ed., Prentice Hall, 1997
(sampling with a fractional delay; the sampled frequency response).

Modules: :mod:`~latency.margins.model` (the loop), :mod:`~latency.margins.grid` (the frequency
grid, refined where the response moves fast), :mod:`~latency.margins.nyquist` (the encirclement
count), :mod:`~latency.margins.result` (the :class:`Margins` record and the
crossover search), :mod:`~latency.margins.hybrid` (hybrid margins, the jitter margin and
:func:`lti_margins` for any python-control plant and controller),
:mod:`~latency.margins.sampled`, :mod:`~latency.margins.pade`, :mod:`~latency.margins.plots`
(Figures, no backend set) and :mod:`~latency.margins.attitude` (the per-axis attitude loop).
"""

from latency.margins.attitude import (
    as_run_margins,
    attitude_delay_sweep,
    attitude_margins,
    attitude_plant,
    first_unstable_delay,
)
from latency.margins.hybrid import jitter_margin, loop_margins, lti_margins
from latency.margins.model import LoopModel, loop_frd, loop_model
from latency.margins.nyquist import nyquist_count
from latency.margins.pade import loop_pade, pade_margins
from latency.margins.plots import bode_data, nyquist_data, plot_bode, plot_nyquist
from latency.margins.result import Margins
from latency.margins.sampled import (
    sampled_loop,
    sampled_margins,
    sampled_plant,
    sampled_spectral_radius,
    sampled_stable,
)

__all__ = [
    "LoopModel",
    "Margins",
    "as_run_margins",
    "attitude_delay_sweep",
    "attitude_margins",
    "attitude_plant",
    "bode_data",
    "first_unstable_delay",
    "jitter_margin",
    "loop_frd",
    "loop_margins",
    "loop_model",
    "loop_pade",
    "lti_margins",
    "nyquist_count",
    "nyquist_data",
    "pade_margins",
    "plot_bode",
    "plot_nyquist",
    "sampled_loop",
    "sampled_margins",
    "sampled_plant",
    "sampled_spectral_radius",
    "sampled_stable",
]
