"""The camera scheme on the rotary table: render, track, solve (``experiments.reproduction``)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from experiments.reproduction.results import CameraRun, ReproductionConfig
from experiments.reproduction.table import RotaryTable
from observer.aekf import AEKFConfig
from observer.closed_form import SeedClosedForm
from observer.cor_model import CorModel
from observer.cor_solver import CorSolver
from observer.pixel_observer import FilterObserver, PixelKalmanObserver, SolverObserver
from observer.tracking import PairTracker
from plant import attitude
from plant.params import PlantParams


# ------------------------------------------------------------------------------------------------
# The camera scheme
# ------------------------------------------------------------------------------------------------
def gk_transt_available() -> tuple[bool, str]:
    """(True, "") if ``observer.trackers.gk_transt`` imports and the shipped TransT weights load
    (SHA-256 checked), else (False, why)."""
    try:
        import observer.trackers.gk_transt  # noqa: F401
        from observer.transt.tracker import TransTTracker

        TransTTracker.small()
    except Exception as exc:  # noqa: BLE001 - any reason the network is unavailable
        return False, f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    return True, ""


def make_locator(kind: str, params: PlantParams) -> tuple[PairTracker, str, str]:
    """(pair tracker, name, note): ``kind`` "gk_transt", "kcf_gk" or "auto" (GK-TransT if
    available, else KCF + GK with the reason in the note). For GK-TransT the note names the
    weights' digest (the shipped file may be retrained between runs)."""
    from observer.trackers import make_pair_tracker

    if kind in ("auto", "gk_transt"):
        ok, why = gk_transt_available()
        if ok:
            from observer.transt.weights import SMALL_WEIGHTS, sha256_of

            sha = sha256_of(SMALL_WEIGHTS)
            return make_pair_tracker("gk_transt", params), \
                "gk_transt", f"weights {SMALL_WEIGHTS.name} SHA-256 {sha[:16]}…"
        if kind == "gk_transt":
            raise RuntimeError(f"GK-TransT is not available: {why}")
        return make_pair_tracker("kcf_gk", params), "kcf_gk", \
            f"GK-TransT unavailable ({why}); used KCF + GK"
    if kind == "kcf_gk":
        return make_pair_tracker("kcf_gk", params), "kcf_gk", ""
    raise ValueError(f"tracker must be 'auto', 'gk_transt' or 'kcf_gk', got {kind!r}")


def add_read_noise(image: NDArray[np.uint8], sigma_dn: float,
                   rng: np.random.Generator) -> NDArray[np.uint8]:
    """``image`` + N(0, σ²) per pixel and channel (DN), rounded and clipped to uint8."""
    if sigma_dn <= 0.0:
        return image
    noise = rng.standard_normal(image.shape, dtype=np.float32)
    out = image.astype(np.float32) + np.float32(sigma_dn) * noise + np.float32(0.5)
    return np.clip(out, 0.0, 255.0).astype(np.uint8)


def _make_renderer(cfg: ReproductionConfig, params: PlantParams) -> tuple[Callable, Callable]:
    """(render(q, t, omega) -> Frame with noise, close())."""
    rng = np.random.default_rng(cfg.camera_seed)
    if cfg.renderer == "mujoco":
        from plant.render_mujoco import MujocoRenderer

        r = MujocoRenderer(params)

        def render(q: NDArray, t: float, omega: NDArray):  # noqa: ANN202
            fr = r.render(q, t, omega=omega)
            return fr, add_read_noise(fr.image, cfg.read_noise_dn, rng)

        return render, r.close
    from plant.render_analytic import AnalyticRenderer, AnalyticRenderOptions

    a = AnalyticRenderer(params, options=AnalyticRenderOptions(noise_sigma_dn=cfg.read_noise_dn),
                         seed=rng)

    def render_a(q: NDArray, t: float, omega: NDArray):  # noqa: ANN202
        fr = a.render(q, t, omega=omega)
        return fr, fr.image

    return render_a, lambda: None


def camera_backends(params: PlantParams) -> dict[str, object]:
    """Fresh per-frame back ends, keyed as ``CAMERA_BACKENDS``."""
    model = CorModel.nominal(params)
    return {
        "camera_closed_form": SolverObserver(SeedClosedForm(params)),
        "camera_least_squares": SolverObserver(CorSolver(model)),
        "camera_least_squares_kalman": PixelKalmanObserver(CorSolver(model)),
        # The table's torque is unknown to the filter: it predicts with zero torque, so its
        # model decelerates the moving rotor by friction (τ_c/J ≈ 1.4 rad/s²) while the table
        # also accelerates it (≈ 1 rad/s² peak for a 10° minimum-jerk move in 1 s). Our choice:
        # a rate random walk q_ω ≈ a²·t_move with a ≈ 2.4 rad/s² over the 1 s move, rounded up
        # to 10 rad²/s³ (the default 0.1 loses lock on the first move). Estimate at the
        # exposure time.
        "camera_aekf": FilterObserver(params, AEKFConfig(q_omega_rad2_per_s3=10.0),
                                      compensate_delay=False),
    }


def run_camera(table: RotaryTable, cfg: ReproductionConfig, params: PlantParams | None = None,
               progress: Callable[[str], None] | None = None) -> tuple[NDArray, CameraRun]:
    """Render, track and solve every frame of ``table``; returns (frame times (N,), record).

    The tracker starts on the first frame with the true marker boxes (a user's first-frame
    annotation). The tilt hint of the GK geometric check (D_exp = L·S·cos β, seed 000 §3.2.2)
    comes from the least-squares estimate of the previous frame. Back ends start at the table's
    first attitude (a per-frame solver only uses it as the first warm start).
    """
    p = params or PlantParams()
    fps = p.camera.frame_rate_hz
    ts = table.frame_times(fps)
    render, close = _make_renderer(cfg, p)
    locator, name, note = make_locator(cfg.tracker, p)
    backends = camera_backends(p)
    q0 = table.sample(0.0).q
    for b in backends.values():
        b.reset(q0, 0.0)
    n = len(ts)
    true_px = np.full((n, 2, 2), np.nan)
    px = np.full((n, 2, 2), np.nan)
    lost = np.zeros(n, bool)
    refined = np.zeros(n, bool)
    qs = {k: np.full((n, 4), np.nan) for k in backends}
    t_loc, t_ren = np.zeros(n), np.zeros(n)
    hint: float | None = None
    try:
        for i, t in enumerate(ts):
            s = table.sample(float(t))
            t0 = time.perf_counter()
            frame, image = render(s.q, float(t), s.omega)
            t1 = time.perf_counter()
            if i == 0:
                locator.start(image, frame.boxes_px, frame.binning)
            locator.tilt_hint_rad = hint
            r = locator.step(image)
            uv, lost_i, reason, refined[i] = r.marker_px, r.lost, r.reason, r.red_refined
            t_loc[i], t_ren[i] = time.perf_counter() - t1, t1 - t0
            true_px[i], px[i], lost[i] = frame.marker_px, uv, lost_i
            for key, b in backends.items():
                b.process(uv, float(t), lost_i, reason, t_loc[i])
                est = b.release(float(t))
                if est.valid:
                    qs[key][i] = est.q
            q_ls = qs["camera_least_squares"][i]
            hint = attitude.tilt(q_ls) if np.all(np.isfinite(q_ls)) else hint
            if progress and (i + 1) % 360 == 0:
                progress(f"{table.axis}: frame {i + 1}/{n}")
    finally:
        close()
    return ts, CameraRun(name, note, true_px, px, lost, refined, qs, t_loc, t_ren)
