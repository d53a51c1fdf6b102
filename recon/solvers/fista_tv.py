r"""FISTA: fast iterative shrinkage/thresholding (Beck & Teboulle 2009) with any prior.

A. Beck, M. Teboulle, "Fast gradient-based algorithms for constrained total variation image
denoising and deblurring problems", IEEE TIP 18(11), 2009.  For

.. math::

    \min_f \; \tfrac12\|g-Hf\|_2^2 + \varphi(f)

(:math:`\varphi` a prior of :mod:`recon.priors`, by default :math:`\tau\,\mathrm{TV}`) with
:math:`L \ge \|H\|_2^2` (power iteration):

.. math::

    f_k &= \mathrm{prox}_{\varphi/L}\bigl(z_k + H^\top(g-Hz_k)/L\bigr) \\
    t_{k+1} &= \bigl(1+\sqrt{1+4t_k^2}\bigr)/2, \qquad
    z_{k+1} = f_k + \frac{t_k-1}{t_{k+1}}(f_k - f_{k-1}).

with an adaptive restart of the momentum (O'Donoghue & Candès 2015).  It minimises the same
objective as TwIST for any operator (any number of views, no
assumption on :math:`HH^\top`), with one forward and one adjoint per iteration.  The TV prox is
warm-started from the previous dual.  With a plug-and-play denoiser in place of the prox
(a prior whose ``value`` is None) it is PnP-FISTA, and the restart tests the step's direction
only.  A prior that re-estimates a state from the iterate (a spectral basis,
:meth:`~recon.priors.base.PriorBase.state_change`) has an objective
:math:`F_k(f) = \tfrac12\|g-Hf\|^2 + \varphi_k(f)` of each iteration's own; the restart
test compares :math:`F_k(f_k)` with :math:`F_k(f_{k-1})`, the previous iterate scored again
with the new state.

With ``metric="bands"`` the step is taken in a diagonal metric :math:`D` constant over each
band (:mod:`recon.solvers.band_metric`), :math:`H^\top H \preceq D`:

.. math::

    f_k = \mathrm{prox}^D_{\varphi}\bigl(z_k + D^{-1}H^\top(g-Hz_k)\bigr),

the same objective, the restart test taken in the metric; the bands the operator sees weakly
are no longer held to the strong bands' step.  It needs a prior that separates over the bands
and is 1-homogeneous (TV); ``metric="auto"`` falls back to the scalar step for others.
"""

from __future__ import annotations

import math

import numpy as np

from recon import kernels
from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.priors.base import describe as prior_info
from recon.priors.base import previous_value, prox_value, state_change
from recon.solvers.base import (IterationLoop, SolverResult, check_problem, data_misfit,
                                operator_norm_sq, prior_value, resolve_prior)

__all__ = ["fista_tv", "uses_band_metric"]


def fista_tv(op: LinearOperator, g: np.ndarray, *, iters: int = 50, prior=None,
             tau: float | None = None, x0: np.ndarray | None = None, tol: float | None = None,
             callback=None, tv_iters: int | None = None, warm_dual: bool | None = None,
             lipschitz: float | None = None, isotropic: bool | None = None,
             objective: bool = False, restart: bool = True,
             threads: int | None = None, metric: str = "scalar",
             metric_exponent: float | None = None, band_metric=None,
             start: str = "adjoint", constants=None) -> SolverResult:
    r"""Reconstruct with FISTA and a prior (by default TV).

    Parameters
    ----------
    op : LinearOperator
        ishape ``(L, H, W)``, any oshape.
    g : ndarray, shape ``op.oshape``
    iters : int
    prior : Prior or str, optional
        The prior :math:`\varphi` (:mod:`recon.priors`; a name is built with ``tau`` as its
        weight).  Default: :math:`\tau\,\mathrm{TV}` with the options below.
    tau : float, optional
        Weight :math:`\tau` of the TV term (default
        :data:`recon.priors.tv.DEFAULT_WEIGHT`\ ``["fista"]``).
    x0 : ndarray, optional
        Start; if omitted, ``start`` says which.
    tol : float, optional
        Stop when the relative change of :math:`f` falls below it.
    callback : Callback, optional
    tv_iters : int, optional
        Chambolle iterations per prox (warm-started; default 2).
    warm_dual : bool, optional
        Default True.
    lipschitz : float, optional
        :math:`L \ge \|H\|^2`; a power iteration if omitted.
    isotropic : bool
    objective : bool
        Record the objective of every iterate (one extra forward per iteration).
    restart : bool
        Adaptive restart of the momentum (default on) when the objective rises or the step
        points against the generalised gradient; costs one forward and a TV norm per
        iteration (the prior's value, where it has one).  Without it the inexact
        (warm-started) prox makes FISTA oscillate.
    threads : int, optional
        Threads of the TV prior and of the momentum's vector kernels.
    metric : {"scalar", "bands", "auto"}
        The step's metric: ``"scalar"`` the step :math:`1/L`; ``"bands"`` a diagonal metric
        constant over each band (:mod:`recon.solvers.band_metric`: the weak bands no longer
        held to the strong ones' step), for priors that separate over the bands and are
        1-homogeneous (TV: the same objective) or that may be taken on the band-weighted cube
        (``subspace-tv``: the prior then reads :math:`\varphi(w\odot x)`); an input error for
        others; ``"auto"`` the band metric where the prior allows it, else the scalar one.
        With ``"bands"``, ``lipschitz`` is not taken.
    metric_exponent : float, optional
        The band metric's exponent :math:`p` in [0, 1]
        (:data:`recon.solvers.band_metric.DEFAULT_EXPONENT` if omitted).
    band_metric : array_like, shape (L,), optional
        The band metric's diagonal :math:`d_l`
        (:func:`recon.solvers.band_metric.band_metric` of this operator), where it has been
        estimated already: the loop takes it instead of estimating it again (frames of a
        sequence through one operator).  Only where the loop runs in the band metric, and
        not with ``metric_exponent``.
    start : {"adjoint", "normalised"}
        The start when ``x0`` is omitted: the gradient step from zero (:math:`H^\top g/L`,
        or :math:`D^{-1}H^\top g` in the band metric), or the normalised back-projection
        :math:`H^\top g / H^\top H\mathbf 1` (:mod:`recon.solvers.start`: without the
        mask's pattern; one forward and one adjoint more).
    constants : recon.solvers.constants.OperatorConstants, optional
        This operator's constants from earlier solves: the band metric or :math:`\|H\|^2`
        is taken from it where it holds them (else estimated and added to it).

    Returns
    -------
    SolverResult
    """
    g, x0, dtype = check_problem(op, g, x0, iters, tau, tol)
    prior = resolve_prior(prior, "fista", op.ishape, dtype, tau=tau, tv_iters=tv_iters,
                          warm_dual=warm_dual, isotropic=isotropic, threads=threads)
    from recon.solvers.constants import OperatorConstants, band_metric_name, lipschitz_name
    from recon.solvers.start import STARTS, normalised_backprojection

    if start not in STARTS:
        raise InputError(f"start must be one of {', '.join(STARTS)}, got {start!r}")
    bands = uses_band_metric(metric, prior, lipschitz)
    loop = IterationLoop(tol, callback, restarts=restart)
    # Without the caller's memo, one for this solve: each constant is estimated either way.
    memo = OperatorConstants() if constants is None else constants
    if bands:
        from recon.solvers.band_metric import DEFAULT_EXPONENT, BandMetric, band_scalable
        from recon.solvers.band_metric import band_metric as estimate_metric

        if band_metric is None:
            exponent = DEFAULT_EXPONENT if metric_exponent is None else metric_exponent
            d = memo.get(band_metric_name(exponent, dtype),
                         lambda: estimate_metric(op, dtype, exponent),
                         check=lambda v: np.shape(v) == op.ishape[:1])
        elif metric_exponent is not None:
            raise InputError("band_metric is estimated with its exponent already: give "
                             "band_metric or metric_exponent, not both")
        else:
            d = np.asarray(band_metric, dtype=np.float64)
            if d.shape != op.ishape[:1]:
                raise InputError(f"band_metric must hold one value per band, shape "
                                 f"{op.ishape[:1]}, got {d.shape}")
        bm = BandMetric(d, dtype, weighted=not band_scalable(prior))
        lip = bm.dmax
    else:
        if metric_exponent is not None:
            raise InputError("metric_exponent sets the band metric: give metric='bands'")
        if band_metric is not None:
            raise InputError("band_metric is the band metric's: this solve runs in the scalar "
                             "metric (metric='scalar', a lipschitz, or a prior the band metric "
                             "does not take)")
        bm = None
        lip = float(lipschitz) if lipschitz is not None else \
            memo.get(lipschitz_name(dtype), lambda: operator_norm_sq(op, dtype=dtype),
                     check=lambda v: np.ndim(v) == 0)
    if not lip > 0:
        raise InputError("the operator is zero (or lipschitz <= 0): nothing to reconstruct")

    if x0 is None and start == "normalised":
        x0 = normalised_backprojection(op, g, dtype)
    elif x0 is None:
        # H^T g / L (scalar metric) or D^{-1} H^T g (band metric): the first gradient step
        # from zero.
        x0 = np.ascontiguousarray(op.adjoint(g), dtype=dtype)
        if bm is None:
            x0 /= lip
        else:
            x0 *= (1.0 / bm.d).astype(dtype)[:, None, None]
    f = x0
    f_prev = f.copy()
    z = f.copy()
    t = 1.0
    restarts = 0
    prev_obj = math.inf
    prev_misfit = None
    history: list[float] = []
    step = np.empty_like(f)
    # Residuals g - H(.) of f_k and f_{k-1} (computed for the restart test) give that of
    # z_{k+1} = f_k + b (f_k - f_{k-1}) by linearity: g - Hz = r_k + b (r_k - r_{k-1}).  So
    # with the restart on, one forward per iteration instead of two.
    r_f = r_f_prev = r_z = None
    for it in range(1, iters + 1):
        if r_z is None:
            r_z = op.forward(z)
            np.subtract(g, r_z, out=r_z)
        f_prev, f = f, f_prev
        if bm is None:
            op.adjoint_add(r_z, z, 1.0 / lip, out=step)
            prior.prox(step, 1.0 / lip, out=f)
        else:
            bm.scaled_step(op, r_z, z, out=step)
            bm.prox(prior, step, out=f)
        # Adaptive restart (O'Donoghue & Candes 2015): momentum is dropped when the objective
        # rises or the step f - f_prev points against the generalised gradient z - f.  With
        # an inexact (warm-started) prox plain FISTA oscillates instead of converging.
        obj = None
        if objective or restart:
            misfit, r_new = data_misfit(op, g, f)
            r_f_prev, r_f = r_f, r_new
            # `step` is free here (the prox has read it; the change test below reuses it).
            # The prox's own value where the prior keeps it (f is its result), else a value
            # call.
            value = _prox_result_value(prox_value, prior, f, bm, step)
            obj = None if value is None else misfit + value
            if obj is not None and prev_misfit is not None and state_change(prior) is not None:
                # A prior that re-estimates a state (a basis) from each iterate changes its
                # value from one iteration to the next: the previous iterate is scored again
                # with this iteration's state, so that the test sees the step, not the turn.
                # f_prev is the previous prox's result: a prior that keeps it in a cheaper
                # form (the subspace's coefficients) scores it from there.
                again = _prox_result_value(previous_value, prior, f_prev, bm, step)
                prev_obj = prev_obj if again is None else prev_misfit + again
            prev_misfit = misfit
        # The momentum step is taken in the same pass as the restart test's inner product
        # and the relative change; when the inner product then asks for a restart, z is
        # reset to f (a restart is rare: a few times a solve).
        forced = restart and obj is not None and obj > prev_obj
        t_next, b = _momentum(1.0 if forced else t)
        dot, change = _momentum_pass(z, f, f_prev, b, bm, threads, step, loop.needs_change)
        if forced or (restart and dot > 0):
            if not forced:
                t_next, b = _momentum(1.0)
                np.copyto(z, f)
            restarts += 1
            loop.restarted()
        prev_obj = obj if obj is not None else prev_obj
        t = t_next
        r_z = None
        if r_f is not None and b == 0.0:
            r_z = r_f.copy()
        elif r_f is not None and r_f_prev is not None:
            r_z = np.subtract(r_f, r_f_prev)
            r_z *= b
            r_z += r_f
        if objective and obj is not None:
            history.append(obj)
        if loop.step(it, f, change, obj, prior_change=state_change(prior)):
            break

    return SolverResult(x=f, iterations=loop.iterations, objective=history,
                        seconds=loop.seconds(), converged=loop.converged,
                        info={"lipschitz": lip, "restarts": restarts,
                              "metric": "bands" if bands else "scalar",
                              **({} if bm is None else {"band_weighted": bm.weighted}),
                              **({} if bm is None else {"band_metric": bm.d.tolist()}),
                              **prior_info(prior)})


def _prox_result_value(kept, prior, x: np.ndarray, bm, work: np.ndarray) -> float | None:
    r"""The prior's value of ``x``, a result of its prox, as the loop minimises it:
    ``kept(prior)`` (:func:`~recon.priors.base.prox_value` of the last result,
    :func:`~recon.priors.base.previous_value` of the one before) where the prior keeps it,
    else a value call; in the band metric ``bm`` its
    :meth:`~recon.solvers.band_metric.BandMetric.kept_value` (``work`` its scratch)."""
    if bm is not None:
        return bm.kept_value(kept, prior, x, work=work)
    value = kept(prior)
    return prior_value(prior, x) if value is None else value


def uses_band_metric(metric: str, prior, lipschitz=None) -> bool:
    """Whether :func:`fista_tv` runs in the band metric with ``metric``, ``prior`` (an object
    or class whose ``band_scalable`` / ``band_weighted`` say so) and ``lipschitz`` (see
    :func:`fista_tv`'s ``metric``); an input error for a combination it refuses."""
    from recon.solvers.band_metric import METRICS, band_scalable, band_weighted

    if metric not in METRICS:
        raise InputError(f"metric must be one of {', '.join(METRICS)}, got {metric!r}")
    if metric == "scalar":
        return False
    if not (band_scalable(prior) or band_weighted(prior)):
        if metric == "bands":
            raise InputError(f"the band metric needs a prior that separates over the bands "
                             f"and is 1-homogeneous (TV), or one that may be taken on the "
                             f"band-weighted cube (subspace-tv); "
                             f"{prior_info(prior)['prior']!r} is neither: use "
                             f"metric='scalar' or 'auto'")
        return False
    if lipschitz is not None:
        if metric == "bands":
            raise InputError("lipschitz sets the scalar step; the band metric estimates its "
                             "own: give one or the other")
        return False
    return True


def _momentum(t: float) -> tuple[float, float]:
    r"""FISTA's next :math:`t_{k+1} = (1+\sqrt{1+4t_k^2})/2` and the momentum
    :math:`\beta = (t_k-1)/t_{k+1}`."""
    t_next = 0.5 * (1.0 + math.sqrt(1.0 + 4.0 * t * t))
    return t_next, (t - 1.0) / t_next


def _momentum_pass(z: np.ndarray, f: np.ndarray, f_prev: np.ndarray, b: float, bm,
                   threads: int | None, work: np.ndarray, change: bool
                   ) -> tuple[float, float | None]:
    r"""The restart test's inner product :math:`\langle z - f, f - f_\mathrm{prev}\rangle`
    (in the band metric ``bm`` where given: each band's term times :math:`d_l`), then ``z``
    :math:`= f + b (f - f_\mathrm{prev})`, and the relative change
    :math:`\|f - f_\mathrm{prev}\| / \|f_\mathrm{prev}\|` where ``change`` asks for it.

    One pass over the three cubes where the kernels run
    (:func:`recon.kernels.vector.momentum_pass`); otherwise the three NumPy steps it
    replaces (the reference, ``work`` their scratch).  Returns ``(dot, change or None)``."""
    from recon.solvers.base import IterationLoop

    arrays = (z, f, f_prev)
    if kernels.usable(*arrays) and all(a.flags.c_contiguous for a in arrays):
        from recon.kernels import vector as kvec

        n_bands = f.shape[0]
        flat = [a.reshape(n_bands, -1) for a in arrays]
        nb = kvec.blocks(flat[0].shape[1])
        dots, sq, size = (np.empty((n_bands, nb), dtype=np.float64) for _ in range(3))
        with kernels.threads(threads):
            kvec.momentum_pass(*flat, z.dtype.type(b), dots.reshape(-1), sq.reshape(-1),
                               size.reshape(-1))
        per_band = dots.sum(axis=1)
        dot = float(per_band.sum()) if bm is None else \
            float(sum(w * d for w, d in zip(bm.d, per_band)))
        if not change:
            return dot, None
        num, den = math.sqrt(float(sq.sum())), math.sqrt(float(size.sum()))
        return dot, (num / den if den > 0 else (0.0 if num == 0 else math.inf))
    dot = _restart_dot(z, f, f_prev, work, threads) if bm is None else \
        bm.restart_dot(z, f, f_prev, threads)
    _extrapolate(f, f_prev, b, z, threads)
    return dot, (IterationLoop.relative_change(f, f_prev, work) if change else None)


def _restart_dot(z: np.ndarray, f: np.ndarray, f_prev: np.ndarray, work: np.ndarray,
                 threads: int | None) -> float:
    r""":math:`\langle z - f, f - f_\mathrm{prev}\rangle`, the restart test's inner product:
    one pass without storing the differences where the kernels run, else through ``work``."""
    if kernels.usable(z, f, f_prev) and all(a.flags.c_contiguous for a in (z, f, f_prev)):
        from recon.kernels import vector as kvec

        partial = np.empty(kvec.blocks(z.size), dtype=np.float64)
        with kernels.threads(threads):
            kvec.diff_dot(z.reshape(-1), f.reshape(-1), f_prev.reshape(-1), partial)
        return float(partial.sum())
    np.subtract(z, f, out=work)
    d = np.subtract(f, f_prev)
    return float(np.vdot(work, d))


def _extrapolate(f: np.ndarray, f_prev: np.ndarray, b: float, out: np.ndarray,
                 threads: int | None) -> np.ndarray:
    r"""``out`` :math:`= f + b (f - f_\mathrm{prev})`; ``out`` may be neither input."""
    if kernels.usable(f, f_prev, out) and all(a.flags.c_contiguous for a in (f, f_prev, out)):
        from recon.kernels import vector as kvec

        with kernels.threads(threads):
            kvec.extrapolate(f.reshape(-1), f_prev.reshape(-1), out.dtype.type(b),
                             out.reshape(-1))
        return out
    np.subtract(f, f_prev, out=out)
    out *= b
    out += f
    return out
