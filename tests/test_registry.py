"""The part registries: what scenarios accept, what ``pmspm parts`` lists and what the builders
build are one list per family."""

from __future__ import annotations

import json
import typing
from pathlib import Path

import pytest
from pydantic import BaseModel, ValidationError
from typer.testing import CliRunner

from controller.registry import CONTROLLERS, REFERENCES, ControllerSpec, ReferenceSpec
from experiments.cli import app
from latency import Scenario, build_loop
from latency.frontends import FRONT_ENDS, LOSS_MODELS, LossSpec
from latency.models import LATENCY_MODELS, LatencyModel
from latency.parts import FAMILIES, parts_markdown
from observer.registry import OBSERVERS, ObserverSpec
from observer.trackers import TRACKERS
from plant.registry import Registry
from plant.renderers import RENDERERS

ROOT = Path(__file__).resolve().parents[1]


def _kinds(union) -> set[str]:
    """The ``kind`` values a discriminated union of settings models accepts."""
    members = typing.get_args(typing.get_args(union)[0])
    return {k for m in members for k in typing.get_args(m.model_fields["kind"].annotation)}


@pytest.mark.parametrize(("registry", "union"), [
    (CONTROLLERS, ControllerSpec), (OBSERVERS, ObserverSpec), (REFERENCES, ReferenceSpec),
    (LATENCY_MODELS, LatencyModel), (LOSS_MODELS, LossSpec),
])
def test_a_scenario_accepts_exactly_the_registered_kinds(registry, union):
    assert set(registry.names()) == _kinds(union)


def test_every_family_is_listed_once():
    assert [r.family for r in FAMILIES] == ["front_end", "tracker", "renderer", "loss",
                                            "observer", "controller", "reference", "latency"]
    assert {FRONT_ENDS.family, TRACKERS.family, RENDERERS.family} <= {r.family for r in FAMILIES}


@pytest.mark.parametrize(("field", "value", "family", "known"), [
    ("controller", {"kind": "magic"}, "controller", "pid, mpc"),
    ("observer", {"kind": "magic"}, "observer", "aekf, ekf, solver"),
    ("reference", {"kind": "magic"}, "reference", "tilt_step, seed_steps"),
    ("controller_latency", {"kind": "magic"}, "latency", "constant, normal"),
    ("measurement", {"loss": {"kind": "magic"}}, "loss", "search_window, calibrated"),
    ("renderer", "magic", "renderer", "analytic, mujoco"),
])
def test_an_unknown_part_is_refused_with_the_registered_names(field, value, family, known):
    with pytest.raises(ValidationError, match=f"unknown {family} 'magic'; choose one of {known}"):
        Scenario.model_validate({"mode": "image", field: value})


def test_each_observer_kind_builds_its_registered_back_end():
    """The loop's observer is the one the registry's builder gives for the kind."""
    built = {}
    for kind in ("aekf", "ekf", "solver", "pixel_kalman"):
        loop = build_loop(Scenario.model_validate({"observer": {"kind": kind}}))
        built[kind] = type(loop.observer).__name__
    assert built == {"aekf": "FilterObserver", "ekf": "FilterObserver",
                     "solver": "SolverObserver", "pixel_kalman": "PixelKalmanObserver"}
    loop = build_loop(Scenario.model_validate({"observer": {"kind": "ekf"}}))
    assert loop.observer.filter.config.adaptive is False


def test_options_irrelevant_to_a_kind_are_refused():
    """Each observer kind takes its own options: the pixel Kalman filter's scales on the solver
    are a mistake, not silently ignored."""
    with pytest.raises(ValidationError, match="pixel_q_scale"):
        Scenario.model_validate({"observer": {"kind": "solver", "pixel_q_scale": 0.5}})


def test_listed_defaults_are_the_settings_models_defaults():
    """``pmspm parts --json`` gives each option's default as the settings model has it (read
    here from a default-constructed model, not from the listing code)."""
    result = CliRunner().invoke(app, ["parts", "--json"])
    assert result.exit_code == 0, result.output
    data = {f["family"]: f for f in json.loads(result.output)}
    assert set(data) == {r.family for r in FAMILIES}
    pid = {o["name"]: o["default"] for o in data["controller"]["parts"][0]["options"]}
    from controller.pid import PIDConfig

    assert pid["config.crossover_rad_s"] == repr(PIDConfig().crossover_rad_s)
    assert len(pid) == len(PIDConfig.model_fields)
    pk = next(p for p in data["observer"]["parts"] if p["name"] == "pixel_kalman")
    assert {o["name"]: o["default"] for o in pk["options"]} == {"pixel_q_scale": "0.01",
                                                               "pixel_r_scale": "0.1"}
    random = next(p for p in data["reference"]["parts"] if p["name"] == "random")
    assert {o["name"] for o in random["options"]} >= {"args.seed", "args.max_rate_rad_s"}
    assert data["tracker"]["renamed"] == {"transt": "gk_transt"}
    n_parts = sum(len(f["parts"]) for f in data.values())
    # 3 front ends, 8 trackers, 2 renderers, 2 loss models, 7 observers, 2 controllers,
    # 5 references, 5 latency models
    assert n_parts == sum(len(r.names()) for r in FAMILIES) == 34


def test_the_command_lists_one_family_and_refuses_an_unknown_one():
    result = CliRunner().invoke(app, ["parts", "tracker"])
    assert result.exit_code == 0
    assert all(name in result.output for name in TRACKERS.names())
    assert "controller" not in result.output
    bad = CliRunner().invoke(app, ["parts", "magic"])
    assert bad.exit_code == 2 and "choose one of front_end, tracker" in bad.output


def test_the_docs_table_is_generated_from_the_registries():
    """docs/parts.md is ``pmspm parts --markdown``; regenerate it when a part changes."""
    committed = (ROOT / "docs" / "parts.md").read_text()
    assert committed == parts_markdown() + "\n", "run: pmspm parts --markdown > docs/parts.md"


def test_a_registry_refuses_a_name_twice_and_warns_on_a_former_one():
    class Opts(BaseModel):
        gain: float = 2.0

    r = Registry("widget", "a test family", "() -> widget", "widget: NAME")
    r.register("a", "the first", lambda: "A", Opts)
    with pytest.raises(ValueError, match="registered twice"):
        r.register("a", "again", lambda: "A")
    r.rename("old_a", "a")
    with pytest.warns(FutureWarning, match="'old_a' is now called 'a'"):
        assert r.get("old_a").build() == "A"
    with pytest.raises(ValueError, match="unknown widget 'b'; choose one of a"):
        r.get("b")
    assert [(o.name, o.default) for o in r.get("a").options()] == [("gain", "2.0")]
