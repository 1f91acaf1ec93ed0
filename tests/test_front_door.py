"""The front door: ``from latency import Scenario, simulate, simulate_many`` is how the README
and the notebooks run a loop, and ``simulate_many`` says which engine runs what and why."""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import pytest

from latency import Scenario, simulate, simulate_many
from latency.simulation import choose_engine

pytestmark = pytest.mark.engine  # runs the compiled engines

ROOT = Path(__file__).resolve().parents[1]
#: Ways to run a loop other than the front door.
BACK_DOORS = re.compile(r"build_loop|ClosedLoop|run_batched|run_images|experiments\.scenario")


def _notebook_code(path: Path) -> str:
    cells = json.loads(path.read_text())["cells"]
    return "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "code")


def test_the_readme_example_runs_through_the_front_door():
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) == 1 and "from latency import Scenario, simulate" in blocks[0]
    namespace: dict = {}
    exec(compile(blocks[0], "README.md", "exec"), namespace)  # noqa: S102 - our own README
    assert len(namespace["runs"]) == 4
    assert namespace["runs"][0].summary["duration_s"] == 2.0


def test_the_readme_and_notebooks_use_only_the_front_door():
    sources = {"README.md": "\n".join(re.findall(r"```python\n(.*?)```",
                                                 (ROOT / "README.md").read_text(), re.S))}
    for nb in sorted((ROOT / "experiments" / "notebooks").glob("*.ipynb")):
        sources[nb.name] = _notebook_code(nb)
    back = {name: BACK_DOORS.findall(code) for name, code in sources.items()}
    assert not any(back.values()), back
    running = [name for name, code in sources.items() if re.search(r"\bsimulate(_many)?\(", code)]
    assert {"README.md", "closed_loop_16_vs_31ms.ipynb"} <= set(running)
    assert all("from latency import" in sources[name] for name in running)


def test_auto_batches_what_it_can_and_says_why_not(caplog):
    measured = Scenario(duration_s=0.3)
    image = Scenario(duration_s=0.3, mode="image")
    orb = Scenario(duration_s=0.3, mode="image", observer={"kind": "orb"})
    assert choose_engine(measured)[0] == "batched"
    assert choose_engine(image, n_image_runs=2)[0] == "batched"
    engine, why = choose_engine(image, n_image_runs=1)
    assert engine == "event" and "single image run" in why
    engine, why = choose_engine(orb, n_image_runs=2)
    assert engine == "event" and "ORB" in why
    with pytest.raises(ValueError, match="ORB observer; use engine='event'"):
        choose_engine(orb, "batched")
    with caplog.at_level(logging.INFO, logger="latency.simulation"):
        (r,) = simulate_many([image])
    assert r.summary["simulated_s"] == pytest.approx(0.3)
    assert any("single image run" in m for m in caplog.messages), caplog.messages


def test_simulate_is_simulate_many_of_one_and_equals_the_event_loop():
    s = Scenario(duration_s=0.5, reference={"kind": "random", "args": {"max_rate_rad_s": 2.0}})
    auto, event = simulate(s), simulate(s, engine="event")
    assert auto.summary["rms_error_deg"] == pytest.approx(event.summary["rms_error_deg"],
                                                          rel=1e-9)
    assert auto.summary["rms_error_deg"] > 0.0


def test_describe_paths_counts_runs_and_builds_one_loop_per_group(monkeypatch):
    """A sweep's paths: every run counted, one loop built per group of runs that differ only
    in seed, name, reference or duration; several image runs go to the batched image engine."""
    import latency.simulation as sim

    built = []
    real = sim.describe_path
    monkeypatch.setattr(sim, "describe_path", lambda *a: built.append(a[0]) or real(*a))
    solver = {"kind": "solver"}
    runs = [Scenario(seed=k, duration_s=0.3 + k, observer=solver) for k in range(3)]
    runs += [Scenario(seed=k, controller={"kind": "mpc"}, observer=solver) for k in range(2)]
    runs += [Scenario(seed=k, mode="image") for k in range(2)]
    paths = sim.describe_paths(runs)
    assert len(built) == 3
    assert paths == {"engine: batched, compiled run loop": 5, "engine: batched image engine": 2}


def test_the_front_door_takes_mappings_and_iterables_and_refuses_what_it_cannot_run():
    """A scenario file's mapping runs as its ``Scenario`` would; any iterable of scenarios is
    taken; an unknown engine, a non-scenario and a lone scenario given to ``simulate_many``
    are refused with messages that say what was expected (an unknown engine once returned no
    results at all)."""
    fields = {"duration_s": 0.3, "seed": 4}
    want = simulate(Scenario(**fields), engine="event").steps
    assert simulate(fields, engine="event").steps.equals(want)
    many = simulate_many((Scenario(**fields) for _ in range(2)), engine="event")
    assert len(many) == 2 and many[1].steps.equals(want)
    with pytest.raises(ValueError, match="engine must be one of auto, batched, event, got 'warp'"):
        simulate_many([Scenario(**fields)], engine="warp")
    with pytest.raises(TypeError, match="scenario 1: expected a latency.Scenario or a mapping"):
        simulate_many([Scenario(**fields), None])
    with pytest.raises(TypeError, match="for one, use simulate"):
        simulate_many(Scenario(**fields))


def test_image_runs_go_to_the_image_engine_with_the_workers_asked_for(monkeypatch):
    """``simulate_many`` hands its image runs, and only those, to the batched image engine
    with the ``workers`` asked for (1 by default: in this process); a worker count that is not
    an integer >= 1 is refused before anything runs."""
    import latency.simulation as sim

    image = [Scenario(duration_s=0.2, mode="image", seed=k) for k in range(2)]
    event = simulate(image[1], engine="event")
    calls = []
    real = sim.run_images

    def recording(build, specs, *, workers, progress):
        calls.append((len(specs), workers))
        return real(build, specs, workers=1, progress=progress)  # in this process

    monkeypatch.setattr(sim, "run_images", recording)
    runs = [image[0], Scenario(duration_s=0.2), image[1]]
    results = simulate_many(runs, workers=2)
    assert calls == [(2, 2)]
    assert [r.summary["simulated_s"] for r in results] == pytest.approx([0.2] * 3)
    assert results[2].steps.equals(event.steps)  # the wall times it records aside, the same run
    measured = ["meas_red_u_px", "meas_red_v_px", "meas_yellow_u_px", "meas_yellow_v_px"]
    assert results[2].frames[measured].equals(event.frames[measured])
    simulate_many(image)
    assert calls[-1] == (2, 1)
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="workers must be an integer >= 1"):
            simulate_many(image, workers=bad)
    assert len(calls) == 2
