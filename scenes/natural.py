"""A natural scene: a real photograph lifted to spectra.

The photograph is one that ships with scikit-image (``astronaut``, ``chelsea``, ``coffee``,
``rocket``…). It is resized to the requested shape (area-averaging when shrinking), decoded from
sRGB to linear RGB and lifted to reflectance with the Mallett & Yuksel (2019) basis
(:func:`scenes.spectra.srgb_to_reflectance`, one matrix product), then lit by the illuminant. Under
D65 the cube renders back to (nearly) the photograph's colours.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from scenes._common import check_shape, wavelengths_or_default
from scenes.spectra import illuminant as _illuminant, srgb_to_reflectance

__all__ = ["PHOTOS", "photo", "natural"]

PHOTOS = ("astronaut", "chelsea", "coffee", "rocket", "immunohistochemistry")


def photo(image: str, shape) -> np.ndarray:
    """The scikit-image photograph ``image`` resized to ``shape``: float32 (H, W, 3) in [0, 1]."""
    import skimage.data
    from skimage.transform import resize

    if image not in PHOTOS:
        raise InputError(f"unknown photograph {image!r}; choose one of {', '.join(PHOTOS)}")
    h, w = check_shape(shape)
    rgb = getattr(skimage.data, image)()[..., :3].astype(np.float32) / 255.0
    if rgb.shape[:2] != (h, w):
        rgb = resize(rgb, (h, w, 3), order=1, anti_aliasing=True, preserve_range=True)
    return np.clip(rgb, 0.0, 1.0).astype(np.float32)


def natural(shape=(256, 256), wavelengths=None, *, image: str = "astronaut", illuminant: str = "D65") -> np.ndarray:
    """Radiance cube (H, W, L) float32 of the photograph ``image`` lifted to spectra."""
    wl = wavelengths_or_default(wavelengths)
    refl = srgb_to_reflectance(photo(image, shape), wl)
    return (refl * _illuminant(illuminant, wl).astype(np.float32)[None, None, :]).astype(np.float32)
