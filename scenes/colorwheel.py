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

__all__ = ["sector_reflectances", "sector_index", "colorwheel", "wheel_weights",
           "wheel_weights_reference"]

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
    weights = wheel_weights(h, w, n, angle_deg, radius, hub, ss)
    spectra = refl * _illuminant(illuminant, wl)[None, :]
    return weighted_scene(weights, spectra)


def wheel_labels(y: np.ndarray, x: np.ndarray, h: int, w: int, n: int, angle_deg: float,
                 radius: float, hub: float) -> np.ndarray:
    """Region of sample points (y, x): sector 0..n-1, ``n`` the background, ``n + 1`` the hub."""
    cy, cx = h / 2.0, w / 2.0
    rad = 0.5 * min(h, w) * radius
    rr = np.hypot(y - cy, x - cx)
    label = sector_index(y, x, cy, cx, n, angle_deg)
    return np.where(rr > rad, n, np.where(rr < hub * rad, n + 1, label))


def wheel_weights_reference(h: int, w: int, n: int, angle_deg: float, radius: float,
                            hub: float, ss: int) -> np.ndarray:
    """Coverage (h, w, n + 2) float32 of every region: all ``ss``² sub-samples of every pixel
    labelled (the plain reference of :func:`wheel_weights`)."""
    y, x = supersample_grid(h, w, ss)
    label = wheel_labels(y, x, h, w, n, angle_deg, radius, hub)
    return np.stack([coverage(label == k, h, w, ss) for k in range(n + 2)], axis=-1)


# A pixel whose centre lies farther than this (pixels) from every edge of the wheel has all its
# sub-samples in one region: they lie within sqrt(2)/2 of the centre, and float32 labelling
# errs by under 10^-2 pixel (the margin's slack is 0.04) on frames up to 10^5 pixels across.
_INTERIOR_MARGIN = 0.75


def wheel_weights(h: int, w: int, n: int, angle_deg: float, radius: float, hub: float,
                  ss: int) -> np.ndarray:
    r"""Coverage (h, w, n + 2) float32 of every region, equal to the bit to
    :func:`wheel_weights_reference`.

    Only pixels near an edge (the rim, the hub's circle, a sector boundary) are sub-sampled,
    with the reference's own float32 arithmetic; every other pixel lies wholly in the region of
    its centre. A pixel at distance :math:`r` from the centre and angle :math:`\delta` from the
    nearest sector boundary lies :math:`r\sin\delta` from it (:math:`\delta \le 90°` since
    :math:`n \ge 2`).
    """
    cy, cx = h / 2.0, w / 2.0
    rad = 0.5 * min(h, w) * radius
    m = _INTERIOR_MARGIN
    dy = cy - (np.arange(h) + 0.5)[:, None]
    dx = (np.arange(w) + 0.5)[None, :] - cx
    r = np.hypot(dy, dx)
    step = 360.0 / n
    phase = np.mod(np.degrees(np.arctan2(dy, dx)) - float(angle_deg), 360.0)
    sector = np.floor(phase / step).astype(np.int64) % n
    within = np.mod(phase, step)
    off_ray = r * np.sin(np.radians(np.minimum(within, step - within)))
    inner = hub * rad
    label = np.where(r > rad, n, np.where(r < inner, n + 1, sector))
    edge = (np.abs(r - rad) <= m) | (np.abs(r - inner) <= m) | \
        ((r > inner - m) & (r < rad + m) & (off_ray <= m))
    weights = np.zeros((h, w, n + 2), np.float32)
    ii, jj = np.nonzero(~edge)
    weights[ii, jj, label[ii, jj]] = 1.0
    ie, je = np.nonzero(edge)
    if ie.size:
        # The reference's sub-sample coordinates (scenes._common.supersample_grid), float32.
        t = (np.arange(ss, dtype=np.float32) + 0.5) / ss
        y = ie.astype(np.float32)[:, None, None] + t[None, :, None]
        x = je.astype(np.float32)[:, None, None] + t[None, None, :]
        y, x = np.broadcast_arrays(y, x)
        sub = wheel_labels(y, x, h, w, n, angle_deg, radius, hub)
        for k in range(n + 2):
            weights[ie, je, k] = (sub == k).mean(axis=(1, 2), dtype=np.float32)
    return weights
