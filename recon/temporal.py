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
shrunk by :math:`\mu`.  :class:`TemporalPrior` is the prior of the sum: any spatial prior's
prox and then :func:`temporal_prox` (a sequential splitting of the prox of the sum, exact when
the two commute, as plug-and-play video solvers do), so it goes with any solver.
:func:`gap_tv_temporal` is GAP (:mod:`recon.solvers.gap_tv`) with that prior around TV, and
carries the iteration's state from one frame to the next.
"""

from __future__ import annotations

import math

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.priors.base import PriorBase, check_prior
from recon.priors.base import stages as prior_stages
from recon.priors.base import state_change as prior_state_change
from recon.priors.tv import TVPrior, check_weight, default_weight
from recon.solvers.base import SolverResult, check_problem
from recon.solvers.gap_tv import gap_tv

__all__ = ["temporal_prox", "TemporalPrior", "gap_tv_temporal"]


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


class TemporalPrior(PriorBase):
    r"""A spatial prior plus the temporal term: :math:`\varphi(f) + \mu\lVert f - r\rVert_1`.

    The prox is the spatial prior's, then :func:`temporal_prox` with threshold :math:`s\mu`
    (skipped where :math:`\mu = 0`).

    Parameters
    ----------
    spatial : Prior
        :math:`\varphi`.
    ref : ndarray (L, H, W)
        :math:`r`, the previous frame's reconstruction (band-major).
    mu : float
        Temporal weight (cube units), ≥ 0.
    """

    name = "temporal"

    def __init__(self, spatial, ref: np.ndarray, mu: float):
        self.spatial = check_prior(spatial)
        ref = np.asarray(ref)
        if ref.ndim != 3:
            raise InputError(f"ref must be a band-major (L, H, W) cube, got shape {ref.shape}")
        if not np.all(np.isfinite(ref)):
            raise InputError("ref contains NaN or infinite values")
        self.ref = ref
        mu = float(mu)
        if not (math.isfinite(mu) and mu >= 0):
            raise InputError(f"mu must be finite and >= 0, got {mu}")
        self.mu = mu
        self.threads = getattr(spatial, "threads", None)

    def prox(self, v, step, out=None):
        out = self.spatial.prox(v, step, out=out)
        if self.mu > 0:
            temporal_prox(out, self.ref, self.mu * float(step), out=out)
        return out

    def value(self, x):
        v = self.spatial.value(x)
        if v is None:
            return None
        return v + self.mu * float(np.sum(np.abs(np.subtract(x, self.ref)), dtype=np.float64))

    def reset(self):
        self.spatial.reset()

    def describe(self):
        inner = self.spatial.describe() if hasattr(self.spatial, "describe") else {}
        return {**inner, "temporal_mu": self.mu}

    def state(self):
        return self.spatial.state() if hasattr(self.spatial, "state") else {}

    def load_state(self, state):
        if hasattr(self.spatial, "load_state"):
            self.spatial.load_state(state)

    def state_change(self):
        return prior_state_change(self.spatial)

    def stages(self):
        """The spatial prior's two stages (:func:`recon.priors.base.stages`), each with the
        temporal term around it; None for a spatial prior of one stage."""
        plan = prior_stages(self.spatial)
        if plan is None:
            return None
        first, n = plan
        return TemporalPrior(first, self.ref, self.mu), n


def gap_tv_temporal(op: LinearOperator, g: np.ndarray, *, ref: np.ndarray, mu: float,
                    iters: int = 20, tau: float | None = None, x0: np.ndarray | None = None,
                    tol: float | None = None, callback=None, tv_iters: int = 2,
                    step: float | None = None, threads: int | None = None,
                    state: dict | None = None, prior=None) -> SolverResult:
    r"""GAP with the temporal term :math:`\mu\lVert f - r\rVert_1` (see the module notes).

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
        As :func:`recon.solvers.gap_tv.gap_tv` (accelerated update, warm TV dual, isotropic).
        ``x0`` defaults to ``ref`` (the warm start).
    state : dict, optional
        The ``info["state"]`` of the previous frame's run: its prior's state (TV: the dual
        ``dual``) and its accumulated residual ``offset`` :math:`e = y_K - g_{t-1}`, which
        start this frame's iteration at :math:`y_0 = g_t + e` instead of :math:`g_t`.  The
        accelerated GAP iteration is a Bregman iteration whose accumulator holds the
        correction for the bias of the denoising step; carrying it (and the dual) over
        continues the previous frame's iteration on the new data instead of restarting it
        from its first step.
    prior : Prior, optional
        The spatial prior :math:`\varphi` in place of :math:`\tau\,\mathrm{TV}` (then
        ``tau`` and ``tv_iters`` must be left out).

    Returns
    -------
    SolverResult
        ``info["state"]`` holds the prior's state and ``offset`` for the next frame.
    """
    g, x0, dtype = check_problem(op, g, x0, iters, tau, tol)
    r = np.ascontiguousarray(ref, dtype=dtype)
    if r.shape != op.ishape:
        raise InputError(f"ref shape {r.shape} does not match the operator's {op.ishape}")
    if prior is None:
        weight = default_weight("gap") if tau is None else check_weight(tau, "tau")
        prior = TVPrior(weight, op.ishape, dtype, iters=tv_iters, warm=True, isotropic=True,
                        threads=threads)
    elif tau is not None:
        raise InputError("tau sets the TV prior; with prior= given, set it on the prior")
    temporal = TemporalPrior(prior, r, mu)
    res = gap_tv(op, g, iters=iters, prior=temporal, x0=r.copy() if x0 is None else x0,
                 tol=tol, callback=callback, step=step, threads=threads, state=state,
                 keep_state=True)
    res.info["mu"] = temporal.mu
    return res
