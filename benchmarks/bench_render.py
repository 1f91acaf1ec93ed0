"""Time per frame of the analytic and the MuJoCo renderer at the default resolution (612 x 512).

Each renderer draws the same random workspace poses (tilt 0-15°, any spin and yaw; fixed seed):
still frames, then frames with motion blur at a random body rate of 10 rad/s over the default
2 ms exposure (automatic number of sub-frames).

Also the renderers' geometric agreement quoted in docs/plant.md: over 100 random workspace
poses (seed 7, still frames), the centroids of the seed's HSV gates (000 §3.2.1,
``observer.gk.hsv_gate.RED``/``YELLOW``) in both renderers' frames, compared with each other and
with the projected disc centres (``Frame.marker_px``), in image px at the default binning.

Run: python benchmarks/bench_render.py [--frames 200] [--agreement-poses 100]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _report import record

from observer.gk.hsv_gate import RED, YELLOW, colour_mask
from plant import attitude
from plant.camera import sensor_to_image
from plant.params import PlantParams
from plant.render_analytic import AnalyticRenderer
from plant.render_mujoco import MujocoRenderer  # sets MUJOCO_GL=egl before importing mujoco

WARMUP = 5
BLUR_RATE_RAD_S = 10.0


def poses(n: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Random workspace attitudes: tilt 0-15°, any spin and yaw."""
    return [
        attitude.from_zyz(
            rng.uniform(0, 2 * np.pi), np.deg2rad(rng.uniform(0, 15)), rng.uniform(0, 2 * np.pi)
        )
        for _ in range(n)
    ]


def time_frames(render, qs, omegas) -> tuple[np.ndarray, float]:
    """Seconds per ``render(q, omega=...)`` call after a warm-up, and the mean n_sub."""
    for q, w in zip(qs[:WARMUP], omegas[:WARMUP], strict=True):
        render(q, omega=w)
    out, n_sub = np.empty(len(qs)), []
    for i, (q, w) in enumerate(zip(qs, omegas, strict=True)):
        t0 = time.perf_counter()
        f = render(q, omega=w)
        out[i] = time.perf_counter() - t0
        n_sub.append(f.n_sub)
    return out, float(np.mean(n_sub))


def centroids_image_px(image: np.ndarray) -> np.ndarray:
    """(2, 2) centroids, image px, of the red then yellow HSV-gated pixels (NaN if < 100)."""
    out = np.full((2, 2), np.nan)
    for k, hsv_range in enumerate((RED, YELLOW)):
        v, u = np.nonzero(colour_mask(image, hsv_range))
        if len(u) >= 100:
            out[k] = u.mean(), v.mean()
    return out


def agreement(p: PlantParams, n: int, seed: int) -> dict[str, float]:
    """Centroid gaps (image px) between the renderers and to the projected truth."""
    qs = poses(n, np.random.default_rng(seed))
    analytic = AnalyticRenderer(p, seed=1)
    gaps, err_a, err_m = [], [], []
    with MujocoRenderer(p) as mj:
        for q in qs:
            fa, fm = analytic.render(q), mj.render(q)
            ca, cm = centroids_image_px(fa.image), centroids_image_px(fm.image)
            truth = sensor_to_image(fa.marker_px, fa.binning)
            gaps.append(np.linalg.norm(ca - cm, axis=1))
            err_a.append(np.linalg.norm(ca - truth, axis=1))
            err_m.append(np.linalg.norm(cm - truth, axis=1))
    gaps, err_a, err_m = (np.concatenate(x) for x in (gaps, err_a, err_m))
    return {  # the issue asks for agreement within 0.5 px
        "agreement_poses": float(n),
        "agreement_markers_not_found": float(np.sum(~np.isfinite(gaps))),
        "centroid_gap_renderers_max_image_px": float(np.nanmax(gaps)),
        "centroid_gap_renderers_median_image_px": float(np.nanmedian(gaps)),
        "centroid_err_analytic_max_image_px": float(np.nanmax(err_a)),
        "centroid_err_analytic_median_image_px": float(np.nanmedian(err_a)),
        "centroid_err_mujoco_max_image_px": float(np.nanmax(err_m)),
        "centroid_err_mujoco_median_image_px": float(np.nanmedian(err_m)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200, help="frames per renderer and case")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--agreement-poses", type=int, default=100,
                    help="random workspace poses for the centroid agreement (seed 7)")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    p = PlantParams()
    qs = poses(args.frames, rng)
    still = [None] * args.frames
    axes = rng.normal(size=(args.frames, 3))
    blur = BLUR_RATE_RAD_S * axes / np.linalg.norm(axes, axis=1, keepdims=True)

    analytic = AnalyticRenderer(p, seed=args.seed)
    a_still, _ = time_frames(analytic.render, qs, still)
    a_blur, a_nsub = time_frames(analytic.render, qs, blur)
    with MujocoRenderer(p) as mj:
        m_still, _ = time_frames(mj.render, qs, still)
        m_blur, m_nsub = time_frames(mj.render, qs, blur)

    figures = {}
    for name, t in [
        ("analytic_render", a_still),
        ("mujoco_render", m_still),
        ("analytic_render_blur", a_blur),
        ("mujoco_render_blur", m_blur),
    ]:
        figures[f"{name}_median_s"] = float(np.median(t))
        figures[f"{name}_p95_s"] = float(np.percentile(t, 95))
    figures["analytic_blur_mean_n_sub"] = a_nsub
    figures["mujoco_blur_mean_n_sub"] = m_nsub
    figures["mujoco_over_analytic_median_ratio"] = float(np.median(m_still) / np.median(a_still))
    figures.update(agreement(p, args.agreement_poses, seed=7))
    w, h = analytic.width, analytic.height
    record(
        "bench_render",
        "Renderers: time per frame",
        figures,
        notes=f"{args.frames} frames of {w} x {h} px (binning {analytic.binning}) per renderer "
        f"and case, random workspace poses (seed {args.seed}), after {WARMUP} warm-up frames. "
        f"Analytic: default options (read noise on). MuJoCo: MUJOCO_GL=egl (Mesa llvmpipe, CPU). "
        f"Blur: body rate {BLUR_RATE_RAD_S} rad/s in a random direction over the default "
        f"{p.camera.exposure_s * 1e3:g} ms exposure, automatic sub-frame count (n_sub). "
        f"The machine's two cores are shared with other work, so the p95 figures are noisy. "
        f"Agreement: {args.agreement_poses} random workspace poses (seed 7), still frames, "
        "analytic renderer seed 1 with read noise; per marker, the distance between the "
        "HSV-gate centroids of the two renderers, and of each to the projected disc centre, "
        "image px (612 x 512); max and median over all markers of all poses.",
    )


if __name__ == "__main__":
    main()
