r"""Glass bodies: the dispersive (Sellmeier) dielectric BSDF and the triangle meshes that carry it.

Mitsuba 3's ``dielectric`` has one index for all wavelengths. :class:`DispersiveDielectric`
refracts with the Sellmeier index :math:`n(\lambda)` of the glass (:mod:`sim.optics.glass`) at the
path's wavelength, as a delta transmission with the unpolarised Fresnel transmittance
:math:`1 - F` (reflections are not traced: they leave the optical path) and the radiance factor
:math:`\eta_{ti}^2` (which cancels between the two faces).

A spectral Mitsuba path carries four wavelengths but only one direction. Refracting all four
along the first wavelength's direction is silently wrong, so on *entering* the glass the BSDF
keeps the first ("hero") wavelength only: weight ×(4, 0, 0, 0). This is unbiased (the film
averages the four) and happens once per path because only refraction is sampled and the prism
is convex, so every path enters it exactly once. Lenses made of the same BSDF after the prism
use ``hero=False``.

The prism (:mod:`sim.optics.prism`) and the real lens singlets (:mod:`sim.optics.lens`) are both
:func:`mesh_shape` bodies of this dielectric; it lives apart from either so that neither
element imports the other.
"""

from __future__ import annotations

import numpy as np

from sim.optics.glass import get_glass
from sim.optics.variant import delta_bsdf_base, ensure_variant, register_plugin

__all__ = ["register", "dispersive_dielectric", "mesh_shape", "PLUGIN"]

PLUGIN = "kaleidospec_sellmeier"


def register():
    """Register the ``kaleidospec_sellmeier`` BSDF with Mitsuba (idempotent)."""
    register_plugin("bsdf", PLUGIN, _dielectric_class)


def _dielectric_class(mi):
    """The ``DispersiveDielectric`` plugin class for the variant ``mi``."""
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

    return DispersiveDielectric


def dispersive_dielectric(glass: str = "BK7", hero: bool = True, fresnel: bool = True) -> dict:
    """Mitsuba dict of the Sellmeier dielectric for ``glass`` (see :mod:`sim.optics.glass`)."""
    register()
    g = get_glass(glass)
    d = {"type": PLUGIN, "hero": bool(hero), "fresnel": bool(fresnel)}
    for i in range(3):
        d[f"B{i + 1}"] = float(g.B[i])
        d[f"C{i + 1}"] = float(g.C[i])
    return d


def mesh_shape(vertices, faces, bsdf, name: str = "mesh"):
    """A Mitsuba triangle mesh built in memory from ``vertices`` (V, 3) and ``faces`` (F, 3).

    Face winding sets the geometric normal (counter-clockwise seen from outside = outward);
    no vertex normals, so the shading is flat and refraction uses the true facet normals.
    ``bsdf`` is a Mitsuba dict or object.
    """
    mi = ensure_variant()
    v = np.ascontiguousarray(vertices, dtype=np.float32)
    f = np.ascontiguousarray(faces, dtype=np.uint32)
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf) if isinstance(bsdf, dict) else bsdf
    mesh = mi.Mesh(name, v.shape[0], f.shape[0], props)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(v.ravel())
    params["faces"] = mi.UInt32(f.ravel())
    params.update()
    return mesh
