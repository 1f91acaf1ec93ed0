"""ORB front end for a textured rotor (seed 001 §4.2); the per-frame attitude solve is
``observer.orb_pose``.

Seed 001 §4.2.1 detects ORB features (oFAST corners, rBRIEF descriptors), matches them by
Hamming distance and removes outliers by random sampling; §4.2.2 back-projects the feature
points of the calibration view onto the scene with the known initial pose (its Eq. 12) and
observes their pixels under the current attitude (Eq. 13). Here:

1. **Reference** (``OrbReference.capture``): a frame of the textured rotor
   (``plant.texture``) at a known attitude ``q_ref``. Its ORB keypoints are back-projected along
   their viewing rays onto the print's plane ``z = -R`` of the rotor frame at ``q_ref``; those
   that land on the print (``margin`` inside its edge) keep their rotor-frame points (m) and
   descriptors.
2. **Matching** (``OrbFrontEnd.measure``): ORB on the current frame; each descriptor's two
   nearest reference descriptors by Hamming distance (brute force), Lowe's ratio test, then
   RANSAC on a homography between the reference and current pixels (the print is planar, so
   the two views are related by a homography once the lens distortion is removed). The inliers
   are the measurement: rotor-frame points (N, 3) and their current pixels (N, 2), sensor px,
   with a per-point noise ``sigma0 * scale_factor**octave`` (a keypoint found on pyramid level
   o is located on a grid ``scale_factor**o`` times coarser).
3. **ORB alone** (``observer.orb_pose.solve_attitude``): the attitude that minimises the
   reprojection error of those points through the camera model (``plant.camera``: the rotor
   turns about its centre, so only the three rotation parameters are free). A closed-form start
   (each viewing ray cut with the sphere on which its point must lie, then the Kabsch rotation)
   and Gauss–Newton on a body-frame rotation vector with Huber weights; the projection Jacobian
   comes from ``cv2.projectPoints``.

Pixels are full-sensor pixels unless a name says ``image``; frames are RGB, binned by
``binning`` (``plant.camera.sensor_to_image``). Bad input (an empty, NaN or wrongly shaped
image, a frame whose size is not the sensor's at its binning, a textureless or blurred frame)
gives a measurement with ``valid=False`` and a ``reason``, never an exception in a loop.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from plant import attitude
from plant.camera import Camera, image_to_sensor, sensor_to_image
from plant.params import PlantParams


class OrbConfig(BaseModel):
    """ORB, matching and RANSAC settings. All defaults are our choice unless cited."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_features: int = Field(
        1000, ge=8, description="Our choice: keypoints per frame (OpenCV's default is 500)."
    )
    n_features_reference: int = Field(
        2000, ge=8, description="Our choice: keypoints of the reference view (computed once)."
    )
    scale_factor: float = Field(1.2, gt=1.0, description="ORB pyramid ratio (OpenCV default).")
    n_levels: int = Field(
        4,
        ge=1,
        description="Our choice: pyramid levels; the rotor's distance is fixed, so scale "
        "changes only by the tilt's foreshortening (< 4 % at 15°).",
    )
    fast_threshold: int = Field(
        20, ge=1, description="FAST intensity threshold (OpenCV default), 8-bit levels."
    )
    ratio: float = Field(
        0.8, gt=0.0, le=1.0, description="Lowe's ratio test on the two nearest Hamming distances."
    )
    ransac_threshold_image_px: float = Field(
        2.0, gt=0.0, description="Our choice: RANSAC reprojection threshold, image px."
    )
    ransac_confidence: float = Field(0.999, gt=0.0, lt=1.0, description="RANSAC confidence.")
    min_inliers: int = Field(
        15,
        ge=4,
        description="Our choice: fewer RANSAC inliers than this make the frame invalid "
        "(a homography from 4 random matches can fit a few outliers by chance).",
    )
    margin_m: float = Field(
        1.0e-3,
        ge=0.0,
        description="Our choice: reference keypoints must back-project this far inside "
        "the print's edge (their 31 px patch then lies mostly on the print).",
    )
    sigma0_px: float = Field(
        2.0,
        gt=0.0,
        description="Our choice: ORB keypoint position noise at pyramid level 0, sensor px "
        "(measured: 1.9 sensor px per coordinate on 4x-binned frames, docs/orb.md).",
    )
    refine: bool = Field(
        True,
        description="Our choice: refine each inlier to sub-pixel precision by Lucas–Kanade "
        "between the reference warped by the RANSAC homography and the current frame.",
    )
    refine_window_image_px: int = Field(
        13, ge=5, description="Our choice: Lucas–Kanade window side, image px (odd)."
    )
    refine_max_shift_image_px: float = Field(
        1.5,
        gt=0.0,
        description="Our choice: a refined point more than this from the homography's "
        "prediction is dropped, image px.",
    )
    sigma_refined_px: float = Field(
        0.5,
        gt=0.0,
        description="Our choice: refined point noise, sensor px (measured 0.3–0.5 sensor px "
        "per coordinate on 4x-binned frames, docs/orb.md).",
    )


@dataclass(frozen=True, eq=False)
class OrbReference:
    """Keypoints of the reference view with their rotor-frame points.

    Attributes
    ----------
    points_rotor_m : (M, 3) rotor-frame points on the print, m.
    descriptors : (M, 32) uint8 rBRIEF descriptors.
    pixels_px : (M, 2) keypoint positions in the reference frame, sensor px.
    octaves : (M,) pyramid level of each keypoint.
    q_ref : (4,) attitude of the reference view.
    binning : binning of the reference frame (current frames must use the same).
    gray : (H, W) uint8 grey reference image (for the sub-pixel refinement).
    """

    points_rotor_m: NDArray[np.float64]
    descriptors: NDArray[np.uint8]
    pixels_px: NDArray[np.float64]
    octaves: NDArray[np.int_]
    q_ref: NDArray[np.float64]
    binning: int
    gray: NDArray[np.uint8]

    @classmethod
    def capture(
        cls,
        image: NDArray[np.uint8],
        binning: int,
        params: PlantParams,
        q_ref: ArrayLike = (1.0, 0.0, 0.0, 0.0),
        print_half_size_m: float | None = None,
        config: OrbConfig | None = None,
    ) -> OrbReference:
        """Build the reference from an RGB ``image`` (binned by ``binning``) taken at the known
        attitude ``q_ref``. ``print_half_size_m`` is half the printed square's side, m
        (default: half the VFC plate, ``plant.texture``'s default). Raises ``ValueError`` if
        fewer than ``config.min_inliers`` keypoints land on the print."""
        c = config or OrbConfig()
        q_ref = attitude.normalize(q_ref, "q_ref")
        gray = _to_gray(image)
        if isinstance(gray, str):
            raise ValueError(f"reference image: {gray}")
        cam = Camera.from_plant(params)
        h = (
            params.vfc.plate_size_mm / 2000.0
            if print_half_size_m is None
            else float(print_half_size_m)
        )
        orb = _orb(c, c.n_features_reference)
        kps, desc = orb.detectAndCompute(gray, None)
        if desc is None or len(kps) == 0:
            raise ValueError("reference image: no ORB keypoints (is the rotor textured?)")
        uv = keypoint_pixels(kps, c.scale_factor, binning)
        P = back_project(cam, uv, q_ref)
        on_print = np.all(np.abs(P[:, :2]) <= h - c.margin_m, axis=1)
        if on_print.sum() < c.min_inliers:
            raise ValueError(
                f"reference image: only {int(on_print.sum())} keypoints on the print "
                f"(need {c.min_inliers})"
            )
        return cls(
            points_rotor_m=P[on_print],
            descriptors=desc[on_print],
            pixels_px=uv[on_print],
            octaves=np.array([k.octave for k in kps])[on_print],
            q_ref=q_ref,
            binning=int(binning),
            gray=gray,
        )


@dataclass(frozen=True, eq=False)
class OrbMeasurement:
    """What the front end found in one frame.

    Attributes
    ----------
    points_rotor_m : (N, 3) rotor-frame points of the inlier matches, m.
    pixels_px : (N, 2) their pixels in this frame, sensor px.
    sigma_px : (N,) their position noise, sensor px.
    valid : enough inliers to use.
    reason : why not ("" when valid).
    n_keypoints, n_matches, n_inliers : keypoints in the frame, matches after the ratio test,
        RANSAC inliers.
    compute_time_s : wall-clock time of ``measure``, s.
    """

    points_rotor_m: NDArray[np.float64]
    pixels_px: NDArray[np.float64]
    sigma_px: NDArray[np.float64]
    valid: bool
    reason: str = ""
    n_keypoints: int = 0
    n_matches: int = 0
    n_inliers: int = 0
    compute_time_s: float = 0.0

    @classmethod
    def invalid(cls, reason: str, **counts) -> OrbMeasurement:
        """A failed measurement: no matches (empty arrays), ``valid`` False, ``reason`` saying why,
        and the feature ``counts`` reached before it failed."""
        empty = np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0)
        return cls(*empty, valid=False, reason=reason, **counts)


def _orb(c: OrbConfig, n_features: int) -> cv2.ORB:
    return cv2.ORB_create(
        nfeatures=n_features,
        scaleFactor=c.scale_factor,
        nlevels=c.n_levels,
        fastThreshold=c.fast_threshold,
    )


def keypoint_pixels(keypoints, scale_factor: float, binning: int) -> NDArray[np.float64]:
    """Positions (N, 2), sensor px, of OpenCV ORB keypoints found in a frame binned by
    ``binning``.

    OpenCV reports a keypoint found at pixel ``p`` of pyramid level o as ``p s^o``
    (s = ``scale_factor``); with pixel centres at integer coordinates the level's pixel ``p``
    covers the frame's ``(p + 1/2) s^o - 1/2``, so OpenCV's positions are ``(s^o - 1)/2`` px
    too far toward the top-left (0.36 px at level 3 with s = 1.2). We add that back: left in,
    it is frozen into the reference's rotor points but stays fixed in the image of later
    frames (measured on 15 rendered poses, plain ORB alone: mean error 0.024° without the
    correction, 0.019° with it; docs/orb.md).
    """
    pts = np.array([k.pt for k in keypoints], dtype=float).reshape(-1, 2)
    scale = float(scale_factor) ** np.array([k.octave for k in keypoints], dtype=float)
    return image_to_sensor(pts + 0.5 * (scale - 1.0)[:, None], binning)


def _to_gray(image) -> NDArray[np.uint8] | str:
    """8-bit grey image from an RGB (or grey) frame, or the reason it is not one."""
    img = np.asarray(image)
    if img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] not in (1, 3)):
        return f"image must be H x W or H x W x 3, got shape {img.shape}"
    if img.size == 0 or min(img.shape[:2]) < 32:
        return f"image too small or empty: shape {img.shape}"
    if img.dtype != np.uint8:
        if not np.all(np.isfinite(img)):
            return "image has NaN or infinite pixels"
        img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(np.ascontiguousarray(img), cv2.COLOR_RGB2GRAY)
    return np.ascontiguousarray(img.reshape(img.shape[:2]))


def normalised_rays(cam: Camera, pixels_px: ArrayLike) -> NDArray[np.float64]:
    """Undistorted viewing directions (N, 3) = (x/z, y/z, 1) of sensor pixels, camera frame
    (= stator axes, ``plant.camera``)."""
    uv = np.asarray(pixels_px, dtype=float).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(uv, cam.matrix(1), np.asarray(cam.params.dist_coeffs, dtype=float))
    xy = xy.reshape(-1, 2)
    return np.column_stack([xy, np.ones(len(xy))])


def back_project(cam: Camera, pixels_px: ArrayLike, q: ArrayLike) -> NDArray[np.float64]:
    """Rotor-frame points (N, 3), m, where the viewing rays of sensor pixels (N, 2) meet the
    print's plane z = -R of the rotor at attitude ``q`` (seed 001 Eq. 12 for a known pose).

    In the stator frame the plane has normal ``n = R(q) e_z`` through ``R(q) (0, 0, -R)``; a ray
    ``C + t d`` meets it at ``t = n·(p0 - C) / n·d``; the point is rotated back by ``R(q)^T``.
    """
    R = attitude.to_matrix(q)
    d = normalised_rays(cam, pixels_px)
    C = cam.center_m
    n = R[:, 2]
    p0 = -cam.rotor_radius_m * n
    t = ((p0 - C) @ n) / (d @ n)
    X = C + t[:, None] * d
    return X @ R  # R^T X for each row


class OrbFrontEnd:
    """ORB keypoints of a frame matched to an ``OrbReference`` (see the module docstring)."""

    def __init__(
        self,
        params: PlantParams,
        reference: OrbReference,
        config: OrbConfig | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        #: Times ``measure`` (``compute_time_s``), s; tests inject a stand-in.
        self.clock = clock
        self.params = params
        self.reference = reference
        self.config = config or OrbConfig()
        self.camera = Camera.from_plant(params)
        self._orb = _orb(self.config, self.config.n_features)
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=False)
        self._ref_ideal = self._ideal(reference.pixels_px)
        self._undistort_maps = self._ideal_maps()
        self._ref_gray_ideal = self._to_ideal_image(reference.gray)

    def _ideal_maps(self) -> tuple[NDArray[np.float32], NDArray[np.float32]] | None:
        """``cv2.remap`` maps from an ideal (pinhole) frame to the distorted one, or None for an
        ideal lens."""
        dist = np.asarray(self.camera.params.dist_coeffs, dtype=float)
        if not np.any(dist):
            return None
        b = self.reference.binning
        K = self.camera.matrix(b)
        w, h = self.camera.size(b)
        return cv2.initUndistortRectifyMap(K, dist, None, K, (w, h), cv2.CV_32FC1)

    def _to_ideal_image(self, gray: NDArray[np.uint8]) -> NDArray[np.uint8]:
        if self._undistort_maps is None:
            return gray
        return cv2.remap(gray, *self._undistort_maps, cv2.INTER_LINEAR)

    def _from_ideal(self, ideal_image_px: NDArray[np.float64]) -> NDArray[np.float64]:
        """Ideal (pinhole) image px of the reference's binning -> sensor px with distortion."""
        b = self.reference.binning
        uv = image_to_sensor(ideal_image_px, b)
        if self._undistort_maps is None:
            return uv
        K = self.camera.matrix(1)
        xy = (uv - K[:2, 2]) / K[0, 0]
        rays = np.column_stack([xy, np.ones(len(xy))])
        out, _ = cv2.projectPoints(
            rays.reshape(-1, 1, 3),
            np.zeros(3),
            np.zeros(3),
            K,
            np.asarray(self.camera.params.dist_coeffs, dtype=float),
        )
        return out.reshape(-1, 2)

    def _refine(
        self, gray: NDArray[np.uint8], H: NDArray[np.float64], ref_ideal: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """Sub-pixel positions (ideal image px) in the current frame of reference points at
        ``ref_ideal`` (ideal image px): the reference image is warped into the current view
        by the homography ``H`` and each point is tracked by pyramidal Lucas–Kanade from its
        predicted position ``H ref``. Returns the positions and which ones converged within
        ``refine_max_shift_image_px``."""
        c = self.config
        cur = self._to_ideal_image(gray)
        h, w = cur.shape
        warped = cv2.warpPerspective(self._ref_gray_ideal, H, (w, h), flags=cv2.INTER_LINEAR)
        pred = cv2.perspectiveTransform(ref_ideal.reshape(-1, 1, 2), H).reshape(-1, 2)
        win = c.refine_window_image_px | 1
        p1, status, _ = cv2.calcOpticalFlowPyrLK(
            warped,
            cur,
            pred.astype(np.float32).reshape(-1, 1, 2),
            pred.astype(np.float32).reshape(-1, 1, 2),
            winSize=(win, win),
            maxLevel=1,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.005),
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        )
        p1 = p1.reshape(-1, 2).astype(float)
        half = win // 2 + 1
        inside = np.all((p1 >= half) & (p1 <= np.array([w, h]) - 1 - half), axis=1)
        ok = status.ravel().astype(bool) & inside
        ok &= np.linalg.norm(p1 - pred, axis=1) <= c.refine_max_shift_image_px
        return p1, ok

    def _ideal(self, pixels_px: NDArray[np.float64]) -> NDArray[np.float64]:
        """Sensor pixels with the lens distortion removed, in image px of the reference's
        binning (a pinhole camera's pixels, where the print's two views are a homography)."""
        if not np.any(self.camera.params.dist_coeffs):
            return sensor_to_image(pixels_px, self.reference.binning)
        K = self.camera.matrix(1)
        ideal = normalised_rays(self.camera, pixels_px)[:, :2] * K[0, 0] + K[:2, 2]
        return sensor_to_image(ideal, self.reference.binning)

    def measure(self, image: NDArray[np.uint8], binning: int) -> OrbMeasurement:
        """Match the ORB keypoints of an RGB ``image`` binned by ``binning`` to the reference."""
        t0 = self.clock()

        def done(m: OrbMeasurement) -> OrbMeasurement:
            return replace(m, compute_time_s=self.clock() - t0)

        c, ref = self.config, self.reference
        gray = self._gray(image, binning)
        if isinstance(gray, str):
            return done(OrbMeasurement.invalid(gray))
        kps, desc = self._orb.detectAndCompute(gray, None)
        n_kp = len(kps)
        if desc is None or n_kp < 2:
            return done(
                OrbMeasurement.invalid(
                    f"too few matches: {n_kp} ORB keypoints (textureless or blurred frame?)",
                    n_keypoints=n_kp,
                )
            )
        pairs = self._matcher.knnMatch(desc, ref.descriptors, k=2)
        good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < c.ratio * p[1].distance]
        n_match = len(good)
        if n_match < c.min_inliers:
            return done(
                OrbMeasurement.invalid(
                    f"too few matches: {n_match} after the ratio test (need {c.min_inliers}; "
                    f"{n_kp} keypoints; textureless or blurred frame?)",
                    n_keypoints=n_kp,
                    n_matches=n_match,
                )
            )
        i_cur = np.array([m.queryIdx for m in good])
        i_ref = np.array([m.trainIdx for m in good])
        cur_px = keypoint_pixels([kps[i] for i in i_cur], c.scale_factor, binning)
        octave = np.array([kps[i].octave for i in i_cur])
        Hmat, inl = self._homography(i_ref, i_cur, cur_px)
        n_in = int(inl.sum())
        if n_in < c.min_inliers:
            return done(
                OrbMeasurement.invalid(
                    f"too few matches: {n_in} RANSAC inliers of {n_match} matches "
                    f"(need {c.min_inliers})",
                    n_keypoints=n_kp,
                    n_matches=n_match,
                    n_inliers=n_in,
                )
            )
        idx = i_ref[inl]
        if c.refine:
            ideal, ok = self._refine(gray, Hmat, self._ref_ideal[idx])
            idx, pix = idx[ok], self._from_ideal(ideal[ok])
            sigma = np.full(len(idx), c.sigma_refined_px)
            if len(idx) < c.min_inliers:
                return done(
                    OrbMeasurement.invalid(
                        f"too few matches: {len(idx)} of {n_in} RANSAC inliers survived the "
                        f"sub-pixel refinement (need {c.min_inliers})",
                        n_keypoints=n_kp,
                        n_matches=n_match,
                        n_inliers=n_in,
                    )
                )
        else:
            pix = cur_px[inl]
            sigma = c.sigma0_px * c.scale_factor ** octave[inl].astype(float)
        return done(
            OrbMeasurement(
                points_rotor_m=ref.points_rotor_m[idx],
                pixels_px=pix,
                sigma_px=sigma,
                valid=True,
                n_keypoints=n_kp,
                n_matches=n_match,
                n_inliers=n_in,
            )
        )

    def _gray(self, image: NDArray[np.uint8], binning: int) -> NDArray[np.uint8] | str:
        """The grey frame, or why it cannot be matched to the reference (another binning, not
        an RGB uint8 image, or a size that is not the camera's at ``binning``)."""
        if binning != self.reference.binning:
            return f"frame binning {binning} differs from the reference's {self.reference.binning}"
        gray = _to_gray(image)
        if isinstance(gray, str):
            return gray
        cam = self.params.camera
        expected = (cam.sensor_height_px // binning, cam.sensor_width_px // binning)
        if gray.shape != expected:  # e.g. a resized frame: its pixels would mean other rays
            return (f"frame size {gray.shape[1]} x {gray.shape[0]} px does not match the camera "
                    f"at binning {binning}: expected {expected[1]} x {expected[0]} px")
        return gray

    def _homography(
        self, i_ref: NDArray[np.int_], i_cur: NDArray[np.int_], cur_px: NDArray[np.float64],
    ) -> tuple[NDArray[np.float64] | None, NDArray[np.bool_]]:
        """RANSAC homography from the reference's to the current keypoints (ideal image
        coordinates) and the inlier mask of the matches, keeping only one-to-one matches."""
        c = self.config
        Hmat, mask = cv2.findHomography(
            self._ref_ideal[i_ref],
            self._ideal(cur_px),
            cv2.RANSAC,
            c.ransac_threshold_image_px,
            maxIters=2000,
            confidence=c.ransac_confidence,
        )
        inl = np.zeros(len(i_ref), bool) if mask is None else mask.ravel().astype(bool)
        # One current keypoint per reference point and vice versa (a duplicate is ambiguous).
        return Hmat, inl & _unique(i_ref) & _unique(i_cur)


def _unique(idx: NDArray[np.int_]) -> NDArray[np.bool_]:
    """Entries whose value occurs once in ``idx``."""
    _, inv, counts = np.unique(idx, return_inverse=True, return_counts=True)
    return counts[inv] == 1


# --- ORB alone: the per-frame attitude solve ------------------------------------------------
