"""The run's events: its frames, releases and commands in the event loop's order.

In a measurement-model run the events' times do not depend on the rotor's state: frames come
on the camera's clock, the frame scheduler decides from the observer's latencies alone which
frames it drops and when it releases the others, and each command comes one controller
latency after its release. So the whole sequence is built before the run (``_schedule``)."""

from __future__ import annotations

import heapq

import numpy as np
from numba import njit
from numpy.typing import NDArray

from latency.compiled import layout
from latency.compiled.cache import compiled_in
from latency.compiled.layout import _COMMAND, _FRAME, _RELEASE
from latency.loop import ClosedLoop, run_streams
from latency.models import Constant
from latency.numba_cache import drop_stale_cache
from latency.pipeline import FrameScheduler

#: The modules whose code these kernels compile in (``cache``).
COMPILED_IN = compiled_in((), (layout,))
drop_stale_cache(__file__, COMPILED_IN)


def _schedule(loop: ClosedLoop) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """The run's handled events in the event loop's order, and its frames' timing.

    The event loop's queue (``ClosedLoop.timeline``: the first frame at mid-exposure, each
    frame pushing the next frame and then its release, each release its command; ties in the
    order pushed) with the run's own streams (``latency.loop.run_streams``): the frames'
    observer latencies drawn from the pipeline's stream, one per processed frame in order
    (``FrameScheduler.next_frame``), the commands' controller latencies from the controller's,
    one per release in order. The draws come first, as many as the run has frames (each
    stream serves one purpose, so the numbers a run uses are the same), and the queue then
    runs compiled (``_event_queue``). Returns the events' times (s), kinds and frame indices,
    and per frame (t_exposure, t_release, dropped)."""
    c = loop.config
    pipe = c.pipeline
    FrameScheduler.check(pipe)
    period, exposure = pipe.frame_period_s, pipe.exposure_s
    n_frames = max(int(np.ceil((c.duration_s - 1e-12 - 0.5 * exposure) / period)), 0) + 1
    if isinstance(pipe.observer, Constant) and isinstance(c.controller_latency, Constant):
        # constant latencies draw nothing: the streams are not needed
        observer = np.full(n_frames, pipe.observer.value_s)
        controller = np.full(n_frames, c.controller_latency.value_s)
    else:
        rng_pipe, rng_ctrl, _ = run_streams(c.seed)
        observer = np.array([pipe.observer.sample(rng_pipe) for _ in range(n_frames)])
        controller = np.array([c.controller_latency.sample(rng_ctrl) for _ in range(n_frames)])
    ev, frames, bad = _event_queue(period, exposure, pipe.readout_s, pipe.mode == "sequential",
                                   pipe.mode == "pipelined", c.duration_s, observer, controller)
    if bad >= 0:
        raise ValueError(f"observer latency must be finite and >= 0, got {observer[bad]}")
    return ev[:, 0].copy(), ev[:, 1].astype(np.int64), ev[:, 2].astype(np.int64), frames


@njit(cache=True)
def _event_queue(period, exposure, readout, sequential, pipelined, duration, observer,
                 controller):
    """The event loop's queue (``_schedule``) with the latencies drawn: the events (time,
    kind, frame) in the order handled, the frames (t_exposure, t_release, dropped) as
    ``FrameScheduler.next_frame`` times them, and the index of the first invalid observer
    latency used (-1: none).

    Compiled mirror of ``latency.pipeline.FrameScheduler.next_frame``."""
    queue = [(0.5 * exposure, 0, _FRAME, 0)]
    heapq.heapify(queue)
    order = 1
    n = observer.shape[0]
    events = np.empty((3 * n, 3))
    frames = np.empty((n, 3))
    n_ev = n_fr = used_obs = used_ctrl = 0
    busy_until = last_release = -np.inf
    while len(queue) > 0 and queue[0][0] < duration - 1e-12:
        t, _, kind, index = heapq.heappop(queue)
        events[n_ev, 0], events[n_ev, 1], events[n_ev, 2] = t, kind, index
        n_ev += 1
        if kind == _FRAME:
            t0 = index * period
            t_exposure, t_ready = t0 + 0.5 * exposure, t0 + exposure + readout
            heapq.heappush(queue, ((index + 1) * period + 0.5 * exposure, order, _FRAME,
                                   index + 1))
            order += 1
            if sequential and t_ready < busy_until:
                frames[n_fr, 0], frames[n_fr, 1], frames[n_fr, 2] = t_exposure, np.nan, 1.0
            else:
                latency = observer[used_obs]
                if latency < 0 or not np.isfinite(latency):
                    return events[:n_ev], frames[:n_fr], used_obs
                used_obs += 1
                t_release = t_ready + latency
                if pipelined:
                    t_release = max(t_release, last_release)
                busy_until = last_release = t_release
                frames[n_fr, 0], frames[n_fr, 1], frames[n_fr, 2] = t_exposure, t_release, 0.0
                heapq.heappush(queue, (t_release, order, _RELEASE, index))
                order += 1
            n_fr += 1
        elif kind == _RELEASE:
            heapq.heappush(queue, (t + controller[used_ctrl], order, _COMMAND, index))
            used_ctrl += 1
            order += 1
    return events[:n_ev], frames[:n_fr], -1
