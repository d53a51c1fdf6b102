r"""The total-variation prior :math:`\varphi(x) = \tau\,\mathrm{TV}(x)` (spatial, per band).

Its proximal map is :class:`recon.prox.tv.TVProx` (Chambolle's dual iteration, see
:mod:`recon.prox.tv`) with the weight :math:`\lambda = s\tau` for a step :math:`s`:

.. math::

    \mathrm{prox}_{s\varphi}(v) = \arg\min_x \tfrac12\|x - v\|_2^2 + s\tau\,\mathrm{TV}(x).

The prox is inexact: ``iters`` dual iterations per call, started from the previous call's dual
(``warm``), which inside a solver (whose prox input changes little from one iteration to the
next) makes one or two iterations enough.  Keep ``iters`` even with a warm dual
(:mod:`recon.prox.tv`'s notes).

This module is also the one place that holds the TV weight's defaults and its valid range:
:data:`DEFAULT_WEIGHT` (each solver's default :math:`\tau` for data scaled to about [0, 1]) and
:func:`check_weight` (finite and :math:`\ge 0`; 0 switches the prior off).
"""

from __future__ import annotations

import math

import numpy as np

from recon import kernels
from recon.errors import InputError
from recon.priors.base import PriorBase, linear_combination, solver_algorithm
from recon.prox.tv import TVProx, tv_norm

__all__ = ["TVPrior", "DEFAULT_WEIGHT", "default_weight", "check_weight"]

#: The default TV weight :math:`\tau` of each solver (by algorithm; ``fista-tv`` and ``gap-tv``
#: are ``fista`` and ``gap``), for data scaled to about [0, 1].  GAP's weight is the strength
#: of its denoising step, the others' the weight of the objective's TV term.
DEFAULT_WEIGHT = {"fista": 0.15, "gap": 0.1, "twist": 0.15, "admm": 0.15}


def default_weight(solver: str) -> float:
    """The default TV weight of ``solver`` (a name of :data:`recon.solvers.SOLVERS`)."""
    try:
        return DEFAULT_WEIGHT[solver_algorithm(solver)]
    except KeyError:
        raise InputError(f"no default TV weight for solver {solver!r} (known: "
                         f"{', '.join(DEFAULT_WEIGHT)}); pass one") from None


def check_weight(tau, what: str = "the TV weight") -> float:
    r"""``tau`` as a float if it is a valid TV weight (finite, :math:`\ge 0`), else an
    :class:`~recon.errors.InputError` naming ``what`` (e.g. ``"--tau"``)."""
    try:
        t = float(tau)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number, got {tau!r}") from None
    if not (math.isfinite(t) and t >= 0):
        raise InputError(f"{what} must be finite and >= 0, got {tau!r}")
    return t


class TVPrior(PriorBase):
    r""":math:`\tau\,\mathrm{TV}`, isotropic or anisotropic, with a warm-started inexact prox.

    Parameters
    ----------
    weight : float
        :math:`\tau \ge 0` (:func:`check_weight`).
    shape : tuple of int, optional
        ``(L, H, W)``; by default taken from the first cube the prior sees (a cube of another
        shape or dtype later starts a fresh, cold dual).
    dtype : numpy dtype, optional
        Working precision of the dual (default: the first cube's).
    iters : int
        Chambolle dual iterations per prox (>= 1).
    warm : bool
        Start each prox from the previous dual (default).
    isotropic : bool
    threads : int, optional
        Threads of the prox and the TV norm (:class:`~recon.prox.tv.TVProx`).
    """

    name = "tv"
    #: TV is a sum over bands and positively 1-homogeneous, so a prox with a step per band is
    #: one call at one step on a band-scaled input (:mod:`recon.solvers.band_metric`).
    band_scalable = True

    def __init__(self, weight: float, shape=None, dtype=None, *, iters: int = 2,
                 warm: bool = True, isotropic: bool = True, threads: int | None = None):
        self.weight = check_weight(weight)
        if isinstance(iters, bool) or int(iters) != iters or int(iters) < 1:
            raise InputError(f"tv_iters must be an integer >= 1, got {iters!r}")
        self.iters = int(iters)
        self.warm = bool(warm)
        self.isotropic = bool(isotropic)
        self.threads = threads
        self._prox: TVProx | None = None
        if shape is not None:
            self._build(tuple(shape), np.dtype(np.float32 if dtype is None else dtype))

    def __repr__(self) -> str:
        return (f"TVPrior(weight={self.weight!r}, iters={self.iters}, warm={self.warm}, "
                f"isotropic={self.isotropic})")

    # -------------------------------------------------------------------------- the contract
    def prox(self, v: np.ndarray, step: float, out: np.ndarray | None = None) -> np.ndarray:
        r""":math:`\mathrm{prox}_{s\tau\mathrm{TV}}(v)` (``iters`` dual iterations)."""
        return self._tv(v)(v, self._lam(step), self.iters, warm=self.warm, out=out)

    def rescaled_prox(self, v: np.ndarray, step: float, factors,
                      out: np.ndarray | None = None) -> np.ndarray:
        r""":math:`r \odot \mathrm{prox}_{s\tau\mathrm{TV}}(v)`: the factors applied as the
        prox writes its result (:class:`TVProx`'s ``out_scale``), not in a pass of their own."""
        return self._tv(v)(v, self._lam(step), self.iters, warm=self.warm, out=out,
                           out_scale=factors)

    def value(self, x: np.ndarray) -> float:
        r""":math:`\tau\,\mathrm{TV}(x)`."""
        return self.weight * tv_norm(x, self.isotropic, self.threads)

    def reset(self) -> None:
        """Zero the dual (the next prox is a cold start)."""
        if self._prox is not None:
            self._prox.reset()

    # ------------------------------------------------------------------ the optional methods
    def gradient_prox(self, op, y, base, step, scale=1.0, out=None) -> np.ndarray:
        r""":math:`\mathrm{prox}_{s\tau\mathrm{TV}}(b + c\,H^\top y)`, fused into one pass
        where the operator allows (:meth:`TVProx.gradient_prox
        <recon.prox.tv.TVProx.gradient_prox>`)."""
        return self._tv(base).gradient_prox(op, y, base, self._lam(step), self.iters,
                                            warm=self.warm, scale=scale, out=out)

    def combine_value(self, a, u, b, v, c, w, out) -> float:
        r"""``out`` :math:`= a u + b v + c w` and :math:`\tau\,\mathrm{TV}(\mathrm{out})`, in
        one pass over the cubes where the kernels run
        (:func:`recon.kernels.tv.combine_tv_rows`)."""
        if kernels.usable(u, v, w, out) and all(x.flags.c_contiguous for x in (u, v, w, out)):
            from recon.kernels import tv as ktv

            t = out.dtype.type
            rows = np.empty(out.shape[:2], dtype=np.float64)
            with kernels.threads(self.threads):
                ktv.combine_tv_rows(t(a), u, t(b), v, t(c), w, out, self.isotropic, rows)
            return self.weight * float(rows.sum(axis=1).sum())
        linear_combination(a, u, b, v, c, w, out, self.threads)
        return self.value(out)

    def refine(self, v, step, out) -> int:
        """``iters`` more warm dual iterations on the same input (a cold first call included:
        the dual is then the one that call left)."""
        self._tv(v)(v, self._lam(step), self.iters, warm=True, out=out)
        return self.iters

    def describe(self) -> dict:
        return {"prior": self.name, "weight": self.weight, "tv_iters": self.iters,
                "warm_dual": self.warm, "isotropic": self.isotropic}

    def state(self) -> dict:
        """``{"dual": copy of the dual}`` (empty before the first prox)."""
        return {} if self._prox is None else {"dual": self._prox.dual.copy()}

    def load_state(self, state: dict) -> None:
        """Start from the dual ``state["dual"]`` (shape ``(2, L, H, W)``)."""
        dual = (state or {}).get("dual")
        if dual is None:
            return
        dual = np.asarray(dual)
        if self._prox is None:
            if dual.ndim != 4 or dual.shape[0] != 2:
                raise InputError(f"state dual must have shape (2, L, H, W), got {dual.shape}")
            self._build(dual.shape[1:], dual.dtype if dual.dtype.kind == "f" else np.float32)
        if dual.shape != self._prox.dual.shape:
            raise InputError(f"state dual shape {dual.shape} != {self._prox.dual.shape}")
        np.copyto(self._prox.dual, dual)

    # ------------------------------------------------------------------------------ helpers
    def _lam(self, step) -> float:
        s = float(step)
        if not (math.isfinite(s) and s >= 0):
            raise InputError(f"the prox step must be finite and >= 0, got {step!r}")
        return self.weight * s

    def _build(self, shape, dtype) -> None:
        self._prox = TVProx(shape, dtype, self.isotropic, self.threads)

    def _tv(self, x) -> TVProx:
        """The TVProx for cubes like ``x`` (built, or rebuilt cold, on a new shape/dtype)."""
        x = np.asarray(x)
        dtype = np.dtype(np.float64 if x.dtype == np.float64 else np.float32)
        p = self._prox
        if p is None or p.shape != x.shape or p.dtype != dtype:
            if x.ndim != 3:
                raise InputError(f"the TV prior works on (L, H, W) cubes, got shape {x.shape}")
            self._build(x.shape, dtype)
        return self._prox
