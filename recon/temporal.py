r"""A temporal total-variation term for video: frame *t* tied to the reconstruction of *t − 1*.

For a video :math:`f_1, f_2, \dots` the temporal TV :math:`\mu\sum_t\lVert f_t - f_{t-1}\rVert_1`
couples all frames.  Solved frame by frame (causally) with the previous reconstruction
:math:`r = \hat f_{t-1}` held fixed, frame *t* solves

.. math:: \min_f \tfrac12\lVert g_t - Hf\rVert_2^2 + \tau\,\mathrm{TV}(f) + \mu\lVert f - r\rVert_1 .

The proximal map of the last term is a soft threshold towards the reference,

.. math:: \mathrm{prox}_{\mu\lVert\cdot - r\rVert_1}(v) = r + \operatorname{sign}(v - r)\,
          \max(|v - r| - \mu, 0),

(:func:`temporal_prox`): voxels that changed by less than :math:`\mu` keep the previous value,
which suppresses frame-to-frame flicker of the noise while moving edges (large changes) pass
shrunk by :math:`\mu`.  :func:`gap_tv_temporal` is GAP-TV (:mod:`recon.solvers.gap_tv`) whose
denoising step applies the spatial TV prox and then :func:`temporal_prox` (a sequential
splitting of the prox of the sum, exact when the two commute, as plug-and-play video solvers
do).  ``mu = 0`` gives GAP-TV exactly.
"""

from __future__ import annotations

import math

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.prox.tv import TVProx
from recon.solvers.base import IterationLoop, SolverResult, check_problem
from recon.solvers.gap_tv import projection_weights

__all__ = ["temporal_prox", "gap_tv_temporal"]


def temporal_prox(v: np.ndarray, ref: np.ndarray, mu: float, out: np.ndarray | None = None
                  ) -> np.ndarray:
    r"""Soft threshold of ``v`` towards ``ref``: :math:`r + \mathrm{soft}(v - r, \mu)`.

    Parameters
    ----------
    v, ref : ndarray, same shape
    mu : float
        Threshold, ≥ 0.
    out : ndarray, optional
        Output buffer (may be ``v``).
    """
    if not (math.isfinite(mu) and mu >= 0):
        raise InputError(f"mu must be finite and >= 0, got {mu}")
    v = np.asarray(v)
    ref = np.asarray(ref)
    if v.shape != ref.shape:
        raise InputError(f"temporal_prox: shapes differ, {v.shape} vs {ref.shape}")
    if out is None:
        out = np.empty_like(v)
    np.subtract(v, ref, out=out)
    d = np.abs(out)
    d -= v.dtype.type(mu)
    np.maximum(d, 0, out=d)
    np.copysign(d, out, out=out)
    out += ref
    return out


def gap_tv_temporal(op: LinearOperator, g: np.ndarray, *, ref: np.ndarray, mu: float,
                    iters: int = 20, tau: float = 0.1, x0: np.ndarray | None = None,
                    tol: float | None = None, callback=None, tv_iters: int = 2,
                    step: float | None = None, threads: int | None = None,
                    state: dict | None = None) -> SolverResult:
    r"""GAP-TV with the temporal term :math:`\mu\lVert f - r\rVert_1` (see the module notes).

    Parameters
    ----------
    op : LinearOperator
        ishape ``(L, H, W)``.
    g : ndarray, shape ``op.oshape``
    ref : ndarray (L, H, W)
        The previous frame's reconstruction :math:`r` (band-major).
    mu : float
        Temporal weight (cube units), ≥ 0.
    iters, tau, x0, tol, callback, tv_iters, step, threads
        As :func:`recon.solvers.gap_tv.gap_tv` (accelerated update, warm TV dual).  ``x0``
        defaults to ``ref`` (the warm start).
    state : dict, optional
        The ``info["state"]`` of the previous frame's run: its TV dual ``dual`` and its
        accumulated residual ``offset`` :math:`e = y_K - g_{t-1}`, which start this frame's
        iteration at :math:`y_0 = g_t + e` instead of :math:`g_t`.  The accelerated GAP
        iteration is a Bregman iteration whose accumulator holds the correction for the bias
        of the TV step; carrying it (and the dual) over continues the previous frame's
        iteration on the new data instead of restarting it from its first step.

    Returns
    -------
    SolverResult
        ``info["state"]`` holds ``dual`` and ``offset`` for the next frame.
    """
    g, x0, dtype = check_problem(op, g, x0, iters, tau, tol)
    r = np.ascontiguousarray(ref, dtype=dtype)
    if r.shape != op.ishape:
        raise InputError(f"ref shape {r.shape} does not match the operator's {op.ishape}")
    if not np.all(np.isfinite(r)):
        raise InputError("ref contains NaN or infinite values")
    mu = float(mu)
    if not (math.isfinite(mu) and mu >= 0):
        raise InputError(f"mu must be finite and >= 0, got {mu}")
    if int(tv_iters) < 1:
        raise InputError(f"tv_iters must be >= 1, got {tv_iters}")
    loop = IterationLoop(tol, callback)
    phi_inv, step = projection_weights(op, dtype, step)

    f = x0 if x0 is not None else r.copy()
    prox = TVProx(op.ishape, dtype, True, threads)
    y = g.copy()
    if state is not None:
        dual, offset = state.get("dual"), state.get("offset")
        if dual is not None:
            if np.shape(dual) != prox.dual.shape:
                raise InputError(f"state dual shape {np.shape(dual)} != {prox.dual.shape}")
            np.copyto(prox.dual, dual)
        if offset is not None:
            if np.shape(offset) != g.shape:
                raise InputError(f"state offset shape {np.shape(offset)} != {g.shape}")
            y += np.asarray(offset, dtype=dtype)
    res = np.empty_like(g)
    f_prev = np.empty_like(f) if loop.needs_change else None
    hf = op.forward(f).astype(dtype, copy=False)
    for it in range(1, int(iters) + 1):
        if f_prev is not None:
            np.copyto(f_prev, f)
        y += g
        y -= hf
        np.subtract(y, hf, out=res)
        res *= phi_inv
        op.adjoint_add(res, f, out=f)
        prox(f, tau, tv_iters, warm=True, out=f)
        if mu > 0:
            temporal_prox(f, r, mu, out=f)
        hf = op.forward(f).astype(dtype, copy=False)
        change = loop.relative_change(f, f_prev, f_prev) if f_prev is not None else None
        if loop.step(it, f, change, None):
            break
    return SolverResult(x=f, iterations=loop.iterations, seconds=loop.seconds(),
                        converged=loop.converged,
                        info={"tv_iters": int(tv_iters), "step": step, "mu": mu,
                              "state": {"dual": prox.dual.copy(), "offset": y - g}})
