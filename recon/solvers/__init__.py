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
from recon.priors.base import describe, stages
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

    A prior solved in two stages (:func:`recon.priors.base.stages`: a plug-and-play
    denoiser that starts from another prior's solve) runs them one after the other: the
    first stage's prior with ``iters``, ``tol`` and ``x0``, then the prior itself for its
    own iterations from the first stage's result, without a stopping rule and with FISTA's
    scalar step (the band metric takes only priors that declare it).  The result holds the
    second stage's cube, both stages' iterations, objectives and seconds, and under
    ``info["first_stage"]`` the first stage's iterations, convergence and prior.  A callback
    sees one count of iterations across the two.  The second stage runs only after a first
    stage that the rule stopped (``tol`` given and met): a first stage that ran out of
    ``iters``, or that the callback stopped, is the result.

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
    plan = stages(kw.get("prior"))
    if plan is None:
        return fn(op, g, iters=iters, tau=tau, x0=x0, tol=tol, callback=callback, **kw)
    return _two_stages(fn, op, g, plan, iters=iters, tau=tau, x0=x0, tol=tol,
                       callback=callback, **kw)


def _two_stages(fn, op, g, plan, *, iters, tau, x0, tol, callback, **kw) -> SolverResult:
    """:func:`solve` for a prior of two stages (``plan``: the first stage's prior and the
    second stage's iterations)."""
    first_prior, n_second = plan
    stopped = []

    def first_callback(it, x, info):
        if callback is not None and callback(it, x, info) is True:
            stopped.append(it)
            return True
        return None

    first = fn(op, g, iters=iters, tau=tau, x0=x0, tol=tol,
               callback=first_callback if callback is not None else None,
               **{**kw, "prior": first_prior})
    summary = {"iterations": first.iterations, "converged": first.converged,
               **describe(first_prior)}
    # The denoiser starts from a converged first stage only: from an early iterate (a cap
    # of a few iterations) it takes the coded artefacts for structure, and with momentum it
    # can diverge.
    if stopped or n_second < 1 or not first.converged:
        return SolverResult(x=first.x, iterations=first.iterations, objective=first.objective,
                            seconds=first.seconds, converged=first.converged,
                            info={**first.info, "first_stage": summary})

    def second_callback(it, x, info):
        return callback(first.iterations + it, x,
                        {**info, "seconds": first.seconds + info.get("seconds", 0.0)})

    second_kw = dict(kw)
    if "metric" in second_kw:           # the band metric takes only priors that declare it
        second_kw["metric"] = "scalar"
        second_kw.pop("metric_exponent", None)
        second_kw.pop("band_metric", None)
    second = fn(op, g, iters=n_second, tau=tau, x0=first.x, tol=None,
                callback=second_callback if callback is not None else None, **second_kw)
    return SolverResult(x=second.x, iterations=first.iterations + second.iterations,
                        objective=list(first.objective) + list(second.objective),
                        seconds=first.seconds + second.seconds, converged=first.converged,
                        info={**second.info, "first_stage": summary})
