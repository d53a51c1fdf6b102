r"""Where each view's light begins: view images that start before the calibrated offsets.

The line captures fix where a scene column lands in every band (the offsets :math:`o_{k,l}`,
whole columns removed per view), and the shifted model puts view column :math:`x` of band
:math:`l` on box column :math:`x + o_{k,l}`: view column 0 is the first box column the bluest
band can reach.  But a view's mask region need not begin there.  On the paper's design the
left, top and bottom views' mask images hold light well *before* their offsets in every band
(from the box's first column in the bluest bands, which the box cuts): those views code scene
columns that a view image starting at column 0 leaves out, and the model would predict none
of that light (docs/calibration.md gives the leads measured).

The *lead* of view :math:`k` is how far its light begins before the offsets,

.. math:: e_k = \max_l \bigl(o_{k,l} - x^{\mathrm{lit}}_{k,l}\bigr),

with :math:`x^{\mathrm{lit}}_{k,l}` the first box column of band :math:`l`'s mask image whose
column mean exceeds ``level`` × the view's typical open level (as in
:func:`~recon.calibration.store.coded_columns`).  A calibration records whole leads
:math:`E_k = \lceil e_k - \text{tolerance}\rceil^+` (``view_leads``, :func:`lead_columns`), and
the shifted model (:func:`~recon.calibration.operator.operator_from_calibration`) starts view
:math:`k`'s image :math:`E_k` columns earlier:

.. math:: o'_{k,l} = o_{k,l} - E_k, \qquad H'_k = T(E_k)\, H_k, \qquad W_{v,k} = W_v + E_k,

(:math:`T(t)` the translation by :math:`t` along x).  The reconstruction grid does not change:
the centre view keeps :math:`E_0 = 0` (it *is* the grid), and view pixels whose scene point
falls off the grid see nothing (:class:`~recon.operators.warp.HomographyWarp`).  Band images
that now begin left of the box lose those columns
(:class:`~recon.operators.calibrated.CalibratedCassi` drops them); the mask images are dark
there anyway.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from recon.errors import InputError

__all__ = ["measure_leads", "lead_columns", "with_leads", "led_view"]


def measure_leads(mask_images, offsets, level: float = 0.1) -> np.ndarray:
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

    Raises
    ------
    InputError
        Mismatched shapes, or a view whose mask images hold no light.
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
        # Bands with no lit column say nothing about where the view begins.
        seen = on.any(axis=1)
        out[k] = float(np.max(o[k, seen] - on[seen].argmax(axis=1)))
    return out


def lead_columns(cal, level: float = 0.1, tolerance: float = 0.25) -> np.ndarray:
    r"""(K,) int64 :math:`E_k`: the whole leads of a calibration's views (centre 0).

    Parameters
    ----------
    cal : recon.calibration.Calibration
    level : float
        As for :func:`measure_leads`.
    tolerance : float
        Leads up to this much past a whole column are rounded down (lit columns are found to
        a pixel, the offsets to a few hundredths).

    Returns
    -------
    (K,) int64
        At most the dispersion's span :math:`\lceil\max o\rceil` (a longer lead would be another
        view's light in the box) and less than the view width.
    """
    e = measure_leads(cal.mask_images, cal.offsets, level)
    span = math.ceil(float(cal.offsets.max()) - 1e-6)
    cap = min(span, cal.view_shape[1] - 1)
    leads = np.clip(np.ceil(e - tolerance), 0, cap).astype(np.int64)
    leads[list(cal.view_ids).index(0)] = 0
    return leads


def with_leads(cal, level: float = 0.1, tolerance: float = 0.25):
    """``cal`` with its ``view_leads`` measured (:func:`lead_columns`); everything else shared."""
    return dataclasses.replace(cal, view_leads=lead_columns(cal, level, tolerance))


def led_view(homography, offsets, lead: int):
    r"""View :math:`k`'s homography and offsets with its image started ``lead`` columns earlier:
    :math:`T(E)\,H` and :math:`o - E`."""
    if lead == 0:
        return homography, offsets
    t = np.eye(3)
    t[0, 2] = lead
    m = t @ np.asarray(homography, dtype=np.float64)
    return m / m[2, 2], np.asarray(offsets, dtype=np.float64) - lead
