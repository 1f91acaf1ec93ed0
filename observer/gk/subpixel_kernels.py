"""Compiled kernels of the sub-pixel stage (``observer.gk.subpixel``): the marker's and the
background's median colours, the edge search's rays and crossings, the curvature burr test,
the algebraic and geometric circle fits with outlier rejection, and the fit's residual and arc
coverage.

Why compiled: a marker crop is about 70 x 70 px with 100-200 edge points, so the stage's
numpy version spent its time in the overhead of some hundred small array operations per fit
(about 1.4 ms of a 1.7 ms fit, two fits a frame). These loops compute the same formulas in the
same order of operations as that version (tests/test_gk_equality.py holds GK-TransT's outputs
to 1e-9 px; the medians are order statistics of exact histograms); the image operations
(colour mask, morphology, connected regions, contours, the coverage map, bilinear sampling)
stay in OpenCV and numpy.

Units: image px of the crop. Every function is self-contained (numba's disk cache is
invalidated when this file changes).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import NDArray

#: ``fit_free``'s status codes: a fit, or why there is none.
FIT_OK, NO_CONVEX_OUTLINE, TOO_FEW_AFTER_BURRS, COLLINEAR = 0, 1, 2, 3


@njit(cache=True)
def median_rgb(image: NDArray[np.uint8], mask: NDArray[np.uint8]) -> NDArray[np.float32]:
    """Per-channel lower median (3,) of the pixels of ``image`` (H, W, 3) where ``mask`` (H, W)
    is non-zero: the value at rank ceil(n/2) of each channel, read from its 256-bin histogram
    (0 when the mask is empty)."""
    hist = np.zeros((3, 256), np.int64)
    n = 0
    for i in range(mask.shape[0]):
        for j in range(mask.shape[1]):
            if mask[i, j]:
                n += 1
                for c in range(3):
                    hist[c, image[i, j, c]] += 1
    k = (n - 1) // 2
    out = np.zeros(3, np.float32)
    for c in range(3):
        seen = 0
        for v in range(256):
            seen += hist[c, v]
            if seen > k:
                out[c] = v
                break
    return out


@njit(cache=True)
def edge_rays(contour: NDArray[np.float64], cx: float, cy: float, width: int, height: int,
              t: NDArray[np.float64]):
    """The contour pixels (n, 2) kept for the edge search (more than 0.5 px from the centroid
    (cx, cy), not on the crop's border of ``width`` x ``height``), their unit rays from the
    centroid (m, 2), and the sampling positions x, y (m, len(t), float32) at distances ``t``
    along each ray."""
    n, nt = contour.shape[0], t.shape[0]
    keep = np.zeros(n, np.bool_)
    norms = np.empty(n)
    for i in range(n):
        x, y = contour[i, 0], contour[i, 1]
        rx, ry = x - cx, y - cy
        norms[i] = math.hypot(rx, ry)
        # on the crop's border the region may go on outside it: no edge of the marker there
        border = x <= 0 or y <= 0 or x >= width - 1 or y >= height - 1
        keep[i] = norms[i] > 0.5 and not border
    m = int(keep.sum())
    pts, u = np.empty((m, 2)), np.empty((m, 2))
    sx, sy = np.empty((m, nt), np.float32), np.empty((m, nt), np.float32)
    k = 0
    for i in range(n):
        if not keep[i]:
            continue
        pts[k, 0], pts[k, 1] = contour[i, 0], contour[i, 1]
        u[k, 0] = (contour[i, 0] - cx) / norms[i]
        u[k, 1] = (contour[i, 1] - cy) / norms[i]
        for j in range(nt):
            sx[k, j] = np.float32(pts[k, 0] + u[k, 0] * t[j])
            sy[k, j] = np.float32(pts[k, 1] + u[k, 1] * t[j])
        k += 1
    return pts, u, sx, sy


@njit(cache=True)
def edge_crossings(profiles: NDArray[np.float32], t: NDArray[np.float64], step: float,
                   pts: NDArray[np.float64], u: NDArray[np.float64]) -> NDArray[np.float64]:
    """Sub-pixel edge points (k, 2): on each ray i, the crossing of the coverage profile
    ``profiles[i]`` (sampled at ``t``) from >= 1/2 to < 1/2 nearest the contour pixel (the first
    of equally near ones), linearly interpolated; rays without a crossing are dropped."""
    m, nt = profiles.shape
    edge = np.empty((m, 2))
    k = 0
    for i in range(m):
        best, jb = np.inf, -1
        for j in range(nt - 1):
            if profiles[i, j] >= 0.5 and profiles[i, j + 1] < 0.5:
                d = abs(0.5 * (t[j] + t[j + 1]))
                if d < best:
                    best, jb = d, j
        if jb < 0:
            continue
        a0, a1 = float(profiles[i, jb]), float(profiles[i, jb + 1])
        ts = t[jb] + (a0 - 0.5) / (a0 - a1) * step
        if not math.isfinite(ts):
            continue
        edge[k, 0] = pts[i, 0] + u[i, 0] * ts
        edge[k, 1] = pts[i, 1] + u[i, 1] * ts
        k += 1
    return edge[:k]


@njit(cache=True)
def curvature(p: NDArray[np.float64], span: int, closed: bool) -> NDArray[np.float64]:
    """Signed curvature (1/px) of the circle through contour points i - span, i, i + span
    (seed 004 eq. 25: 4·area/(abc)); wraps around when ``closed``, else clips at the ends."""
    n = p.shape[0]
    k = np.zeros(n)
    if n < 3:
        return k
    for i in range(n):
        if closed:
            a, c = (i - span) % n, (i + span) % n
        else:
            a, c = min(max(i - span, 0), n - 1), min(max(i + span, 0), n - 1)
        abx, aby = p[i, 0] - p[a, 0], p[i, 1] - p[a, 1]
        bcx, bcy = p[c, 0] - p[i, 0], p[c, 1] - p[i, 1]
        cax, cay = p[a, 0] - p[c, 0], p[a, 1] - p[c, 1]
        denom = (math.sqrt(abx * abx + aby * aby) * math.sqrt(bcx * bcx + bcy * bcy)
                 * math.sqrt(cax * cax + cay * cay))
        cross = abx * bcy - aby * bcx
        k[i] = 2.0 * cross / max(denom, 1e-12) if denom > 1e-12 else 0.0
    return k


@njit(cache=True)
def burrs(k: NDArray[np.float64], k_ref: float, factor: float) -> NDArray[np.bool_]:
    """True where the curvature ``k`` is a burr's: above ``factor`` k_ref (seed 004 §4.2) or
    below k_ref / ``factor`` (straight or concave pieces, our addition)."""
    return (k > factor * k_ref) | (k < k_ref / factor)


@njit(cache=True)
def algebraic(p: NDArray[np.float64]):
    """Kåsa's least-squares circle x² + y² = a x + b y + c (relative to the points' mean):
    (centre x, centre y, R, ok); not ok when the points are collinear."""
    n = p.shape[0]
    if n < 3:
        return math.nan, math.nan, math.nan, False
    mx, my = 0.0, 0.0
    for i in range(n):
        mx += p[i, 0]
        my += p[i, 1]
    mx, my = mx / n, my / n
    A, rhs = np.empty((n, 3)), np.empty(n)
    for i in range(n):
        qx, qy = p[i, 0] - mx, p[i, 1] - my
        A[i, 0], A[i, 1], A[i, 2] = qx, qy, 1.0
        rhs[i] = qx * qx + qy * qy
    sol, _, rank, _ = np.linalg.lstsq(A, rhs, np.finfo(np.float64).eps * max(n, 3))
    cx, cy = 0.5 * sol[0], 0.5 * sol[1]
    r2 = sol[2] + (cx * cx + cy * cy)
    finite = math.isfinite(sol[0]) and math.isfinite(sol[1]) and math.isfinite(sol[2])
    if not finite or r2 <= 0.0 or rank < 3:
        return math.nan, math.nan, math.nan, False
    return cx + mx, cy + my, math.sqrt(r2), True


@njit(cache=True)
def residuals(p: NDArray[np.float64], cx: float, cy: float, R: float) -> NDArray[np.float64]:
    """Geometric residuals |p_j - c| - R (n,)."""
    out = np.empty(p.shape[0])
    for j in range(p.shape[0]):
        out[j] = math.hypot(p[j, 0] - cx, p[j, 1] - cy) - R
    return out


@njit(cache=True)
def geometric(p: NDArray[np.float64], cx: float, cy: float, R: float, max_iter: int,
              tol: float):
    """Geometric least-squares circle (seed 004 eqs. 27-28) by Gauss-Newton from (cx, cy, R):
    (centre x, centre y, R, residuals (n,)). Stops when the largest step is below ``tol``,
    after ``max_iter`` steps, or when the normal equations are singular."""
    n = p.shape[0]
    JTJ, JTr = np.empty((3, 3)), np.empty(3)
    for _ in range(max_iter):
        JTJ[:] = 0.0
        JTr[:] = 0.0
        for j in range(n):
            dx, dy = p[j, 0] - cx, p[j, 1] - cy
            d = max(math.hypot(dx, dy), 1e-12)
            g0, g1, r = -dx / d, -dy / d, d - R  # the row of J is (g0, g1, -1)
            JTJ[0, 0] += g0 * g0
            JTJ[0, 1] += g0 * g1
            JTJ[0, 2] -= g0
            JTJ[1, 1] += g1 * g1
            JTJ[1, 2] -= g1
            JTJ[2, 2] += 1.0
            JTr[0] -= g0 * r
            JTr[1] -= g1 * r
            JTr[2] += r
        JTJ[1, 0], JTJ[2, 0], JTJ[2, 1] = JTJ[0, 1], JTJ[0, 2], JTJ[1, 2]
        try:  # LAPACK's gesv, as numpy's solve; a singular matrix ends the iteration
            step = np.linalg.solve(JTJ, JTr)
        except Exception:  # noqa: BLE001 - numba catches no narrower class
            break
        cx, cy, R = cx + step[0], cy + step[1], R + step[2]
        if max(abs(step[0]), abs(step[1]), abs(step[2])) < tol:
            break
    return cx, cy, R, residuals(p, cx, cy, R)


@njit(cache=True)
def robust(p: NDArray[np.float64], cx: float, cy: float, R: float, outlier_k: float,
           floor_px: float, min_points: int, max_iter: int):
    """The geometric fit with up to three rounds of dropping the points whose residual exceeds
    ``outlier_k`` robust sigmas (1.4826 MAD) or ``floor_px``, keeping at least ``min_points``:
    (centre x, centre y, R, residuals, points kept, points dropped)."""
    cx, cy, R, res = geometric(p, cx, cy, R, max_iter, 1e-7)
    n_out = 0
    for _ in range(3):
        med = np.median(res)
        sigma = 1.4826 * np.median(np.abs(res - med))
        bad = np.abs(res) > max(outlier_k * sigma, floor_px)
        n_bad = int(bad.sum())
        if n_bad == 0 or p.shape[0] - n_bad < min_points:
            break
        n_out += n_bad
        p = p[~bad]
        cx, cy, R, res = geometric(p, cx, cy, R, max_iter, 1e-7)
    return cx, cy, R, res, p, n_out


@njit(cache=True)
def arc_coverage(p: NDArray[np.float64], cx: float, cy: float) -> float:
    """Fraction of the 36 ten-degree sectors around (cx, cy) that hold a point of ``p``."""
    seen = np.zeros(36, np.bool_)
    for j in range(p.shape[0]):
        ang = math.atan2(p[j, 1] - cy, p[j, 0] - cx)
        seen[int(math.floor((ang + math.pi) / (2 * math.pi) * 36)) % 36] = True
    return seen.sum() / 36.0


@njit(cache=True)
def rms(res: NDArray[np.float64]) -> float:
    """Root mean square of ``res``."""
    return math.sqrt(np.mean(res * res))


@njit(cache=True)
def fit_free(edge: NDArray[np.float64], r_area: float, span_fraction: float, factor: float,
             outlier_k: float, floor_px: float, min_points: int, max_iter: int):
    """Steps 3-4 of the stage without a known radius: burr removal over a span of
    ``span_fraction`` r_area (seed 004 eq. 25), the algebraic start, the robust geometric fit.
    Returns (status (``FIT_OK`` or why not), centre x, centre y, R, RMS residual, points used,
    burrs, outliers, arc coverage); with a status other than ``FIT_OK`` only the points
    counted so far are meaningful."""
    n = edge.shape[0]
    spacing = 1.0
    if n > 1:
        s = 0.0
        for i in range(n - 1):
            s += math.hypot(edge[i + 1, 0] - edge[i, 0], edge[i + 1, 1] - edge[i, 1])
        spacing = s / (n - 1)
    span = max(2, int(np.round(span_fraction * r_area / max(spacing, 1e-6))))
    k = curvature(edge, span, True)
    k_ref = np.median(k)
    if k_ref < 0.0:  # the contour runs clockwise: make the marker's convex outline positive
        k, k_ref = -k, -k_ref
    nan = math.nan
    if k_ref <= 0.0:
        return NO_CONVEX_OUTLINE, nan, nan, nan, nan, n, 0, 0, 0.0
    burr = burrs(k, k_ref, factor)
    pts = edge[~burr]
    n_burrs = int(burr.sum())
    if pts.shape[0] < min_points:
        return TOO_FEW_AFTER_BURRS, nan, nan, nan, nan, pts.shape[0], n_burrs, 0, 0.0
    cx, cy, R, ok = algebraic(pts)
    if not ok:
        return COLLINEAR, nan, nan, nan, nan, pts.shape[0], n_burrs, 0, 0.0
    cx, cy, R, res, pts, n_out = robust(pts, cx, cy, R, outlier_k, floor_px, min_points,
                                         max_iter)
    return (FIT_OK, cx, cy, R, rms(res), pts.shape[0], n_burrs, n_out,
            arc_coverage(pts, cx, cy))
