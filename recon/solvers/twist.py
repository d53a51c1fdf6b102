r"""TwIST: two-step iterative shrinkage/thresholding (Bioucas-Dias & Figueiredo 2007).

J. M. Bioucas-Dias, M. A. T. Figueiredo, "A new TwIST: two-step iterative
shrinkage/thresholding algorithms for image restoration", IEEE TIP 16(12), 2007 — the solver
of the paper (Sec. 3.2, Eq. 6) for

.. math::

    \min_f \; \tfrac12\|g-Hf\|_2^2 + \varphi(f),

with a prior :math:`\varphi` of :mod:`recon.priors` that has a value (the monotone test needs
the objective), by default :math:`\tau\,\mathrm{TV}` (the paper's).

With :math:`s` an upper estimate of :math:`\|H\|_2^2` (``max_svd``) and
:math:`\Psi_{1/s} = \mathrm{prox}_{\varphi/s}`, the IST step is
:math:`\Gamma(f) = \Psi_{1/s}\bigl(f + H^\top(g-Hf)/s\bigr)` and the two-step update is

.. math::

    f_{t+1} = (1-\alpha) f_{t-1} + (\alpha-\beta) f_t + \beta\,\Gamma(f_t),

with, for the spectrum of :math:`H^\top H/s` in :math:`[\lambda_1, 1]`,
:math:`\rho_0 = (1-\lambda_1)/(1+\lambda_1)`, :math:`\alpha = 2/(1+\sqrt{1-\rho_0^2})`,
:math:`\beta = 2\alpha/(\lambda_1+1)` (the authors' default is :math:`\lambda_1 = 10^{-4}`;
here :math:`10^{-2}`, see :data:`DEFAULT_LAM1`).

Cost per iteration: one adjoint (the gradient step :math:`f_t + H^\top(g-Hf_t)/s`, fused by
:meth:`~recon.operators.LinearOperator.adjoint_add`; a doubling of :math:`s` recomputes it),
one prox and one forward, of :math:`\Gamma(f_t)`.  The candidate's residual needs no forward
of its own: the weights :math:`(1-\alpha) + (\alpha-\beta) + \beta = 1`, so by linearity

.. math::

    g - Hf_{t+1} = (1-\alpha)(g-Hf_{t-1}) + (\alpha-\beta)(g-Hf_t) + \beta\,(g-H\Gamma(f_t)),

and a rejected candidate costs no forward either (its fallback :math:`\Gamma(f_t)` already has
its residual).

Monotone safeguard (on by default, as in the authors' ``TwIST.m``): when a two-step update
raises the objective it is rejected and the plain IST step :math:`\Gamma(f_t)` is taken; if that
too raises the objective, the warm-started prox is first continued on the same input (up to
``_MAX_REFINE`` more dual iterations: a 2-iteration prox is inexact near convergence; the
prior's ``refine``), and only
then is :math:`s` taken to be too small and doubled.  So the objective never increases.  The
first iteration is an IST step.
"""

from __future__ import annotations

import math

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.priors.base import combine_value, linear_combination, refine, state_change
from recon.priors.base import describe as prior_info
from recon.solvers.base import (IterationLoop, SolverResult, check_problem, data_misfit,
                                prior_value, resolve_prior)

__all__ = ["twist", "twist_parameters", "norm_estimate", "DEFAULT_LAM1"]

#: Default lower spectral bound :math:`\lambda_1` of TwIST for CASSI.  The authors' default
#: 1e-4 (alpha = 1.96, beta = 3.92) extrapolates so hard that most two-step updates are rejected
#: by the monotone test and replaced by plain IST steps; 1e-2 (alpha = 1.67, beta = 3.30)
#: reaches a lower objective in 50 iterations on the kaleidoscope benchmark, while 5e-2 is too
#: timid (docs/reconstruction.md).
DEFAULT_LAM1 = 1e-2

# Extra dual iterations (per outer iteration) spent refining an IST step's prox that failed to
# decrease the objective, before max_svd is doubled.  With 2 warm dual iterations such failures
# appear near convergence (measured: 2 doublings in 50 iterations on the kaleidoscope benchmark,
# each halving the step for the rest of the run); refining first removes them.
_MAX_REFINE = 8

# Doublings of max_svd allowed within one iteration before the iterate is kept unchanged.
_MAX_DOUBLINGS = 8


def twist_parameters(lam1: float = 1e-4, lam_n: float = 1.0) -> tuple[float, float]:
    r"""TwIST's :math:`(\alpha, \beta)` for the spectrum bounds :math:`[\lambda_1, \lambda_N]`."""
    if not (0 < lam1 <= lam_n):
        raise InputError(f"need 0 < lam1 <= lam_n, got {lam1}, {lam_n}")
    rho0 = (1 - lam1 / lam_n) / (1 + lam1 / lam_n)
    alpha = 2.0 / (1.0 + math.sqrt(1.0 - rho0 * rho0))
    beta = alpha * 2.0 / (lam1 + lam_n)
    return alpha, beta


def norm_estimate(op: LinearOperator, start: np.ndarray | None = None, n_iter: int = 6,
                  safety: float = 1.02, seed: int = 0) -> float:
    r"""Estimate :math:`\|H\|_2^2`, the top eigenvalue of :math:`A = H^\top H`, by Lanczos.

    ``n_iter`` Lanczos steps build the tridiagonal :math:`T_k = V_k^\top A V_k` of the Krylov
    space of ``start``; its top eigenvalue (a Ritz value) approaches :math:`\lambda_{\max}(A)`
    from below much faster than a power iteration does (measured on the kaleidoscope problem,
    645x501x25, 5 views, from :math:`H^\top g`: 6 steps give 52.4 of about 55.2, where 15
    power iterations from a random start gave 49.9), and the result is multiplied by
    ``safety``.  Any residual underestimate is caught by TwIST's monotone test, which doubles
    :math:`s` when an IST step fails to decrease the objective.

    Parameters
    ----------
    op : LinearOperator
    start : ndarray, shape ``op.ishape``, optional
        Start vector (TwIST passes its first iterate :math:`H^\top g`); random if omitted or
        zero.
    n_iter : int
        Lanczos steps, one forward/adjoint pair each.
    safety : float
    seed : int
        For the random start.

    Returns
    -------
    float
        0.0 when :math:`H` vanishes on the Krylov space (the zero operator).
    """
    n_iter = int(n_iter)
    if n_iter < 1:
        raise InputError(f"norm_iters must be >= 1, got {n_iter}")
    dtype = np.float64 if start is not None and start.dtype == np.float64 else np.float32
    v = None if start is None else np.array(start, dtype=dtype)
    if v is None or not np.any(v):
        from recon.probes import standard_normal

        v = standard_normal(np.random.default_rng(seed), op.ishape, dtype)
    v /= np.linalg.norm(v)
    alphas: list[float] = []
    betas: list[float] = []
    v_prev = None
    tmp = np.empty_like(v)
    for _ in range(n_iter):
        w = np.asarray(op.adjoint(op.forward(v)), dtype=dtype)
        a = float(np.vdot(w, v))
        alphas.append(a)
        w -= np.multiply(v, a, out=tmp)
        if v_prev is not None:
            w -= np.multiply(v_prev, betas[-1], out=tmp)
        b = float(np.sqrt(np.vdot(w, w)))
        if b <= 1e-6 * max(abs(a), 1e-30):
            break  # the Krylov space is invariant: T holds exact eigenvalues
        betas.append(b)
        w *= 1.0 / b
        v_prev, v = v, w
    k = len(alphas)
    t = np.diag(alphas) + np.diag(betas[:k - 1], 1) + np.diag(betas[:k - 1], -1)
    top = float(np.linalg.eigvalsh(t)[-1])
    return safety * top if top > 0 else 0.0


def twist(op: LinearOperator, g: np.ndarray, *, iters: int = 50, prior=None,
          tau: float | None = None, x0: np.ndarray | None = None, tol: float | None = None,
          callback=None, tv_iters: int | None = None, warm_dual: bool | None = None,
          lam1: float = DEFAULT_LAM1, alpha: float | None = None, beta: float | None = None,
          monotone: bool = True, max_svd: float | None = None, norm_iters: int = 6,
          isotropic: bool | None = None, threads: int | None = None) -> SolverResult:
    r"""Reconstruct with TwIST and a prior (by default TV).

    Parameters
    ----------
    op : LinearOperator
        ishape ``(L, H, W)``, any oshape.
    g : ndarray, shape ``op.oshape``
    iters : int
        Outer (accepted) iterations.
    prior : Prior or str, optional
        The prior :math:`\varphi` (:mod:`recon.priors`; a name is built with ``tau`` as its
        weight); it must have a value.  Default: :math:`\tau\,\mathrm{TV}` with the options
        below.
    tau : float, optional
        Weight :math:`\tau` of the TV term (paper: 0.1-0.15; default
        :data:`recon.priors.tv.DEFAULT_WEIGHT`\ ``["twist"]``).
    x0 : ndarray, optional
        Start; :math:`H^\top g` (the paper's choice) if omitted.
    tol : float, optional
        Stop when the relative change of :math:`f` falls below it.
    callback : Callback, optional
    tv_iters : int, optional
        Chambolle iterations per TV prox (default 2).  The paper uses about 10 from a cold start; with the
        warm-started dual (the default) 2 suffice (keep it even: with the dual step 1/4 an odd
        count leaves a period-2 oscillation of a warm dual).
    warm_dual : bool, optional
        Start each prox from the previous dual (default; more accurate for the same cost).
    lam1, alpha, beta : float
        TwIST parameters; ``alpha``/``beta`` default to :func:`twist_parameters` of ``lam1``.
        The default ``lam1`` is :data:`DEFAULT_LAM1` (1e-2), not the paper's 1e-4: see there.
    monotone : bool
        The monotone safeguard (default on).  Without it TwIST can diverge on CASSI.
    max_svd : float, optional
        Estimate of :math:`\|H\|^2`; :func:`norm_estimate` (``norm_iters`` Lanczos steps from
        the first iterate) if omitted.  Doubled whenever an IST step fails to decrease the
        objective.
    norm_iters : int
        Lanczos steps (forward/adjoint pairs) of the norm estimate when ``max_svd`` is omitted.
    isotropic : bool, optional
    threads : int, optional
        Threads of the TV prox, the TV norm and the two-step combination.

    Returns
    -------
    SolverResult
        ``objective`` holds the objective of every accepted iterate; ``info`` has
        ``max_svd``, ``alpha``, ``beta``, ``rejected`` (two-step updates replaced by IST),
        ``svd_doublings``, ``prox_refinements`` (continued proxes of failed IST steps) and
        the prior's description (TV: ``tv_iters`` ...).

    Raises
    ------
    InputError
        Bad inputs, or a prior without a value (a plug-and-play denoiser: use ``fista``,
        ``gap-tv`` or ``admm``).
    """
    g, x0, dtype = check_problem(op, g, x0, iters, tau, tol)
    prior = resolve_prior(prior, "twist", op.ishape, dtype, tau=tau, tv_iters=tv_iters,
                          warm_dual=warm_dual, isotropic=isotropic, threads=threads)
    a_def, b_def = twist_parameters(lam1)
    alpha = a_def if alpha is None else float(alpha)
    beta = b_def if beta is None else float(beta)
    loop = IterationLoop(tol, callback)
    x = x0 if x0 is not None else np.ascontiguousarray(op.adjoint(g), dtype=dtype)
    if max_svd is None:
        max_svd = norm_estimate(op, x, norm_iters)
    max_svd = float(max_svd)
    if not max_svd > 0:
        raise InputError("the operator is zero (or max_svd <= 0): nothing to reconstruct")
    xm1 = x.copy()           # f_{t-1}
    ist = np.empty_like(x)   # Gamma(f_t)
    vin = np.empty_like(x)   # the prox input f_t + H^T(g - H f_t)/s
    new = np.empty_like(x)   # two-step candidate
    # Residuals g - H(.) of f_t, f_{t-1}, Gamma(f_t) and the candidate.  H is linear and the
    # two-step weights sum to one, so the candidate's residual is the same combination of the
    # others: one forward (of Gamma(f_t)) per iteration, whether the candidate is kept or not.
    misfit, resid = data_misfit(op, g, x)
    resid_m1 = resid.copy()
    resid_ist = np.empty_like(resid)
    resid_new = np.empty_like(resid)
    value = prior_value(prior, x)
    if value is None:
        raise InputError(f"twist needs a prior with a value (its monotone test compares "
                         f"objectives); {prior_info(prior)['prior']!r} has none: use fista-tv, "
                         f"gap-tv or admm")
    prev_f = misfit + value
    history: list[float] = []
    rejected = doublings = refinements = 0
    twist_steps = 0          # TwIST.m's TwIST_iters: 0 forces an IST step
    c_m1, c_0 = 1.0 - alpha, alpha - beta

    for it in range(1, iters + 1):
        ist_svd = None       # max_svd for which `ist` holds Gamma(x)
        ist_f = None         # objective at `ist`, once computed
        tries = refined = 0
        svd_at_start = max_svd
        while True:
            if ist_svd != max_svd:
                # The gradient step, fused with the adjoint where the operator can; a
                # doubled s (rare) recomputes the adjoint rather than keeping it.
                op.adjoint_add(resid, x, 1.0 / max_svd, out=vin)
                prior.prox(vin, 1.0 / max_svd, out=ist)
                _residual(op, g, ist, resid_ist)
                ist_svd, ist_f = max_svd, None
                if state_change(prior) is not None:
                    # A prior that re-estimates a state (a basis) in its prox changes its
                    # value with it: the iterate the tests compare with is scored again
                    # with the new state, so that they see the step, not the state's turn.
                    prev_f = 0.5 * float(np.vdot(resid, resid)) + prior.value(x)
            if twist_steps != 0:
                # f_{t+1} = (1-alpha) f_{t-1} + (alpha-beta) f_t + beta Gamma(f_t)
                value_new = combine_value(prior, c_m1, xm1, c_0, x, beta, ist, new)
                linear_combination(c_m1, resid_m1, c_0, resid, beta, resid_ist, resid_new,
                                   threads)
                f_val = 0.5 * float(np.vdot(resid_new, resid_new)) + value_new
                if monotone and f_val > prev_f:
                    rejected += 1
                    twist_steps = 0
                    continue
                twist_steps += 1
                xm1, x, new = x, new, xm1
                resid_m1, resid, resid_new = resid, resid_new, resid_m1
                break
            if ist_f is None:
                ist_f = 0.5 * float(np.vdot(resid_ist, resid_ist)) + prior.value(ist)
            f_val = ist_f
            if f_val > prev_f:
                done = refine(prior, vin, 1.0 / max_svd, ist) if refined < _MAX_REFINE else 0
                if done:
                    # A few warm dual iterations need not decrease the objective near the
                    # optimum: continue the prox on the same input before blaming s.
                    _residual(op, g, ist, resid_ist)
                    refined += done
                    refinements += 1
                    ist_f = None
                    continue
                if tries < _MAX_DOUBLINGS:
                    max_svd *= 2.0
                    doublings += 1
                    tries += 1
                    continue
                # No step decreases the objective (rounding at convergence): stay put.  The
                # doublings did not help, so s was not the cause: undo them, or they pile up
                # over iterations until s overflows float32 and the iterate becomes NaN.
                doublings -= tries
                max_svd = svd_at_start
                f_val = prev_f
                np.copyto(xm1, x)
                np.copyto(resid_m1, resid)
                twist_steps = 0
                break
            twist_steps += 1
            xm1, x, ist = x, ist, xm1
            resid_m1, resid, resid_ist = resid, resid_ist, resid_m1
            break
        history.append(f_val)
        change = None
        if loop.needs_change:
            change = loop.relative_change(x, xm1, new)
        prev_f = f_val
        if loop.step(it, x, change, f_val, prior_change=state_change(prior),
                     max_svd=max_svd):
            break

    return SolverResult(x=x, iterations=loop.iterations, objective=history,
                        seconds=loop.seconds(), converged=loop.converged,
                        info={"max_svd": max_svd, "alpha": alpha, "beta": beta,
                              "rejected": rejected, "svd_doublings": doublings,
                              "prox_refinements": refinements, **prior_info(prior)})


def _residual(op: LinearOperator, g: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
    """``out = g - H x``."""
    np.subtract(g, op.forward(x), out=out)
