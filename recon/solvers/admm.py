r"""ADMM (half-quadratic splitting with a scaled dual): the solver for plug-and-play priors.

For

.. math::

    \min_f \; \tfrac12\|g-Hf\|_2^2 + \varphi(f)

with any prior :math:`\varphi` of :mod:`recon.priors` (by default :math:`\tau\,\mathrm{TV}`),
split :math:`f = z` and iterate, with the penalty :math:`\rho > 0` and the scaled dual
:math:`u` (Boyd et al. 2011, Sec. 3.1.1):

.. math::

    x_{k+1} &= \arg\min_x \tfrac12\|g-Hx\|^2 + \tfrac\rho2\|x - (z_k - u_k)\|^2
             = (H^\top H + \rho I)^{-1}\bigl(H^\top g + \rho(z_k - u_k)\bigr) \\
    z_{k+1} &= \mathrm{prox}_{\varphi/\rho}(x_{k+1} + u_k) \\
    u_{k+1} &= u_k + x_{k+1} - z_{k+1}.

The :math:`x` step is exact where :math:`HH^\top = \Phi` is diagonal (single-view CASSI: the
Sherman–Morrison–Woodbury identity gives
:math:`(H^\top H + \rho I)^{-1} b = \bigl(b - H^\top(\rho + \Phi)^{-1}Hb\bigr)/\rho`, one
forward and one adjoint), and otherwise ``cg_iters`` conjugate-gradient iterations
warm-started from the previous :math:`x` (one forward and one adjoint each, plus one for the
starting residual).  The :math:`z` step is the prior's prox, or for a plug-and-play prior its
denoiser at the strength :math:`1/\rho`; the TV prox is warm-started across iterations.

With a convex prior and an exact :math:`x` step ADMM converges to the minimiser for any
:math:`\rho` (the same one as FISTA and TwIST); :math:`\rho` sets only the speed.  With
``adapt`` the penalty follows the residual balancing rule (Boyd et al. 2011, Sec. 3.4.1):
doubled when the primal residual :math:`\|x-z\|` exceeds 10 times the dual one
:math:`\rho\|z_{k+1}-z_k\|`, halved in the opposite case (and :math:`u` rescaled), at most
``adapt`` times, so that :math:`\rho` is eventually fixed and convergence holds.

S. Boyd, N. Parikh, E. Chu, B. Peleato, J. Eckstein, "Distributed optimization and statistical
learning via the alternating direction method of multipliers", Found. Trends Mach. Learn.
3(1), 2011.  S. V. Venkatakrishnan, C. A. Bouman, B. Wohlberg, "Plug-and-play priors for model
based reconstruction", GlobalSIP 2013.
"""

from __future__ import annotations

import math

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.priors.base import describe as prior_info
from recon.priors.base import state_change
from recon.solvers.base import (IterationLoop, SolverResult, check_problem, data_misfit,
                                gram_is_diagonal, operator_norm_sq, prior_value, resolve_prior,
                                safe_reciprocal)

__all__ = ["admm", "DEFAULT_RHO"]

#: Default penalty :math:`\rho` relative to :math:`\|H\|_2^2` (the operator's scale).
DEFAULT_RHO = 0.1


def admm(op: LinearOperator, g: np.ndarray, *, iters: int = 50, prior=None,
         tau: float | None = None, x0: np.ndarray | None = None, tol: float | None = None,
         callback=None, rho: float | None = None, adapt: int = 10, cg_iters: int = 3,
         exact: bool | None = None, tv_iters: int | None = None,
         warm_dual: bool | None = None, isotropic: bool | None = None,
         objective: bool = False, threads: int | None = None) -> SolverResult:
    r"""Reconstruct with ADMM and a prior (by default TV).

    Parameters
    ----------
    op : LinearOperator
        ishape ``(L, H, W)``, any oshape.
    g : ndarray, shape ``op.oshape``
    iters : int
        Outer iterations.
    prior : Prior or str, optional
        The prior :math:`\varphi` (:mod:`recon.priors`; a name is built with ``tau`` as its
        weight), or a plug-and-play denoiser prior.  Default :math:`\tau\,\mathrm{TV}` with the
        options below.
    tau : float, optional
        Weight of the TV term (default :data:`recon.priors.tv.DEFAULT_WEIGHT`\ ``["admm"]``).
    x0 : ndarray, optional
        Start of :math:`x` and :math:`z`; :math:`H^\top g / \|H\|^2` if omitted.
    tol : float, optional
        Stop when the relative change of :math:`z` falls below it.
    callback : Callback, optional
        Sees :math:`z`, the iterate the solver returns.
    rho : float, optional
        Penalty :math:`\rho > 0`; :data:`DEFAULT_RHO` times :math:`\|H\|^2` if omitted.
    adapt : int
        Most changes of :math:`\rho` by residual balancing (0: fixed :math:`\rho`).
    cg_iters : int
        Conjugate-gradient iterations of the :math:`x` step where it is not exact (>= 1).
    exact : bool, optional
        Force (True) or forbid (False) the exact :math:`x` step; by default it is used where
        :math:`HH^\top` is diagonal (tested by one probe).  True on an operator whose
        :math:`HH^\top` is not diagonal is an input error.
    tv_iters, warm_dual, isotropic
        The TV prior's options (see :class:`~recon.priors.TVPrior`).
    objective : bool
        Record :math:`\frac12\|g-Hz\|^2+\varphi(z)` every iteration (one forward), where the
        prior has a value.
    threads : int, optional
        Threads of the TV prior.

    Returns
    -------
    SolverResult
        ``x`` is :math:`z` (the iterate the prior acted on last); ``info`` has ``rho`` (the
        final one), ``rho_changes``, ``exact``, ``cg_iters``, ``primal_residual`` (the last
        :math:`\|x-z\|/\|z\|`) and the prior's description.

    Raises
    ------
    InputError
        Bad inputs (see :func:`~recon.solvers.base.check_problem`), a zero operator, bad
        ``rho``/``cg_iters``/``adapt``, ``exact=True`` where :math:`HH^\top` is not diagonal.
    """
    g, x0, dtype = check_problem(op, g, x0, iters, tau, tol)
    prior = resolve_prior(prior, "admm", op.ishape, dtype, tau=tau, tv_iters=tv_iters,
                          warm_dual=warm_dual, isotropic=isotropic, threads=threads)
    if isinstance(cg_iters, bool) or int(cg_iters) != cg_iters or cg_iters < 1:
        raise InputError(f"cg_iters must be an integer >= 1, got {cg_iters!r}")
    if isinstance(adapt, bool) or int(adapt) != adapt or adapt < 0:
        raise InputError(f"adapt must be an integer >= 0, got {adapt!r}")
    cg_iters, adapt = int(cg_iters), int(adapt)
    loop = IterationLoop(tol, callback)

    phi = _diagonal_gram(op, dtype, exact)
    use_exact = phi is not None
    if rho is None:
        scale = float(phi.max()) if use_exact else operator_norm_sq(op, dtype=dtype)
        if not scale > 0:
            raise InputError("the operator is zero: nothing to reconstruct")
        rho = DEFAULT_RHO * scale
    rho = float(rho)
    if not (math.isfinite(rho) and rho > 0):
        raise InputError(f"rho must be finite and > 0, got {rho}")

    htg = np.ascontiguousarray(op.adjoint(g), dtype=dtype)
    if x0 is None:
        lip = float(phi.max()) if use_exact else operator_norm_sq(op, dtype=dtype)
        if not lip > 0:
            raise InputError("the operator is zero: nothing to reconstruct")
        x0 = htg / dtype.type(lip)
    x = x0
    z = x.copy()
    u = np.zeros_like(x)
    b = np.empty_like(x)
    v = np.empty_like(x)
    z_prev = np.empty_like(x)
    cg = _CG(op, dtype) if not use_exact else None
    history: list[float] = []
    changes = 0
    primal = math.nan

    for it in range(1, iters + 1):
        # x step: (H^T H + rho I) x = H^T g + rho (z - u)
        np.subtract(z, u, out=b)
        b *= dtype.type(rho)
        b += htg
        if use_exact:
            _exact_step(op, phi, rho, b, out=x)
        else:
            cg.solve(rho, b, x, cg_iters)
        # z step: the prior's prox at step 1/rho
        np.add(x, u, out=v)
        np.copyto(z_prev, z)
        prior.prox(v, 1.0 / rho, out=z)
        # dual step
        u += x
        u -= z
        # Residuals (relative to |z|) for the balancing rule and the info.
        zn = math.sqrt(float(np.vdot(z, z))) or 1.0
        np.subtract(x, z, out=v)
        primal = math.sqrt(float(np.vdot(v, v))) / zn
        np.subtract(z, z_prev, out=v)
        dz = math.sqrt(float(np.vdot(v, v))) / zn
        if changes < adapt:
            dual = rho * dz
            if primal > 10.0 * dual:
                rho *= 2.0
                u *= dtype.type(0.5)
                changes += 1
            elif dual > 10.0 * primal:
                rho *= 0.5
                u *= dtype.type(2.0)
                changes += 1
        obj = None
        if objective:
            value = prior_value(prior, z)
            if value is not None:
                obj = data_misfit(op, g, z)[0] + value
                history.append(obj)
        if loop.step(it, z, dz if loop.needs_change else None, obj,
                     prior_change=state_change(prior), rho=rho):
            break

    return SolverResult(x=z, iterations=loop.iterations, objective=history,
                        seconds=loop.seconds(), converged=loop.converged,
                        info={"rho": rho, "rho_changes": changes, "exact": use_exact,
                              "cg_iters": 0 if use_exact else cg_iters,
                              "primal_residual": primal, **prior_info(prior)})


def _diagonal_gram(op: LinearOperator, dtype, exact: bool | None) -> np.ndarray | None:
    r""":math:`\Phi = \mathrm{diag}(HH^\top)` (shape ``oshape``) where :math:`HH^\top` is
    diagonal and the exact step is allowed, else None."""
    if exact is False:
        return None
    try:
        phi = np.asarray(op.row_norms_sq(), dtype=np.float64)
    except NotImplementedError:
        phi = None
    if phi is not None and phi.shape == tuple(op.oshape) and \
            gram_is_diagonal(op, safe_reciprocal(phi, dtype), dtype):
        return phi.astype(dtype)
    if exact:
        raise InputError("exact=True needs an operator whose H H^T is diagonal (single-view "
                         "CASSI); this one's is not")
    return None


def _exact_step(op: LinearOperator, phi: np.ndarray, rho: float, b: np.ndarray,
                out: np.ndarray) -> np.ndarray:
    r"""``out`` :math:`= (H^\top H + \rho I)^{-1} b = (b - H^\top(\rho+\Phi)^{-1}Hb)/\rho` for a
    diagonal :math:`HH^\top = \Phi`."""
    hb = op.forward(b)
    hb /= (phi + phi.dtype.type(rho))
    op.adjoint_add(hb, b, -1.0, out=out)
    out *= out.dtype.type(1.0 / rho)
    return out


class _CG:
    r"""Conjugate gradients on :math:`(H^\top H + \rho I)x = b`, warm-started from ``x``, with
    its work arrays kept between calls."""

    def __init__(self, op: LinearOperator, dtype):
        self.op = op
        shape = op.ishape
        self.r = np.empty(shape, dtype=dtype)
        self.p = np.empty(shape, dtype=dtype)
        self.ap = np.empty(shape, dtype=dtype)

    def _apply(self, rho: float, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        """``out`` :math:`= (H^\\top H + \\rho I)x` (one forward, one adjoint)."""
        return self.op.adjoint_add(self.op.forward(x), x * out.dtype.type(rho), 1.0, out=out)

    def solve(self, rho: float, b: np.ndarray, x: np.ndarray, n_iter: int) -> np.ndarray:
        r, p, ap = self.r, self.p, self.ap
        self._apply(rho, x, ap)
        np.subtract(b, ap, out=r)
        np.copyto(p, r)
        rr = float(np.vdot(r, r))
        # Stop only at rounding level: an x step solved loosely is a fixed point of the outer
        # iteration (x = z, no change) short of the minimiser.
        stop = float(np.finfo(b.dtype).eps) ** 2 * max(float(np.vdot(b, b)), 1e-300)
        for _ in range(n_iter):
            if rr <= stop:
                break
            self._apply(rho, p, ap)
            pap = float(np.vdot(p, ap))
            if not pap > 0:
                break
            a = rr / pap
            x += x.dtype.type(a) * p
            r -= r.dtype.type(a) * ap
            rr_new = float(np.vdot(r, r))
            p *= p.dtype.type(rr_new / rr)
            p += r
            rr = rr_new
        return x
