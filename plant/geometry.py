"""Where the magnets, coils and markers are (seed 000 §2.1, §3.2.2).

All positions are unit axes or points in metres; magnet axes and marker points are in the rotor
frame, coil axes in the stator frame.
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from plant.params import MotorParams, RotorParams, VFCParams


@lru_cache(maxsize=1)
def icosahedron_face_normals() -> NDArray[np.float64]:
    """The 20 face normals of a regular icosahedron turned so that one face looks along +Z.

    With a three-fold axis along Z the face-centre latitudes are ±90° (1 each), ±48.19° (3 each)
    and ±19.47° (6 each). The rotation about Z is fixed so that one face of the +48.19° band lies
    at azimuth 0.
    """
    p = (1.0 + 5.0**0.5) / 2.0
    verts = []
    for a, b in itertools.product((-1.0, 1.0), repeat=2):
        verts += [(0.0, a, b * p), (a, b * p, 0.0), (b * p, 0.0, a)]
    V = np.array(verts)
    # Faces are the vertex triples that are pairwise one edge (length 2) apart.
    faces = [
        f
        for f in itertools.combinations(range(12), 3)
        if all(
            abs(np.linalg.norm(V[i] - V[j]) - 2.0) < 1e-9 for i, j in itertools.combinations(f, 2)
        )
    ]
    N = np.array([V[list(f)].mean(axis=0) for f in faces])
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    # Rotate the first normal onto +Z (Rodrigues), then spin the 48° band to azimuth 0.
    n0, z = N[0], np.array([0.0, 0.0, 1.0])
    v, c = np.cross(n0, z), float(n0 @ z)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    R = np.eye(3) + vx + vx @ vx / (1.0 + c)
    N = N @ R.T
    band = N[np.abs(N[:, 2] - 5.0**0.5 / 3.0) < 1e-6]
    psi = np.arctan2(band[0, 1], band[0, 0])
    cz, sz = np.cos(-psi), np.sin(-psi)
    N = N @ np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]).T
    return N[np.lexsort((np.mod(np.arctan2(N[:, 1], N[:, 0]), 2 * np.pi), -N[:, 2].round(6)))]


def magnet_axes() -> NDArray[np.float64]:
    """Unit axes (18, 3) of the rotor magnets in the rotor frame (seed 000 §2.1).

    The face centres of the icosahedron without the two polar faces: 3 at +48.19°, 6 at +19.47°,
    6 at -19.47° and 3 at -48.19° latitude, in that order, each band by increasing azimuth.
    """
    N = icosahedron_face_normals()
    return N[np.abs(N[:, 2]) < 0.99]


def magnet_polarity() -> NDArray[np.float64]:
    """Polarity s_j = ±1 of each magnet (18,). Our choice: alternating per latitude band
    (N, S, N, S from top to bottom), which the DESIGN check found well posed."""
    lat = np.arcsin(magnet_axes()[:, 2])
    bands = np.unique(np.round(lat, 6))[::-1]  # top to bottom
    index = np.searchsorted(-bands, -np.round(lat, 6))
    return np.where(index % 2 == 0, 1.0, -1.0)


def coil_axes(motor: MotorParams) -> NDArray[np.float64]:
    """Unit axes (16, 3) of the stator coils in the stator frame, pointing from the motor
    centre to each coil: 8 at +latitude (azimuth 0°, 45°, ...), then 8 at -latitude offset by
    ``lower_layer_offset_deg`` (seed 000 §2.1: 16 coils in two layers; angles our choice)."""
    lat = np.deg2rad(motor.coil_latitude_deg)
    az = np.deg2rad(np.arange(8) * 45.0)
    upper = np.column_stack(
        [np.cos(lat) * np.cos(az), np.cos(lat) * np.sin(az), np.full(8, np.sin(lat))]
    )
    az2 = az + np.deg2rad(motor.lower_layer_offset_deg)
    lower = np.column_stack(
        [np.cos(lat) * np.cos(az2), np.cos(lat) * np.sin(az2), np.full(8, -np.sin(lat))]
    )
    return np.vstack([upper, lower])


def marker_points(rotor: RotorParams, vfc: VFCParams) -> NDArray[np.float64]:
    """Centres (2, 3) of the red main and yellow auxiliary markers in the rotor frame (m).

    They lie on the flat VFC plate tangent to the rotor at the bottom pole (0, 0, -R), at
    ``∓L/2`` along the rotor x axis (see ``VFCParams``).
    """
    half = 0.5 * vfc.L_m
    z = -rotor.radius_m
    return np.array([[-half, 0.0, z], [half, 0.0, z]])


def bottom_pole(rotor: RotorParams) -> NDArray[np.float64]:
    """The bottom pole (virtual pole of seed 000 §2.3) in the rotor frame (m)."""
    return np.array([0.0, 0.0, -rotor.radius_m])
