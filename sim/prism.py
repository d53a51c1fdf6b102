"""The dispersive prism: a Sellmeier dielectric BSDF and the prism mesh at minimum deviation.

Mitsuba 3's ``dielectric`` has one index for all wavelengths. :class:`DispersiveDielectric`
refracts with the Sellmeier index :math:`n(\\lambda)` of the glass (:mod:`sim.glass`) at the
path's wavelength, as a delta transmission with the unpolarised Fresnel transmittance
:math:`1 - F` (reflections are not traced: they leave the optical path) and the radiance factor
:math:`\\eta_{ti}^2` (which cancels between the two faces).

A spectral Mitsuba path carries four wavelengths but only one direction. Refracting all four
along the first wavelength's direction is silently wrong, so on *entering* the glass the BSDF
keeps the first ("hero") wavelength only: weight ×(4, 0, 0, 0). This is unbiased (the film
averages the four) and happens once per path because only refraction is sampled and the prism
is convex, so every path enters it exactly once. Lenses made of the same BSDF after the prism
use ``hero=False``.

:func:`prism_geometry` places a prism of apex angle :math:`A` at minimum deviation for the
centre wavelength :math:`\\lambda_c`: the beam arrives along :math:`+z` at the incidence
:math:`\\theta_1 = \\arcsin(n(\\lambda_c)\\sin(A/2))`, runs parallel to the base inside and
leaves deviated by :math:`\\delta = 2\\theta_1 - A` toward the base, in the x–z plane.
"""

from __future__ import annotations

import numpy as np

from sim.glass import get_glass, min_deviation_incidence_rad
from sim.variant import delta_bsdf_base, ensure_variant

__all__ = ["register", "dispersive_dielectric", "prism_geometry", "prism_shape", "PLUGIN"]

PLUGIN = "kaleidospec_sellmeier"
_registered = False


def register():
    """Register the ``kaleidospec_sellmeier`` BSDF with Mitsuba (idempotent)."""
    global _registered
    mi = ensure_variant()
    if _registered:
        return
    import drjit as dr

    class DispersiveDielectric(delta_bsdf_base()):
        """Smooth dielectric with a Sellmeier index at the hero wavelength (delta transmission)."""

        def __init__(self, props):
            super().__init__(props)
            self.B = [float(props.get(f"B{i}", 0.0)) for i in (1, 2, 3)]
            self.C = [float(props.get(f"C{i}", 0.0)) for i in (1, 2, 3)]
            self.hero = bool(props.get("hero", True))
            self.fresnel = bool(props.get("fresnel", True))

        def index(self, wavelength_nm):
            lam2 = dr.square(wavelength_nm * 1e-3)
            n2 = 1.0
            for b, c in zip(self.B, self.C):
                n2 = n2 + b * lam2 / (lam2 - c)
            return dr.sqrt(n2)

        def sample(self, ctx, si, sample1, sample2, active=True):
            lam0 = si.wavelengths[0]
            eta = self.index(lam0)
            cos_i = mi.Frame3f.cos_theta(si.wi)
            r, cos_t, eta_it, eta_ti = mi.fresnel(cos_i, eta)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = mi.refract(si.wi, cos_t, eta_ti)
            bs.pdf = 1.0
            bs.eta = eta_it
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DeltaTransmission)
            bs.sampled_component = 0
            t = (1.0 - r) if self.fresnel else dr.select(r < 1.0, 1.0, 0.0)
            if ctx.mode == mi.TransportMode.Radiance:
                t = t * dr.square(eta_ti)
            w = mi.Spectrum(t)
            if self.hero:
                entering = cos_i > 0
                w = dr.select(entering, w * mi.Spectrum(4.0, 0.0, 0.0, 0.0), w)
            return bs, dr.select(active & (r < 1.0), w, mi.Spectrum(0.0))

        def to_string(self):
            return f"DispersiveDielectric[B={self.B}, C={self.C}, hero={self.hero}]"

    mi.register_bsdf(PLUGIN, lambda props: DispersiveDielectric(props))
    _registered = True


def dispersive_dielectric(glass: str = "BK7", hero: bool = True, fresnel: bool = True) -> dict:
    """Mitsuba dict of the Sellmeier dielectric for ``glass`` (see :mod:`sim.glass`)."""
    register()
    g = get_glass(glass)
    d = {"type": PLUGIN, "hero": bool(hero), "fresnel": bool(fresnel)}
    for i in range(3):
        d[f"B{i + 1}"] = float(g.B[i])
        d[f"C{i + 1}"] = float(g.C[i])
    return d


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
    from sim.lens import mesh_shape

    v, f, d, p, q, t = prism_geometry(glass, apex_deg, center_nm, entry_point, height_mm,
                                      depth_mm, base_side)
    mesh = mesh_shape(v, f, dispersive_dielectric(glass, hero=hero, fresnel=fresnel), "prism")
    return mesh, d, p, q, t
