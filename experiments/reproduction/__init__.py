"""Paper reproduction: the rotary-table step tests of seed 000 §5.

The seed checks its camera scheme and a MEMS baseline against a hydraulic rotary table: single-axis
steps with a 5 s dwell after each (spin 0–75° by 10°, §5.1; tilt 0–15° by 5°, §5.2; yaw by 10° at a
15° tilt, turned by the table about the stator Z axis, §5.3), and reports the RMSE over the
steady-state frames of the dwells. This package simulates that bench.

**The table** (``RotaryTable``): a perfect kinematic table. The step attitudes are those of
``controller.reference.SeedSteps``; between two steps the table moves along a minimum-jerk profile
(``move_s``, our choice: 1 s, so that the tracker sees motion and the IMU sees a realistic rate),
then dwells ``dwell_s`` (seed 000 §5: 5 s). Timeline: a rest of ``rest_s`` at the first value (the
MEMS zeroing window, §5.3), then for step k a move [T_k, T_k + move_s) from value k − 1 to value k
(no motion for k = 0) and the dwell [T_k + move_s, T_k + move_s + dwell_s), with
T_k = rest_s + k (move_s + dwell_s). The attitude, body rate and body acceleration are exact
(``controller.reference.zyz_sample``): each protocol is a straight line in the Z-Y-Z angles
``R = Rz(γ) Ry(β) Rz(α)`` (``plant.attitude``), spin (v, 0, 0), tilt (−a, v, a) toward azimuth a,
rotary-table yaw (0, β, v).

**The camera scheme** (``run_camera``): each frame (36 frames/s, mid-exposure times k/36 s) is
rendered at the table's attitude with its body rate (motion blur over the exposure), Gaussian read
noise is added (the sensor noise of our camera model), a tracker + the GK assistance locates the two
markers (GK-TransT when its shipped weights load, else OpenCV KCF + GK assistance), and per-frame
attitude back ends turn the pixels into attitudes: the seed's closed form (§2.3–2.5,
``observer.closed_form``), the CoR-constrained least squares (``observer.cor_solver``), and the
least squares on the seed's pixel Kalman filter (§3.2.1, ``observer.pixel_observer``).

**The MEMS scheme** (``run_mems``): ``observer.imu`` simulates the IMU (ICM42605 class, 200 Hz,
bias drift) on the same truth and ``observer.mems`` runs its estimator with the seed's initial bias
zeroing, SO(3) yaw decoupling Ψ = atan2(R21, R11) and phase unwrapping (§5.3). Its output is
sampled at the camera's frame times (zero-order hold of the latest IMU sample), since the seed
collects both schemes synchronously and counts steady-state windows in frames.

**What each scheme's angle is** (``measured_angle``):

* spin test (§5.1, zero tilt): the total turn about Z, i.e. the decoupled yaw Ψ of the estimate,
  which at β = 0 equals α + γ and is what the seed's image spin (the azimuth of the red → yellow
  vector) measures; for the MEMS its zeroed Ψ;
* tilt test (§5.2): the tilt β of the estimate (``plant.attitude``);
* yaw test (§5.3, 15° tilt): the camera's Z-Y-Z yaw γ (the azimuth of the pole offset, which is
  what the seed's camera yaw is); for the MEMS the seed's decoupled yaw Ψ, unwrapped and zeroed.
  On this bench (α = 0) the true Ψ equals the true γ, the table angle.

Spin and yaw traces are unwrapped (``observer.mems.unwrap_phase``) and put on the 2π branch of the
table's angle at their first valid sample. The camera's angles are absolute (no zeroing). The MEMS
Ψ is zeroed by the estimator at its first valid sample (the seed's "initial bias zeroing"), and the
table's angle at that time is added back, so that all traces compare with the table's angle.

**Steady state and RMSE** (``steady_state_mask``, ``steady_state_rmse``; seed 000 §5): within each
dwell, every run of 90 consecutive frames (2.5 s at 36 frames/s) whose population standard
deviation (ddof = 0) of the measured angle is strictly below 0.3° is a steady window; a window
must lie entirely inside one dwell and contain no invalid frame; windows slide by one frame. The
steady-state frames are the union of all steady windows of all dwells, and
RMSE = sqrt(mean((θ_measured − θ_table)²)) over those frames (seed 000 §5's formula). A dwell
without any steady window contributes no frames (and is counted, see ``SteadyState``).

Units: SI inside (rad, s, sensor px); degrees only in the ``*_deg`` fields, tables and plots.

Modules: ``table`` (protocols, the seed's figures, the rotary table), ``steady`` (steady state,
RMSE, measured angles), ``results`` (configuration and results), ``camera`` and ``run`` (the
schemes and one axis's step test), ``tables`` (tables and figures) and ``page`` (the generated
docs/reproduction.md). Everything public is importable from ``experiments.reproduction``.
"""

from experiments.reproduction.camera import (
    add_read_noise,
    camera_backends,
    gk_transt_available,
    make_locator,
    run_camera,
)
from experiments.reproduction.page import (
    dwell_poses,
    pixel_stats,
    reproduction_page,
    tracking_section,
)
from experiments.reproduction.results import (
    CameraRun,
    ReproductionConfig,
    StepTestResult,
    Trace,
)
from experiments.reproduction.run import (
    run_mems,
    run_step_test,
    truth_trajectory,
)
from experiments.reproduction.steady import (
    SteadyState,
    crb_angle_rms_rad,
    disc_centroid_offset_px,
    measured_angle,
    steady_state_mask,
    steady_state_rmse,
    unwrap_to_reference,
)
from experiments.reproduction.table import (
    AXES,
    CAMERA_BACKENDS,
    MEMS_VARIANTS,
    SEED_RMSE_DEG,
    STEADY_STD_MAX_RAD,
    STEADY_WINDOW_FRAMES,
    Axis,
    RotaryTable,
    make_table,
    zyz_line,
)
from experiments.reproduction.tables import (
    SEED_TRACKING,
    markdown_step_table,
    plot_step_test,
    results_table,
    tracking_table_markdown,
)

__all__ = [
    "AXES",
    "Axis",
    "CAMERA_BACKENDS",
    "CameraRun",
    "MEMS_VARIANTS",
    "ReproductionConfig",
    "RotaryTable",
    "SEED_RMSE_DEG",
    "SEED_TRACKING",
    "STEADY_STD_MAX_RAD",
    "STEADY_WINDOW_FRAMES",
    "SteadyState",
    "StepTestResult",
    "Trace",
    "add_read_noise",
    "camera_backends",
    "crb_angle_rms_rad",
    "disc_centroid_offset_px",
    "dwell_poses",
    "gk_transt_available",
    "make_locator",
    "make_table",
    "markdown_step_table",
    "measured_angle",
    "pixel_stats",
    "plot_step_test",
    "reproduction_page",
    "results_table",
    "run_camera",
    "run_mems",
    "run_step_test",
    "steady_state_mask",
    "steady_state_rmse",
    "tracking_section",
    "tracking_table_markdown",
    "truth_trajectory",
    "unwrap_to_reference",
    "zyz_line",
]
