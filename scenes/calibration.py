"""Calibration targets (paper Sec. 4.1–4.2): checkerboard, uniform white, thin vertical line, and
the comb (a lattice of single lit texels) that measures every pixel's footprint.

Spectrally flat reflectors under an equal-energy illuminant by default (``illuminant="E"``), so a
monochromatic capture at any band sees the same target. Band-by-band captures are made by the
simulator selecting one band, not here.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from scenes._common import check_shape, wavelengths_or_default
from scenes.spectra import illuminant as _illuminant

__all__ = ["checkerboard", "white", "line", "comb"]


def _flat(refl: np.ndarray, wl: np.ndarray, illum: str) -> np.ndarray:
    return (refl.astype(np.float32)[:, :, None]
            * _illuminant(illum, wl).astype(np.float32)[None, None, :]).astype(np.float32)


def checkerboard(
    shape=(256, 256),
    wavelengths=None,
    *,
    square: int = 16,
    illuminant: str = "E",
    white: float = 0.9,
    black: float = 0.05,
) -> np.ndarray:
    """Checkerboard of ``square``-pixel squares, centred on the frame, top-left square white
    when the centre falls on a corner (OpenCV finds its inner corners)."""
    h, w = check_shape(shape)
    wl = wavelengths_or_default(wavelengths)
    if int(square) < 2 or not 0 <= black < white <= 1:
        raise InputError("need square ≥ 2 px and 0 ≤ black < white ≤ 1")
    s = int(square)
    ry = (np.arange(h) - h // 2) // s
    rx = (np.arange(w) - w // 2) // s
    on = ((ry[:, None] + rx[None, :]) % 2 == 0)
    return _flat(np.where(on, white, black), wl, illuminant)


def white(shape=(256, 256), wavelengths=None, *, illuminant: str = "E", reflectance: float = 1.0) -> np.ndarray:
    """Uniform white target (H, W, L): the flat-field used to capture each view's shifted mask."""
    h, w = check_shape(shape)
    wl = wavelengths_or_default(wavelengths)
    if not 0 < reflectance <= 1:
        raise InputError("reflectance must lie in (0, 1]")
    return _flat(np.full((h, w), float(reflectance)), wl, illuminant)


def line(
    shape=(256, 256),
    wavelengths=None,
    *,
    width: int = 1,
    column: int | None = None,
    illuminant: str = "E",
    reflectance: float = 1.0,
) -> np.ndarray:
    """A thin bright vertical line ``width`` px wide at ``column`` (default: the centre) on black:
    monochromatic captures of it give the dispersion φ(λ)."""
    h, w = check_shape(shape)
    wl = wavelengths_or_default(wavelengths)
    c = w // 2 if column is None else int(column)
    if int(width) < 1 or not 0 <= c < w or c + int(width) > w:
        raise InputError(f"line of width {width} at column {c} does not fit a width of {w}")
    refl = np.zeros((h, w))
    refl[:, c:c + int(width)] = float(reflectance)
    return _flat(refl, wl, illuminant)


def comb(
    shape=(256, 256),
    wavelengths=None,
    *,
    period=(3, 5),
    phase=(0, 0),
    illuminant: str = "E",
    reflectance: float = 1.0,
) -> np.ndarray:
    r"""A lattice of single lit texels on black: texel :math:`(y, x)` is lit when
    :math:`y \equiv a \pmod{P_y}` and :math:`x \equiv b \pmod{P_x}`.

    The :math:`P_y P_x` phases :math:`(a, b)` together light every texel exactly once; when a
    pixel's footprint on the target is smaller than the period, each phase shows the pixel at
    most one lit texel, so band-pass captures of all phases measure the pixel's weight for every
    texel it sees (:mod:`recon.calibration.footprint`).
    """
    h, w = check_shape(shape)
    wl = wavelengths_or_default(wavelengths)
    try:
        py, px = (int(v) for v in period)
        a, b = (int(v) for v in phase)
    except (TypeError, ValueError):
        raise InputError(f"period and phase must be pairs of integers, got {period!r}, "
                         f"{phase!r}") from None
    if py < 1 or px < 1 or py > h or px > w:
        raise InputError(f"comb period {(py, px)} must be positive and fit the target {(h, w)}")
    if not (0 <= a < py and 0 <= b < px):
        raise InputError(f"comb phase {(a, b)} must lie in [0, {py}) x [0, {px})")
    if not 0 < reflectance <= 1:
        raise InputError("reflectance must lie in (0, 1]")
    refl = np.zeros((h, w))
    refl[a::py, b::px] = float(reflectance)
    return _flat(refl, wl, illuminant)
