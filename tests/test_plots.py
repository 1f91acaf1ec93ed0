"""experiments.plots: figures built without pyplot state, saved where asked, frames picked at
the right times."""

from types import SimpleNamespace

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from experiments.plots import plot_runs_side_by_side, strip_rows


def _run(duration_s: float, dt_s: float) -> SimpleNamespace:
    t = np.arange(0.0, duration_s + 1e-9, dt_s)
    cols = {"t_s": t, "tilt_deg": np.sin(t), "ref_tilt_deg": np.ones_like(t),
            "error_deg": np.abs(np.sin(t) - 1.0)}
    cols |= {f"torque_delivered_{c}_Nm": 1e-3 * t for c in "xyz"}
    return SimpleNamespace(steps=pd.DataFrame(cols))


def test_side_by_side_saves_a_figure_and_leaves_pyplot_alone(tmp_path):
    plt.close("all")
    path = tmp_path / "runs.png"
    fig = plot_runs_side_by_side({"a": _run(1.0, 0.01), "b": _run(0.5, 0.02)}, path)
    assert isinstance(fig, Figure) and len(fig.axes) == 6
    assert path.stat().st_size > 10_000
    assert plt.get_fignums() == []


def test_strip_rows_are_the_nearest_to_times_spread_inside_the_longest_run():
    results = {"long": _run(1.0, 0.01), "short": _run(0.4, 0.1)}
    rows = strip_rows(results, 4)
    # times 0.2, 0.4, 0.6, 0.8 s: the 10 ms run has them all; the short one stops at 0.4 s
    np.testing.assert_allclose(rows["long"].t_s, [0.2, 0.4, 0.6, 0.8], atol=1e-9)
    np.testing.assert_allclose(rows["short"].t_s, [0.2, 0.4, 0.4, 0.4], atol=1e-9)
