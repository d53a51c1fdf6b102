"""The X-Rite ColorChecker Classic: 24 measured patch reflectances under a chosen illuminant.

Reflectances are N. Ohta's measurements shipped with colour-science
(``colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]``). The chart fills the frame as 6 columns ×
4 rows of cells; each patch is its cell minus a black margin (``border`` × the smaller cell side)
on every side, so patches are separated by black strips like the real chart's frame.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from scenes._common import check_shape, wavelengths_or_default
from scenes.spectra import colorchecker_reflectances, illuminant as _illuminant

__all__ = ["ROWS", "COLS", "patch_boxes", "colorchecker"]

ROWS, COLS = 4, 6


def patch_boxes(shape, border: float = 0.12) -> np.ndarray:
    """Pixel boxes of the 24 patches in chart order (row-major, dark skin first).

    Returns
    -------
    numpy.ndarray
        int (24, 4): ``row0, col0, row1, col1`` (end-exclusive).
    """
    h, w = check_shape(shape)
    if not 0.0 <= border < 0.5:
        raise InputError(f"border must lie in [0, 0.5), got {border}")
    ch, cw = h / ROWS, w / COLS
    m = border * min(ch, cw)
    r = np.arange(ROWS, dtype=np.float64)[:, None].repeat(COLS, 1).ravel()
    c = np.arange(COLS, dtype=np.float64)[None, :].repeat(ROWS, 0).ravel()
    boxes = np.stack([np.round(r * ch + m), np.round(c * cw + m),
                      np.round((r + 1) * ch - m), np.round((c + 1) * cw - m)], axis=1).astype(int)
    if np.any(boxes[:, 2] <= boxes[:, 0]) or np.any(boxes[:, 3] <= boxes[:, 1]):
        raise InputError(f"shape {h}×{w} is too small for a 6×4 chart")
    return boxes


def colorchecker(
    shape=(240, 360),
    wavelengths=None,
    *,
    illuminant: str = "D65",
    border: float = 0.12,
    border_reflectance: float = 0.03,
) -> np.ndarray:
    """Radiance cube (H, W, L) float32 of the ColorChecker under ``illuminant`` (D65, A, LED, E).

    Patch *k* holds reflectance_k(λ) · illuminant(λ); the frame holds the flat
    ``border_reflectance`` (black plastic, ≈ 3 %).
    """
    h, w = check_shape(shape)
    wl = wavelengths_or_default(wavelengths)
    if not 0.0 <= border_reflectance <= 1.0:
        raise InputError("border_reflectance must lie in [0, 1]")
    refl = np.concatenate([colorchecker_reflectances(wl),
                           np.full((1, wl.size), float(border_reflectance))])
    labels = np.full((h, w), 24, dtype=np.int16)
    for k, (r0, c0, r1, c1) in enumerate(patch_boxes((h, w), border)):
        labels[r0:r1, c0:c1] = k
    spectra = (refl * _illuminant(illuminant, wl)[None, :]).astype(np.float32)
    return spectra[labels]
