"""Hyperspectral cube files: spectral OpenEXR, ``.npz``, ``.npy``, MATLAB ``.mat`` and CAVE PNGs.

In memory a cube is (H, W, L) float32 with wavelengths (L,) in nm (or ``None`` where the file
does not say).  Formats, chosen by the suffix (a path without a suffix is a CAVE folder):

``.exr`` — spectral OpenEXR
    One float32 channel per band named after the spectral OpenEXR layout of Fichet et al. (JCGT
    2021) for emissive images: ``S0.<wavelength>nm`` with the wavelength written with six
    decimals and a *comma* as the decimal separator, e.g. ``S0.450,000000nm``.  The header holds
    ``spectralLayoutVersion = "1.0"`` and ``wavelengths`` (a float-vector attribute, nm).
    OpenEXR sorts channels by name, so the reader orders bands by the wavelength parsed from each
    name (which is exact; the float32 header attribute is only cross-checked).
``.npz`` — arrays ``cube`` (H, W, L) and ``wavelengths`` (L,) (absent when unknown).
``.npy`` — the (H, W, L) array alone; wavelengths must come from elsewhere.
``.mat`` — MATLAB.  Written under ``img`` (the MST/TSA-Net key) plus ``wavelengths`` (1×L), as
    v5 (scipy, default) or v7.3 (HDF5, see :func:`recon.io.arrays.save_mat`).  Read from
    ``key`` if given, else ``img``, else ``cube``, else the single 3-D variable.
folder — CAVE layout
    ``<name>_01.png`` … ``<name>_NN.png``, 16-bit greyscale, band ``i`` at 400 + 10·(i − 1) nm
    (31 bands span 400–700 nm).  Values are ``uint16 / 65535``; writing requires values in
    [0, 1] and wavelengths on that grid.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from recon.errors import InputError
from recon.io.arrays import (
    _load_npy,
    _load_npz,
    _pick,
    check_array,
    check_file,
    load_mat,
    read_exr,
    save_mat,
    write_exr,
)
from recon.io.atomic import atomic_dir, atomic_path

__all__ = ["read_cube", "write_cube", "exr_channel_name", "parse_exr_channel", "cave_wavelengths",
           "CASSI_28_WAVELENGTHS", "standard_wavelengths"]

PathLike = str | os.PathLike

_EXR_CHANNEL = re.compile(r"^(?:S0\.)?(\d+(?:[.,]\d*)?)nm$")
_CAVE_BAND = re.compile(r"^(?P<name>.+)_(?P<idx>\d{2,3})\.png$", re.IGNORECASE)


def exr_channel_name(wavelength: float) -> str:
    """``S0.450,000000nm`` for 450 nm (spectral OpenEXR, emissive, comma decimal separator)."""
    return "S0." + f"{float(wavelength):.6f}".replace(".", ",") + "nm"


def parse_exr_channel(name: str) -> float | None:
    """The wavelength in nm of a spectral channel name, or None if it is not one."""
    m = _EXR_CHANNEL.match(name)
    return float(m.group(1).replace(",", ".")) if m else None


def cave_wavelengths(n_bands: int) -> np.ndarray:
    """400, 410, … nm: the CAVE band grid."""
    return 400.0 + 10.0 * np.arange(n_bands, dtype=np.float64)


#: The 28 band centres (nm) of the CASSI benchmark world (TSA-Net's real captures and the KAIST
#: and CAVE scenes as MST uses them): 450–650 nm, denser in the blue, where the prism disperses
#: more.  Its ``.mat`` files carry no wavelengths; these are what they mean.
CASSI_28_WAVELENGTHS = (453.3, 457.6, 462.1, 466.8, 471.6, 476.5, 481.6, 486.9, 492.4, 498.0,
                        503.9, 509.9, 516.2, 522.7, 529.5, 536.5, 543.8, 551.4, 558.6, 567.5,
                        575.3, 584.3, 594.4, 604.2, 614.4, 625.1, 636.3, 648.1)


def standard_wavelengths(n_bands: int) -> np.ndarray:
    """What a cube without wavelengths most likely means: :data:`CASSI_28_WAVELENGTHS` for 28
    bands, else ``n_bands`` evenly spaced over the same 450–650 nm."""
    if int(n_bands) == len(CASSI_28_WAVELENGTHS):
        return np.array(CASSI_28_WAVELENGTHS, dtype=np.float64)
    return np.linspace(450.0, 650.0, int(n_bands))


def _check_wavelengths(wl, n_bands: int, where) -> np.ndarray | None:
    if wl is None:
        return None
    w = np.asarray(wl)
    if w.dtype == bool or not (np.issubdtype(w.dtype, np.floating) or np.issubdtype(w.dtype, np.integer)):
        raise InputError(f"{where}: wavelengths have dtype {w.dtype}, expected real numbers")
    w = w.astype(np.float64).reshape(-1)
    if w.size != n_bands:
        raise InputError(f"{where}: {w.size} wavelengths for a cube of {n_bands} bands")
    if not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise InputError(f"{where}: wavelengths must be finite and positive")
    if n_bands > 1 and np.any(np.diff(w) <= 0):
        raise InputError(f"{where}: wavelengths must be strictly increasing")
    return w


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------
def read_cube(path: PathLike, *, key: str | None = None, wavelengths=None) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a cube (H, W, L) float32 and its wavelengths (L,) in nm, or None if unknown.

    Parameters
    ----------
    path : path-like
        A file (``.exr``, ``.npz``, ``.npy``, ``.mat``) or a CAVE folder.
    key : str, optional
        ``.mat``/``.npz`` variable holding the cube.
    wavelengths : array (L,), optional
        Overrides (or supplies) the wavelengths.

    Raises
    ------
    InputError
        For anything that is not a valid cube, naming the file.
    """
    p = Path(path)
    if p.is_dir():
        cube, wl = _read_cave(p)
    else:
        p = check_file(p)
        ext = p.suffix.lower()
        if ext == ".exr":
            cube, wl = _read_exr_cube(p)
        elif ext == ".npz":
            arrays = _load_npz(p)
            arr = _pick(arrays, p, key, 3, "cube", preferred=("cube",))
            cube = check_array(arr, p, ndim=3, what="cube")
            wl = arrays.get("wavelengths")
            wl = _check_wavelengths(wl, cube.shape[2], p) if wl is not None else None
        elif ext == ".npy":
            cube = check_array(_load_npy(p), p, ndim=3, what="cube")
            wl = None
        elif ext == ".mat":
            arrays = load_mat(p)
            arr = _pick(arrays, p, key, 3, "cube", preferred=("img", "cube"))
            cube = check_array(arr, p, ndim=3, what="cube")
            wl = arrays.get("wavelengths")
            wl = _check_wavelengths(wl, cube.shape[2], p) if wl is not None else None
        else:
            raise InputError(
                f"{p}: unsupported cube file type {ext or '(none)'}; use .exr, .npz, .npy, .mat or a CAVE folder"
            )
    if wavelengths is not None:
        wl = _check_wavelengths(wavelengths, cube.shape[2], p)
    return cube, wl


def _read_exr_cube(p: Path) -> tuple[np.ndarray, np.ndarray]:
    chans, header = read_exr(p)
    bands = []
    for name, pix in chans.items():
        wl = parse_exr_channel(name)
        if wl is None:
            raise InputError(f"{p}: channel {name!r} is not a spectral band (expected e.g. S0.450,000000nm)")
        bands.append((wl, name))
    bands.sort()
    wls = np.array([w for w, _ in bands])
    if len(set(wls.tolist())) != len(wls):
        raise InputError(f"{p}: two channels name the same wavelength")
    shapes = {chans[n].shape for _, n in bands}
    if len(shapes) != 1:
        raise InputError(f"{p}: channels have different sizes {sorted(shapes)}")
    for _, n in bands:
        if chans[n].dtype.kind == "u":
            raise InputError(f"{p}: channel {n!r} is UINT, expected HALF or FLOAT")
    cube = np.stack([chans[n] for _, n in bands], axis=-1)
    cube = check_array(cube, p, ndim=3, what="cube")
    hw = header.get("wavelengths")
    if hw is not None:
        hw = np.asarray(hw, dtype=np.float64).reshape(-1)
        if hw.size != wls.size or not np.allclose(hw, wls, rtol=1e-6, atol=1e-3):
            raise InputError(f"{p}: the 'wavelengths' header disagrees with the channel names")
    return cube, _check_wavelengths(wls, cube.shape[2], p)


def _read_cave(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    import imageio.v3 as iio

    found: dict[str, dict[int, Path]] = {}
    for f in folder.iterdir():
        m = _CAVE_BAND.match(f.name)
        if m and f.is_file():
            found.setdefault(m.group("name"), {})[int(m.group("idx"))] = f
    if not found:
        raise InputError(f"{folder}: no CAVE band images (<name>_01.png ...) in this folder")
    if len(found) > 1:
        raise InputError(f"{folder}: band images of several cubes ({', '.join(sorted(found))})")
    name, files = next(iter(found.items()))
    n = max(files)
    missing = [i for i in range(1, n + 1) if i not in files]
    if missing:
        raise InputError(f"{folder}: band image(s) {missing} of {name!r} are missing")
    bands = []
    for i in range(1, n + 1):
        f = check_file(files[i])
        try:
            img = iio.imread(f, plugin="pillow")
        except Exception as err:
            raise InputError(f"{f}: not a readable PNG (corrupt or truncated?)") from err
        if img.ndim == 3:
            # Some CAVE scenes store bands as RGB(A) PNGs with equal colour channels.
            img = img[..., 0]
        if img.ndim != 2:
            raise InputError(f"{f}: expected a greyscale image, got shape {img.shape}")
        if img.dtype == np.uint16:
            scale = 65535.0
        elif img.dtype == np.uint8:
            scale = 255.0
        else:
            raise InputError(f"{f}: pixel type {img.dtype}, expected 8- or 16-bit")
        bands.append(img.astype(np.float32) / np.float32(scale))
    if len({b.shape for b in bands}) != 1:
        raise InputError(f"{folder}: band images have different sizes")
    cube = check_array(np.stack(bands, axis=-1), folder, ndim=3, what="cube")
    return cube, cave_wavelengths(n)


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------
def write_cube(
    path: PathLike,
    cube,
    wavelengths=None,
    *,
    key: str = "img",
    mat_version: str = "5",
    cave_name: str | None = None,
    protect=(),
) -> Path:
    """Write a cube (H, W, L) atomically; the format follows the suffix (see the module notes).

    Parameters
    ----------
    path : path-like
        Output file, or a folder (no suffix) for the CAVE PNG layout.
    cube : array (H, W, L)
    wavelengths : array (L,), optional
        Required for ``.exr``; stored in ``.npz``/``.mat``; must be the CAVE grid for folders.
    key : str
        ``.mat`` variable name for the cube (``img``, as MST).
    mat_version : {"5", "7.3"}
    cave_name : str, optional
        Band file prefix for CAVE folders (default: the folder name).
    protect : iterable of path-like
        Input files that ``path`` must not overwrite.
    """
    p = Path(path)
    cube = np.asarray(cube)
    if cube.ndim != 3:
        raise InputError(f"{p}: a cube to write must be (H, W, L), got shape {cube.shape}")
    cube = check_array(cube, p, ndim=3, what="cube to write")
    wl = _check_wavelengths(wavelengths, cube.shape[2], p)
    ext = p.suffix.lower()
    if ext == ".exr":
        if wl is None:
            raise InputError(f"{p}: spectral OpenEXR needs the wavelengths of the bands")
        names = [exr_channel_name(w) for w in wl]
        if len(set(names)) != len(names):
            raise InputError(f"{p}: wavelengths closer than 1e-6 nm cannot be told apart")
        header = {"spectralLayoutVersion": "1.0", "wavelengths": wl.astype(np.float32)}
        write_exr(p, {n: cube[:, :, i] for i, n in enumerate(names)}, header, protect=protect)
    elif ext == ".npz":
        arrays = {"cube": cube}
        if wl is not None:
            arrays["wavelengths"] = wl
        with atomic_path(p, protect=protect) as tmp:
            np.savez_compressed(tmp, **arrays)
    elif ext == ".npy":
        with atomic_path(p, protect=protect) as tmp:
            np.save(tmp, cube, allow_pickle=False)
    elif ext == ".mat":
        arrays = {key: cube}
        if wl is not None:
            arrays["wavelengths"] = wl
        save_mat(p, arrays, version=mat_version, protect=protect)
    elif ext == "":
        _write_cave(p, cube, wl, cave_name or p.name, protect)
    else:
        raise InputError(f"{p}: unsupported cube file type {ext}; use .exr, .npz, .npy, .mat or a folder")
    return p


def _write_cave(folder: Path, cube: np.ndarray, wl, name: str, protect) -> None:
    import imageio.v3 as iio

    n = cube.shape[2]
    if n > 999:
        raise InputError(f"{folder}: too many bands ({n}) for the CAVE layout")
    if wl is not None and not np.allclose(wl, cave_wavelengths(n), atol=1e-6):
        raise InputError(f"{folder}: the CAVE layout implies bands at 400, 410, ... nm; these wavelengths differ")
    lo, hi = float(cube.min()), float(cube.max())
    if lo < 0.0 or hi > 1.0:
        raise InputError(f"{folder}: CAVE PNGs hold values in [0, 1]; this cube spans [{lo:g}, {hi:g}] (scale it first)")
    q = np.round(cube * 65535.0).astype(np.uint16)
    width = 2 if n < 100 else 3
    with atomic_dir(folder, protect=protect) as tmp:
        for i in range(n):
            iio.imwrite(tmp / f"{name}_{i + 1:0{width}d}.png", q[:, :, i], plugin="pillow")
