"""A stand-in for ``time.perf_counter`` in tests of timing bookkeeping: its readings do not depend
on the machine's load, so the "measured" latencies of a test run are the same on a busy and an
idle machine."""

import numpy as np


class StepClock:
    """Each call returns the previous reading plus a step (s) drawn uniformly from
    ``[low_s, high_s]`` with a seeded generator (a fixed step when they are equal).

    A timed section that reads the clock twice therefore lasts one step, and an outer timer
    around an inner one lasts at least as long as the inner one.
    """

    def __init__(self, low_s: float, high_s: float | None = None, seed: int = 0) -> None:
        self.low_s = low_s
        self.high_s = low_s if high_s is None else high_s
        self.rng = np.random.default_rng(seed)
        self.now_s = 0.0
        self.calls = 0

    def __call__(self) -> float:
        self.now_s += float(self.rng.uniform(self.low_s, self.high_s))
        self.calls += 1
        return self.now_s
