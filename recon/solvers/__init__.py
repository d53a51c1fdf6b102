r"""Iterative solvers for :math:`\min_f \frac12\|g-Hf\|^2 + \varphi(f)`.

All take a :class:`~recon.operators.LinearOperator` with ishape ``(L, H, W)`` and a prior
:math:`\varphi` (``prior=``, :mod:`recon.priors`; by default :math:`\tau\,\mathrm{TV}`, set
by ``tau=``) and return a :class:`SolverResult`; :func:`solve` picks one by name from
:data:`SOLVERS`.  One loop per algorithm: FISTA (``fista-tv``), GAP (``gap-tv``), TwIST
(``twist``, priors with a value only) and ADMM (``admm``, the plug-and-play solver); the
``-tv`` in the first two names is their default prior.
"""

from __future__ import annotations

from recon.errors import InputError
from recon.solvers.admm import admm
from recon.solvers.base import Callback, SolverResult, objective, operator_norm_sq
from recon.solvers.fista_tv import fista_tv
from recon.solvers.gap_tv import gap_tv
from recon.solvers.twist import twist, twist_parameters

#: Solver functions by name.
SOLVERS = {"twist": twist, "gap-tv": gap_tv, "fista-tv": fista_tv, "admm": admm}

__all__ = ["SOLVERS", "solve", "SolverResult", "Callback", "objective", "operator_norm_sq",
           "twist", "twist_parameters", "gap_tv", "fista_tv", "admm"]


def solve(name: str, op, g, *, iters: int, tau: float | None = None, x0=None, tol=None,
          callback=None, **kw) -> SolverResult:
    """Run the solver ``name`` (a key of :data:`SOLVERS`); extra keywords (``prior=`` ...) go
    to the solver.

    Raises
    ------
    InputError
        Unknown solver name, an option the solver does not take, or bad inputs.
    """
    try:
        fn = SOLVERS[name]
    except KeyError:
        raise InputError(f"unknown solver {name!r}; choose one of {', '.join(SOLVERS)}") from None
    import inspect

    params = inspect.signature(fn).parameters
    unknown = sorted(k for k in kw if k not in params)
    if unknown:
        raise InputError(f"solver {name!r} has no option(s) {', '.join(unknown)}")
    return fn(op, g, iters=iters, tau=tau, x0=x0, tol=tol, callback=callback, **kw)
