"""The catalogue of command-line mistakes: each exits with status 2 and one message naming the
problem, without a traceback, before any expensive work (docs/reliability.md).

Every row runs in-process (typer's CliRunner). The expensive entry points (a run, a sweep, a
latency measurement, the study, the tuning, rendering the tracking sequences, the
margins) are replaced by functions that fail the test, so a row passes only if its mistake is
caught first.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
from typer.testing import CliRunner

from experiments.cli import app

pytestmark = pytest.mark.engine  # runs the compiled engines

RUNNER = CliRunner()


@dataclass(frozen=True)
class Case:
    """One mistake: the command line (``{d}`` is the test's folder), the files it needs
    (name -> text or bytes, under ``{d}``), the expected exit code and message fragment."""

    id: str
    argv: tuple[str, ...]
    fragment: str
    files: dict[str, str | bytes] = field(default_factory=dict)
    code: int = 2


def scenario(id: str, text: str, fragment: str) -> Case:
    """``pmspm simulate`` on a scenario file with ``text``."""
    return Case(id, ("simulate", "{d}/s.yaml", "--out", "{d}/out"), fragment, {"s.yaml": text})


def sweep(id: str, text: str, fragment: str, *options: str) -> Case:
    """``pmspm sweep`` on a sweep file with ``text``."""
    argv = ("sweep", "{d}/w.yaml", "--out", "{d}/out", *options)
    return Case(id, argv, fragment, {"w.yaml": text})


def codesign(id: str, text: str, fragment: str, *options: str) -> Case:
    """``pmspm codesign`` on a spec file with ``text``."""
    argv = ("codesign", "{d}/c.yaml", "--out", "{d}/out", *options)
    return Case(id, argv, fragment, {"c.yaml": text})


def command(id: str, fragment: str, *argv: str, files: dict | None = None) -> Case:
    return Case(id, tuple(argv), fragment, files or {})


OK_SWEEP = "base: {duration_s: 0.3}\ngrid: {seed: [0, 1]}\n"
BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{n}: &{n} [{', '.join([f'*{p}'] * 9)}]\n" for p, n in zip("abcdefg", "bcdefgh", strict=True)
)
CROSSOVER_RANGE = "--crossover-rad-s must be a finite number >= 0.001 and <= 10000"
DELAY_RANGE = "--delay-ms must be a finite number >= 0 and <= 1000"
TILT_10_STOP = "plant: {rotor: {tilt_stop_deg: 10}}\n"

CASES = [
    # --- the scenario file itself ---------------------------------------------------------
    command("missing-file", "no such file", "simulate", "{d}/nope.yaml"),
    command("directory", "is a directory", "simulate", "{d}/folder", files={"folder/x": "a"}),
    command("binary-file", "binary file", "simulate", "{d}/b.yaml",
            files={"b.yaml": b"\x89PNG\r\n\x1a\n\x00\x00"}),
    command("not-utf8", "binary file", "simulate", "{d}/b.yaml",
            files={"b.yaml": b"name: caf\xe9\n"}),
    scenario("empty-file", "", "the file is empty"),
    scenario("only-comments", "# nothing here\n\n", "the file is empty"),
    scenario("tab-indent", "pipeline:\n\tframe_rate_hz: 30\n", "YAML does not allow tabs"),
    scenario("bad-indent", "pipeline:\n  frame_rate_hz: 30\n mode: pipelined\n",
             "not valid YAML: expected <block end>"),
    scenario("unclosed-bracket", "seed: [1, 2\n", "not valid YAML"),
    scenario("unclosed-quote", "name: 'abc\n", "not valid YAML"),
    scenario("duplicate-key", "duration_s: 1\nduration_s: 2\n", "duplicate key 'duration_s'"),
    scenario("duplicate-nested-key", "controller: {kind: pid, kind: mpc}\n",
             "duplicate key 'kind'"),
    scenario("alias-bomb", BOMB, "alias bomb"),
    scenario("deep-nesting", "a: " + "[" * 60 + "]" * 60 + "\n", "nested more than 50 levels"),
    scenario("parser-stack-nesting", "a: " + "[" * 5000 + "]" * 5000 + "\n",
             "nested more than 50 levels"),
    command("character-device", "not a regular file", "simulate", "/dev/null"),
    scenario("top-level-list", "- duration_s: 1\n", "expected a mapping"),
    scenario("top-level-scalar", "hello\n", "expected a mapping"),
    scenario("python-tag", "name: !!python/object/apply:os.system [ls]\n",
             "could not determine a constructor"),
    scenario("two-documents", "seed: 1\n---\nseed: 2\n", "expected a single document"),
    scenario("huge-file", "# " + "x" * 1_000_100 + "\nseed: 1\n", "too large"),
    scenario("non-string-key", "1: 2\n", "Keys should be strings"),
    # --- scenario fields ------------------------------------------------------------------
    scenario("unknown-field", "colour: red\n", "colour"),
    scenario("negative-duration", "duration_s: -1\n", "duration_s"),
    scenario("inf-duration", "duration_s: .inf\n", "duration_s must be a finite number"),
    scenario("nan-duration", "duration_s: .nan\n", "duration_s must be a finite number"),
    scenario("huge-duration", "duration_s: 7200\n", "less than or equal to 3600"),
    scenario("text-duration", "duration_s: long\n", "duration_s"),
    scenario("seed-minus-one", "seed: -1\n", "seed: Input should be greater than or equal to 0"),
    scenario("fractional-seed", "seed: 1.5\n", "seed"),
    scenario("boolean-seed", "seed: true\n", "seed must be an integer >= 0, got True"),
    scenario("name-with-slash", "name: a/b\n", "name 'a/b'"),
    scenario("name-dotdot", "name: ..\n", "name '..'"),
    scenario("name-parent-path", "name: ../../etc\n", "'..'"),
    scenario("name-empty", "name: ''\n", "name ''"),
    scenario("name-too-long", f"name: {'x' * 101}\n", "1-100 letters"),
    scenario("name-leading-dash", "name: -rf\n", "not start"),
    scenario("bad-mode", "mode: video\n", "mode"),
    scenario("bad-renderer", "renderer: blender\n", "renderer"),
    scenario("bad-tracker", "mode: image\ntracker: sift\n", "tracker"),
    scenario("tracker-without-images", "tracker: csrt\n", "needs mode: image"),
    scenario("bad-on-invalid", "on_invalid: explode\n", "on_invalid"),
    scenario("controller-rate-inf", "controller_rate_hz: .inf\n",
             "controller_rate_hz must be a finite number"),
    scenario("controller-rate-inf-as-text", "controller_rate_hz: 'inf'\n",
             "controller_rate_hz must be a finite number"),
    scenario("filter-noise-inf-as-text", "observer: {aekf: {q_quat_per_s: '+Infinity'}}\n",
             "observer.aekf.q_quat_per_s: Input should be a finite number"),
    scenario("controller-rate-zero", "controller_rate_hz: 0\n", "controller_rate_hz"),
    scenario("controller-rate-negative", "controller_rate_hz: -5\n", "controller_rate_hz"),
    scenario("controller-rate-above-physics", "controller_rate_hz: 5000\n",
             "faster than the physics"),
    # pipeline and latency
    scenario("frame-rate-zero", "pipeline: {frame_rate_hz: 0}\n", "frame_rate_hz"),
    scenario("frame-rate-inf", "pipeline: {frame_rate_hz: .inf}\n",
             "pipeline.frame_rate_hz must be a finite number"),
    scenario("frame-rate-unreachable", "plant: {camera: {frame_rate_hz: 1000}}\n",
             "exceeds the frame period"),
    scenario("exposure-longer-than-frame", "plant: {camera: {exposure_s: 0.05}}\n",
             "exceeds the frame period"),
    scenario("pipeline-contradicts-camera", "pipeline: {frame_rate_hz: 72}\n",
             "differs from plant.camera.frame_rate_hz"),
    scenario("negative-readout", "pipeline: {readout_s: -1}\n", "readout_s"),
    scenario("bad-pipeline-mode", "pipeline: {mode: parallel}\n", "pipeline.mode"),
    scenario("delay-longer-than-run",
             "duration_s: 0.5\npipeline: {observer: {kind: constant, value_s: 0.6}}\n",
             "not shorter than duration_s"),
    scenario("delay-equal-to-run",
             "duration_s: 0.5\npipeline: {observer: {kind: constant, value_s: 0.5}}\n",
             "not shorter than duration_s"),
    scenario("delay-inf", "pipeline: {observer: {kind: constant, value_s: .inf}}\n",
             "pipeline.observer.value_s must be a finite number"),
    scenario("delay-negative", "pipeline: {observer: {kind: constant, value_s: -0.01}}\n",
             "value_s"),
    scenario("delay-unknown-kind", "pipeline: {observer: {kind: weibull}}\n", "observer"),
    scenario("delay-std-nan",
             "pipeline: {observer: {kind: normal, mean_value_s: 0.01, std_s: .nan}}\n",
             "std_s must be a finite number"),
    scenario("uniform-reversed",
             "pipeline: {observer: {kind: uniform, low_s: 0.03, high_s: 0.01}}\n",
             "high_s"),
    scenario("empirical-empty", "pipeline: {observer: {kind: empirical, samples_s: []}}\n",
             "samples_s"),
    scenario("controller-latency-inf",
             "controller_latency: {kind: constant, value_s: .inf}\n",
             "controller_latency.value_s must be a finite number"),
    scenario("controller-latency-longer-than-run",
             "duration_s: 0.5\ncontroller_latency: {kind: constant, value_s: 0.6}\n",
             "no command would take effect"),
    scenario("controller-latency-word", "controller_latency: sometimes\n",
             "controller_latency"),
    scenario("measured-latency-without-images", "observer_latency: measured\n",
             "'measured' needs mode: image"),
    # controllers
    scenario("bad-controller-kind", "controller: {kind: lqr}\n", "controller"),
    scenario("crossover-inf", "controller: {kind: pid, config: {crossover_rad_s: .inf}}\n",
             "controller.config.crossover_rad_s must be a finite number"),
    scenario("crossover-negative", "controller: {kind: pid, config: {crossover_rad_s: -3}}\n",
             "crossover_rad_s"),
    scenario("zero-ratio-below-one", "controller: {kind: pid, config: {zero_ratio: 0.5}}\n",
             "zero_ratio"),
    scenario("integral-ratio-inf", "controller: {kind: pid, config: {integral_ratio: .inf}}\n",
             "integral_ratio must be a finite number"),
    scenario("unstable-pid-rule",
             "controller: {kind: pid, config: {zero_ratio: 1.01, integral_ratio: 0.5}}\n",
             "the loop is unstable"),
    scenario("torque-limit-inf", "controller: {kind: pid, config: {torque_limit_Nm: .inf}}\n",
             "torque_limit_Nm must be a finite number"),
    scenario("tracking-time-nan", "controller: {kind: pid, config: {tracking_time_s: .nan}}\n",
             "tracking_time_s must be a finite number"),
    scenario("inertia-inf", "controller: {kind: pid, config: {inertia_kgm2: [0.1, .inf, 0.1]}}\n",
             "inertia_kgm2.1 must be a finite number"),
    scenario("inertia-negative",
             "controller: {kind: pid, config: {inertia_kgm2: [0.1, -0.1, 0.1]}}\n",
             "inertia_kgm2 must be positive"),
    scenario("bad-anti-windup", "controller: {kind: pid, config: {anti_windup: magic}}\n",
             "anti_windup"),
    scenario("mpc-short-horizon", "controller: {kind: mpc, config: {horizon_steps: 1}}\n",
             "horizon_steps"),
    scenario("mpc-step-inf", "controller: {kind: mpc, config: {step_s: .inf}}\n",
             "step_s must be a finite number"),
    scenario("mpc-bandwidth-inf", "controller: {kind: mpc, config: {bandwidth_rad_s: .inf}}\n",
             "bandwidth_rad_s must be a finite number"),
    scenario("mpc-bad-solver", "controller: {kind: mpc, config: {solver: gurobi}}\n", "solver"),
    scenario("mpc-low-damping", "controller: {kind: mpc, config: {damping: 0.1}}\n", "damping"),
    # observers (their settings; their behaviour on frames is tested elsewhere)
    scenario("bad-observer-kind", "observer: {kind: magic}\n", "observer.kind"),
    scenario("filter-noise-inf", "observer: {aekf: {q_quat_per_s: .inf}}\n",
             "observer.aekf.q_quat_per_s must be a finite number"),
    scenario("filter-sigma-nan", "observer: {aekf: {sigma_px: .nan}}\n",
             "observer.aekf.sigma_px must be a finite number"),
    scenario("filter-window-zero", "observer: {aekf: {window_N: 0}}\n", "window_N"),
    scenario("filter-theta-negative", "observer: {aekf: {theta: -1}}\n", "theta"),
    scenario("pixel-q-zero", "observer: {kind: pixel_kalman, pixel_q_scale: 0}\n",
             "pixel_q_scale"),
    scenario("pixel-r-inf", "observer: {kind: pixel_kalman, pixel_r_scale: .inf}\n",
             "pixel_r_scale must be a finite number"),
    scenario("orb-without-images", "observer: {kind: orb_aekf}\n", "needs mode: image"),
    scenario("texture-with-markers", "texture: {seed: 0}\n", "has no markers"),
    scenario("orb-coast-zero", "mode: image\nobserver: {kind: orb, orb_max_coast_s: 0}\n",
             "orb_max_coast_s"),
    scenario("measurement-dropout-above-one", "measurement: {dropout_prob: 1.5}\n",
             "dropout_prob"),
    scenario("measurement-sigma-inf", "measurement: {sigma_px: .inf}\n",
             "measurement.sigma_px must be a finite number"),
    # references
    scenario("bad-reference-kind", "reference: {kind: spiral}\n", "reference"),
    scenario("tilt-step-beyond-workspace", "reference: {kind: tilt_step, tilt_deg: 20}\n",
             "tilt_deg"),
    scenario("tilt-step-inf", "reference: {kind: tilt_step, tilt_deg: .inf}\n",
             "reference.tilt_deg must be a finite number"),
    scenario("tilt-step-negative-time", "reference: {kind: tilt_step, t_step_s: -1}\n",
             "t_step_s"),
    scenario("tilt-step-after-the-run", "duration_s: 1\nreference: {kind: tilt_step, "
             "t_step_s: 5}\n", "the reference starts at 5 s, not before the run ends"),
    scenario("cone-starts-after-the-run", "duration_s: 1\nreference: {kind: cone, args: "
             "{tilt_deg: 5, yaw_rate_rad_s: 1, t_start_s: 2}}\n", "not before the run ends"),
    scenario("random-reference-seed-negative",
             "reference: {kind: random, args: {max_rate_rad_s: 2, seed: -1}}\n", "args.seed"),
    scenario("camera-exposure-beyond-frame", "plant: {camera: {frame_rate_hz: 1000}}\n",
             "exceeds the frame period"),
    scenario("tilt-step-beyond-stop",
             TILT_10_STOP + "reference: {kind: tilt_step, tilt_deg: 12}\n",
             "beyond the tilt stop"),
    scenario("cone-beyond-stop",
             TILT_10_STOP + "reference: {kind: cone, args: {tilt_deg: 14, yaw_rate_rad_s: 1}}\n",
             "beyond the tilt stop"),
    scenario("random-beyond-stop",
             TILT_10_STOP + "reference: {kind: random, args: {max_rate_rad_s: 2, "
             "tilt_max_deg: 14}}\n", "beyond the tilt stop"),
    scenario("ramp-beyond-stop",
             TILT_10_STOP + "reference: {kind: ramp, args: {start_deg: [0, 0, 0], "
             "stop_deg: [0, 14, 0], duration_s: 0.5}}\n", "beyond the tilt stop"),
    scenario("ramp-beyond-workspace",
             "reference: {kind: ramp, args: {start_deg: [0, 0, 0], stop_deg: [0, 30, 0], "
             "duration_s: 1}}\n", "tilt 30.0° is outside the 0–15.0° workspace"),
    scenario("ramp-missing-duration",
             "reference: {kind: ramp, args: {start_deg: [0, 0, 0], stop_deg: [0, 5, 0]}}\n",
             "args.duration_s: Field required"),
    scenario("random-missing-rate", "reference: {kind: random}\n",
             "args.max_rate_rad_s: Field required"),
    scenario("random-rate-zero", "reference: {kind: random, args: {max_rate_rad_s: 0}}\n",
             "args.max_rate_rad_s"),
    scenario("cone-unknown-arg",
             "reference: {kind: cone, args: {tilt_deg: 5, yaw_rate_rad_s: 1, speed: 2}}\n",
             "args.speed"),
    scenario("cone-rate-inf", "reference: {kind: cone, args: {tilt_deg: 5, yaw_rate_rad_s: "
             ".inf}}\n", "reference.args.yaw_rate_rad_s must be a finite number"),
    scenario("seed-steps-bad-axis", "reference: {kind: seed_steps, args: {axis: roll}}\n",
             "args.axis"),
    scenario("reference-args-list", "reference: {kind: cone, args: [1, 2]}\n", "args"),
    # plant
    scenario("negative-mass", "plant: {rotor: {mass_kg: -1}}\n", "mass_kg"),
    scenario("tilt-stop-inf", "plant: {rotor: {tilt_stop_deg: .inf}}\n",
             "plant.rotor.tilt_stop_deg must be a finite number"),
    scenario("physics-step-too-long", "plant: {physics_dt_s: 0.1}\n", "physics_dt_s"),
    scenario("camera-binning-zero", "plant: {camera: {binning: 0}}\n", "binning"),
    scenario("coil-current-nan", "plant: {motor: {i_max_A: .nan}}\n",
             "plant.motor.i_max_A must be a finite number"),
    # --- sweep files ----------------------------------------------------------------------
    command("sweep-missing-file", "no such file", "sweep", "{d}/nope.yaml"),
    command("sweep-directory", "is a directory", "sweep", "{d}/folder",
            files={"folder/x": "a"}),
    sweep("sweep-empty", "", "the file is empty"),
    sweep("sweep-duplicate-key", "grid: {seed: [0]}\ngrid: {seed: [1]}\n",
          "duplicate key 'grid'"),
    sweep("sweep-alias-bomb", BOMB.replace("a:", "base:", 1), "alias bomb"),
    sweep("sweep-tabs", "grid:\n\tseed: [0, 1]\n", "YAML does not allow tabs"),
    sweep("sweep-unknown-top-key", "base: {}\ngrids: {seed: [0]}\n", "unknown top-level keys"),
    sweep("sweep-base-not-mapping", "base: [1, 2]\ngrid: {seed: [0]}\n",
          "base must be a mapping"),
    sweep("sweep-grid-not-mapping", "grid: [seed, 0]\n", "grid must be a mapping"),
    sweep("sweep-grid-value-not-list", "grid: {seed: 3}\n", "grid.seed must be a non-empty list"),
    sweep("sweep-grid-empty-list", "grid: {seed: []}\n", "grid.seed must be a non-empty list"),
    sweep("sweep-grid-empty-path-part", "grid: {'pipeline..mode': [sequential]}\n",
          "must be a dotted field path"),
    sweep("sweep-grid-through-scalar", "base: {name: a}\ngrid: {name.x: [1]}\n",
          "name is not a mapping"),
    sweep("sweep-grid-too-large",
          "grid:\n" + "".join(f"  k{i}: [0, 1]\n" for i in range(17)), "more than 100000"),
    sweep("sweep-grid-bad-run", "base: {duration_s: 0.3}\ngrid: {seed: [0, -1]}\n",
          "(run 2 of 2)"),
    sweep("sweep-grid-inf-rate", "grid: {pipeline.frame_rate_hz: [36, .inf]}\n",
          "pipeline.frame_rate_hz must be a finite number"),
    sweep("sweep-grid-unknown-field", "grid: {colour: [red]}\n", "colour"),
    sweep("sweep-workers-zero", OK_SWEEP, "--workers must be >= 1", "--workers", "0"),
    sweep("sweep-workers-negative", OK_SWEEP, "--workers must be >= 1", "--workers", "-2"),
    sweep("sweep-workers-text", OK_SWEEP, "Invalid value for '--workers'", "--workers", "two"),
    sweep("sweep-scheduler-word", OK_SWEEP, "--scheduler 'somewhere'", "--scheduler",
          "somewhere"),
    sweep("sweep-scheduler-no-port", OK_SWEEP, "is neither 'local' nor", "--scheduler",
          "tcp://host"),
    sweep("sweep-scheduler-bad-port", OK_SWEEP, "is neither 'local' nor", "--scheduler",
          "tcp://host:99999"),
    sweep("sweep-scheduler-http", OK_SWEEP, "is neither 'local' nor", "--scheduler",
          "http://host:8786"),
    sweep("sweep-scheduler-space", OK_SWEEP, "is neither 'local' nor", "--scheduler",
          "tcp://my host:8786"),
    Case("sweep-out-is-a-file", ("sweep", "{d}/w.yaml", "--out", "{d}/w.yaml"),
         "cannot write results there", {"w.yaml": OK_SWEEP}),
    Case("sweep-out-under-a-file", ("sweep", "{d}/w.yaml", "--out", "{d}/w.yaml/sub"),
         "cannot write results there", {"w.yaml": OK_SWEEP}),
    # --- simulate: output, and the warning of a crossover out of reach ---------------------
    Case("simulate-out-is-a-file", ("simulate", "{d}/s.yaml", "--out", "{d}/s.yaml"),
         "cannot write results there", {"s.yaml": "seed: 1\n"}),
    Case("simulate-out-in-proc", ("simulate", "{d}/s.yaml", "--out", "/proc/pmspm-out"),
         "cannot write results there", {"s.yaml": "seed: 1\n"}),
    Case("simulate-out-nul-byte", ("simulate", "{d}/s.yaml", "--out", "{d}/a\x00b"),
         "embedded null byte", {"s.yaml": "seed: 1\n"}),
    # Warnings print after validation and before the output folder is checked: a file given
    # as --out then stops these rows before the run.
    Case("warning-crossover-above-nyquist",
         ("simulate", "{d}/s.yaml", "--out", "{d}/s.yaml"),
         "warning: crossover 300 rad/s is above the camera's Nyquist frequency",
         {"s.yaml": "controller: {kind: pid, config: {crossover_rad_s: 300}}\n"}),
    Case("warning-crossover-saturates",
         ("simulate", "{d}/s.yaml", "--out", "{d}/s.yaml"),
         "more than the torque limit",
         {"s.yaml": "controller: {kind: pid, config: {crossover_rad_s: 300}}\n"}),
    Case("warning-crossover-below-friction",
         ("simulate", "{d}/s.yaml", "--out", "{d}/s.yaml"),
         "less than the bearing's dry friction",
         {"s.yaml": "controller: {kind: pid, config: {crossover_rad_s: 1}}\n"}),
    Case("warning-mpc-bandwidth",
         ("simulate", "{d}/s.yaml", "--out", "{d}/s.yaml"),
         "warning: MPC bandwidth 150 rad/s is above the camera's Nyquist frequency",
         {"s.yaml": "controller: {kind: mpc, config: {bandwidth_rad_s: 150, step_s: 0.005}}\n"}),
    # --- margins --------------------------------------------------------------------------
    command("margins-crossover-nan", CROSSOVER_RANGE, "margins", "--crossover-rad-s", "nan"),
    command("margins-crossover-inf", CROSSOVER_RANGE, "margins", "--crossover-rad-s", "inf"),
    command("margins-crossover-zero", CROSSOVER_RANGE, "margins", "--crossover-rad-s", "0"),
    command("margins-crossover-negative", CROSSOVER_RANGE, "margins", "--crossover-rad-s", "-4"),
    command("margins-crossover-huge", "the margin computation does not finish", "margins",
            "--crossover-rad-s", "1e9"),
    command("margins-crossover-tiny", "--crossover-rad-s must be a finite number >= 0.001",
            "margins", "--crossover-rad-s", "1e-9"),
    command("margins-delay-huge", "the margin computation does not finish", "margins",
            "--delay-ms", "1e300"),
    command("margins-crossover-text", "Invalid value for '--crossover-rad-s'", "margins",
            "--crossover-rad-s", "fast"),
    command("margins-frame-rate-nan", "--frame-rate-hz must be a finite number > 0",
            "margins", "--frame-rate-hz", "nan"),
    command("margins-frame-rate-inf", "--frame-rate-hz must be a finite number > 0",
            "margins", "--frame-rate-hz", "inf"),
    command("margins-frame-rate-zero", "--frame-rate-hz must be a finite number > 0",
            "margins", "--frame-rate-hz", "0"),
    command("margins-frame-rate-negative", "--frame-rate-hz must be a finite number > 0",
            "margins", "--frame-rate-hz", "-36"),
    command("margins-frame-rate-unreachable", "exceeds the frame period", "margins",
            "--frame-rate-hz", "1000"),
    command("margins-bad-observer", "--observer must be sequential or pipelined", "margins",
            "--observer", "parallel"),
    command("margins-delay-nan", DELAY_RANGE, "margins", "--delay-ms", "nan"),
    command("margins-delay-inf", DELAY_RANGE, "margins", "--delay-ms", "inf"),
    command("margins-delay-negative", DELAY_RANGE, "margins", "--delay-ms", "-5"),
    command("margins-out-under-a-file", "cannot write results there", "margins", "--out",
            "{d}/f.txt/sub", files={"f.txt": "x"}),
    # --- measure-latency ------------------------------------------------------------------
    command("latency-bad-tracker", "--tracker must be one of kcf, csrt, gk_transt",
            "measure-latency", "--tracker", "sift"),
    command("latency-frames-zero", "--frames must be between 1 and 100000", "measure-latency",
            "--frames", "0"),
    command("latency-frames-negative", "--frames must be between 1 and 100000",
            "measure-latency", "--frames", "-3"),
    command("latency-frames-huge", "--frames must be between 1 and 100000", "measure-latency",
            "--frames", "1000000"),
    command("latency-frames-text", "Invalid value for '--frames'", "measure-latency", "--frames",
            "many"),
    command("latency-out-is-a-file", "cannot write results there", "measure-latency", "--out",
            "{d}/f.txt", files={"f.txt": "x"}),
    command("latency-out-under-a-file", "cannot write results there", "measure-latency",
            "--out", "{d}/f.txt/sub", files={"f.txt": "x"}),
    # --- bench-trackers -------------------------------------------------------------------
    command("bench-seeds-zero", "seeds must be >= 1", "bench-trackers", "--stand-in",
            "--seeds", "0", "--out", "{d}/b"),
    command("bench-bad-case", "cases must be among", "bench-trackers", "--stand-in",
            "--cases", "fog", "--out", "{d}/b"),
    command("bench-bad-tracker", "unknown trackers ['sift']", "bench-trackers", "--stand-in",
            "--trackers", "sift", "--out", "{d}/b"),
    command("bench-too-few-frames", "frames must be >= 2", "bench-trackers", "--stand-in",
            "--cases", "clean", "--frames", "1", "--out", "{d}/b"),
    command("bench-blur-frames", "frames must be >= 161", "bench-trackers", "--stand-in",
            "--cases", "blur", "--frames", "100", "--out", "{d}/b"),
    command("bench-torch-threads-zero", "--torch-threads must be >= 1", "bench-trackers",
            "--stand-in", "--torch-threads", "0", "--out", "{d}/b"),
    command("bench-out-is-a-file", "cannot write results there", "bench-trackers",
            "--stand-in", "--out", "{d}/f.txt", files={"f.txt": "x"}),
    # --- tune-kalman ----------------------------------------------------------------------
    command("tune-delay-nan", "--delays-ms must be a finite number >= 0", "tune-kalman",
            "--delays-ms", "nan", "--out", "{d}/t"),
    command("tune-delay-inf", "--delays-ms must be a finite number >= 0", "tune-kalman",
            "--delays-ms", "inf", "--out", "{d}/t"),
    command("tune-delay-negative", "--delays-ms must be a finite number >= 0", "tune-kalman",
            "--delays-ms", "16", "--delays-ms", "-1", "--out", "{d}/t"),
    command("tune-delay-longer-than-run", "is not shorter than duration_s", "tune-kalman",
            "--delays-ms", "5000", "--out", "{d}/t"),
    command("tune-duration-too-long", "less than or equal to 3600", "tune-kalman",
            "--duration-s", "7200", "--out", "{d}/t"),
    command("tune-grid-points-huge", "--grid-points <= 100", "tune-kalman", "--grid-points",
            "100000", "--out", "{d}/t"),
    command("tune-duration-zero", "--duration-s must be a finite number > 0", "tune-kalman",
            "--duration-s", "0", "--out", "{d}/t"),
    command("tune-duration-nan", "--duration-s must be a finite number > 0", "tune-kalman",
            "--duration-s", "nan", "--out", "{d}/t"),
    command("tune-duration-inf", "--duration-s must be a finite number > 0", "tune-kalman",
            "--duration-s", "inf", "--out", "{d}/t"),
    command("tune-grid-points-one", "need 2 <= --grid-points <= 100", "tune-kalman",
            "--grid-points", "1", "--out", "{d}/t"),
    command("tune-trials-negative", "--trials >= 0", "tune-kalman", "--trials", "-1", "--out",
            "{d}/t"),
    command("tune-workers-zero", "--workers must be >= 1", "tune-kalman", "--workers", "0",
            "--out", "{d}/t"),
    command("tune-scheduler-bogus", "is neither 'local' nor", "tune-kalman", "--scheduler",
            "cluster", "--out", "{d}/t"),
    command("tune-storage-word", "is not a database URL", "tune-kalman", "--storage", "bogus",
            "--out", "{d}/t"),
    command("tune-storage-unknown-dialect", "is not a database URL", "tune-kalman",
            "--storage", "nosuchdb://host/x", "--out", "{d}/t"),
    command("tune-storage-missing-folder", "does not exist", "tune-kalman", "--storage",
            "sqlite:////nonexistent-pmspm/optuna.db", "--out", "{d}/t"),
    command("tune-out-is-a-file", "cannot write results there", "tune-kalman", "--out",
            "{d}/f.txt", files={"f.txt": "x"}),
    # --- study -------------------------------------------------------------------------
    command("study-workers-zero", "--workers must be >= 1", "study", "--workers", "0",
            "--out", "{d}/o"),
    command("study-workers-negative", "--workers must be >= 1", "study", "--workers", "-1",
            "--out", "{d}/o"),
    command("study-scheduler-bogus", "is neither 'local' nor", "study", "--scheduler",
            "tcp:/host:8786", "--out", "{d}/o"),
    command("study-out-is-a-file", "cannot write results there", "study", "--out", "{d}/f.txt",
            files={"f.txt": "x"}),
    # --- codesign ------------------------------------------------------------------------
    command("codesign-missing-file", "no such file", "codesign", "{d}/nope.yaml"),
    codesign("codesign-unknown-field", "bogus: 1\n", "bogus: Extra inputs are not permitted"),
    codesign("codesign-range-reversed", "camera: {exposure_s: [0.004, 0.001]}\n",
             "camera.exposure_s: high (0.001) must be >= low (0.004)"),
    codesign("codesign-rows-too-small", "camera: {rows: [8]}\n",
             "camera.rows.0: Input should be greater than or equal to 16"),
    codesign("codesign-unknown-tracker", "trackers: [nope]\n", "not in tracker_models"),
    codesign("codesign-latency-file-missing",
             "tracker_models: {mine: {latency_file: nope.json}}\n",
             "latency_file: no such file: nope.json"),
    codesign("codesign-loss-above-one", "constraints: {max_loss_of_control: 2}\n",
             "constraints.max_loss_of_control: Input should be less than or equal to 1"),
    codesign("codesign-reference-beyond-stop",
             TILT_10_STOP + "references: [{kind: tilt_step, tilt_deg: 12}]\n",
             "references[0]: the reference reaches 12° of tilt, beyond the tilt stop"),
    codesign("codesign-sampler-unknown", "search: {sampler: grid}\n",
             "search.sampler: Input should be 'nsga2' or 'tpe'"),
    codesign("codesign-storage-bogus", "search: {storage: bogus}\n", "is not a database URL"),
    codesign("codesign-trials-zero", "name: x\n", "--trials must be >= 1", "--trials", "0"),
    codesign("codesign-workers-zero", "name: x\n", "--workers must be >= 1", "--workers", "0"),
    # --- the command line's own grammar ---------------------------------------------------
    command("unknown-command", "No such command", "simulat"),
    command("unknown-option", "No such option", "margins", "--crossover", "3"),
    command("missing-scenario-argument", "Missing argument", "simulate"),
    command("option-without-value", "requires an argument", "sweep", "{d}/w.yaml",
            "--workers"),
]


def _forbid_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """Replace the entry points of expensive work with functions that fail the test."""
    import experiments.codesign.search
    import experiments.sequences
    import experiments.study
    import experiments.sweep
    import experiments.tuning
    import latency.margins
    import latency.profile
    import latency.simulation

    def work(*args, **kwargs):
        raise AssertionError("expensive work started before the mistake was caught")

    for module, name in [
        (latency.simulation, "simulate"),
        (experiments.codesign.search, "run_search"),
        (experiments.sweep, "run_sweep"),
        (experiments.study, "run_study"),
        (experiments.tuning, "tune_kalman"),
        (experiments.sequences, "validation_suite"),
        (latency.profile, "measure_locator_latency"),
        (latency.profile, "measure_orb_latency"),
        (latency.profile, "measure_pair_tracker_latency"),
        (latency.margins, "attitude_margins"),
        (experiments.study, "pid_axis_margins"),
        (experiments.study, "margins_table"),
    ]:
        monkeypatch.setattr(module, name, work)


def test_the_catalogue_is_large_and_its_ids_unique():
    assert len(CASES) > 100
    assert len({c.id for c in CASES}) == len(CASES)


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_cli_mistake_exits_2_with_a_message(case: Case, tmp_path, monkeypatch):
    _forbid_work(monkeypatch)
    monkeypatch.chdir(tmp_path)
    for name, content in case.files.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
    argv = [a.replace("{d}", str(tmp_path)) for a in case.argv]
    result = RUNNER.invoke(app, argv, env={"COLUMNS": "200"})
    output = result.output
    assert "Traceback" not in output
    assert not isinstance(result.exception, AssertionError), output
    assert result.exit_code == case.code, output
    assert case.fragment in output, output


def test_the_default_scenario_gives_no_reach_warning():
    from latency import Scenario

    assert Scenario().reach_warnings() == []


@pytest.mark.parametrize(
    "crossover_rad_s, frame_rate_hz, warned",
    [(110.0, 36.0, False), (116.0, 36.0, True), (116.0, 72.0, False), (230.0, 72.0, True)],
)
def test_the_nyquist_warning_sits_at_pi_times_the_frame_rate(
    crossover_rad_s, frame_rate_hz, warned
):
    from latency import Scenario

    # pi x 36 frames/s = 113.1 rad/s; pi x 72 frames/s = 226.2 rad/s.
    s = Scenario.model_validate(
        {
            "controller": {"kind": "pid", "config": {"crossover_rad_s": crossover_rad_s}},
            "plant": {"camera": {"frame_rate_hz": frame_rate_hz}},
        }
    )
    assert any("Nyquist" in w for w in s.reach_warnings()) == warned


@pytest.mark.parametrize(
    "fields, fragment",
    [
        ({"controller_rate_hz": float("inf")}, "finite number"),
        ({"seed": -1}, "greater than or equal to 0"),
        ({"pipeline": {"frame_rate_hz": 1000.0}}, "more than the camera can reach"),
        ({"duration_s": 0.01}, "no estimate would arrive"),
        ({"controller_latency": {"kind": "constant", "value_s": 1.0}}, "no command would"),
    ],
)
def test_the_loop_config_rejects_what_cannot_run(fields, fragment):
    """The loop's own settings check the same, for code that builds a loop without a
    scenario (a 1 s run, a 2 ms exposure, GK-TransT's 16.33 ms by default)."""
    from pydantic import ValidationError

    from latency.loop_config import LoopConfig

    with pytest.raises(ValidationError, match=fragment):
        LoopConfig.model_validate({"duration_s": 1.0, **fields})
