"""Resolution targets: a Siemens star and groups of bars, spectrally grey.

Both are binary reflectance patterns (``white`` / ``black`` reflectances, flat in λ) under an
illuminant, anti-aliased with ``aa``² sub-samples per pixel. A Siemens star with S spoke pairs
has local period 2πr/S at radius r, so the radius at which the spokes blur out measures the
resolution directly.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from scenes._common import check_shape, coverage, supersample_grid, wavelengths_or_default
from scenes.spectra import illuminant as _illuminant

__all__ = ["siemens_star", "bars"]


def _grey(fraction_white: np.ndarray, wl: np.ndarray, white: float, black: float, illum: str) -> np.ndarray:
    if not 0.0 <= black < white <= 1.0:
        raise InputError("need 0 ≤ black < white ≤ 1 reflectances")
    refl = black + (white - black) * fraction_white
    return (refl[:, :, None] * _illuminant(illum, wl)[None, None, :].astype(np.float32)).astype(np.float32)


def siemens_star(
    shape=(256, 256),
    wavelengths=None,
    *,
    spokes: int = 36,
    illuminant: str = "D65",
    white: float = 0.9,
    black: float = 0.05,
    aa: int = 4,
) -> np.ndarray:
    """Siemens star with ``spokes`` white/black spoke pairs filling the frame (H, W, L)."""
    h, w = check_shape(shape)
    wl = wavelengths_or_default(wavelengths)
    if int(spokes) < 2 or not 1 <= int(aa) <= 16:
        raise InputError("need spokes ≥ 2 and 1 ≤ aa ≤ 16")
    ss = int(aa)
    y, x = supersample_grid(h, w, ss)
    theta = np.arctan2(h / 2.0 - y, x - w / 2.0)
    inside = np.hypot(y - h / 2.0, x - w / 2.0) <= 0.5 * min(h, w) * 0.95
    on = (np.sin(int(spokes) * theta) >= 0) & inside
    return _grey(coverage(on, h, w, ss), wl, white, black, illuminant)


def bars(
    shape=(256, 256),
    wavelengths=None,
    *,
    periods=(2, 3, 4, 6, 8, 12, 16),
    orientation: str = "vertical",
    illuminant: str = "D65",
    white: float = 0.9,
    black: float = 0.05,
) -> np.ndarray:
    """Groups of bars of the given periods (px, half white), side by side across the frame.

    ``orientation="vertical"`` gives vertical bars (varying along x, the dispersion axis);
    ``"horizontal"`` varies along y.
    """
    h, w = check_shape(shape)
    wl = wavelengths_or_default(wavelengths)
    p = np.asarray(periods, dtype=np.float64).ravel()
    if p.size == 0 or np.any(~np.isfinite(p)) or np.any(p < 1):
        raise InputError("bar periods must be ≥ 1 px")
    if orientation not in ("vertical", "horizontal"):
        raise InputError("orientation must be 'vertical' or 'horizontal'")
    n = w if orientation == "vertical" else h
    group = np.minimum((np.arange(n) * p.size) // n, p.size - 1)
    start = (np.arange(p.size) * n) // p.size
    local = np.arange(n) - start[group]
    profile = ((local % p[group]) < p[group] / 2.0).astype(np.float32)
    # one dark pixel at the start of each group keeps neighbouring groups apart
    profile[local < 1] = 0.0
    frac = np.broadcast_to(profile[None, :] if orientation == "vertical" else profile[:, None], (h, w))
    return _grey(np.ascontiguousarray(frac), wl, white, black, illuminant)
