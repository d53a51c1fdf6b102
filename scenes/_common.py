"""Helpers shared by the scene modules: argument checks and the default band grid."""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from scenes.spectra import check_wavelengths

#: The paper's bands, used when a scene is asked for without wavelengths.
DEFAULT_WAVELENGTHS = np.arange(450.0, 701.0, 10.0)


def check_shape(shape) -> tuple[int, int]:
    """(H, W) as two integers ≥ 2."""
    try:
        h, w = (int(s) for s in shape)
    except (TypeError, ValueError):
        raise InputError(f"scene shape must be (H, W), got {shape!r}") from None
    if h < 2 or w < 2 or h * w > 64_000_000:
        raise InputError(f"scene shape must be between 2×2 and 64 Mpixel, got {h}×{w}")
    return h, w


def wavelengths_or_default(wavelengths) -> np.ndarray:
    return check_wavelengths(DEFAULT_WAVELENGTHS if wavelengths is None else wavelengths)


def flat_scene(labels: np.ndarray, spectra: np.ndarray) -> np.ndarray:
    """Cube (H, W, L) float32 whose pixel is ``spectra[labels]`` (a gather, no per-pixel loop)."""
    return np.asarray(spectra, np.float32)[labels]


def weighted_scene(weights: np.ndarray, spectra: np.ndarray) -> np.ndarray:
    """Cube = weights (H, W, K) @ spectra (K, L): area-weighted mixtures at anti-aliased edges."""
    return (np.asarray(weights, np.float32) @ np.asarray(spectra, np.float32)).astype(np.float32)


def supersample_grid(h: int, w: int, ss: int) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel sample coordinates (y, x) in pixel units, shape (h·ss, w·ss), pixel centres at
    integer + 0.5."""
    t = (np.arange(ss, dtype=np.float32) + 0.5) / ss
    ys = (np.arange(h, dtype=np.float32)[:, None] + t[None, :]).ravel()
    xs = (np.arange(w, dtype=np.float32)[:, None] + t[None, :]).ravel()
    return np.meshgrid(ys, xs, indexing="ij")


def coverage(mask_ss: np.ndarray, h: int, w: int, ss: int) -> np.ndarray:
    """Fraction of each pixel's ``ss``² sub-samples where ``mask_ss`` is True, float32 (h, w)."""
    return mask_ss.reshape(h, ss, w, ss).mean(axis=(1, 3), dtype=np.float32)
