"""The kaleidoscope: four first-surface aluminium mirrors lining a square tube.

The tube runs from the diffuser (z = 0) to z = ``mirror_length_mm`` along the optical axis; its
four walls are ``tube_width_mm`` × ``mirror_length_mm`` rectangles at x = ±w/2 and y = ±w/2 with
Mitsuba's ``conductor`` BSDF (complex index of ``mirror_material``, spectral, so the reflectance
and its angle dependence are physical: Al reflects ~91–92 % in the visible). The rectangles are
one-sided and face inward: a ray meeting a wall from outside is absorbed, as by the tube's
back. Seen from the relay lens, the walls fold the diffuser into a 3×3 grid of virtual copies in
the diffuser plane; copies to the left/right (above/below) of the centre are mirror images, the
corners are reflected twice.
"""

from __future__ import annotations

from sim.optics.variant import ensure_variant

__all__ = ["mirror_shapes"]


def mirror_shapes(design, z0: float = 0.0) -> dict:
    """Mitsuba dicts of the four mirrors, keyed ``mirror_left`` … ``mirror_bottom``.

    Parameters
    ----------
    design : sim.optics.design.Design
        Uses ``tube_width_mm``, ``mirror_length_mm`` and ``mirror_material``.
    z0 : float
        z of the tube's entrance (the diffuser plane).
    """
    mi = ensure_variant()
    w, L = float(design.tube_width_mm), float(design.mirror_length_mm)
    zc = z0 + L / 2.0
    out = {}
    walls = {
        "mirror_left": ([-w / 2, 0.0, zc], [1.0, 0.0, 0.0]),
        "mirror_right": ([w / 2, 0.0, zc], [-1.0, 0.0, 0.0]),
        "mirror_bottom": ([0.0, -w / 2, zc], [0.0, 1.0, 0.0]),
        "mirror_top": ([0.0, w / 2, zc], [0.0, -1.0, 0.0]),
    }
    for name, (c, n) in walls.items():
        o = mi.ScalarPoint3f(*c)
        # local z -> inward normal, local y -> the tube axis (+z), local x -> across the wall
        xf = mi.ScalarTransform4f().look_at(origin=o, target=o + mi.ScalarVector3f(*n),
                                            up=mi.ScalarVector3f(0, 0, 1))
        xf = xf @ mi.ScalarTransform4f().scale([w / 2, L / 2, 1.0])
        out[name] = {
            "type": "rectangle",
            "to_world": xf,
            "bsdf": {"type": "conductor", "material": design.mirror_material},
        }
    return out
