"""Raw sensor frames: a single-channel float32 OpenEXR image plus a JSON sidecar.

``frame.exr`` holds the sensor frame (H, W) in channel ``Y``; ``frame.json`` (same stem) holds
arbitrary metadata as a JSON object.  The simulator records there the design parameters, the
design hash, the exposure, the wavelengths and the random seed; reconstruction reads them back
without importing the simulator.  NumPy arrays and scalars in the metadata are stored as JSON
lists and numbers (they come back as lists).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from recon.errors import InputError
from recon.io.arrays import check_array, check_file, read_exr, read_json_object, write_exr
from recon.io.atomic import write_text

__all__ = ["read_raw", "write_raw", "sidecar_path"]

PathLike = str | os.PathLike


def sidecar_path(path: PathLike) -> Path:
    """``<name>.json`` next to ``<name>.exr``."""
    return Path(path).with_suffix(".json")


def _jsonable(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"metadata value of type {type(obj).__name__} is not JSON-serialisable")


def write_raw(path: PathLike, frame, metadata: dict | None = None, *, protect=()) -> tuple[Path, Path]:
    """Write a raw frame (``.exr``) and its metadata sidecar (``.json``), each atomically.

    The sidecar is serialised before anything is written, so bad metadata leaves no file.
    The two files are replaced one after the other (image, then sidecar).

    Returns
    -------
    (exr_path, json_path)
    """
    p = Path(path)
    if p.suffix.lower() != ".exr":
        raise InputError(f"{p}: a raw frame is written as .exr")
    a = np.asarray(frame)
    if a.ndim != 2:
        raise InputError(f"{p}: a raw frame must be 2-D, got shape {a.shape}")
    a = check_array(a, p, ndim=2, what="raw frame")
    meta = {} if metadata is None else metadata
    if not isinstance(meta, dict):
        raise InputError(f"{p}: metadata must be a dict, got {type(meta).__name__}")
    try:
        text = json.dumps(meta, default=_jsonable, indent=2, sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as err:
        raise InputError(f"{p}: metadata cannot be written as JSON: {err}") from err
    side = sidecar_path(p)
    protect = tuple(protect)
    write_exr(p, {"Y": a}, {"comment": "kaleidospec raw frame; metadata in " + side.name}, protect=protect)
    write_text(side, text + "\n", protect=protect)
    return p, side


def read_raw(path: PathLike, *, require_metadata: bool = True) -> tuple[np.ndarray, dict]:
    """Read a raw frame (H, W) float32 and its metadata dict.

    Parameters
    ----------
    path : path-like
        The ``.exr`` frame; the sidecar is ``<name>.json``.
    require_metadata : bool
        If False, a missing sidecar gives an empty dict instead of an error.
    """
    p = check_file(path)
    chans, _ = read_exr(p)
    if len(chans) != 1:
        raise InputError(f"{p}: a raw frame has one channel, this file has {len(chans)} ({', '.join(sorted(chans))})")
    pix = next(iter(chans.values()))
    if pix.dtype.kind == "u":
        raise InputError(f"{p}: the channel is UINT, expected HALF or FLOAT")
    frame = check_array(pix, p, ndim=2, what="raw frame")
    side = sidecar_path(p)
    if not side.exists():
        if require_metadata:
            raise InputError(f"{side}: the metadata sidecar of {p.name} is missing")
        return frame, {}
    return frame, read_json_object(check_file(side))
