"""2-D arrays (measurements, masks) from ``.npy``, ``.npz``, ``.mat`` and single-channel ``.exr``.

Also the validation and low-level readers shared by :mod:`recon.io.cubes` and
:mod:`recon.io.raw`: every failure (missing, empty, unreadable or truncated file, a dtype that is
not a real number, NaN/Inf, a wrong number of dimensions, a missing key) becomes one
:class:`recon.errors.InputError` whose message starts with the file name.

MATLAB files: v5 (and older) are read with :func:`scipy.io.loadmat`; v7.3 files are HDF5 and are
read with h5py.  MATLAB stores arrays column-major, so h5py sees every v7.3 array with its axes
reversed; the readers here transpose them back, so an array saved in MATLAB as H×W×L comes back
(H, W, L) from both versions.
"""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path
from typing import Iterable

import numpy as np

from recon.errors import InputError
from recon.io.atomic import atomic_path

__all__ = [
    "MEASUREMENT_KEYS",
    "MASK_KEYS",
    "read_array",
    "read_named_array",
    "read_array2d",
    "write_array2d",
    "check_array",
    "check_file",
    "load_mat",
    "read_exr",
    "write_exr",
]

PathLike = str | os.PathLike

#: Names under which the CASSI world's files keep a measurement, tried in this order when no key
#: is given: ``meas_real`` (TSA-Net's real captures, also in MST), then the usual others.
MEASUREMENT_KEYS = ("meas_real", "meas", "measurement", "measurements", "meas_sim", "y", "g")
#: Names under which they keep a mask: the shifted mask cube published with real captures
#: (``mask_3d_shift``, H×(W+step·(L−1))×L) before the plain H×W mask.
MASK_KEYS = ("mask_3d_shift", "mask3d_shift", "mask", "Phi", "phi")

_MAT_HEADER = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created by: kaleidospec HDF5 schema 1.00 ."


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------
def check_file(path: PathLike) -> Path:
    """The path as a :class:`Path`, after checking it is an existing, non-empty, readable file."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file")
    if p.is_dir():
        raise InputError(f"{p}: is a folder, expected a file")
    if p.stat().st_size == 0:
        raise InputError(f"{p}: the file is empty")
    if not os.access(p, os.R_OK):
        raise InputError(f"{p}: the file is not readable")
    return p


def read_json_object(path: PathLike) -> dict:
    """The JSON object (a dict) in a file: sidecars and calibration metadata.

    Raises
    ------
    InputError
        Unreadable, not valid JSON, or valid JSON that is not an object.
    """
    import json

    p = Path(path)
    try:
        meta = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise InputError(f"{p}: not valid JSON ({err})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{p}: the metadata must be a JSON object")
    return meta


def check_array(a, path: PathLike, *, ndim: int | Iterable[int] | None = None, what: str = "array",
                allow_bool: bool = False) -> np.ndarray:
    """Validate a loaded array and return it as C-contiguous float32.

    Accepts real floating and integer dtypes (integers, e.g. 16-bit images, are converted to
    float32 unscaled); rejects complex, object and strings, NaN/Inf, empty arrays and a
    wrong number of dimensions.  Bool is rejected unless ``allow_bool`` (binary masks: True =
    open = 1.0); a boolean measurement or cube is a mistake.
    """
    a = np.asarray(a)
    if allow_bool and a.dtype == bool:
        a = a.astype(np.float32)
    if a.dtype == bool or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise InputError(f"{path}: {what} has dtype {a.dtype}, expected real numbers")
    if ndim is not None:
        allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
        if a.ndim not in allowed:
            want = " or ".join(f"{n}-D" for n in allowed)
            raise InputError(f"{path}: {what} is {a.ndim}-D with shape {a.shape}, expected {want}")
    if a.size == 0:
        raise InputError(f"{path}: {what} is empty (shape {a.shape})")
    with np.errstate(over="ignore"):  # values beyond float32 become Inf and are caught below
        a = np.ascontiguousarray(a, dtype=np.float32)
    if not np.all(np.isfinite(a)):
        raise InputError(f"{path}: {what} contains NaN or Inf (or values beyond float32)")
    return a


# --------------------------------------------------------------------------------------------
# OpenEXR
# --------------------------------------------------------------------------------------------
@contextlib.contextmanager
def _quiet_stdio():
    """Silence stdout and stderr (the Python objects and file descriptors 1 and 2): the OpenEXR
    bindings and C++ library print their own diagnostics for corrupt files, and the command
    line promises one line on stderr."""
    import io

    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    null = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(null, 1)
        os.dup2(null, 2)
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, null):
            os.close(fd)


def _openexr():
    """The OpenEXR module, its library's thread pool sized to the CPUs the process may use
    (:func:`recon.kernels.cores`) unless someone sized it already: the library compresses and
    decompresses a file's line blocks on it, the same bytes as with no threads."""
    import OpenEXR

    if OpenEXR.global_thread_count() == 0:
        from recon.kernels import cores

        OpenEXR.set_global_thread_count(cores())
    return OpenEXR


def read_exr(path: PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Read every channel of a single-part scanline/tiled OpenEXR file.

    Returns
    -------
    channels : dict name -> (H, W) array (native dtype: float32, float16 or uint32)
    header : dict of header attributes
    """
    OpenEXR = _openexr()
    p = check_file(path)
    try:
        with _quiet_stdio():
            f = OpenEXR.File(str(p), separate_channels=True)
            header = dict(f.header())
            chans = {name: np.asarray(ch.pixels) for name, ch in f.channels().items()}
    except Exception as err:  # OpenEXR raises RuntimeError/ValueError with C++ messages
        raise InputError(f"{p}: not a readable OpenEXR file (corrupt or truncated?)") from err
    if not chans or any(c is None or c.size == 0 for c in chans.values()):
        raise InputError(f"{p}: the OpenEXR file has no pixel data")
    return chans, header


def write_exr(path: PathLike, channels: dict[str, np.ndarray], header: dict | None = None, *, protect=()) -> Path:
    """Write float32 channels to a ZIP-compressed scanline OpenEXR file, atomically."""
    OpenEXR = _openexr()

    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    hdr.update(header or {})
    chans = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}
    with atomic_path(path, protect=protect) as tmp:
        OpenEXR.File(hdr, chans).write(str(tmp))
    return Path(path)


# --------------------------------------------------------------------------------------------
# MATLAB
# --------------------------------------------------------------------------------------------
def _is_hdf5(p: Path) -> bool:
    import h5py

    try:
        return bool(h5py.is_hdf5(str(p)))
    except OSError:
        return False


def load_mat(path: PathLike) -> dict[str, np.ndarray]:
    """All numeric arrays of a MATLAB file (v4/v5/v7 or v7.3), keyed by variable name.

    v7.3 arrays are transposed back to MATLAB's axis order (see the module notes).  Variables
    that are not plain arrays (structs, cells, strings) are skipped.
    """
    p = check_file(path)
    out: dict[str, np.ndarray] = {}
    if _is_hdf5(p):
        import h5py

        try:
            with h5py.File(p, "r") as f:
                for name, obj in f.items():
                    if isinstance(obj, h5py.Dataset) and not name.startswith("#"):
                        arr = obj[()]
                        if isinstance(arr, np.ndarray) and arr.dtype.fields is None:
                            out[name] = arr.T
        except Exception as err:
            raise InputError(f"{p}: not a readable MATLAB v7.3 (HDF5) file") from err
        return out
    import scipy.io

    try:
        data = scipy.io.loadmat(str(p))
    except Exception as err:
        raise InputError(f"{p}: not a readable MATLAB file (corrupt or truncated?)") from err
    for name, arr in data.items():
        if not name.startswith("__") and isinstance(arr, np.ndarray) and arr.dtype.fields is None \
                and arr.dtype != object:
            out[name] = arr
    return out


def save_mat(path: PathLike, arrays: dict[str, np.ndarray], *, version: str = "5", protect=()) -> Path:
    """Save arrays to a MATLAB file atomically: ``version`` ``"5"`` (scipy) or ``"7.3"`` (HDF5).

    The v7.3 file carries MATLAB's 512-byte header and ``MATLAB_class`` attributes so MATLAB
    itself can load it; arrays are written transposed (MATLAB is column-major).
    """
    with atomic_path(path, protect=protect) as tmp:
        if version == "5":
            import scipy.io

            scipy.io.savemat(str(tmp), arrays, do_compression=True, oned_as="row")
        elif version == "7.3":
            import h5py

            classes = {np.dtype("float32"): "single", np.dtype("float64"): "double",
                       np.dtype("uint16"): "uint16", np.dtype("uint8"): "uint8",
                       np.dtype("int32"): "int32", np.dtype("int64"): "int64"}
            with h5py.File(tmp, "w", userblock_size=512) as f:
                for name, arr in arrays.items():
                    arr = np.asarray(arr)
                    if arr.ndim == 1:
                        arr = arr[None, :]  # MATLAB has no 1-D arrays: a row vector
                    if arr.dtype not in classes:
                        arr = arr.astype(np.float64)
                    ds = f.create_dataset(name, data=arr.T, compression="gzip")
                    ds.attrs["MATLAB_class"] = np.bytes_(classes[arr.dtype])
            head = _MAT_HEADER.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"
            with open(tmp, "r+b") as fh:
                fh.write(head.ljust(512, b"\x00"))
        else:
            raise InputError(f"{path}: unknown MATLAB version {version!r} (use '5' or '7.3')")
    return Path(path)


def _pick(arrays: dict[str, np.ndarray], p: Path, key: str | None, ndim: int | tuple, what: str,
          preferred: tuple[str, ...] = ()) -> np.ndarray:
    """The array under ``key``; else the first of ``preferred`` present; else the only array
    with the wanted number of dimensions."""
    return _pick_named(arrays, p, key, ndim, what, preferred)[1]


def _pick_named(arrays: dict[str, np.ndarray], p: Path, key: str | None, ndim: int | tuple,
                what: str, preferred: tuple[str, ...] = ()) -> tuple[str, np.ndarray]:
    """:func:`_pick` and the name it picked."""
    if key is not None:
        if key not in arrays:
            have = ", ".join(sorted(arrays)) or "none"
            raise InputError(f"{p}: no variable {key!r} (variables: {have})")
        return key, arrays[key]
    for k in preferred:
        if k in arrays:
            return k, arrays[k]
    allowed = (ndim,) if isinstance(ndim, int) else tuple(ndim)
    # MATLAB scalars and vectors are 2-D (1×n): never candidates for an image or a cube.
    cands = {k: v for k, v in arrays.items() if v.ndim in allowed and min(v.shape) > 1}
    if len(cands) != 1:
        have = ", ".join(f"{k}{tuple(v.shape)}" for k, v in sorted(arrays.items())) or "none"
        why = "no" if not cands else "more than one"
        raise InputError(f"{p}: {why} {what} candidate; name one with a key (variables: {have})")
    return next(iter(cands.items()))


def _load_npz(p: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(p, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except Exception as err:
        raise InputError(f"{p}: not a readable .npz file (corrupt, truncated or pickled?)") from err


def _load_npy(p: Path) -> np.ndarray:
    try:
        return np.load(p, allow_pickle=False)
    except Exception as err:
        raise InputError(f"{p}: not a readable .npy file (corrupt, truncated or pickled?)") from err


# --------------------------------------------------------------------------------------------
# public readers / writers
# --------------------------------------------------------------------------------------------
def read_array(path: PathLike, *, key: str | None = None, ndim: int | tuple = 2, what: str = "array",
               allow_bool: bool = False) -> np.ndarray:
    """Read one real array of the given dimensionality as float32.

    Parameters
    ----------
    path : path-like
        ``.npy``, ``.npz`` (``key`` or the single array with ``ndim`` dimensions), ``.mat``
        (same rule), ``.exr`` (``key`` names the channel, else the file must have exactly one).
    key : str, optional
        Variable, array or channel name.
    ndim : int or tuple of int
        Accepted numbers of dimensions.
    what : str
        What the array is, for error messages (``"measurement"``, ``"mask"``).
    allow_bool : bool
        Accept a boolean array as 0/1 (masks); see :func:`check_array`.
    """
    return read_named_array(path, key=key, ndim=ndim, what=what, allow_bool=allow_bool)[0]


def read_named_array(path: PathLike, *, key: str | None = None, ndim: int | tuple = 2,
                     what: str = "array", allow_bool: bool = False,
                     preferred: tuple[str, ...] = ()) -> tuple[np.ndarray, str | None]:
    """:func:`read_array`, and the name of the variable or channel it read.

    Parameters
    ----------
    preferred : tuple of str
        Without ``key``, the first of these names present in a ``.npz`` or ``.mat`` file is
        read (e.g. :data:`MEASUREMENT_KEYS`); with none present, the single array with ``ndim``
        dimensions.  Other parameters as in :func:`read_array`.

    Returns
    -------
    array : float32 array
    name : str or None
        The variable or channel read; None for a ``.npy`` file (it holds one array).
    """
    p = check_file(path)
    ext = p.suffix.lower()
    name = None
    if ext == ".npy":
        arr = _load_npy(p)
    elif ext == ".npz":
        name, arr = _pick_named(_load_npz(p), p, key, ndim, what, preferred)
    elif ext == ".mat":
        name, arr = _pick_named(load_mat(p), p, key, ndim, what, preferred)
    elif ext == ".exr":
        chans, _ = read_exr(p)
        if key is not None:
            if key not in chans:
                raise InputError(f"{p}: no channel {key!r} (channels: {', '.join(sorted(chans))})")
            name = key
        elif len(chans) == 1:
            name = next(iter(chans))
        else:
            raise InputError(f"{p}: {len(chans)} channels; name one with a key ({', '.join(sorted(chans))})")
        arr = chans[name]
    else:
        raise InputError(f"{p}: unsupported file type {ext or '(none)'}; use .npy, .npz, .mat or .exr")
    return check_array(arr, p, ndim=ndim, what=what, allow_bool=allow_bool), name


def read_array2d(path: PathLike, *, key: str | None = None, what: str = "array",
                 allow_bool: bool = False) -> np.ndarray:
    """A 2-D float32 array (a measurement or a mask); see :func:`read_array`."""
    return read_array(path, key=key, ndim=2, what=what, allow_bool=allow_bool)


def write_array2d(path: PathLike, arr, *, key: str = "data", mat_version: str = "5", protect=()) -> Path:
    """Write a 2-D array atomically as ``.npy``, ``.npz`` / ``.mat`` (under ``key``) or a
    single-channel float32 ``.exr`` (channel ``Y``)."""
    p = Path(path)
    a = np.asarray(arr)
    if a.ndim != 2:
        raise InputError(f"{p}: expected a 2-D array to write, got shape {a.shape}")
    a = np.ascontiguousarray(a, dtype=np.float32)
    ext = p.suffix.lower()
    if ext == ".npy":
        with atomic_path(p, protect=protect) as tmp:
            np.save(tmp, a, allow_pickle=False)
    elif ext == ".npz":
        with atomic_path(p, protect=protect) as tmp:
            np.savez_compressed(tmp, **{key: a})
    elif ext == ".mat":
        save_mat(p, {key: a}, version=mat_version, protect=protect)
    elif ext == ".exr":
        write_exr(p, {"Y": a}, protect=protect)
    else:
        raise InputError(f"{p}: unsupported file type {ext or '(none)'}; use .npy, .npz, .mat or .exr")
    return p
