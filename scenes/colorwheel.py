"""A spectral colour wheel: N sectors painted with measured reflectances, rotatable for video.

Sector spectra are the ColorChecker's chromatic patches (measured reflectances), ordered by hue
(the angle of their sRGB colour in the a*b*-like opponent plane) and spread evenly over that
list, so N = 6 gives red, yellow, green, cyan, blue and magenta-like sectors. The disc of radius
``radius`` × min(H, W)/2 sits on a dark background with a white hub; edges are anti-aliased by
``aa``² sub-samples per pixel. Sector *k* spans polar angles
[angle_deg + k·360/N, angle_deg + (k+1)·360/N), measured counter-clockwise from +x with y up, so
advancing ``angle_deg`` by 360/N moves every sector onto the next one's place.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from scenes._common import check_shape, coverage, supersample_grid, wavelengths_or_default, weighted_scene
from scenes.spectra import colorchecker_reflectances, illuminant as _illuminant

__all__ = ["sector_reflectances", "sector_index", "colorwheel"]

# ColorChecker patch indices of the chromatic patches (skin tones and neutrals excluded).
_CHROMATIC = [2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17]


def sector_reflectances(n: int, wavelengths) -> np.ndarray:
    """Reflectances (n, L) of the n sectors: chromatic ColorChecker patches sorted by hue."""
    if not 2 <= int(n) <= len(_CHROMATIC):
        raise InputError(f"a colour wheel needs 2..{len(_CHROMATIC)} sectors, got {n}")
    grid = np.arange(400.0, 701.0, 10.0)
    r = colorchecker_reflectances(grid)[_CHROMATIC]
    # Opponent-colour hue from broad red/green/blue band averages of the reflectance.
    red, green, blue = (r[:, (grid >= lo) & (grid < hi)].mean(1) for lo, hi in
                        ((590, 701), (500, 590), (400, 500)))
    hue = np.degrees(np.arctan2(np.sqrt(3.0) * (green - blue), 2 * red - green - blue)) % 360.0
    order = np.array(_CHROMATIC)[np.argsort(hue)]
    pick = order[np.round(np.arange(int(n)) * len(order) / int(n)).astype(int)]
    return colorchecker_reflectances(wavelengths)[pick]


def sector_index(y: np.ndarray, x: np.ndarray, cy: float, cx: float, n: int, angle_deg: float) -> np.ndarray:
    """Sector of points (y, x) (pixel units, y down) for a wheel centred at (cy, cx)."""
    theta = np.degrees(np.arctan2(cy - y, x - cx)) - float(angle_deg)
    return (np.floor((theta % 360.0) / (360.0 / n)).astype(np.int64)) % n


def colorwheel(
    shape=(256, 256),
    wavelengths=None,
    *,
    sectors: int = 6,
    angle_deg: float = 0.0,
    illuminant: str = "D65",
    radius: float = 0.9,
    hub: float = 0.15,
    background_reflectance: float = 0.03,
    aa: int = 4,
) -> np.ndarray:
    """Radiance cube (H, W, L) float32 of an N-sector colour wheel rotated by ``angle_deg``."""
    h, w = check_shape(shape)
    wl = wavelengths_or_default(wavelengths)
    n, ss = int(sectors), int(aa)
    if not np.isfinite(angle_deg):
        raise InputError("angle_deg must be finite")
    if ss < 1 or ss > 16 or not 0 < radius <= 1 or not 0 <= hub < 1:
        raise InputError("need 1 ≤ aa ≤ 16, 0 < radius ≤ 1 and 0 ≤ hub < 1")
    refl = np.concatenate([sector_reflectances(n, wl),
                           np.full((1, wl.size), float(background_reflectance)),
                           np.ones((1, wl.size))])  # background, white hub
    y, x = supersample_grid(h, w, ss)
    cy, cx = h / 2.0, w / 2.0
    rad = 0.5 * min(h, w) * radius
    rr = np.hypot(y - cy, x - cx)
    label = sector_index(y, x, cy, cx, n, angle_deg)
    label = np.where(rr > rad, n, np.where(rr < hub * rad, n + 1, label))
    weights = np.stack([coverage(label == k, h, w, ss) for k in range(n + 2)], axis=-1)
    spectra = refl * _illuminant(illuminant, wl)[None, :]
    return weighted_scene(weights, spectra)
