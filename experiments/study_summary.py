"""The headline study's plain-language findings (``experiments.study``): every number taken
from the study's tables or measured in the run, and the predicted stability boundary."""

from __future__ import annotations

import numpy as np
import pandas as pd

from experiments.study_config import DUAL_MS, GK_MS, OWN_DELAY_MS, TRACKER_NAMES, StudyConfig
from experiments.study_plots import (
    CONTROLLER_STYLE,
)
from experiments.study_sweep import RANDOM_CONTROLLERS, STEP_CONTROLLERS
from latency.metrics import SETTLE_BAND_DEG


def predicted_boundary_ms(margins: pd.DataFrame) -> float:
    """First vision delay (ms) at which the sequential-observer loop is unstable: the
    headroom of the zero-delay row (the delay scanned through the pipeline)."""
    row = margins[(margins.observer == "sequential") & np.isclose(margins.vision_delay_ms, 0.0)]
    return float(1e3 * row.headroom_s.iloc[0]) if len(row) else float("nan")


def _at(df: pd.DataFrame, mode: str, d_ms: float, col: str) -> float:
    row = df[(df.observer == mode) & (np.isclose(df.vision_delay_ms, d_ms))]
    return float(row[col].iloc[0]) if len(row) else float("nan")


def _ci(row: pd.Series, col: str, scale: float = 1.0, fmt: str = ".2f") -> str:
    """``mean (low–high)`` of an interval column; the mean alone without an interval."""
    m, lo, hi = (scale * float(row[c]) for c in (col, f"{col}_lo", f"{col}_hi"))
    if not np.isfinite(m):
        return "—"
    return f"{m:{fmt}} ({lo:{fmt}}–{hi:{fmt}})" if np.isfinite(lo) else f"{m:{fmt}}"


def _preview_lines(step: pd.DataFrame) -> list[str]:
    """What the MPC's reference preview changes on the step at GK-TransT's latency: the RMS
    error over the run, not the tail metrics (overshoot, settling, steady-state error), which
    the two variants can share."""
    at = step[np.isclose(step.vision_delay_ms, GK_MS)].set_index("controller")
    if not {"mpc", "mpc_nopreview"} <= set(at.index):
        return []
    with_p, without = at.loc["mpc"], at.loc["mpc_nopreview"]
    return [
        f"- **MPC reference preview.** On the 5° step at {GK_MS:.2f} ms the RMS error over "
        f"the run is {_ci(with_p, 'rms_error_deg', fmt='.3f')}° with preview and "
        f"{_ci(without, 'rms_error_deg', fmt='.3f')}° without: previewing, the MPC starts "
        "moving before the step. Its overshoot, settling time and steady-state error can "
        "nevertheless equal those without preview: once the step is past, both see the same "
        "constant reference and their trajectories meet within a few tenths of a second, "
        "long before the slow creep into the settling band (Coulomb friction) that sets "
        "those metrics."
    ]


def _loss_lines(loss: pd.DataFrame, intervals: pd.DataFrame, cfg: StudyConfig) -> list[str]:
    """Per controller: each tracker at its own seed latency (its own loss model), lost frames
    on the random references and the probability of loss of control."""
    lines: list[str] = []
    if loss.empty:
        return lines
    model = ("its calibrated loss model" if cfg.loss_model == "calibrated"
             else f"the hand-set {cfg.search_radius_px:g} px search window")
    rnd = intervals[intervals.reference.str.startswith("random")]
    for ctrl in RANDOM_CONTROLLERS:
        parts = []
        for tracker in cfg.trackers:
            d = OWN_DELAY_MS.get(tracker)
            if d is None:
                continue
            g = loss[(loss.controller == ctrl) & (loss.tracker == tracker)
                     & np.isclose(loss.vision_delay_ms, d)]
            lf = rnd[(rnd.controller == ctrl) & (rnd.tracker == tracker)
                     & np.isclose(rnd.vision_delay_ms, d)]
            if not len(g):
                continue
            lost = ", ".join(f"{r.reference.removeprefix('random_').replace('rad_s', ' rad/s')}"
                             f" {_ci(r, 'lost_frame_fraction', 100.0, '.1f')} %"
                             for _, r in lf.iterrows())
            parts.append(f"{TRACKER_NAMES.get(tracker, tracker)} at its {d:.2f} ms: "
                         f"P(loss of control) {_ci(g.iloc[0], 'p_loss_of_control')} "
                         f"({int(g.iloc[0].n_runs)} runs), lost frames {lost}")
        if parts:
            lines.append(f"- **{ctrl.upper()}: tracking loss and loss of control, each tracker "
                         f"at its own latency** (random references, each tracker's loss from "
                         f"{model}; loss of control: sustained tilt-stop contact, marker loss, "
                         f"an error beyond what the reference demands, or divergence): "
                         + "; ".join(parts) + ".")
    return lines


def _image_loop_lines(image: pd.DataFrame | None) -> list[str]:
    """The image-engine section in a line per tracker: lost frames from the trackers
    themselves at the seed's two latencies, and the agreement of the calibrated models."""
    title = "- **Tracking loss from the trackers themselves (image engine).** "
    if image is None:
        return [title + "Not run in this study (`StudyConfig.image_loop` is off)."]
    if not len(image):
        return [title + "Not run: no tracker to run."]
    parts = []
    for tracker, g in image.groupby("tracker", sort=False):
        at = "; ".join(
            f"{r.vision_delay_ms:.2f} ms, {r.max_rate_rad_s:g} rad/s: "
            f"{_ci(r, 'image_lost_frame_fraction', 100.0, '.1f')} % (model "
            f"{_ci(r, 'model_lost_frame_fraction', 100.0, '.1f')} %)"
            for _, r in g.iterrows())
        parts.append(f"{TRACKER_NAMES.get(tracker, tracker)}, lost frames in PID runs: {at}; "
                     f"the calibrated model agrees on {int(g.agree.sum())} of {len(g)} points")
    return [title + ". ".join(parts) + "."]


def summary_text(
    margins: pd.DataFrame, intervals: pd.DataFrame, loss: pd.DataFrame, ts: dict,
    measured: dict[str, float], facts: dict, cfg: StudyConfig,
    mpc_margins: pd.DataFrame | None = None, image: pd.DataFrame | None = None,
) -> list[str]:
    """Plain-language findings, every number taken from the tables or measured in this run."""
    step = intervals[intervals.reference == "tilt_step_5deg"]
    return (_phase_margin_lines(margins, facts, cfg) + _latency_lines(measured, facts)
            + _mpc_margin_lines(mpc_margins) + _loss_lines(loss, intervals, cfg)
            + _step_lines(step, cfg) + _preview_lines(step) + _image_loop_lines(image)
            + _friction_lines(step, facts, cfg))


def _phase_margin_lines(margins: pd.DataFrame, facts: dict, cfg: StudyConfig) -> list[str]:
    """The PID's phase margin, headroom, delay and jitter margins at the seed's two latencies
    (sequential and pipelined observer) and the predicted stability boundary."""
    fps, period = facts["frame_rate_hz"], facts["frame_period_ms"]
    pm_gk = _at(margins, "sequential", GK_MS, "phase_margin_deg")
    pm_dual = _at(margins, "sequential", DUAL_MS, "phase_margin_deg")
    pm_dual_p = _at(margins, "pipelined", DUAL_MS, "phase_margin_deg")
    head_gk = 1e3 * _at(margins, "sequential", GK_MS, "headroom_s")
    dm_gk = 1e3 * _at(margins, "sequential", GK_MS, "delay_margin_s")
    jm_dual = 1e3 * _at(margins, "sequential", DUAL_MS, "jitter_margin_s")
    dm_dual = 1e3 * _at(margins, "sequential", DUAL_MS, "delay_margin_s")
    boundary = predicted_boundary_ms(margins)
    lines = [
        f"- **Phase margin.** With the PID tuned for a {cfg.crossover_rad_s:g} rad/s crossover "
        f"at {fps:g} frames/s, GK-TransT's {GK_MS:.2f} ms leaves {pm_gk:.1f}° of phase margin; "
        f"the loop tolerates {head_gk:.1f} ms more vision delay before it is unstable "
        f"(scanned through the sequential pipeline; the constant-delay margin at the fixed "
        f"{period:.1f} ms update period would say {dm_gk:.1f} ms, but beyond one frame period "
        f"the observer drops frames). The dual TransT's {DUAL_MS:.2f} ms leaves {pm_dual:.1f}°: "
        f"it is slower than the {period:.1f} ms frame period, so a sequential observer also "
        f"drops frames and lowers the update rate; a pipelined observer would keep "
        f"{pm_dual_p:.1f}°. There the jitter margin of the PID as it runs is {jm_dual:.1f} ms "
        f"(constant-delay margin {dm_dual:.1f} ms). The sequential loop is predicted unstable "
        f"from {boundary:.1f} ms of vision delay.",
    ]
    return lines


def _latency_lines(measured: dict[str, float], facts: dict) -> list[str]:
    """The trackers' latencies measured on this machine (ms, median) beside the seed's."""
    lines: list[str] = []
    if measured:
        names = {"gk_transt": ("GK-TransT", GK_MS), "dual_transt": ("dual TransT", DUAL_MS)}
        parts = [f"{names[k][0]} {v:.2f} ms (seed: {names[k][1]:.2f} ms)"
                 for k, v in measured.items()]
        lines.append(
            f"- **Latency measured here.** Median per frame on this machine "
            f"({facts['processor']}, {facts['cpus']:.0f} CPUs seen by Python): "
            + "; ".join(parts) + ". Marked on the plots beside the seed's figures."
        )
    else:
        lines.append("- **Latency measured here.** Not measured: the TransT network could not "
                     "be loaded.")
    return lines


def _mpc_margin_lines(mpc_margins: pd.DataFrame | None) -> list[str]:
    """The delay-aware MPC's linearised margins at the seed's two latencies (none without
    the MPC's margins table)."""
    lines: list[str] = []
    if mpc_margins is not None:
        aware = mpc_margins[mpc_margins.delay_aware]

        def deg(mode: str, d: float) -> str:
            v = _at(aware, mode, d, "phase_margin_deg")
            if not np.isfinite(v):
                return "none (unstable)"
            n = int(_at(aware, mode, d, "n_crossovers"))
            w = _at(aware, mode, d, "crossover_rad_s")
            gm = _at(aware, mode, d, "gain_margin")
            head = 1e3 * _at(aware, mode, d, "headroom_s")
            cond = bool(_at(aware, mode, d, "conditionally_stable"))
            extra = f"; {n} gain crossovers, this one critical" if n > 1 else ""
            extra += "; conditionally stable" if cond else ""
            return (f"{v:.1f}° at {w:.1f} rad/s (gain margin {gm:.2f}, headroom {head:.1f} ms"
                    f"{extra})")

        lines.append(
            f"- **MPC margins (linearised law).** The delay-aware MPC keeps "
            f"{deg('sequential', GK_MS)} at {GK_MS:.2f} ms. At {DUAL_MS:.2f} ms a sequential "
            f"observer lowers its update rate and leaves {deg('sequential', DUAL_MS)}; a "
            f"pipelined one keeps {deg('pipelined', DUAL_MS)}."
        )
    return lines


def _step_lines(step: pd.DataFrame, cfg: StudyConfig) -> list[str]:
    """Per seed latency, the 5° tilt step of every step controller: overshoot (%), settling
    (s, or how often it settles) and steady-state error (deg), with their intervals."""
    lines: list[str] = []
    for d in (GK_MS, DUAL_MS):
        at = step[np.isclose(step.vision_delay_ms, d)].set_index("controller")
        parts = []
        for ctrl in STEP_CONTROLLERS:
            if ctrl not in at.index:
                continue
            r = at.loc[ctrl]
            settled = float(r.p_settled)
            settle = (f"settles in {_ci(r, 'settling_time_s')} s" if settled == 1.0 else
                      "does not settle within the run" if settled == 0.0 else
                      f"settles in {100 * settled:.0f} % of the runs")
            over = _ci(r, "overshoot_pct", fmt=".1f")
            sse = _ci(r, "steady_state_error_deg", fmt=".3f")
            parts.append(f"{CONTROLLER_STYLE[ctrl][1]}: overshoot {over} %, {settle}, "
                         f"steady-state error {sse}°")
        if parts:
            lines.append(f"- **5° tilt step at {d:.2f} ms** (band ±{SETTLE_BAND_DEG:g}°, "
                         f"{cfg.duration_s:g} s runs). " + "; ".join(parts) + ".")
    return lines


def _friction_lines(step: pd.DataFrame, facts: dict, cfg: StudyConfig) -> list[str]:
    """Why the PID's step does not settle at GK-TransT's latency, when it does not: Coulomb
    friction (mN·m) and the friction compensation that is the remedy."""
    lines: list[str] = []
    pid_gk = step[(step.controller == "pid") & np.isclose(step.vision_delay_ms, GK_MS)]
    coulomb_mNm = 1e3 * facts["coulomb_Nm"]
    if len(pid_gk) and float(pid_gk.p_settled.iloc[0]) < 1.0:
        lines.append(
            f"- **Coulomb friction.** With the default {coulomb_mNm:g} mN·m the PID's "
            "integrator winds up while the rotor sticks and drives it slowly past the target: "
            "the step does not settle within the run. The remedy measured here is the PID's "
            f"friction compensation ({cfg.friction_compensation_Nm * 1e3:g} mN·m, "
            "`PIDConfig.friction_compensation_Nm`; row 'PID + friction compensation')."
        )
    return lines


