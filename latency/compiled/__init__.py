"""The compiled run loop: a whole measurement-model run, events and physics, in one numba call.

The default measurement-model case (``coverage``): the measurement front end (pixel noise,
dropouts, outliers, the tracker-window loss model, the blur limit, the region of interest), the
per-frame least-squares observer (``observer.pixel_observer.SolverObserver`` with
``observer.cor_solver.CorSolver``) alone or behind the pixel Kalman filters
(``PixelKalmanObserver``), the PID (``controller.pid.PIDController``) or the MPC
(``controller.mpc.MPCController`` with its default SQP + HPIPM solver and a fixed compute
latency, its whole solver as machine code: ``controller.mpc_machine``), sequential or pipelined
frames, an observer and a controller latency from a model (any ``latency.models`` kind), no
disturbance, the controller on each released estimate. The event loop
(``latency.loop.ClosedLoop``) stays the reference: this package computes the same run, run by
run, and the agreement tests (tests/test_batched.py, tests/test_compiled_mpc.py) hold it to it.

How. In such a run the events' times do not depend on the rotor's state, so the run's event
sequence is built first (``events``: the latencies drawn as the event loop draws them, then
``FrameScheduler``'s rules and the same priority queue, compiled), and the reference is
sampled at the grid points and at the events' times (``Reference.sample_many``). Then the
kernel (``kernel._run_events``, numba, cached on disk) walks the events: between two events it
advances the rotor with the compiled physics step (``steps``: ``plant.rigid_body._step_row``,
the one code of the physics) and records the steps table's rows and the tilt-stop events; on a
frame it runs the front end (``frontend``), drawing its noise from the front end's own
``numpy.random.Generator`` (numba draws the same numbers as numpy from the same Generator, in
the same order as ``MeasurementFrontEnd.capture``); on a release the observer (``observer``:
the pixel Kalman filters when the run has them, the warm-started Levenberg-Marquardt solve of
``observer.cor_solver._lm``) and the PID law (``pid``) or the MPC's command (``mpc``: the
delay compensation, the warm start and the generated SQP solver, called through its address);
on a command the least-norm current allocation (``allocation``). A command whose least-norm
currents break the limits returns to Python for the LP of ``plant.torque.allocate`` and the
kernel resumes from it (``run``). The per-step and per-frame logs are arrays (``layout``); the
events are codes with their numbers, written out as the event loop's texts at the end
(``tables``).

The mirror. Each compiled function that computes what a Python function of the event loop
computes names it ("Compiled mirror of ...") and the Python function names it back ("Mirrored
in ..."); tests/test_compiled_mirror.py checks each pair equal on random inputs and that every
pointer has its counterpart (docs/architecture.md lists the pairs).

Where it differs from the event loop: the controller's compute time is not timed per call
(``frames.controller_compute_s`` is NaN; the controller latency is a model in every run it
covers), and the arithmetic of a few small products is ordered differently (rounding, 1e-16);
the MPC's solver is the event loop's SQP written out as C (the same iterates to rounding), and
its solver statistics (``MPCController.unconverged`` and the like) are not kept.

``coverage`` says which path the batched engine takes for a run and, for the lockstep rounds,
why (the first of the run's parts or settings that the compiled loop lacks).
"""

from latency.compiled.coverage import Coverage, coverage
from latency.compiled.coverage import _solver_observer as _solver_observer
from latency.compiled.layout import CAPTURE_REASONS, EVENT_KINDS
from latency.compiled.run import run

__all__ = ["CAPTURE_REASONS", "EVENT_KINDS", "Coverage", "coverage", "run"]
