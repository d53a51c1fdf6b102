r"""A calibrated solve's operator constants, cached next to the calibration they come from.

A solve through a calibrated model first estimates numbers that depend on the operator alone:
the row scale :math:`s` that brings its rows to unit mean squared norm
(:func:`kaleidospec.reconstruct.unit_row_scale`), and FISTA's band metric or
:math:`\|sH\|^2` (:mod:`recon.solvers.constants`).  They cost forward/adjoint pairs, as
many as tens of iterations (figures in ``docs/speed_product.md``), and they are the same for
every frame measured with that calibration and those views.  :func:`constants_for` keeps them in
one cache entry per calibration, view set and model
(``solve-<design hash>-<key>-v<version>.json`` in the cache folder, :mod:`recon.io.cache`:
checksummed, written atomically, removed and estimated again when damaged), so that only the
first solve estimates them.

The key is a digest of the calibration's arrays (not its file name: a calibration made again
gets new constants), the views, the model and whether the kernels or the NumPy paths made
them; the entry's version is a digest of the code
that makes the operator and the estimates, so a change there estimates them again.  The values
are kept as JSON numbers, which read back to the same doubles: a solve with the cached
constants gives the same bits as one that estimates them
(``tests/kaleidospec/test_solve_constants.py``).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from recon.solvers.constants import OperatorConstants

__all__ = ["KIND", "code_version", "calibration_digest", "constants_for", "entry_path"]

#: The cache entries' kind (:mod:`recon.io.cache`).
KIND = "solve-constants"
#: The sources whose code decides the constants' values (a digest of them is the entries'
#: version): the calibrated operators and their kernels, the estimators, the application's
#: operator and row scale.
_SOURCES = ("recon/operators", "recon/kernels", "recon/solvers", "recon/calibration",
            "recon/probes.py", "kaleidospec/reconstruct.py", "kaleidospec/models.py",
            "kaleidospec/solve_constants.py")
_VERSION: list[str] = []


def code_version() -> str:
    """A digest of the sources that decide the constants (:data:`_SOURCES`)."""
    if not _VERSION:
        root = Path(__file__).resolve().parent.parent
        h = hashlib.sha256()
        for rel in _SOURCES:
            p = root / rel
            for f in sorted(p.rglob("*.py")) if p.is_dir() else [p]:
                h.update(f.relative_to(root).as_posix().encode())
                h.update(f.read_bytes())
        _VERSION.append(h.hexdigest()[:16])
    return _VERSION[0]


def calibration_digest(cal) -> str:
    """SHA-256 of the calibration's arrays and of the metadata the operator reads, computed
    from the arrays in memory (so a calibration changed in memory gets its own key)."""
    from recon.calibration.store import ARRAY_FIELDS, OPTIONAL_ARRAY_FIELDS
    from recon.io.cache import array_digest

    arrays = {n: getattr(cal, n) for n in ARRAY_FIELDS + OPTIONAL_ARRAY_FIELDS
              if getattr(cal, n) is not None}
    meta = json.dumps([list(cal.view_ids), list(cal.cube_shape), cal.design_hash])
    return hashlib.sha256((array_digest(arrays) + meta).encode()).hexdigest()


def _key(cal, view_ids, model: str) -> str:
    from recon import kernels

    # The kernels and the NumPy reference round differently: each keeps its own estimates.
    blob = json.dumps({"calibration": calibration_digest(cal),
                       "views": [int(v) for v in view_ids], "model": str(model),
                       "kernels": bool(kernels.enabled())}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


def entry_path(folder, cal, key: str) -> Path:
    """The cache entry of the constants with key ``key`` in ``folder``: named by the code's
    version too, as the calibrations are, so that other code (another checkout, an upgrade)
    keeps its own entry instead of finding this one foreign and removing it."""
    return Path(folder) / f"solve-{cal.design_hash or 'none'}-{key[:16]}-v{code_version()}.json"


def constants_for(cal, view_ids, model: str, cache_dir=None) -> OperatorConstants:
    """The memo of the calibrated operator of ``cal``'s views ``view_ids`` with ``model``
    (:func:`kaleidospec.reconstruct.calibrated_operator`): loaded from the cache folder
    (``cache_dir``, default the simulator's, :func:`kaleidospec.instrument.cache_dir`) where
    an entry is there, written back whenever a solve adds a constant to it."""
    from kaleidospec.instrument import cache_dir as folder
    from recon.errors import InputError
    from recon.io import cache

    try:
        where = folder(cache_dir)
    except InputError as exc:      # a cache folder that cannot be written: this solve only
        cache.warn(f"operator constants kept for this solve only: {exc}")
        return OperatorConstants()
    key = _key(cal, view_ids, model)
    path = entry_path(where, cal, key)
    design = cal.design_hash
    got = cache.read_json(path, kind=KIND, design_hash=design, version=code_version(), key=key)
    values = {} if got is None else got.get("constants", {})

    def save(memo: OperatorConstants) -> None:
        try:
            cache.write_json(path, {"constants": memo.as_dict()}, kind=KIND, design_hash=design,
                             version=code_version(), key=key)
        except OSError as exc:      # a full disk costs the next solve its estimate, no more
            cache.warn(f"{path}: operator constants not saved: {exc}")

    try:
        return OperatorConstants(values, on_new=save)
    except Exception as exc:        # noqa: BLE001 - a value the memo refuses: start afresh
        cache.discard(path, f"not valid operator constants: {exc}")
        return OperatorConstants({}, on_new=save)

