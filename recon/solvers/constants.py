r"""The constants a solve estimates from its operator alone, kept for the next solve.

Before its first iteration a solver estimates numbers that depend on the operator :math:`H`
and on nothing else: FISTA's step :math:`1/\|H\|^2` (15 power iterations) or its band metric
:math:`D = \alpha\,\mathrm{diag}(s_l)` (:mod:`recon.solvers.band_metric`: a Hutchinson probe and
15 power iterations), and the application's row scale.  Each costs forward/adjoint pairs, as
many as tens of iterations of a large calibrated model; every frame measured through the same
instrument and views would repeat them.

:class:`OperatorConstants` keeps them by name.  A solver that is handed one (``constants=``)
asks it for each constant with the estimate to run when it is not there yet
(:meth:`OperatorConstants.get`); the estimate is the one the solver would run without it, so a
solve gives the same bits with or without a memo, and with a full one.  The memo belongs to
*one* operator: whoever makes it keys it on everything the operator is built from (the
application keeps it on disk next to the calibration, ``kaleidospec.solve_constants``).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from recon.errors import InputError

__all__ = ["OperatorConstants", "band_metric_name", "lipschitz_name"]


def lipschitz_name(dtype) -> str:
    r"""Name of :math:`\|H\|^2` as :func:`recon.solvers.base.operator_norm_sq` estimates it
    in ``dtype`` (its default iterations and seed)."""
    return f"lipschitz_{np.dtype(dtype).name}"


def band_metric_name(exponent: float, dtype) -> str:
    """Name of the band metric's diagonal (:func:`recon.solvers.band_metric.band_metric`) with
    exponent ``exponent`` in ``dtype`` (its default seed)."""
    return f"band_metric_p{float(exponent)!r}_{np.dtype(dtype).name}"


def _checked(name: str, value):
    """``value`` as a positive finite float, or a 1-D float64 array of them; else InputError."""
    if isinstance(value, (float, int, np.floating, np.integer)) and not isinstance(value, bool):
        v = float(value)
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"operator constant {name!r} must be positive and finite, got {v}")
        return v
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.ndim != 1 or a.size == 0 or not np.all(np.isfinite(a)) or not np.all(a > 0):
        raise InputError(f"operator constant {name!r} must be a positive number or a 1-D "
                         f"array of positive numbers")
    return a


class OperatorConstants:
    """Constants of one operator by name: positive floats, or 1-D arrays of them.

    Parameters
    ----------
    values : mapping, optional
        Constants already known (loaded from a cache): each is checked as it is taken.
    on_new : callable, optional
        ``on_new(memo)`` after a constant was estimated and added (a cache writes its file).
    """

    def __init__(self, values=None, on_new: Callable[["OperatorConstants"], None] | None = None):
        self._values = {}
        for name, v in dict(values or {}).items():
            self._values[str(name)] = _checked(str(name), v)
        self._on_new = on_new
        #: The names estimated through this memo (not found in it).
        self.estimated: list[str] = []

    def __contains__(self, name) -> bool:
        return name in self._values

    def get(self, name: str, estimate: Callable[[], object], check: Callable | None = None):
        """The constant ``name``: the value kept, where there is one that passes ``check``
        (``check(value) -> bool``; e.g. one value per band), else ``estimate()``, kept when it
        is a positive finite number or array of them (else returned as it is, not kept).
        Arrays are returned as copies."""
        v = self._values.get(name)
        if v is not None and (check is None or check(v)):
            return v.copy() if isinstance(v, np.ndarray) else v
        raw = estimate()
        try:
            v = _checked(name, raw)
        except InputError:
            # Not a constant to keep (a zero operator's norm): the caller's own checks say
            # what is wrong with it.
            return raw
        self._values[name] = v
        self.estimated.append(name)
        if self._on_new is not None:
            self._on_new(self)
        return v.copy() if isinstance(v, np.ndarray) else v

    def as_dict(self) -> dict:
        """``{name: float or list of floats}``: JSON-ready, exact (a float's ``repr`` reads
        back to the same double)."""
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                for k, v in sorted(self._values.items())}
