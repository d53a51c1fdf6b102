"""The coded aperture: a chrome-on-quartz binary random mask in the relay's image plane.

The pattern is :meth:`sim.optics.design.Design.mask_pattern` (True = open quartz, False = chrome,
guard stripes and field stop included), given as the sensor sees it: cell (i, j) is imaged at
sensor ``mask_origin_px + (i, j)·mask_cell_px`` for the centre band. The collimator and the
imaging lens form an inverting relay of magnification M = f_img/f_col, so a mask point at world
(x, y) (relative to the axis) is imaged at the sensor position −M·(x, y) in the orientation of
:data:`sim.optics.diffuser.SENSOR_FROM_DIFFUSER`; :func:`cell_index` inverts that map.

The BSDF is a delta transmission straight through (a thin plate at normal incidence does not
bend rays) with weight :math:`T_q(\\lambda)` where the cell is open and 0 on chrome. The quartz
(fused silica, Sellmeier) plate's transmittance with incoherent multiple reflections is
:math:`T_q = (1 - R)/(1 + R)`, :math:`R = ((n-1)/(n+1))^2` (≈ 0.93).
"""

from __future__ import annotations

import numpy as np

from sim.optics.variant import delta_bsdf_base, ensure_variant, register_plugin

__all__ = ["register", "mask_shape", "cell_index", "quartz_transmittance", "PLUGIN"]

PLUGIN = "kaleidospec_mask"


def quartz_transmittance(wavelength_nm) -> np.ndarray:
    """Normal-incidence transmittance of an uncoated fused-silica plate, (1−R)/(1+R)."""
    from sim.optics.glass import get_glass

    n = get_glass("FusedSilica").n(wavelength_nm)
    R = ((n - 1.0) / (n + 1.0)) ** 2
    return (1.0 - R) / (1.0 + R)


def _geometry(design):
    from sim.optics.diffuser import SENSOR_FROM_DIFFUSER

    sx, sy = SENSOR_FROM_DIFFUSER
    M = design.mask_to_sensor
    pix = design.sensor_pixel_um * 1e-3
    r0, c0 = design.mask_origin_px
    return dict(sx=-sx, sy=-sy, M=M, pix=pix, r0=r0, c0=c0, cell=design.mask_cell_px,
                n=design.mask_cells, H=design.sensor_height_px, W=design.sensor_width_px)


def cell_index(p_x, p_y, g):
    """Mask cell (flat index i·n + j) of mask-plane points (relative to the axis) and ``inside``."""
    import drjit as dr

    mi = ensure_variant()
    col = 0.5 * g["W"] + g["M"] * g["sx"] * p_x / g["pix"]
    row = 0.5 * g["H"] + g["M"] * g["sy"] * p_y / g["pix"]
    j = dr.floor((col - g["c0"]) / g["cell"])
    i = dr.floor((row - g["r0"]) / g["cell"])
    n = g["n"]
    inside = (i >= 0) & (i < n) & (j >= 0) & (j < n)
    idx = mi.UInt32(dr.clip(i, 0, n - 1)) * n + mi.UInt32(dr.clip(j, 0, n - 1))
    return idx, inside


def register():
    """Register the ``kaleidospec_mask`` BSDF with Mitsuba (idempotent)."""
    register_plugin("bsdf", PLUGIN, _mask_class)


def _mask_class(mi):
    """The ``MaskBSDF`` plugin class for the variant ``mi``."""
    import drjit as dr

    class MaskBSDF(delta_bsdf_base()):
        """Binary chrome-on-quartz mask: delta pass-through weighted by T_q or 0."""

        def __init__(self, props):
            super().__init__(props)
            self.geom = None
            self.open = mi.Float(0.0)
            self.center = [0.0, 0.0]

        def set_pattern(self, pattern: np.ndarray, geom: dict, center_xy):
            self.open = mi.Float(np.ascontiguousarray(pattern, dtype=np.float32).ravel())
            self.geom = geom
            self.center = [float(center_xy[0]), float(center_xy[1])]

        def sample(self, ctx, si, sample1, sample2, active=True):
            idx, inside = cell_index(si.p.x - self.center[0], si.p.y - self.center[1], self.geom)
            o = dr.gather(mi.Float, self.open, idx, active & inside)
            o = dr.select(inside, o, 0.0)
            n2 = 1.0
            lam2 = dr.square(si.wavelengths * 1e-3)
            for b, c in zip((0.6961663, 0.4079426, 0.8974794),
                            (0.0684043 ** 2, 0.1162414 ** 2, 9.896161 ** 2)):
                n2 = n2 + b * lam2 / (lam2 - c)
            n = dr.sqrt(n2)
            R = dr.square((n - 1.0) / (n + 1.0))
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = -si.wi
            bs.pdf = 1.0
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DeltaTransmission)
            bs.sampled_component = 0
            w = (1.0 - R) / (1.0 + R) * o
            return bs, dr.select(active, mi.Spectrum(w), mi.Spectrum(0.0))

        def to_string(self):
            return "MaskBSDF[]"

    return MaskBSDF


def mask_shape(design, z: float, pattern: np.ndarray | None = None) -> dict:
    """The mask plate at ``z`` (a square of ``mask_size_mm``, on the axis) with its BSDF.

    ``pattern`` defaults to ``design.mask_pattern()``; pass an all-True array for an open
    aperture (e.g. to image the scene without coding).
    """
    mi = ensure_variant()
    register()
    if pattern is None:
        pattern = design.mask_pattern()
    bsdf = mi.load_dict({"type": PLUGIN})
    bsdf.set_pattern(pattern, _geometry(design), (0.0, 0.0))
    # The plate's holder is opaque: outside the patterned square the BSDF reads chrome, so a
    # plate three times larger also acts as the field stop around it.
    half = 1.5 * float(design.mask_size_mm)
    xf = mi.ScalarTransform4f().translate([0.0, 0.0, float(z)]).scale([half, half, 1.0])
    return {"type": "rectangle", "to_world": xf, "bsdf": bsdf}
