"""A short closed demo of the plant: a tilt step under a PD torque law on the true state.

PLACEHOLDER for the headline study (issue 6). There is no camera in this loop yet and no delay:
the torque law reads the simulated attitude directly. It exercises the parts that have landed:
MuJoCo dynamics, K(q) with bounded current allocation, the tilt stop and both renderers.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from rich.progress import track  # noqa: E402

from plant import attitude  # noqa: E402
from plant.dynamics import MujocoPlant  # noqa: E402
from plant.params import PlantParams  # noqa: E402


@dataclass(frozen=True)
class PDLaw:
    """tau_body = Kp e - Kd omega with e the rotation vector of q^-1 ⊗ q_ref (body frame).

    Gains for a crossover near ``bandwidth_rad_s`` on the rigid inertia J (N·m·s²/rad):
    Kp = J w_c², Kd = 2 zeta J w_c. Our placeholder until the controllers of issue 5 land.
    """

    Kp_Nm_per_rad: float
    Kd_Nms_per_rad: float

    @classmethod
    def for_bandwidth(cls, J_kgm2: float, bandwidth_rad_s: float, zeta: float = 0.8) -> PDLaw:
        return cls(J_kgm2 * bandwidth_rad_s**2, 2 * zeta * J_kgm2 * bandwidth_rad_s)

    def torque_stator(self, q: NDArray, omega: NDArray, q_ref: NDArray) -> NDArray[np.float64]:
        """Requested torque in the stator frame (N·m)."""
        e = attitude.to_rotvec(attitude.multiply(attitude.conjugate(q), q_ref))
        return attitude.to_matrix(q) @ (self.Kp_Nm_per_rad * e - self.Kd_Nms_per_rad * omega)


def simulate_tilt_step(
    params: PlantParams,
    tilt_deg: float = 10.0,
    yaw_deg: float = 30.0,
    t_step_s: float = 0.05,
    duration_s: float = 0.8,
    bandwidth_rad_s: float = 40.0,
) -> pd.DataFrame:
    """Run the tilt step; one row per physics step (SI units, angles also in degrees)."""
    plant = MujocoPlant(params)
    law = PDLaw.for_bandwidth(params.rotor.inertia_com_kgm2[0], bandwidth_rad_s)
    # A pure tilt toward azimuth yaw, no net turn about the shaft: spin = -yaw (at beta = 0 the
    # seed's spin and yaw add up).
    q_ref_step = attitude.from_zyz(-np.deg2rad(yaw_deg), np.deg2rad(tilt_deg), np.deg2rad(yaw_deg))
    h = params.physics_dt_s
    rows = []
    for k in track(range(round(duration_s / h)), description="demo: tilt step"):
        t = k * h
        q_ref = q_ref_step if t >= t_step_s else np.array([1.0, 0, 0, 0])
        alloc = plant.allocate(law.torque_stator(plant.q, plant.omega, q_ref))
        q = plant.q
        alpha, beta, gamma = attitude.to_zyz(q)
        rows.append(
            {
                "t_s": t,
                "tilt_ref_deg": np.degrees(attitude.tilt(q_ref)),
                "tilt_deg": np.degrees(beta),
                "yaw_deg": np.degrees(gamma) if beta > 1e-3 else np.nan,
                "error_deg": np.degrees(attitude.geodesic_angle(q, q_ref)),
                "torque_Nm": float(np.linalg.norm(alloc.delivered)),
                "i_max_abs_A": float(np.abs(alloc.currents).max()),
                "saturated": alloc.saturated,
                "stop_active": plant.tilt_stop_active(),
                **{f"q{c}": v for c, v in zip("wxyz", q, strict=True)},
                **{f"omega_{c}_rad_s": v for c, v in zip("xyz", plant.omega, strict=True)},
            }
        )
        plant.step(alloc.currents, h)
    return pd.DataFrame(rows)


def _plot(df: pd.DataFrame, path: Path, i_max: float) -> None:
    fig, ax = plt.subplots(3, 1, figsize=(8, 7.5), sharex=True)
    ax[0].plot(df.t_s, df.tilt_ref_deg, "k--", label="reference")
    ax[0].plot(df.t_s, df.tilt_deg, label="tilt β")
    ax[0].set_ylabel("tilt (deg)")
    ax[0].legend()
    ax[1].plot(df.t_s, df.error_deg)
    ax[1].set_ylabel("geodesic error (deg)")
    ax[1].set_yscale("log")
    ax[2].plot(df.t_s, df.torque_Nm, label="|T| delivered (N·m)")
    ax[2].plot(df.t_s, df.i_max_abs_A / i_max, label="max |I| / i_max")
    ax[2].fill_between(df.t_s, 0, df.saturated.astype(float), alpha=0.2, label="saturated")
    ax[2].set_xlabel("time (s)")
    ax[2].legend()
    fig.suptitle("Placeholder demo: tilt step under a PD law on the true state")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_demo(out_root: Path = Path("runs"), params: PlantParams | None = None) -> Path:
    """Simulate, render a few frames, plot, and write ``runs/<timestamp>-demo/report.md``."""
    from PIL import Image

    from plant.render_analytic import AnalyticRenderer
    from plant.render_mujoco import MujocoRenderer

    params = params or PlantParams()
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    out = out_root / f"{stamp}-demo"
    out.mkdir(parents=True, exist_ok=False)
    df = simulate_tilt_step(params)
    df.to_parquet(out / "timeseries.parquet")
    _plot(df, out / "tilt_step.png", params.motor.i_max_A)

    frames = []
    analytic = AnalyticRenderer(params, seed=0)
    with MujocoRenderer(params) as realistic:
        for t in (0.0, 0.1, 0.2, df.t_s.iloc[-1]):
            row = df.iloc[(df.t_s - t).abs().argmin()]
            q = row[["qw", "qx", "qy", "qz"]].to_numpy(float)
            omega = row[["omega_x_rad_s", "omega_y_rad_s", "omega_z_rad_s"]].to_numpy(float)
            for name, r in (("analytic", analytic), ("mujoco", realistic)):
                frame = r.render(q, t_exposure=float(row.t_s), omega=omega)
                fname = f"frame_{name}_{row.t_s * 1000:04.0f}ms.png"
                Image.fromarray(frame.image).save(out / fname)
                frames.append((fname, row.t_s, row.tilt_deg))

    final = df.iloc[-1]
    settle = df[(df.t_s > 0.05) & (df.error_deg > 0.05 * df.tilt_ref_deg)].t_s.max() - 0.05
    lines = [
        "# Placeholder demo (not the headline study)",
        "",
        "The headline study of issue 6 will replace this. Here the plant follows a 10° tilt step",
        "at 30° yaw under a PD torque law that reads the *true* attitude: no camera, no delay.",
        "",
        f"- final tilt: {final.tilt_deg:.3f}° (reference {final.tilt_ref_deg:.1f}°), "
        f"geodesic error {final.error_deg:.4f}°",
        f"- 5 % settling time after the step: {settle * 1000:.0f} ms",
        f"- allocation saturated in {100 * df.saturated.mean():.1f} % of the steps; "
        f"peak |I| = {df.i_max_abs_A.max():.2f} A of {params.motor.i_max_A} A",
        f"- tilt stop engaged: {bool(df.stop_active.any())}",
        "",
        "![tilt step](tilt_step.png)",
        "",
        "Frames from the bottom camera (analytic and MuJoCo renderers, same geometry):",
        "",
    ]
    lines += [f"- t = {t:.3f} s, tilt {b:.2f}°: ![{f}]({f})" for f, t, b in frames]
    lines += ["", "Time series: `timeseries.parquet` (one row per 1 ms physics step)."]
    (out / "report.md").write_text("\n".join(lines) + "\n")
    return out
