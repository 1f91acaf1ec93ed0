"""The MuJoCo model of the motor and its camera scene from ``PlantParams`` (MJCF as data).

* Rotor: one body on a ball joint at the motor centre O, with the inertia, mass and centre-of-mass
  offset of ``RotorParams`` (gravity acts when the offset is non-zero), viscous damping as joint
  ``damping``. The model carries the scene, the state and the sensors; ``plant.rigid_body``
  integrates the motion (with K(q) I, the Coulomb friction and the tilt stop, none of which is a
  MuJoCo actuator or constraint model), see ``plant.dynamics``.
* Tilt stop: not in the model; ``plant.rigid_body`` applies its contact torque, about the axis
  along which the tilt grows, so spin and yaw stay free.
* Scene: the bottom camera of ``plant.camera`` (MuJoCo cameras look along their -z with +y up in
  the image, so ``xyaxes = (1 0 0, 0 -1 0)`` gives image u along +X and v along +Y), a ring of
  lights around it, the dark VFC plate at the bottom pole with the red and yellow marker discs.
* Textured variant (``texture=``; off by default): instead of the marker discs, a
  square mesh on the plane z = -R carries the printed pattern of ``plant.texture`` as a 2-D
  texture asset (``mjcf_assets``), with texture coordinates at its corners so that texel
  (i, j) lands on the rotor point of ``plant.texture.Texture``'s convention.
"""

from __future__ import annotations

import numpy as np

from plant.camera import Camera
from plant.geometry import marker_points
from plant.params import PlantParams
from plant.texture import Texture, encode_png

#: Marker colours (RGB in [0, 1]); inside the seed's HSV gates (000 §3.2.1) after shading.
RED_RGB = (0.86, 0.08, 0.06)
YELLOW_RGB = (0.95, 0.80, 0.08)
PLATE_RGB = (0.08, 0.08, 0.09)
ROTOR_RGB = (0.55, 0.56, 0.58)
#: Lighting (our choice): the headlight (at the camera) and a ring of six spotlights around the
#: lens light a surface that faces the camera with a total of about 1.0, so it renders at its
#: rgb colour above (rotor mid grey, plate dark, markers saturated red and yellow) and darkens
#: mildly toward the rotor's silhouette, as in ``plant.render_analytic``. No specular light:
#: the plate and discs are matte prints.
#: File name under which the print of the textured variant is handed to MuJoCo (``mjcf_assets``).
TEXTURE_FILE = "rotor_print.png"
HEADLIGHT_AMBIENT = 0.42
HEADLIGHT_DIFFUSE = 0.30
RING_DIFFUSE = 0.06


def _v(x) -> str:
    return " ".join(f"{float(v):.9g}" for v in np.ravel(x))


def mjcf_assets(texture: Texture | None) -> dict[str, bytes]:
    """The asset files that ``build_mjcf(..., texture=texture)`` refers to, for
    ``mujoco.MjModel.from_xml_string(xml, assets)``; empty without a texture."""
    return {} if texture is None else {TEXTURE_FILE: encode_png(texture)}


def _print_mesh(texture: Texture) -> tuple[str, str]:
    """(asset, geom) MJCF of the textured variant's print: a square of two triangles on the
    plane z = -R facing the camera (-z), texture corner (0, 0) at rotor (-h, -h) and (1, 1) at
    (h, h), as in ``plant.texture``."""
    h, z = texture.half_size_m, texture.z_m
    verts = [[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]]
    asset = f"""  <asset>
    <texture name="print" type="2d" file="{TEXTURE_FILE}"/>
    <material name="print" texture="print" rgba="1 1 1 1" specular="0" shininess="0"
              reflectance="0"/>
    <mesh name="print" vertex="{_v(verts)}" texcoord="0 0 1 0 1 1 0 1" face="0 2 1 0 3 2"
          inertia="shell"/>
  </asset>
"""
    geom = """      <geom name="print" type="mesh" mesh="print" material="print"
            contype="0" conaffinity="0" mass="0"/>"""
    return asset, geom


def _delayed_sensor(p: PlantParams, sensor_delay_s: float | None) -> str:
    """The MJCF line of the ``rotor_quat_delayed`` ballquat sensor delayed by
    ``sensor_delay_s`` (s), with enough samples kept for the delay at the physics step; ""
    without a delay. ``ValueError`` for a negative delay."""
    if sensor_delay_s is None:
        return ""
    if not sensor_delay_s >= 0:
        raise ValueError(f"sensor_delay_s must be >= 0, got {sensor_delay_s}")
    n = int(np.ceil(sensor_delay_s / p.physics_dt_s)) + 2
    return (
        f'\n    <ballquat name="rotor_quat_delayed" joint="ball" nsample="{n}" '
        f'delay="{sensor_delay_s:.9g}"/>'
    )


def _ring_lights(cam_z: float) -> str:
    """MJCF lines of the six spot lights of the ring light: 60 mm around the optical axis,
    20 mm above the camera at height ``cam_z`` (m), pointing up at the rotor."""
    ring = 0.06
    return "\n".join(
        f'    <light name="ring{k}" pos="{_v([ring * np.cos(a), ring * np.sin(a), cam_z + 0.02])}" '
        f'dir="0 0 1" diffuse="{_v([RING_DIFFUSE] * 3)}" specular="0 0 0" castshadow="false" '
        f'type="spot" cutoff="40"/>'
        for k, a in enumerate(np.deg2rad(np.arange(0, 360, 60)))
    )


def build_mjcf(
    p: PlantParams, sensor_delay_s: float | None = None, texture: Texture | None = None
) -> str:
    """MJCF text of the motor and scene for parameters ``p``.

    ``sensor_delay_s`` adds a ``ballquat`` sensor ``rotor_quat_delayed`` that reports the
    attitude that much earlier through MuJoCo's native sensor delay (MuJoCo >= 3.5), an
    independent check of the timed loop's delay pipeline.

    ``texture`` (default None) replaces the two marker discs by the printed pattern
    of ``plant.texture.generate_texture``; load the model with ``mjcf_assets(texture)``.
    """
    delayed = _delayed_sensor(p, sensor_delay_s)
    r, cam = p.rotor, Camera.from_plant(p)
    R = r.radius_m
    w_full, h_full = cam.size(1)
    f_px = cam.matrix(1)[1, 1]
    fovy_deg = np.degrees(2.0 * np.arctan((h_full / 2.0) / f_px))
    red, yellow = marker_points(r, p.vfc)
    marker_r = p.vfc.marker_diameter_mm / 2000.0
    half_plate = p.vfc.plate_size_mm / 2000.0
    # Marker discs: bottom faces exactly in the plane z = -R (ground truth), 20 µm thick so that
    # their side walls do not show at 15° tilt (0.4 mm walls moved the centroid by 0.45 px); the
    # plate's bottom face sits just above them (depth precision at 0.3 m is a few µm).
    disc_half = 1e-5
    plate_half = 5e-4
    plate_z = -R + 2 * disc_half + plate_half
    cam_z = cam.center_m[2]
    lights = _ring_lights(cam_z)
    markers = f"""
      <geom name="marker_red" type="cylinder" pos="{_v(red + [0, 0, disc_half])}"
            size="{marker_r:.9g} {disc_half:.9g}" rgba="{_v(RED_RGB)} 1"
            contype="0" conaffinity="0" mass="0"/>
      <geom name="marker_yellow" type="cylinder" pos="{_v(yellow + [0, 0, disc_half])}"
            size="{marker_r:.9g} {disc_half:.9g}" rgba="{_v(YELLOW_RGB)} 1"
            contype="0" conaffinity="0" mass="0"/>"""
    asset = ""
    if texture is not None:
        asset, geom = _print_mesh(texture)
        markers = "\n" + geom
        half_plate = max(half_plate, texture.half_size_m)  # the dark plate backs the print
    dt = p.physics_dt_s
    return f"""<mujoco model="pmspm">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{dt:.9g}" integrator="RK4" gravity="0 0 {-r.gravity_m_s2:.9g}"/>
  <visual>
    <global offwidth="{w_full}" offheight="{h_full}" fovy="{fovy_deg:.9g}"/>
    <headlight ambient="{_v([HEADLIGHT_AMBIENT] * 3)}" diffuse="{_v([HEADLIGHT_DIFFUSE] * 3)}"
               specular="0 0 0"/>
    <quality offsamples="4"/>
  </visual>
{asset}  <worldbody>
{lights}
    <camera name="bottom" pos="{_v(cam.center_m)}" xyaxes="1 0 0 0 -1 0" fovy="{fovy_deg:.9g}"/>
    <body name="rotor">
      <joint name="ball" type="ball" damping="{r.viscous_Nms_per_rad:.9g}"/>
      <inertial pos="{_v(r.com_offset_m)}" mass="{r.mass_kg:.9g}"
                diaginertia="{_v(r.inertia_com_kgm2)}"/>
      <geom name="shell" type="sphere" size="{R - 1e-3:.9g}" rgba="{_v(ROTOR_RGB)} 1"
            contype="0" conaffinity="0" mass="0"/>
      <geom name="shaft" type="capsule" fromto="0 0 {R:.9g} 0 0 {R + 0.04:.9g}" size="0.006"
            rgba="0.7 0.7 0.72 1" contype="0" conaffinity="0" mass="0"/>
      <geom name="vfc_plate" type="box" pos="0 0 {plate_z:.9g}"
            size="{half_plate:.9g} {half_plate:.9g} {plate_half:.9g}" rgba="{_v(PLATE_RGB)} 1"
            contype="0" conaffinity="0" mass="0"/>{markers}
    </body>
  </worldbody>
  <sensor>
    <ballquat name="rotor_quat" joint="ball"/>
    <ballangvel name="rotor_angvel" joint="ball"/>{delayed}
  </sensor>
</mujoco>
"""
