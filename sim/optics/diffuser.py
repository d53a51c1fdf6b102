"""The holographic diffuser: an area emitter whose radiance is the scene's hyperspectral cube.

The objective images the scene onto the diffuser, which scatters it into the kaleidoscope. We
model the diffuser as a Lambertian area emitter (a rectangle across the tube's entrance, facing
the tube) whose spectral radiance at world point :math:`(x, y)` and wavelength λ is

.. math:: L(x, y, \\lambda) = T_d \\; f\\big(r(y), c(x), l(\\lambda)\\big),

with :math:`T_d` the diffuser transmittance and :math:`f` the cube, piecewise constant: each cube
pixel is a uniform square patch, each band a box :math:`[\\lambda_l - \\Delta_l/2, \\lambda_l +
\\Delta_l/2)` (zero outside all bands). The cube covers the part of the diffuser that the
centre view's sensor rectangle sees (:func:`cube_region`), so one cube pixel maps to one sensor
pixel when the cube is ``view_size_px`` square; the rest of the diffuser is dark.

The lookup works from the world position of the hit (not Mitsuba's ``uv``), so the orientation
is explicit: cube row 0 is at the *top* of the centre view on the sensor and column 0 at its
left (Mitsuba's bitmap textures put row 0 at the bottom, one reason not to use them). The same
:func:`texel_index` gives the transport cache its texel indices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.optics.variant import ensure_variant, register_plugin

__all__ = ["CubeRegion", "cube_region", "register", "texel_index",
           "diffuser_shape", "PLUGIN"]

PLUGIN = "kaleidospec_cubetex"


@dataclass(frozen=True)
class CubeRegion:
    """Where the cube lies on the diffuser (world mm, z = 0 plane).

    Texel (r, c) covers x ∈ [x0 + c·dx, x0 + (c+1)·dx) · sx and y likewise with sy; the signs
    sx, sy (±1) put row 0 at the top and column 0 at the left of the centre view on the sensor.
    """

    x0: float
    y0: float
    dx: float
    dy: float
    height: int
    width: int
    sx: float
    sy: float


#: Orientation of the diffuser on the sensor: sensor column grows with −x (sx = −1) and sensor
#: row with +y (sy = +1). The relay and the 4f collimator/imaging relay each invert the image
#: once, so this is the camera's own convention (:mod:`sim.optics.camera`, up = +y, looking back along
#: the folded axis): ``tests/sim/optics/test_optics.py`` renders an asymmetric target and checks
#: that the centre view comes out upright and unflipped.
SENSOR_FROM_DIFFUSER = (-1.0, 1.0)


def cube_region(design, shape) -> CubeRegion:
    """The diffuser area covered by a cube of ``shape`` (H, W): the centre view's rectangle.

    The view rectangle is ``v = design.view_size_px`` pixels; back on the diffuser that
    is :math:`s = v\\,\\Delta / (m\\, M)` mm (Δ pixel pitch, m relay minification, M = f_img/f_col),
    centred on the axis. A cube of H×W pixels divides it into H rows and W columns.
    """
    H, W = int(shape[0]), int(shape[1])
    v = design.view_size_px
    side = v * design.sensor_pixel_um * 1e-3 / (design.minification * design.mask_to_sensor)
    sx, sy = SENSOR_FROM_DIFFUSER
    return CubeRegion(x0=-side / 2, y0=-side / 2, dx=side / W, dy=side / H, height=H, width=W,
                      sx=sx, sy=sy)


def texel_index(p, region: CubeRegion):
    """Flat texel index r·W + c of world points ``p`` (drjit Point3f) and an ``inside`` mask."""
    import drjit as dr

    mi = ensure_variant()
    # Coordinates along the sensor's column and row directions.
    xs = region.sx * p.x
    ys = region.sy * p.y
    c = dr.floor((xs - region.x0) / region.dx)
    r = dr.floor((ys - region.y0) / region.dy)
    inside = (c >= 0) & (c < region.width) & (r >= 0) & (r < region.height)
    idx = mi.UInt32(dr.clip(r, 0, region.height - 1)) * region.width + mi.UInt32(
        dr.clip(c, 0, region.width - 1))
    return idx, inside


def register():
    """Register the ``kaleidospec_cubetex`` texture with Mitsuba (idempotent)."""
    register_plugin("texture", PLUGIN, _texture_class)


def _texture_class(mi):
    """The ``CubeTexture`` plugin class for the variant ``mi``."""
    import drjit as dr

    class CubeTexture(mi.Texture):
        """Spectral texture reading a band-major cube at (world x, y, wavelength)."""

        def __init__(self, props):
            mi.Texture.__init__(self, props)
            self.region = None
            self.data = mi.Float(0.0)
            self.edges = [0.0, 1.0]
            self.scale = 1.0
            self.peak = 0.0

        def set_cube(self, cube_lhw: np.ndarray, edges, region: CubeRegion, scale: float):
            """Load a band-major cube (L, H, W) with its band ``edges`` (L+1,) and placement."""
            self.data = mi.Float(np.ascontiguousarray(cube_lhw, dtype=np.float32).ravel())
            self.edges = [float(e) for e in edges]
            self.region = region
            self.scale = float(scale)
            self.peak = float(np.max(cube_lhw)) * self.scale if cube_lhw.size else 0.0

        def eval(self, si, active=True):
            idx, inside = texel_index(si.p, self.region)
            npix = self.region.height * self.region.width
            out = mi.Spectrum(0.0)
            for k in range(4):
                lam = si.wavelengths[k]
                band = mi.UInt32(0)
                for e in self.edges[1:-1]:
                    band += mi.UInt32(dr.select(lam >= e, 1, 0))
                ok = inside & (lam >= self.edges[0]) & (lam < self.edges[-1]) & active
                val = dr.gather(mi.Float, self.data, band * npix + idx, ok)
                out[k] = dr.select(ok, val * self.scale, 0.0)
            return out

        def eval_1(self, si, active=True):
            return dr.mean(self.eval(si, active))

        def mean(self):
            return self.peak * 0.5

        def max(self):
            return self.peak

        def is_spatially_varying(self):
            return True

        def traverse(self, callback):
            pass

        def to_string(self):
            return "CubeTexture[]"

    return CubeTexture


def diffuser_shape(design, cube_lhw: np.ndarray | None, wavelengths, z: float = 0.0):
    """The diffuser rectangle (tube cross-section at ``z``, facing +z) emitting the cube.

    Parameters
    ----------
    design : sim.optics.design.Design
    cube_lhw : ndarray (L, H, W) or None
        Band-major radiance cube; None gives a dark emitter (for tracing the transport cache).
    wavelengths : array_like (L,)
        Band centres of the cube (nm).

    Returns
    -------
    shape_dict : dict
        Mitsuba dict of the emitting rectangle (its BSDF is ``null``: rays that reach it end,
        the ray continues into empty space).
    texture : CubeTexture
        The texture object (its region is used by the transport tracer).
    """
    mi = ensure_variant()
    register()
    tex = mi.load_dict({"type": PLUGIN})
    if cube_lhw is None:
        cube_lhw = np.zeros((1, 1, 1), dtype=np.float32)
        wavelengths = [float(design.prism_center_nm)]
    shape = cube_lhw.shape[1:]
    from sim.bands import band_edges

    tex.set_cube(cube_lhw, band_edges(wavelengths, design), cube_region(design, shape),
                 design.diffuser_transmittance)
    half = 0.5 * design.tube_width_mm
    xf = mi.ScalarTransform4f().translate([0.0, 0.0, float(z)]).scale([half, half, 1.0])
    return {
        "type": "rectangle",
        "to_world": xf,
        "emitter": {"type": "area", "radiance": tex},
        "bsdf": {"type": "null"},
    }, tex
