"""The seed's closed-form attitude from two marker pixels (seed 000 §2.3–2.5).

Steps, as the seed writes them (pixels are full-sensor pixels, angles rad):

1. **Virtual pole** (eq. 1 and 7): ``(u, v) = ((u_r + u_y)/2, (v_r + v_y)/2)``, the midpoint of
   the red (main) and yellow (auxiliary) marker pixels.
2. **Yaw** (§2.3): sign inversion ``Δu = −(u − u0)``, ``Δv = −(v − v0)`` with (u0, v0) the image
   centre; the acute temporary angle ``γ_temp = arctan|Δv/Δu|``; the quadrant mapping to
   ``γ_calc ∈ [0, 2π)``; the mirror correction ``γ_final = 2π − γ_calc`` (0 stays 0).
3. **Spin** (§2.4): ``α0 = atan2(ΔV_spin, ΔU_spin)`` of the red → yellow vector, normalised to
   [0, 2π); the seed applies *no* axis inversion here, arguing that the upward view's mirror
   cancels the downward v axis.
4. **Tilt** (§2.5): with d the pole's physical displacement on the sensor,
   ``d = √(((u − u0) d_u)² + ((v − v0) d_v)²)`` (d_u, d_v the pixel pitch, m), f the focal length,
   ``β = arcsin((h_c + R) d / (R √(f² + d²))) − arctan(d/f)``.

What falls out of our geometry (``plant.camera``: camera at (0, 0, −(R + h_c)) looking +Z,
u along stator X, v along Y; docs/plant.md):

* **Sign inversion.** A tilt toward azimuth γ moves the bottom pole to −R sin β (cos γ, sin γ),
  i.e. the pole pixel moves *opposite* to the tilt direction. Inverting the offset points it
  along (cos γ, sin γ) in (u, v): step 2 without the mirror already returns γ.
* **Mirror.** The map from stator (X, Y) to image (u, v) is orientation-preserving here
  (``image_handedness`` = +1, computed from the camera model): an angle measured from +u toward
  +v (which is what atan2 of pixel offsets measures) is an angle counter-clockwise about +Z seen
  from above. That a CCW turn *looks* clockwise on a screen with v down is the same fact. This is
  exactly the seed's argument for the spin (step 3), and it applies to the yaw in the same image:
  the seed's yaw mirror correction ``2π − γ_calc`` would return −γ in our geometry (a test shows
  it). We therefore apply the mirror correction to *both* angles if and only if the camera's
  image is mirrored (handedness −1), and the handedness is computed, not chosen. With our camera
  the yaw's mirror step is the identity; ``literal_yaw_mirror=True`` keeps the seed's step as
  printed for comparison.
* **Spin convention.** Under ``R = Rz(γ) Ry(β) Rz(α)`` (``plant.attitude``) the red → yellow
  vector is ``R e_x``, whose image azimuth is ``γ + atan2(sin α, cos β cos α) ≈ α + γ`` for small
  tilt: the seed's image spin is the *total* turn about Z. (In the seed's spin tests the tilt is
  0, where our convention puts γ = 0 and both readings agree; in its yaw test at 15° tilt the image
  spin follows the yaw.) By default we convert with ``α = α_seed − γ`` (``spin_mode="zyz"``), which
  is also what keeps the attitude continuous through β = 0, where γ is undefined;
  ``spin_mode="as_written"`` uses ``α = α_seed`` directly.

The small-tilt approximations the seed makes, and which we keep: the spin ignores the
foreshortening of the tilted red → yellow vector (error up to ``atan(1/cos β) − π/4`` ≈ 1.0° at
β = 15°), and the midpoint of the two projected markers is taken for the projection of the pole
(perspective shifts it when the two markers are at different depths). The tilt formula itself
is exact for a pinhole camera given the true pole pixel. Distortion is ignored.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from observer.types import SolverResult
from plant import attitude
from plant.camera import Camera
from plant.geometry import bottom_pole
from plant.params import PlantParams

TWO_PI = 2.0 * np.pi


def virtual_pole(uv_red: ArrayLike, uv_yellow: ArrayLike) -> NDArray[np.float64]:
    """Seed 000 eq. (1)/(7): the virtual pole (u, v), px, as the markers' midpoint."""
    return 0.5 * (np.asarray(uv_red, dtype=float) + np.asarray(uv_yellow, dtype=float))


def image_handedness(p: PlantParams) -> int:
    """+1 if an angle from +u toward +v in the image is counter-clockwise about stator +Z (seen
    from above, the right-hand sense), −1 if the image is mirrored.

    Computed from the camera model: the images of small steps along stator X and Y at the
    bottom pole's rest position, and the sign of their 2-D cross product.
    """
    cam = Camera.from_plant(p)
    pole = bottom_pole(p.rotor)
    eps = 1e-3
    uv = cam.project(np.array([pole, pole + [eps, 0.0, 0.0], pole + [0.0, eps, 0.0]]))
    ex, ey = uv[1] - uv[0], uv[2] - uv[0]
    return 1 if ex[0] * ey[1] - ex[1] * ey[0] > 0.0 else -1


def yaw_from_pole(
    u: float, v: float, u0: float, v0: float, mirror: bool
) -> float:
    """Seed 000 §2.3: yaw γ (rad, [0, 2π)) from the virtual pole (u, v) and the image centre
    (u0, v0), px: sign inversion, acute γ_temp, quadrant mapping, then the mirror correction
    ``2π − γ_calc`` if ``mirror``. At Δu = Δv = 0 the yaw is undefined and 0 is returned."""
    du, dv = -(u - u0), -(v - v0)  # sign inversion: the pole moves opposite to the tilt
    if du == 0.0 and dv == 0.0:
        return 0.0
    g_temp = np.pi / 2.0 if du == 0.0 else float(np.arctan(abs(dv / du)))  # acute angle
    if du >= 0.0 and dv >= 0.0:
        g_calc = g_temp
    elif du < 0.0 and dv >= 0.0:
        g_calc = np.pi - g_temp
    elif du < 0.0 and dv < 0.0:
        g_calc = np.pi + g_temp
    else:
        g_calc = TWO_PI - g_temp
    g_calc = float(np.mod(g_calc, TWO_PI))
    if mirror:
        return TWO_PI - g_calc if g_calc != 0.0 else 0.0
    return g_calc


def spin_from_markers(uv_red: ArrayLike, uv_yellow: ArrayLike, mirror: bool) -> float:
    """Seed 000 §2.4: image spin α (rad, [0, 2π)) = azimuth of the red → yellow pixel vector,
    ``atan2(v_y − v_r, u_y − u_r)``; negated first if the image is mirrored (not in our
    geometry, and not in the seed's)."""
    d = np.asarray(uv_yellow, dtype=float) - np.asarray(uv_red, dtype=float)
    a0 = float(np.arctan2(d[1], d[0]))
    if mirror:
        a0 = -a0
    return a0 + TWO_PI if a0 < 0.0 else a0


def tilt_from_pole(
    u: float, v: float, u0: float, v0: float, pixel_m: tuple[float, float], f_m: float,
    h_c_m: float, R_m: float,
) -> float:
    """Seed 000 §2.5 (the equation after eq. 8): tilt β (rad) from the virtual pole (u, v), px.

    ``d = √(((u − u0) d_u)² + ((v − v0) d_v)²)`` (m on the sensor), then
    ``β = arcsin((h_c + R) d / (R √(f² + d²))) − arctan(d/f)``. Returns NaN if the arcsine's
    argument exceeds 1 (a pole offset no tilt can produce).
    """
    d_u, d_v = pixel_m
    d = float(np.hypot((u - u0) * d_u, (v - v0) * d_v))
    arg = (h_c_m + R_m) * d / (R_m * np.hypot(f_m, d))
    if arg > 1.0:
        return float("nan")
    return float(np.arcsin(arg) - np.arctan(d / f_m))


@dataclass(frozen=True)
class SeedAngles:
    """The seed's three outputs (rad): image spin α_seed (total turn about Z, see the module
    docstring), tilt β and yaw γ."""

    spin: float
    tilt: float
    yaw: float


class SeedClosedForm:
    """The seed's closed form as an ``AttitudeSolver`` (seed 000 §2.3–2.5).

    Parameters
    ----------
    p : plant parameters: focal length, pixel pitch and image centre from
        ``plant.camera.Camera.matrix(1)`` (((W − 1)/2, (H − 1)/2) in sensor px unless the camera
        has calibrated intrinsics), h_c and R.
    spin_mode : ``"zyz"`` (default): ``α = α_seed − γ``; ``"as_written"``: ``α = α_seed``.
    literal_yaw_mirror : apply the seed's yaw mirror correction as printed regardless of the
        geometry (wrong for our camera; for comparison only).
    """

    def __init__(
        self, p: PlantParams, spin_mode: str = "zyz", literal_yaw_mirror: bool = False
    ) -> None:
        if spin_mode not in ("zyz", "as_written"):
            raise ValueError(f"spin_mode must be 'zyz' or 'as_written', got {spin_mode!r}")
        c = p.camera
        K = Camera.from_plant(p).matrix(1)  # calibrated intrinsics when the camera has them
        self.f_m = c.focal_length_m
        self.pixel_m = (c.focal_length_m / K[0, 0], c.focal_length_m / K[1, 1])
        self.u0, self.v0 = float(K[0, 2]), float(K[1, 2])
        self.h_c_m = c.h_c_m
        self.R_m = p.rotor.radius_m
        self.spin_mode = spin_mode
        self.handedness = image_handedness(p)
        mirrored = self.handedness < 0
        self.yaw_mirror = True if literal_yaw_mirror else mirrored
        self.spin_mirror = mirrored

    def angles(self, marker_px: ArrayLike) -> SeedAngles:
        """The seed's (spin, tilt, yaw), rad, from the red and yellow pixels (rows 0 and 1).
        No validation; NaN propagates."""
        uv = np.asarray(marker_px, dtype=float)
        u, v = virtual_pole(uv[0], uv[1])
        gamma = yaw_from_pole(u, v, self.u0, self.v0, self.yaw_mirror)
        alpha = spin_from_markers(uv[0], uv[1], self.spin_mirror)
        beta = tilt_from_pole(u, v, self.u0, self.v0, self.pixel_m, self.f_m, self.h_c_m,
                              self.R_m)
        return SeedAngles(alpha, beta, gamma)

    def zyz(self, marker_px: ArrayLike) -> tuple[float, float, float]:
        """(α, β, γ) of ``plant.attitude`` (rad) from the seed's angles (see ``spin_mode``)."""
        a = self.angles(marker_px)
        alpha = a.spin - a.yaw if self.spin_mode == "zyz" else a.spin
        return float(np.mod(alpha, TWO_PI)), a.tilt, a.yaw

    def solve(
        self, marker_px: NDArray[np.float64], q_prev: NDArray[np.float64] | None = None
    ) -> SolverResult:
        """Attitude from marker pixels (N ≥ 2, 2), sensor px; ``q_prev`` is not used.

        Invalid (with a reason) if the array has the wrong shape, the red or yellow pixel is
        missing or not finite, the two coincide, or the pole offset admits no tilt.
        """
        uv = np.asarray(marker_px, dtype=float)
        if uv.ndim != 2 or uv.shape[1] != 2 or uv.shape[0] < 2:
            return SolverResult.invalid(f"marker_px must have shape (N >= 2, 2), got {uv.shape}")
        if not np.all(np.isfinite(uv[:2])):
            return SolverResult.invalid("red or yellow marker pixel missing or not finite")
        if np.allclose(uv[0], uv[1]):
            return SolverResult.invalid("red and yellow markers coincide: spin undefined")
        alpha, beta, gamma = self.zyz(uv)
        if not np.isfinite(beta):
            return SolverResult.invalid("pole offset too large for the tilt model (arcsin > 1)")
        return SolverResult(q=attitude.from_zyz(alpha, beta, gamma), iterations=0)
