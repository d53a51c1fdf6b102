r"""GAP: generalized alternating projection with a prior's denoising step (Yuan 2016).

X. Yuan, "Generalized alternating projection based total variation minimization for
compressive sensing", ICIP 2016.  With :math:`\Phi = \mathrm{diag}(HH^\top)` (the operator's
``row_norms_sq()``) and a prior :math:`\varphi` (:mod:`recon.priors`; by default
:math:`\tau\,\mathrm{TV}`, GAP-TV), one iteration of the accelerated form is

.. math::

    y_{k}   &= y_{k-1} + (g - Hf_{k-1}), \quad y_0 = g                     \\
    \theta_k &= f_{k-1} + H^\top\!\bigl(\Phi^{-1}(y_k - Hf_{k-1})\bigr)   \\
    f_k     &= \mathrm{prox}_{\varphi}(\theta_k)

(the plain form uses :math:`g` instead of :math:`y_k`).  For single-view CASSI
:math:`HH^\top` is diagonal, so the :math:`\theta` step is the exact Euclidean projection on
:math:`\{f: Hf = y_k\}`; with several views it is the usual diagonal approximation.  The
denoising step is the prior's prox at step 1 (a plug-and-play denoiser in its place gives
PnP-GAP).

Speed: the TV step is a Chambolle dual projection whose dual is carried over from one outer
iteration to the next, so 1-2 inner iterations replace the 5 cold ones of the public code.
:math:`Hf_k` is computed once per iteration and reused by the next one (and by the objective).
The :math:`\theta` step and the denoising step go through the prior's ``gradient_prox``
(:mod:`recon.priors.base`): for TV one pass over the cube where the operator allows
(:meth:`TVProx.gradient_prox <recon.prox.TVProx.gradient_prox>`: single-view CASSI and other
small permutation-view CASSI operators), else ``adjoint_add`` then the prox.
"""

from __future__ import annotations

import math

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.priors.base import describe as prior_info
from recon.priors.base import gradient_prox, state_change
from recon.solvers.base import (IterationLoop, SolverResult, check_problem,
                                preconditioned_norm_sq, prior_value, resolve_prior, row_norms_sq,
                                safe_reciprocal)

__all__ = ["gap_tv"]


def projection_weights(op: LinearOperator, dtype,
                       step: float | None = None) -> tuple[np.ndarray, float]:
    r"""GAP's weights :math:`s\,\Phi^{-1}`, :math:`\Phi = \mathrm{diag}(HH^\top)`, shape ``oshape``.

    The step :math:`s` is 1 where :math:`HH^\top` is diagonal and
    :math:`1/\lVert\Phi^{-1/2}H\rVert^2` otherwise (several views share scene voxels), unless
    given.  Rows of :math:`H` that are zero get weight 0.  Returns the weights and :math:`s`.
    """
    phi_inv = safe_reciprocal(row_norms_sq(op), dtype)
    if phi_inv.shape != op.oshape:
        raise InputError(f"row_norms_sq() shape {phi_inv.shape} != oshape {op.oshape}")
    if not np.any(phi_inv):
        # H = 0 (e.g. an all-closed mask): every f fits the data, so the answer would be the
        # start, 0, with no warning.  TwIST and FISTA refuse this problem too.
        raise InputError("the operator is zero (every row of H is zero, e.g. an all-closed "
                         "mask): nothing to reconstruct")
    if step is None:
        step = 1.0 / preconditioned_norm_sq(op, phi_inv, dtype=dtype)
    step = float(step)
    if not (math.isfinite(step) and step > 0):
        raise InputError(f"step must be > 0, got {step}")
    if step != 1.0:
        phi_inv *= step
    return phi_inv, step


def gap_tv(op: LinearOperator, g: np.ndarray, *, iters: int = 50, prior=None,
           tau: float | None = None, x0: np.ndarray | None = None, tol: float | None = None,
           callback=None, tv_iters: int | None = None, warm_dual: bool | None = None,
           accelerate: bool = True, isotropic: bool | None = None, objective: bool = False,
           step: float | None = None, threads: int | None = None,
           state: dict | None = None, keep_state: bool = False) -> SolverResult:
    r"""Reconstruct with GAP and a prior (by default TV: GAP-TV).

    Parameters
    ----------
    op : LinearOperator
        ishape ``(L, H, W)``, any oshape; ``op.row_norms_sq()`` gives :math:`\Phi`.
    g : ndarray, shape ``op.oshape``
        The measurement (float64 keeps the loop in float64).
    iters : int
        Outer iterations.
    prior : Prior or str, optional
        The prior :math:`\varphi` whose prox (step 1) is the denoising step
        (:mod:`recon.priors`; a name is built with ``tau`` as its weight).  Default:
        :math:`\tau\,\mathrm{TV}` with the options below.
    tau : float, optional
        The TV-denoising weight :math:`\lambda` of every step (for data scaled to about [0, 1],
        0.05-0.2; default :data:`recon.priors.tv.DEFAULT_WEIGHT`\ ``["gap"]``).  GAP-TV does
        not minimise :math:`\frac12\|g-Hf\|^2+\tau\mathrm{TV}(f)` exactly; the objective it
        reports uses the same ``tau``.
    x0 : ndarray, shape (L, H, W), optional
        Warm start; :math:`H^\top\Phi^{-1} g` (the minimum-norm solution when
        :math:`HH^\top` is diagonal) if omitted.
    tol : float, optional
        Stop when the relative change of :math:`f` falls below it.
    callback : Callback, optional
    tv_iters : int, optional
        Chambolle iterations per outer iteration (default 2).
    warm_dual : bool, optional
        Keep the TV dual between outer iterations (default).  ``False`` with ``tv_iters=5``
        is the public GAP-TV.
    accelerate : bool
        The accelerated update (default) or the plain one.
    isotropic : bool, optional
        Isotropic (default) or anisotropic TV.
    objective : bool
        Record :math:`\frac12\|g-Hf_k\|^2+\varphi(f_k)` every iteration (a TV norm per
        iteration; the forward is reused), where the prior has a value.
    step : float, optional
        Step :math:`\mu` of the projection, :math:`\theta_k = f_{k-1} + \mu H^\top\Phi^{-1}(\dots)`.
        Default :math:`1/\nu` with :math:`\nu = \|\Phi^{-1/2}H\|^2`
        (:func:`~recon.solvers.base.preconditioned_norm_sq`): 1 for single-view CASSI (the
        exact projection), smaller with several views, where :math:`\mu = 1` diverges.
    threads : int, optional
        Threads of the TV prox (:class:`~recon.prox.TVProx`).
    state : dict, optional
        Continue an earlier run (a video's previous frame): its ``info["state"]``, whose
        ``offset`` :math:`e = y_K - g_\mathrm{prev}` starts the accumulator at
        :math:`y_0 = g + e` and whose other entries go to the prior's ``load_state`` (TV: its
        dual).
    keep_state : bool
        Return that state in ``info["state"]``.

    Returns
    -------
    SolverResult

    Raises
    ------
    InputError
        Bad inputs (see :func:`~recon.solvers.base.check_problem`), or an operator that is
        zero (:math:`\Phi = 0`, e.g. an all-closed mask).

    Notes
    -----
    With the accelerated update, ``tau`` does not fix the end point.  :math:`y_k` accumulates
    the residuals, so the iteration moves towards a data-consistent cube (a Bregman iteration)
    whatever ``tau``: a large ``tau`` slows the approach but does not flatten the cube, and on
    noisy data more iterations (or more views, i.e. more rows to fit) eventually fit the noise.
    The plain update (``accelerate=False``) has a ``tau``-dependent fixed point: as
    ``tau`` grows it tends to a cube that is flat in every band, at the levels of the
    :math:`\Phi^{-1}`-weighted least-squares fit.  ``tests/recon/stress`` checks both.
    """
    g, x0, dtype = check_problem(op, g, x0, iters, tau, tol)
    prior = resolve_prior(prior, "gap", op.ishape, dtype, tau=tau, tv_iters=tv_iters,
                          warm_dual=warm_dual, isotropic=isotropic, threads=threads)
    loop = IterationLoop(tol, callback)
    phi_inv, step = projection_weights(op, dtype, step)

    f = x0 if x0 is not None else np.ascontiguousarray(op.adjoint(g * phi_inv), dtype=dtype)
    # The accumulator starts at g: with the minimum-norm start (Hf = g) the first step is then
    # a pure TV step, where y = 0 would first send f to zero.
    y = g.copy()
    if state is not None:
        state = dict(state)
        offset = state.pop("offset", None)
        if hasattr(prior, "load_state"):
            prior.load_state(state)
        if offset is not None:
            if np.shape(offset) != g.shape:
                raise InputError(f"state offset shape {np.shape(offset)} != {g.shape}")
            y += np.asarray(offset, dtype=dtype)
    r = np.empty_like(g)
    f_prev = np.empty_like(f) if loop.needs_change else None
    hf = op.forward(f)
    history: list[float] = []

    for it in range(1, iters + 1):
        if f_prev is not None:
            np.copyto(f_prev, f)
        if accelerate:
            y += g
            y -= hf
            np.subtract(y, hf, out=r)
        else:
            np.subtract(g, hf, out=r)
        r *= phi_inv
        # The projection and the TV step, fused into one pass over the cube where the
        # operator allows (TVProx.gradient_prox).
        gradient_prox(prior, op, r, f, 1.0, out=f)
        hf = op.forward(f).astype(dtype, copy=False)
        obj = None
        if objective:
            value = prior_value(prior, f)
            if value is not None:
                np.subtract(g, hf, out=r)
                obj = 0.5 * float(np.vdot(r, r)) + value
                history.append(obj)
        change = loop.relative_change(f, f_prev, f_prev) if f_prev is not None else None
        if loop.step(it, f, change, obj, prior_change=state_change(prior)):
            break

    info = {"accelerate": accelerate, "step": step, **prior_info(prior)}
    if keep_state:
        state_out = prior.state() if hasattr(prior, "state") else {}
        info["state"] = {**state_out, "offset": y - g}
    return SolverResult(x=f, iterations=loop.iterations, objective=history,
                        seconds=loop.seconds(), converged=loop.converged, info=info)
