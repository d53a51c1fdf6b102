r"""What every solver shares: the result record, the callback protocol, input checks, stopping,
and the prior a solver is given (:func:`resolve_prior`).

Every solver minimises (or, for GAP and a plug-and-play denoiser, approximately minimises)

.. math::

    \min_f \; \tfrac12 \|g - Hf\|_2^2 + \varphi(f)

for a :class:`~recon.operators.LinearOperator` :math:`H` with ``ishape`` ``(L, H, W)`` (the
band-major cube) and any ``oshape`` (``(K, Hv, Wm)`` for CASSI, any number of views), and a
prior :math:`\varphi` (:mod:`recon.priors`; by default :math:`\tau\,\mathrm{TV}`).  The loop
runs in float32, or in float64 when the measurement is float64 (for precision checks).

Stopping: after ``iters`` iterations, or earlier when ``tol`` is given and the relative change
:math:`\|f_{k}-f_{k-1}\|_2 / \|f_{k-1}\|_2` falls below it (``converged=True``), or when the
callback returns ``True``.  After a momentum restart (:meth:`IterationLoop.restarted`) the
test is held for half as many iterations as the momentum had run before it, at least 2 and
at most :data:`RESTART_HOLD`: a restart sets the momentum to zero, and the next changes are
those of plain gradient steps, smaller than the accelerated ones by a factor that grows with
the iterations since the restart, so on a slowly converging problem they fall below ``tol``
far from the minimum.  Restarts that follow each other closely (the momentum no longer
accelerates) hold the test briefly, so that they cannot hold it for ever.

A prior that re-estimates part of itself from the iterate (a spectral basis) reports how far
that moved at its last call (:func:`recon.priors.base.state_change`).  With such a prior the
test also needs

- that change below ``tol``: the solve has converged only when the prior's own estimate has
  settled too;
- in a solver that restarts its momentum (FISTA), a restart within the last :data:`COAST`
  iterations: while the momentum runs on unbroken the iterate travels along a valley of the
  objective at a small, slowly falling change per iteration and a PSNR still rising, and the
  restart that marks the valley's end has not come (docs/priors.md, "The stopping rule
  waits for the basis").
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.priors import check_prior, make_prior
from recon.priors.tv import check_weight
from recon.prox.tv import tv_norm

__all__ = ["SolverResult", "Callback", "IterationLoop", "check_problem", "objective",
           "operator_norm_sq", "power_iteration", "resolve_prior", "RESTART_HOLD", "COAST"]

#: The most iterations after a momentum restart (the restart's own included) in which the
#: stopping rule is not tested (see the module notes).
RESTART_HOLD = 10

#: With a prior that re-estimates itself from the iterate, the most iterations the momentum may
#: have run since its last restart (or the start) for the stopping rule to be tested (see the
#: module notes).
COAST = 50


@dataclass
class SolverResult:
    """The outcome of a solver run.

    Attributes
    ----------
    x : ndarray, shape (L, H, W)
        The reconstruction (band-major, the dtype of the loop).
    iterations : int
        Outer iterations done.
    objective : list of float
        :math:`\\tfrac12\\|g-Hf_k\\|^2+\\tau\\mathrm{TV}(f_k)` after every iteration, when it was
        computed (TwIST always; other solvers with ``objective=True``); empty otherwise.
    seconds : float
        Wall time of the solve (set-up included, callback time excluded).
    converged : bool
        True when the ``tol`` test stopped the loop.
    info : dict
        Solver-specific extras (step sizes, counts of rejected steps, ...).
    """

    x: np.ndarray
    iterations: int
    objective: list[float] = field(default_factory=list)
    seconds: float = 0.0
    converged: bool = False
    info: dict[str, Any] = field(default_factory=dict)


class Callback(Protocol):
    """Called once per outer iteration, after the iterate is updated.

    Parameters
    ----------
    iteration : int
        1-based iteration number.
    x : ndarray, shape (L, H, W)
        The current iterate.  Read-only by contract: the solver keeps using this buffer.
    info : dict
        At least ``"rel_change"`` (float, relative change of the iterate), ``"seconds"``
        (time since the start), ``"objective"`` (float or None) and ``"held"`` (whether the
        stopping rule is held this iteration, after a momentum restart).

    Returns
    -------
    bool or None
        ``True`` stops the solver after this iteration.
    """

    def __call__(self, iteration: int, x: np.ndarray, info: dict) -> bool | None: ...


def check_problem(op: LinearOperator, g, x0, iters, tau, tol):
    """Validate a problem and return ``(g, x0, dtype)`` in the working precision.

    Raises
    ------
    InputError
        For every bad input (shape, dtype, non-finite values, bad parameters).
    """
    if not isinstance(op, LinearOperator):
        raise InputError(f"op must be a recon LinearOperator, got {type(op).__name__}")
    if len(op.ishape) != 3:
        raise InputError(f"solvers need an operator on (L, H, W) cubes, got ishape {op.ishape}")
    g = np.asarray(g)
    if g.shape != op.oshape:
        raise InputError(f"measurement shape {g.shape} does not match the operator's "
                         f"{op.oshape}")
    if not (np.issubdtype(g.dtype, np.floating) or np.issubdtype(g.dtype, np.integer)):
        raise InputError(f"measurement must be real numbers, got dtype {g.dtype}")
    dtype = np.dtype(np.float64) if g.dtype == np.float64 else np.dtype(np.float32)
    g = np.ascontiguousarray(g, dtype=dtype)
    if not np.all(np.isfinite(g)):
        raise InputError("measurement contains NaN or infinite values")
    if x0 is not None:
        x0 = np.asarray(x0)
        if x0.shape != op.ishape:
            raise InputError(f"x0 shape {x0.shape} does not match the operator's {op.ishape}")
        x0 = np.array(x0, dtype=dtype, order="C", copy=True)
        if not np.all(np.isfinite(x0)):
            raise InputError("x0 contains NaN or infinite values")
    if isinstance(iters, bool) or not isinstance(iters, (int, np.integer)) or iters < 1:
        raise InputError(f"iters must be an integer >= 1, got {iters!r}")
    if tau is not None:
        check_weight(tau, "tau")
    if tol is not None:
        tol = float(tol)
        if not math.isfinite(tol) or tol <= 0:
            raise InputError(f"tol must be > 0, got {tol}")
    return g, x0, dtype


def resolve_prior(prior, solver: str, shape, dtype, *, tau=None, tv_iters=None,
                  warm_dual=None, isotropic=None, threads=None):
    r"""The prior a solver runs with, reset (a cold start).

    Parameters
    ----------
    prior : Prior, str or None
        A :class:`~recon.priors.Prior`; or a name of :data:`recon.priors.PRIORS`, built with
        ``tau`` as its weight; or None: the TV prior :math:`\tau\,\mathrm{TV}` (``tau``
        None: the solver's default, :data:`recon.priors.tv.DEFAULT_WEIGHT`), the solvers'
        behaviour before priors were parts.
    solver : str
        The solver's name (for the default weight).
    shape, dtype
        The cube's shape and the loop's precision.
    tau, tv_iters, warm_dual, isotropic, threads
        The TV prior's options (None: its defaults).  With a prior object, only ``threads``
        may be given (for the solver's own work): the prior carries its options.

    Raises
    ------
    InputError
        A prior object given together with TV options, or an unknown name.
    """
    tv = {k: v for k, v in (("tv_iters", tv_iters), ("warm_dual", warm_dual),
                            ("isotropic", isotropic)) if v is not None}
    if prior is None or isinstance(prior, str):
        prior = make_prior("tv" if prior is None else prior, shape=shape, dtype=dtype,
                           weight=tau, solver=solver, threads=threads, **tv)
    else:
        given = sorted((["tau"] if tau is not None else []) + list(tv))
        if given:
            raise InputError(f"{', '.join(given)} set the TV prior; with prior= given, set "
                             f"them on the prior itself")
        check_prior(prior)
    prior.reset()
    return prior


def prior_value(prior, x) -> float | None:
    """:math:`\varphi(x)` as a float, or None where the prior defines no value."""
    v = prior.value(x)
    return None if v is None else float(v)


def data_misfit(op: LinearOperator, g: np.ndarray, x: np.ndarray) -> tuple[float, np.ndarray]:
    r"""Return :math:`\tfrac12\|g-Hx\|^2` and the residual :math:`g-Hx`."""
    r = op.forward(x)
    np.subtract(g, r, out=r)
    return 0.5 * float(np.vdot(r, r)), r


def objective(op: LinearOperator, g: np.ndarray, x: np.ndarray, tau: float | None = None,
              isotropic: bool = True, prior=None) -> float | None:
    r""":math:`\tfrac12\|g-Hx\|_2^2 + \tau\,\mathrm{TV}(x)` (one forward), or with
    ``prior`` :math:`\tfrac12\|g-Hx\|_2^2 + \varphi(x)` (None where the prior has no value)."""
    if prior is not None:
        if tau is not None:
            raise InputError("objective: give tau (TV) or prior, not both")
        value = prior_value(check_prior(prior), x)
        return None if value is None else data_misfit(op, g, x)[0] + value
    if tau is None:
        raise InputError("objective: give tau (the TV weight) or a prior")
    return data_misfit(op, g, x)[0] + float(tau) * tv_norm(x, isotropic)


def operator_norm_sq(op: LinearOperator, n_iter: int = 15, dtype=np.float32,
                     seed: int = 0) -> float:
    r"""Estimate :math:`\|H\|_2^2`, the largest eigenvalue of :math:`H^\top H`, by power iteration.

    A power iteration approaches the top eigenvalue from below; the estimate is multiplied by
    1.02 so that a step :math:`1/\|H\|^2` stays on the safe side after ``n_iter`` iterations.
    """
    return 1.02 * power_iteration(op, n_iter, dtype, seed)


def power_iteration(op: LinearOperator, n_iter: int, dtype=np.float32, seed: int = 0,
                    weights: np.ndarray | None = None) -> float:
    r"""The top eigenvalue of :math:`W H^\top H W` after ``n_iter`` power iterations from a
    normal draw (``seed``), :math:`W = \mathrm{diag}(w)` one factor per slice of the first axis
    (``weights``, shape ``(ishape[0],)``; the identity when omitted); 0 for a zero operator.

    The iterate, :math:`H^\top H` of it (and the weighted iterate) live in cubes allocated
    once: the adjoint is written into a zeroed cube by the operator's gradient step
    (``adjoint_add``, :math:`0 + H^\top y`, the same values as ``adjoint``), not into a new
    cube an iteration.
    """
    from recon.probes import standard_normal

    x = standard_normal(np.random.default_rng(seed), op.ishape, dtype)
    x /= np.linalg.norm(x)
    w = None if weights is None else np.asarray(weights).astype(dtype).reshape(
        (-1,) + (1,) * (x.ndim - 1))
    xw = None if w is None else np.empty_like(x)
    y = np.empty_like(x)
    lam = 0.0
    for _ in range(int(n_iter)):
        y.fill(0)
        if w is None:
            op.adjoint_add(op.forward(x), y, 1.0, out=y)
        else:
            op.adjoint_add(op.forward(np.multiply(x, w, out=xw)), y, 1.0, out=y)
            y *= w
        lam = float(np.linalg.norm(y))
        if lam == 0.0:
            return 0.0
        np.divide(y, lam, out=x)
    return lam


class IterationLoop:
    """Book-keeping of an outer loop: relative change, tolerance, callback, timing.

    Parameters
    ----------
    tol : float or None
    callback : Callback or None
    restarts : bool
        The solver restarts its momentum and says so (:meth:`restarted`): with a prior that
        reports a state the rule then also waits for a restart within :data:`COAST`
        iterations.
    """

    def __init__(self, tol, callback, restarts: bool = False):
        self.tol = tol
        self.callback = callback
        self.restarts = bool(restarts)
        self.t0 = time.perf_counter()
        self.callback_seconds = 0.0
        self.converged = False
        self.iterations = 0
        self._hold = 0
        self._last_restart = 0

    def restarted(self) -> None:
        """The solver dropped its momentum in the iteration under way: hold the stopping rule
        for half as many iterations, this one included, as the momentum ran since the
        previous restart (or the start), at least 2 and at most :data:`RESTART_HOLD`; a hold
        under way is not shortened."""
        it = self.iterations + 1
        hold = min(RESTART_HOLD, max(2, (it - self._last_restart) // 2))
        self._hold = max(self._hold, hold)
        self._last_restart = it

    @property
    def needs_change(self) -> bool:
        """Whether the relative change must be measured (costs two passes over the cube)."""
        return self.tol is not None or self.callback is not None

    @staticmethod
    def relative_change(x: np.ndarray, x_prev: np.ndarray, work: np.ndarray) -> float:
        r""":math:`\|x-x_\mathrm{prev}\|/\|x_\mathrm{prev}\|` using ``work`` as scratch."""
        den = float(np.sqrt(np.vdot(x_prev, x_prev)))
        np.subtract(x, x_prev, out=work)  # work may alias x_prev: its norm is taken first
        num = float(np.sqrt(np.vdot(work, work)))
        return num / den if den > 0 else (0.0 if num == 0 else math.inf)

    def step(self, it: int, x: np.ndarray, rel_change: float | None,
             obj: float | None = None, prior_change: float | None = None, **extra) -> bool:
        """Record iteration ``it`` (1-based); return True when the loop must stop.

        ``prior_change`` is the prior's :func:`~recon.priors.base.state_change` (None: the
        prior has nothing of the kind); the rule then needs it below ``tol`` as well and, in
        a solver that restarts its momentum, a restart within :data:`COAST` iterations."""
        self.iterations = it
        stop = False
        held = self._hold > 0
        self._hold = max(self._hold - 1, 0)
        if (self.tol is not None and rel_change is not None and rel_change < self.tol
                and not held and self._prior_settled(it, prior_change)):
            self.converged = True
            stop = True
        if self.callback is not None:
            t = time.perf_counter()
            info = {"objective": obj, "rel_change": rel_change, "held": held,
                    "prior_change": prior_change,
                    "seconds": t - self.t0 - self.callback_seconds, **extra}
            if self.callback(it, x, info) is True:
                stop = True
            self.callback_seconds += time.perf_counter() - t
        return stop

    def _prior_settled(self, it: int, prior_change: float | None) -> bool:
        """The rule's tests for a prior that reports a state (see :meth:`step`): its change
        below ``tol`` and, where the solver restarts its momentum, no run of more than
        :data:`COAST` iterations since the last restart; True for a prior without one."""
        if prior_change is None:
            return True
        coasting = self.restarts and it - self._last_restart > COAST
        return prior_change < self.tol and not coasting

    def seconds(self) -> float:
        return time.perf_counter() - self.t0 - self.callback_seconds


def gram_is_diagonal(op: LinearOperator, phi_inv: np.ndarray, dtype=np.float32,
                     rng: np.random.Generator | None = None) -> bool:
    r"""Whether :math:`HH^\top = \Phi` is diagonal (single-view CASSI), :math:`\Phi^{-1}` =
    ``phi_inv`` (0 on rows that see nothing): one probe :math:`HH^\top u = \Phi u` for a
    random :math:`u` drawn from ``rng`` (one forward/adjoint pair)."""
    rng = np.random.default_rng(0) if rng is None else rng
    u = rng.standard_normal(op.oshape).astype(dtype)
    u *= (phi_inv > 0)
    hhu = op.forward(op.adjoint(u)).astype(np.float64)
    phi = np.zeros(phi_inv.shape, dtype=np.float64)
    np.divide(1.0, phi_inv, out=phi, where=phi_inv > 0)
    # Sums of squares without BLAS: OpenBLAS threads its float64 dot from a few ten thousand
    # elements, and waking its threads on a busy machine costs more than the sum.
    d = hhu - phi * u
    err = math.sqrt(float(np.sum(d * d))) / max(math.sqrt(float(np.sum(hhu * hhu))), 1e-30)
    return err < (1e-5 if np.dtype(dtype) == np.float32 else 1e-10)


def preconditioned_norm_sq(op: LinearOperator, phi_inv: np.ndarray, n_iter: int = 15,
                           dtype=np.float32, seed: int = 0) -> float:
    r"""Estimate :math:`\nu = \|\Phi^{-1/2}H\|_2^2`, the top eigenvalue of :math:`H^\top\Phi^{-1}H`.

    When :math:`HH^\top = \Phi` is diagonal (single-view CASSI), :math:`H^\top\Phi^{-1}H` is an
    orthogonal projection and :math:`\nu = 1`; one probe :math:`HH^\top u = \Phi u` for a random
    :math:`u` detects that case (one forward/adjoint pair).  Otherwise (several views see the
    same voxel) a power iteration estimates :math:`\nu` (up to :math:`K`), times 1.02.
    """
    rng = np.random.default_rng(seed)
    if gram_is_diagonal(op, phi_inv, dtype, rng):
        return 1.0
    from recon.probes import standard_normal

    x = standard_normal(rng, op.ishape, dtype)
    x /= np.linalg.norm(x)
    lam = 0.0
    for _ in range(int(n_iter)):
        y = op.adjoint(op.forward(x) * phi_inv)
        lam = float(np.linalg.norm(y))
        if lam == 0.0:
            return 1.0
        x = (y / lam).astype(dtype, copy=False)
    return 1.02 * lam


def row_norms_sq(op: LinearOperator) -> np.ndarray:
    r"""The diagonal of :math:`HH^\top` that GAP's projection needs; an operator without
    per-row norms (its rows share pixels, e.g. a blurred model) is an input error, not a crash."""
    try:
        return op.row_norms_sq()
    except NotImplementedError as e:
        raise InputError(f"gap-tv needs the operator's row norms: {e}") from None


def safe_reciprocal(a: np.ndarray, dtype) -> np.ndarray:
    """``1/a`` where ``a > 0``, else 0 (rows of H that see nothing carry no information)."""
    a = np.asarray(a, dtype=np.float64)
    out = np.zeros(a.shape, dtype=np.float64)
    np.divide(1.0, a, out=out, where=a > 0)
    return out.astype(dtype)
