"""The dispersive prism: a mesh of Sellmeier glass (:mod:`sim.optics.dielectric`) at minimum deviation.

The glass refracts every path with the index :math:`n(\\lambda)` at the path's (hero)
wavelength, so the prism spreads the bands along :math:`x` (:mod:`sim.optics.dielectric` explains the
hero wavelength and the Fresnel weight).

:func:`prism_geometry` places a prism of apex angle :math:`A` at minimum deviation for the
centre wavelength :math:`\\lambda_c`: the beam arrives along :math:`+z` at the incidence
:math:`\\theta_1 = \\arcsin(n(\\lambda_c)\\sin(A/2))`, runs parallel to the base inside and
leaves deviated by :math:`\\delta = 2\\theta_1 - A` toward the base, in the x–z plane.
"""

from __future__ import annotations

import numpy as np

from sim.optics.dielectric import dispersive_dielectric, mesh_shape
from sim.optics.glass import min_deviation_incidence_rad

__all__ = ["prism_geometry", "prism_shape"]


def prism_geometry(glass: str, apex_deg: float, center_nm: float, entry_point,
                   height_mm: float, depth_mm: float, base_side: float = 1.0):
    """Vertices, faces and exit axis of a prism at minimum deviation for ``center_nm``.

    Parameters
    ----------
    glass, apex_deg, center_nm
        Glass name, apex angle A (degrees) and the wavelength at minimum deviation.
    entry_point : sequence of 3 floats
        Where the optical axis (travelling along +z) should cross the middle of the prism.
    height_mm : float
        Height of the prism from base to apex (its faces are ``height/cos(A/2)`` long).
    depth_mm : float
        Extent along y (the non-dispersing direction).
    base_side : float
        +1: the base (where light is deviated to) toward +x; −1 toward −x.

    Returns
    -------
    vertices : ndarray (6, 3)
    faces : ndarray (8, 3)
        Counter-clockwise seen from outside (outward normals).
    exit_dir : ndarray (3,)
        Direction of the centre wavelength's ray after the prism.
    exit_point : ndarray (3,)
        Where the axis ray leaves the exit face.
    entry_surface : ndarray (3,)
        Where the axis ray meets the entry face.
    glass_path : float
        Length of the axis ray inside the glass (mm).
    """
    A = np.radians(float(apex_deg))
    th1 = min_deviation_incidence_rad(glass, apex_deg, center_nm)
    h = float(height_mm)
    # Prism frame (x', u): base on u = 0 from -h tan(A/2) to +h tan(A/2), apex at (0, h).
    # The axis ray runs inside along +x' at height u0; it arrives along (cos(θ1-A/2), sin(θ1-A/2)).
    u0 = 0.45 * h
    alpha = th1 - A / 2.0
    # Rotate the frame by -alpha so the incoming direction becomes +z (world):
    # x' -> world (z, x) components; map (x', u) to (z, x_w) with u toward -base_side*x.
    ca, sa = np.cos(alpha), np.sin(alpha)

    def to_world(xp, u):
        # rotate (xp, u) by -alpha: incoming (ca, sa) -> (1, 0)
        zr = ca * xp + sa * u
        ur = -sa * xp + ca * u
        return np.array([-base_side * ur, zr])  # (x_w, z_w) relative

    t = np.tan(A / 2.0)
    pts2 = [(-h * t, 0.0), (h * t, 0.0), (0.0, h)]
    # The axis point inside the prism at (0, u0) must land on entry_point.
    ref = to_world(0.0, u0)
    e = np.asarray(entry_point, dtype=np.float64)
    half = 0.5 * float(depth_mm)
    verts = []
    for y in (-half, half):
        for (xp, u) in pts2:
            xw, zw = to_world(xp, u) - ref
            verts.append([e[0] + xw, e[1] + y, e[2] + zw])
    verts = np.asarray(verts)
    faces = np.array([
        [0, 2, 1], [3, 4, 5],          # triangular ends
        [0, 1, 4], [0, 4, 3],          # base
        [1, 2, 5], [1, 5, 4],          # exit face
        [2, 0, 3], [2, 3, 5],          # entry face
    ], dtype=np.int64)
    # Orient every face outward (robust to the chosen base side).
    centroid = verts.mean(axis=0)
    for k, (a, b, c) in enumerate(faces):
        n = np.cross(verts[b] - verts[a], verts[c] - verts[a])
        if n @ (verts[a] - centroid) < 0:
            faces[k] = [a, c, b]
    # Exit direction of the centre wavelength: (cos α, -sin α) in the prism frame.
    d2 = to_world(ca, -sa) - to_world(0.0, 0.0)
    exit_dir = np.array([d2[0], 0.0, d2[1]])
    exit_dir /= np.linalg.norm(exit_dir)
    # The axis ray meets the exit face at x' = (h - u0) tan(A/2).
    xw, zw = to_world((h - u0) * t, u0) - ref
    exit_point = e + np.array([xw, 0.0, zw])
    xw, zw = to_world(-(h - u0) * t, u0) - ref
    entry_surface = e + np.array([xw, 0.0, zw])
    return verts, faces, exit_dir, exit_point, entry_surface, 2.0 * (h - u0) * t


def prism_shape(glass: str, apex_deg: float, center_nm: float, entry_point, height_mm: float,
                depth_mm: float, base_side: float = 1.0, hero: bool = True, fresnel: bool = True):
    """The prism as a Mitsuba mesh with the Sellmeier BSDF.

    Returns (mesh, exit_dir, exit_point, entry_surface, glass_path); see :func:`prism_geometry`.
    """
    v, f, d, p, q, t = prism_geometry(glass, apex_deg, center_nm, entry_point, height_mm,
                                      depth_mm, base_side)
    mesh = mesh_shape(v, f, dispersive_dielectric(glass, hero=hero, fresnel=fresnel), "prism")
    return mesh, d, p, q, t
