"""Scenes by name, and cube files resampled to a design's bands.

:func:`get_scene` builds a built-in scene (:func:`list_scenes`) or, when ``name`` is a path to a
cube file (anything :func:`recon.io.cubes.read_cube` reads: spectral EXR, ``.npz``, ``.npy``,
``.mat``, a CAVE folder), loads it, resamples it linearly in λ onto ``wavelengths`` and, when
``shape`` is given, resizes it spatially (bilinear, anti-aliased when shrinking).
"""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Callable

import numpy as np

from recon.errors import InputError
from scenes._common import check_shape, wavelengths_or_default

__all__ = ["list_scenes", "get_scene", "load_cube_scene", "resample_bands"]

_CUBE_SUFFIXES = {".exr", ".npz", ".npy", ".mat"}


def _builders() -> dict[str, Callable[..., np.ndarray]]:
    from scenes import calibration, colorchecker, colorwheel, natural, reflectances, resolution

    return {
        "colorchecker": colorchecker.colorchecker,
        "colorwheel": colorwheel.colorwheel,
        "siemens_star": resolution.siemens_star,
        "bars": resolution.bars,
        "natural": natural.natural,
        "reflectances": reflectances.reflectance_mosaic,
        "checkerboard": calibration.checkerboard,
        "white": calibration.white,
        "line": calibration.line,
    }


def list_scenes() -> list[str]:
    """Names of the built-in scenes."""
    return sorted(_builders())


def resample_bands(cube: np.ndarray, src_wl, dst_wl) -> np.ndarray:
    """Linear interpolation of a cube (H, W, L_src) along λ onto ``dst_wl`` → (H, W, L_dst).

    ``dst_wl`` must lie inside [src_wl[0], src_wl[-1]] (no extrapolation), else InputError.
    """
    src = np.asarray(src_wl, dtype=np.float64)
    dst = np.asarray(dst_wl, dtype=np.float64)
    if src.size != cube.shape[-1]:
        raise InputError(f"cube has {cube.shape[-1]} bands but {src.size} wavelengths")
    if src.size > 1 and np.any(np.diff(src) <= 0):
        raise InputError("cube wavelengths must be strictly increasing")
    if dst[0] < src[0] - 1e-6 or dst[-1] > src[-1] + 1e-6:
        raise InputError(
            f"cube covers {src[0]:g}–{src[-1]:g} nm but {dst[0]:g}–{dst[-1]:g} nm are needed"
        )
    if src.size == dst.size and np.allclose(src, dst, atol=1e-6):
        return np.ascontiguousarray(cube, dtype=np.float32)
    out = np.empty(cube.shape[:2] + (dst.size,), dtype=np.float32)
    for k, lam in enumerate(dst):  # one output band at a time: a blend of two input bands
        i = int(np.clip(np.searchsorted(src, lam, side="right") - 1, 0, max(src.size - 2, 0)))
        if src.size == 1:
            out[:, :, k] = cube[:, :, 0]
            continue
        t = float(np.clip((lam - src[i]) / (src[i + 1] - src[i]), 0.0, 1.0))
        out[:, :, k] = (1.0 - t) * cube[:, :, i] + t * cube[:, :, i + 1]
    return out


def load_cube_scene(path, shape=None, wavelengths=None, *, file_wavelengths=None, key: str | None = None) -> np.ndarray:
    """A cube file resampled to ``wavelengths`` (and resized to ``shape`` if given)."""
    from recon.io.cubes import read_cube

    wl = wavelengths_or_default(wavelengths)
    cube, src_wl = read_cube(path, key=key, wavelengths=file_wavelengths)
    if src_wl is None:
        raise InputError(f"{path}: the file does not give wavelengths; pass file_wavelengths")
    cube = np.asarray(cube, dtype=np.float32)
    if cube.ndim != 3:
        raise InputError(f"{path}: a cube must be (H, W, L), got shape {cube.shape}")
    if not np.all(np.isfinite(cube)):
        raise InputError(f"{path}: the cube holds non-finite values")
    if np.any(cube < 0):
        raise InputError(f"{path}: the cube holds negative radiance")
    out = resample_bands(cube, src_wl, wl)
    if shape is not None:
        h, w = check_shape(shape)
        if out.shape[:2] != (h, w):
            from skimage.transform import resize

            out = resize(out, (h, w, out.shape[2]), order=1, anti_aliasing=True,
                         preserve_range=True).astype(np.float32)
    return np.clip(out, 0.0, None)


def _is_path(name: str) -> bool:
    p = Path(name)
    return p.suffix.lower() in _CUBE_SUFFIXES or "/" in name or "\\" in name or p.is_dir()


def get_scene(name: str, shape=(256, 256), wavelengths=None, **params) -> tuple[np.ndarray, np.ndarray]:
    """Build the scene ``name`` (or load a cube file) → (cube (H, W, L) float32, wavelengths (L,)).

    Parameters
    ----------
    name : str
        A built-in scene (:func:`list_scenes`) or the path of a cube file.
    shape : (int, int)
        (H, W). For a file, ``None`` keeps the file's size.
    wavelengths : array_like, optional
        Band centres (nm); 450–700 nm step 10 by default.
    **params
        Scene parameters (see each scene function); unknown names raise InputError.
    """
    wl = wavelengths_or_default(wavelengths)
    name = str(name)
    builders = _builders()
    if name in builders:
        fn = builders[name]
        allowed = {p for p, v in inspect.signature(fn).parameters.items() if v.kind == v.KEYWORD_ONLY}
        unknown = sorted(set(params) - allowed)
        if unknown:
            raise InputError(
                f"scene {name!r} has no parameter(s) {', '.join(unknown)}; it takes: "
                f"{', '.join(sorted(allowed)) or 'none'}"
            )
        cube = fn(check_shape(shape), wl, **params)
    elif _is_path(name):
        allowed = {"file_wavelengths", "key"}
        unknown = sorted(set(params) - allowed)
        if unknown:
            raise InputError(f"a cube file takes only {', '.join(sorted(allowed))}, not {', '.join(unknown)}")
        cube = load_cube_scene(name, shape, wl, **params)
    else:
        raise InputError(f"unknown scene {name!r}; built-in scenes: {', '.join(list_scenes())}")
    cube = np.ascontiguousarray(cube, dtype=np.float32)
    if cube.shape[-1] != wl.size or cube.ndim != 3:
        raise InputError(f"scene {name!r} produced shape {cube.shape}, expected (H, W, {wl.size})")
    if not np.all(np.isfinite(cube)) or np.any(cube < 0):
        raise InputError(f"scene {name!r} is not finite and non-negative")
    return cube, wl.copy()
