"""Lenses inside the scene: an ideal thin lens BSDF, and real spherical singlets as meshes.

Mitsuba 3 has no in-scene lens, so the relay and collimating lenses are surfaces with a BSDF
that bends every ray the way an ideal (aberration-free) thin lens of focal length :math:`f`
does. In the lens's local frame (:math:`z` along the axis, the hit point at
:math:`p = (p_x, p_y, 0)` relative to the lens centre) a ray of direction :math:`d` leaves with

.. math:: d' \\propto \\Big(\\frac{d_x}{|d_z|} - \\frac{p_x}{f},\\;
                            \\frac{d_y}{|d_z|} - \\frac{p_y}{f},\\; \\operatorname{sign} d_z\\Big),

i.e. all rays parallel to :math:`d` meet at the point where the undeviated chief ray through the
centre crosses the back focal plane. This maps direction tangents linearly and therefore images
every plane onto its conjugate exactly (1/a + 1/b = 1/f, magnification −b/a), with no
aberrations, and is symmetric, so it works for rays going either way (the path tracer traces
from the sensor back to the diffuser). The interaction is a delta transmission of weight
``transmittance`` (radiance is conserved along the bent ray, as étendue is).

:func:`spherical_lens_mesh` builds a real biconvex singlet (two spherical caps and an edge) with
trimesh for the ``dielectric`` BSDF or the Sellmeier glass of :mod:`sim.optics.dielectric`; its normals
face outward, as Mitsuba's dielectric needs to tell inside from outside.
"""

from __future__ import annotations

import numpy as np

from sim.optics.dielectric import dispersive_dielectric, mesh_shape
from sim.optics.variant import delta_bsdf_base, ensure_variant, register_plugin

__all__ = ["register", "thin_lens_bsdf", "lens_shape", "spherical_lens_mesh", "real_lens_shape",
           "PLUGIN"]

PLUGIN = "kaleidospec_thinlens"


def register():
    """Register the ``kaleidospec_thinlens`` BSDF with Mitsuba (idempotent)."""
    register_plugin("bsdf", PLUGIN, _thin_lens_class)


def _thin_lens_class(mi):
    """The ``ThinLensBSDF`` plugin class for the variant ``mi``."""
    import drjit as dr

    class ThinLensBSDF(delta_bsdf_base()):
        """Ideal thin lens as a delta transmission (see the module docstring)."""

        def __init__(self, props):
            super().__init__(props)
            self.f = props.get("focal_length", 50.0)
            c = props.get("center", [0.0, 0.0, 0.0])
            self.center = mi.ScalarPoint3f(float(c[0]), float(c[1]), float(c[2]))
            self.transmittance = props.get("transmittance", 1.0)

        def sample(self, ctx, si, sample1, sample2, active=True):
            p = si.sh_frame.to_local(si.p - mi.Point3f(self.center))
            d = -si.wi
            az = dr.abs(d.z)
            sgn = dr.select(d.z >= 0, 1.0, -1.0)
            wo = dr.normalize(mi.Vector3f(d.x / az - p.x / self.f, d.y / az - p.y / self.f, sgn))
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = wo
            bs.pdf = 1.0
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DeltaTransmission)
            bs.sampled_component = 0
            ok = active & (az > 1e-6)
            return bs, dr.select(ok, mi.Spectrum(self.transmittance), mi.Spectrum(0.0))

        def to_string(self):
            return f"ThinLensBSDF[f={self.f}]"

    return ThinLensBSDF


def thin_lens_bsdf(focal_mm: float, center, transmittance: float = 1.0) -> dict:
    """Mitsuba dict of an ideal thin lens BSDF of focal length ``focal_mm`` centred at ``center``."""
    register()
    return {
        "type": PLUGIN,
        "focal_length": float(focal_mm),
        "center": [float(v) for v in center],
        "transmittance": float(transmittance),
    }


def lens_shape(focal_mm: float, center, diameter_mm: float, normal=(0.0, 0.0, 1.0),
               transmittance: float = 1.0) -> dict:
    """A disk of ``diameter_mm`` at ``center`` whose BSDF is the ideal thin lens.

    Parameters
    ----------
    focal_mm : float
        Focal length f (mm).
    center : sequence of 3 floats
        Lens centre (mm, world).
    diameter_mm : float
        Clear aperture; rays outside it miss the lens (and are lost).
    normal : sequence of 3 floats
        Optical axis; the sign does not matter (the lens is symmetric).
    transmittance : float
        Weight of the transmitted ray (coating losses).
    """
    mi = ensure_variant()
    c = mi.ScalarPoint3f(*[float(v) for v in center])
    n = mi.ScalarVector3f(*[float(v) for v in normal])
    up = mi.ScalarVector3f(0, 1, 0) if abs(float(n[1])) < 0.9 else mi.ScalarVector3f(1, 0, 0)
    r = 0.5 * float(diameter_mm)
    xf = mi.ScalarTransform4f().look_at(origin=c, target=c + n, up=up) @ mi.ScalarTransform4f().scale([r, r, 1.0])
    return {"type": "disk", "to_world": xf,
            "bsdf": thin_lens_bsdf(focal_mm, center, transmittance)}


def spherical_lens_mesh(focal_mm: float, diameter_mm: float, n_glass: float = 1.5168,
                        center=(0.0, 0.0, 0.0), sections: int = 96):
    """A real equiconvex spherical singlet as a trimesh ``Trimesh`` (mm, axis along +z).

    The radii follow the thin-lens lensmaker's equation with a thickness correction,
    :math:`1/f = (n-1)\\,[2/R - (n-1) t / (n R^2)]`, solved for R with the centre thickness
    t set by the sag of both caps plus a 1 mm edge. Normals face outward.

    Parameters
    ----------
    focal_mm, diameter_mm : float
        Focal length and clear diameter (mm).
    n_glass : float
        Refractive index used to size the radii (at the design wavelength).
    center : sequence of 3 floats
        Position of the lens centre.
    sections : int
        Angular resolution of the caps.
    """
    import trimesh

    r_ap = 0.5 * float(diameter_mm)
    R = 2.0 * (n_glass - 1.0) * focal_mm
    for _ in range(50):  # fixed point on the thickness correction
        sag = R - np.sqrt(max(R * R - r_ap * r_ap, 1e-9))
        t = 2.0 * sag + 1.0
        # 1/f = (n-1)(2/R - (n-1) t / (n R^2)) solved for R (larger root).
        a, b, c = 1.0 / focal_mm, -2.0 * (n_glass - 1.0), (n_glass - 1.0) ** 2 * t / n_glass
        R = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)
    sag = R - np.sqrt(R * R - r_ap * r_ap)
    t = 2.0 * sag + 1.0
    rings, segs = 24, int(sections)
    rho = np.linspace(0.0, r_ap, rings + 1)
    phi = np.linspace(0.0, 2 * np.pi, segs, endpoint=False)
    verts, faces = [], []

    def cap(sign):
        base = len(verts)
        z0 = sign * (t / 2.0)
        verts.append([0.0, 0.0, z0])
        for rr in rho[1:]:
            z = sign * (t / 2.0 - (R - np.sqrt(R * R - rr * rr)))
            for ph in phi:
                verts.append([rr * np.cos(ph), rr * np.sin(ph), z])
        for j in range(segs):
            a_, b_ = base + 1 + j, base + 1 + (j + 1) % segs
            faces.append([base, a_, b_] if sign > 0 else [base, b_, a_])
        for i in range(rings - 1):
            r0, r1 = base + 1 + i * segs, base + 1 + (i + 1) * segs
            for j in range(segs):
                a0, b0 = r0 + j, r0 + (j + 1) % segs
                a1, b1 = r1 + j, r1 + (j + 1) % segs
                if sign > 0:
                    faces.extend([[a0, a1, b1], [a0, b1, b0]])
                else:
                    faces.extend([[a0, b1, a1], [a0, b0, b1]])
        return base + 1 + (rings - 1) * segs  # first vertex of the outer ring

    top = cap(+1.0)
    bot = cap(-1.0)
    for j in range(segs):
        a0, b0 = top + j, top + (j + 1) % segs
        a1, b1 = bot + j, bot + (j + 1) % segs
        faces.extend([[a0, b0, b1], [a0, b1, a1]])
    mesh = trimesh.Trimesh(np.asarray(verts) + np.asarray(center, float), np.asarray(faces),
                           process=True)
    mesh.fix_normals()  # outward, as Mitsuba's dielectric expects
    return mesh


def real_lens_shape(focal_mm: float, center, diameter_mm: float, glass: str = "BK7",
                    design_nm: float = 587.6, axis=(0.0, 0.0, 1.0), hero: bool = False):
    """A real equiconvex BK-7 (or other glass) singlet as a Mitsuba mesh with the dispersive
    dielectric of :mod:`sim.optics.dielectric` (so it shows chromatic aberration; slower than
    the ideal thin lens), its axis rotated from +z onto ``axis``.

    ``hero`` stays False: the backward path meets the prism (which keeps only the first
    wavelength, once) before any lens, so the lens refracts with that same first wavelength
    and must not zero-and-reweight a second time.
    """
    from sim.optics.glass import refractive_index

    mesh = spherical_lens_mesh(focal_mm, diameter_mm, float(refractive_index(glass, design_nm)))
    v = np.asarray(mesh.vertices, dtype=np.float64)
    ax = np.asarray(axis, float) / np.linalg.norm(axis)
    z = np.array([0.0, 0.0, 1.0])
    if abs(abs(ax @ z) - 1.0) > 1e-9:
        k = np.cross(z, ax)
        s, c = np.linalg.norm(k), ax @ z
        k /= s
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        v = v @ (np.eye(3) + s * K + (1 - c) * K @ K).T
    v = v + np.asarray(center, float)
    return mesh_shape(v, np.asarray(mesh.faces), dispersive_dielectric(glass, hero=hero),
                      name="lens")
