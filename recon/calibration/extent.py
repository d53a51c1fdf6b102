r"""Where each view's light begins: view images that start before the calibrated offsets.

The line captures fix where a scene column lands in every band (the offsets :math:`o_{k,l}`,
whole columns removed per view), and the operator puts view column :math:`x` of band :math:`l`
on box column :math:`x + o_{k,l}`: view column 0 is the first column of the box that the
bluest band can reach.  But a view's mask region need not begin there.  On the paper's design
the left, top and bottom views' mask images hold light 12–19 px *before* their offsets in every
band (from the box's first column in the bluest bands, which the box cuts): the mask codes scene
columns there that a view image starting at column 0 leaves out, and the model predicts none of
that light (up to 55 % model error in those columns).

The *lead* of view :math:`k` is how far its light begins before the offsets,

.. math:: e_k = \max_l \bigl(o_{k,l} - x^{\mathrm{lit}}_{k,l}\bigr),

with :math:`x^{\mathrm{lit}}_{k,l}` the first box column of band :math:`l`'s mask image whose
column mean exceeds ``level`` × the view's typical open level (as in
:func:`~recon.calibration.store.coded_columns`).  :func:`extend_views` starts every view image
:math:`E = \lceil\max_k e_k\rceil` columns earlier, and the reconstruction grid with it, so that
the centre view stays the identity:

.. math:: o'_{k,l} = o_{k,l} - E, \qquad H'_k = T(E)\, H_k\, T(-E), \qquad
          W'_v = W_m - \lceil\max o'\rceil = W_v + E,

(:math:`T(t)` the translation by :math:`t` along x), and the grid's width is recomputed with
:func:`~recon.calibration.store.union_width`.  Bands whose image now begins left of the box
lose those columns (:class:`~recon.operators.CalibratedCassi` drops them); their mask image is
dark there anyway.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from recon.errors import InputError

__all__ = ["view_leads", "extend_views"]


def view_leads(mask_images, offsets, level: float = 0.1) -> np.ndarray:
    r"""(K,) :math:`e_k`: how many columns before its offsets each view's light begins.

    Parameters
    ----------
    mask_images : (K, L, Hv, Wm) array_like
    offsets : (K, L) array_like
        Box column where each band's view column 0 lands.
    level : float
        A column is lit when its mean exceeds ``level`` × the view's median lit column mean.

    Returns
    -------
    (K,) float64
        Negative where the light begins after the offsets in every band.
    """
    c = np.asarray(mask_images)
    o = np.asarray(offsets, dtype=np.float64)
    if c.ndim != 4 or o.shape != c.shape[:2]:
        raise InputError(f"need (K, L, Hv, Wm) mask images and (K, L) offsets, got "
                         f"{c.shape} and {o.shape}")
    out = np.empty(c.shape[0], dtype=np.float64)
    for k in range(c.shape[0]):
        prof = c[k].mean(axis=1, dtype=np.float64)                  # (L, Wm)
        lit = prof[prof > 0]
        if lit.size == 0:
            raise InputError(f"view {k}: the mask images hold no light")
        on = prof > level * float(np.median(lit))
        first = np.where(on.any(axis=1), on.argmax(axis=1), c.shape[3])
        # Bands with no lit column say nothing about where the view begins.
        seen = on.any(axis=1)
        out[k] = float(np.max(o[k, seen] - first[seen])) if seen.any() else -np.inf
    return out


def extend_views(cal, level: float = 0.1, tolerance: float = 0.25):
    r"""The calibration with every view image starting :math:`E` columns earlier.

    Parameters
    ----------
    cal : recon.calibration.Calibration
    level : float
        As for :func:`view_leads`.
    tolerance : float
        Leads up to this much past a whole column are rounded down (the lit columns are found
        to a pixel; the offsets to a few hundredths).

    Returns
    -------
    Calibration
        ``cal`` itself when no view leads (:math:`E = 0`); otherwise a copy with offsets,
        homographies and cube shape changed as in the module docstring.  Everything else is
        shared with ``cal``.

    Raises
    ------
    InputError
        The calibration holds the smeared model's kernels (their columns are box columns that
        must stay in the box) or the footprint model (whose grid is the target's, not this).
    """
    from recon.calibration.store import _SNAP, union_width

    leads = view_leads(cal.mask_images, cal.offsets, level)
    lead = max(0, math.ceil(float(np.max(leads)) - tolerance))
    if lead == 0:
        return cal
    if cal.tap_start is not None or cal.has_footprint:
        raise InputError("extend the views before the footprint model is measured, and not "
                         "with the smeared model's kernels (box columns that must stay in the box)")
    # A lead longer than the dispersion itself would be light from another view in the box.
    span = math.ceil(float(cal.offsets.max()) - _SNAP)
    lead = min(lead, span)
    t = np.eye(3)
    t[0, 2] = lead
    ti = np.linalg.inv(t)
    hs = np.stack([t @ h @ ti for h in cal.homographies])
    hs /= hs[:, 2:3, 2:3]
    offsets = cal.offsets - lead
    wm = cal.mask_images.shape[3]
    wv = wm - math.ceil(float(offsets.max()) - _SNAP)
    width = union_width(cal.mask_images, offsets, hs, wv)
    return dataclasses.replace(cal, offsets=offsets, homographies=hs,
                               cube_shape=(cal.cube_shape[0], width, cal.n_bands))
