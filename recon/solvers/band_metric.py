r"""A diagonal metric constant over each band, for proximal-gradient solvers.

The columns of a spectral imager's operator :math:`H` are far from equal: the bands at the
ends of the range reach the sensor through a weak mask transmission and a low sensor response,
so on the calibrated models the mean squared column norm of band :math:`l`,

.. math::

    c_l = \frac{1}{HW}\sum_{i,j} \|H e_{l,i,j}\|^2
        = \frac{1}{HW}\,\mathrm{tr}\bigl(H_l^\top H_l\bigr),

varies across the bands by an order of magnitude.  A gradient step :math:`1/\|H\|^2` is then
set by the strongest bands and the weak ones converge that many times slower.  The metric

.. math::

    D = \alpha\,\mathrm{diag}(s_l\, I_{HW}), \qquad s_l = c_l^{\,p}, \qquad
    \alpha = \bigl\|H\,\mathrm{diag}(s)^{-1/2}\bigr\|_2^2 ,

is a majoriser of the data term's Hessian (:math:`H^\top H \preceq D`, because
:math:`\alpha` is the top eigenvalue of :math:`S^{-1/2}H^\top H S^{-1/2}`), so the step
:math:`f \leftarrow \mathrm{prox}^D_\varphi\bigl(z + D^{-1}H^\top(g-Hz)\bigr)` with the prox in
the metric :math:`D`,

.. math::

    \mathrm{prox}^D_\varphi(v) = \arg\min_x \tfrac12\|x-v\|_D^2 + \varphi(x),

keeps every guarantee of the scalar step (Combettes & Vũ 2014, variable metric
forward-backward) and minimises the same objective.  :math:`\alpha` is estimated
(:func:`_metric_norm_sq`: 15 power iterations, times 1.02, as the scalar step's
:math:`\|H\|^2`); a power iteration approaches the top eigenvalue from below, and on the
calibrated `paper` operators the estimate falls short of it (docs/speed_product.md, "The
step's estimate"): the step is then longer than the majoriser's, and the momentum's adaptive
restart keeps it stable.  :math:`p = 1` equalises the bands' column norms; :math:`p = 1/2`
(the default, :data:`DEFAULT_EXPONENT`) goes half way, which converges
faster early on the calibrated models (docs/speed_product.md).

That prox is exact and cheap when the prior separates over the bands and is positively
homogeneous of degree one, :math:`\varphi(x) = \sum_l \varphi_l(x_l)` with
:math:`\varphi_l(\lambda x_l) = \lambda\varphi_l(x_l)` for :math:`\lambda > 0` (TV summed over
bands): then :math:`\mathrm{prox}_{\sigma\varphi_l}(v_l) = r\,\mathrm{prox}_{(\sigma/r)
\varphi_l}(v_l/r)` for any :math:`r > 0`, so with :math:`\sigma_l = 1/d_l` and a common step
:math:`\sigma_0 = 1/\max_l d_l`, :math:`r_l = \sigma_l/\sigma_0 \ge 1`,

.. math::

    \bigl(\mathrm{prox}^D_\varphi(v)\bigr)_l = r_l\,\bigl(\mathrm{prox}_{\sigma_0\varphi}
    (v / r)\bigr)_l,

one call of the prior's own prox at one step.  For the TV prox on the dual (Chambolle) the
scaled call runs exactly the iterations of the per-band one, warm dual included.  A prior
declares the property with the attribute ``band_scalable = True``
(:class:`~recon.priors.TVPrior`).

A prior that couples the bands may instead declare ``band_weighted = True``: in the band
metric it is taken on the band-weighted cube, :math:`\psi(x) = \varphi(w \odot x)` with
:math:`w_l = \sqrt{d_l/\max_l d_l}`, whose prox in the metric is exact,

.. math::

    \mathrm{prox}^D_\psi(v) = w^{-1} \odot \mathrm{prox}_{\sigma_0\varphi}(w \odot v),

because :math:`\tfrac12\|x-v\|_D^2 = \tfrac{1}{2\sigma_0}\|w\odot x - w\odot v\|^2`.
The objective is then :math:`\tfrac12\|g-Hx\|^2 + \varphi(w\odot x)`: the prior weighs each
band by how strongly the operator sees it (the spectral subspace is estimated, and its
coefficient images regularised, on :math:`w \odot x`).  Other priors get the scalar metric.

:math:`c_l` is estimated with one Hutchinson probe: for a Rademacher cube :math:`u`,
:math:`\mathbb E[u \odot H^\top H u] = \mathrm{diag}(H^\top H)`, and its mean over a band's
:math:`HW` pixels has a relative error of order :math:`1/\sqrt{HW}` (one forward and one
adjoint; a fixed seed makes the solve reproducible).

P. L. Combettes, B. C. Vũ, "Variable metric forward-backward splitting with applications to
monotone inclusions in duality", Optimization 63(9), 2014.  M. F. Hutchinson, "A stochastic
estimator of the trace of the influence matrix for Laplacian smoothing splines", Commun.
Stat. Simul. Comput. 18(3), 1989.
"""

from __future__ import annotations

import math

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.solvers.base import power_iteration

__all__ = ["DEFAULT_EXPONENT", "METRICS", "band_scalable", "band_weighted",
           "band_column_norms_sq", "band_metric", "BandMetric"]

#: The exponent :math:`p` of :math:`s_l = c_l^p` when none is given.
DEFAULT_EXPONENT = 0.5
#: The metrics a solver's ``metric=`` takes: ``"scalar"`` (:math:`\|H\|^2 I`), ``"bands"``
#: (this module; an input error for a prior that is not band-scalable) and ``"auto"``
#: (``"bands"`` where the prior allows it, else ``"scalar"``).
METRICS = ("scalar", "bands", "auto")
#: Floor of :math:`c_l` relative to the largest: a band the operator barely sees is not given
#: an unbounded step.
FLOOR = 1e-3


def band_scalable(prior) -> bool:
    """Whether ``prior`` separates over the bands and is positively 1-homogeneous (its
    ``band_scalable`` attribute; False when absent)."""
    return bool(getattr(prior, "band_scalable", False))


def band_weighted(prior) -> bool:
    """Whether ``prior`` may be taken on the band-weighted cube in the band metric (its
    ``band_weighted`` attribute; False when absent)."""
    return bool(getattr(prior, "band_weighted", False))


def band_column_norms_sq(op: LinearOperator, dtype=np.float32, seed: int = 0) -> np.ndarray:
    r""":math:`c_l`, the mean squared column norm of every band of ``op`` (one Hutchinson
    probe: one forward and one adjoint), float64 of shape ``(L,)``; a band whose estimate is
    not positive gets 0."""
    rng = np.random.default_rng(seed)
    u = rng.integers(0, 2, size=op.ishape, dtype=np.int8).astype(dtype)
    u *= 2
    u -= 1
    hu = op.adjoint(op.forward(u))
    hu *= u
    c = hu.reshape(hu.shape[0], -1).mean(axis=1, dtype=np.float64)
    return np.maximum(c, 0.0)


def _metric_norm_sq(op: LinearOperator, isq: np.ndarray, dtype, n_iter: int = 15,
                    seed: int = 0) -> float:
    r""":math:`\|H S^{-1/2}\|_2^2` by power iteration (``isq`` = :math:`s^{-1/2}` per band),
    times 1.02 as :func:`~recon.solvers.base.operator_norm_sq`."""
    return 1.02 * power_iteration(op, n_iter, dtype, seed, weights=isq)


def band_metric(op: LinearOperator, dtype=np.float32, exponent: float = DEFAULT_EXPONENT,
                seed: int = 0) -> np.ndarray:
    r"""The diagonal :math:`d_l = \alpha s_l` of the metric (float64, shape ``(L,)``).

    Raises
    ------
    InputError
        A zero operator, or an exponent outside [0, 1].
    """
    p = float(exponent)
    if not (math.isfinite(p) and 0.0 <= p <= 1.0):
        raise InputError(f"the band metric's exponent must be in [0, 1], got {exponent!r}")
    c = band_column_norms_sq(op, dtype, seed)
    top = float(c.max())
    if not top > 0:
        raise InputError("the operator is zero: nothing to reconstruct")
    s = np.maximum(c / top, FLOOR) ** p
    alpha = _metric_norm_sq(op, 1.0 / np.sqrt(s), dtype, seed=seed)
    if not alpha > 0:
        raise InputError("the operator is zero: nothing to reconstruct")
    return alpha * s


class BandMetric:
    r"""The metric :math:`D = \mathrm{diag}(d_l)` in a proximal-gradient loop.

    Parameters
    ----------
    d : array_like, shape (L,)
        :math:`d_l > 0` (:func:`band_metric`).
    dtype
        The loop's precision.
    weighted : bool
        The prior is taken on the band-weighted cube :math:`w\odot x` (a ``band_weighted``
        prior, see the module notes) rather than scaled per band (a ``band_scalable`` one).
    """

    def __init__(self, d, dtype, weighted: bool = False):
        d = np.asarray(d, dtype=np.float64)
        if d.ndim != 1 or not np.all(np.isfinite(d)) or not np.all(d > 0):
            raise InputError("the band metric must be positive and finite, one value per band")
        self.d = d
        self.dmax = float(d.max())
        #: :math:`\sigma_0 = 1/\max_l d_l`, the step of the prior's prox.
        self.step = 1.0 / self.dmax
        self.weighted = bool(weighted)
        self._w = (d / self.dmax).astype(dtype)                     # 1/r_l, in (0, 1]
        self._r_bands = (self.dmax / d).astype(dtype)               # r_l >= 1
        self._q = np.sqrt(self.dmax / d)                                     # 1/w_l
        self._sqrt_r = self._q.astype(dtype)[:, None, None]

    def scaled_step(self, op: LinearOperator, r: np.ndarray, z: np.ndarray,
                    out: np.ndarray) -> np.ndarray:
        r"""``out`` :math:`= (z + D^{-1}H^\top r)/r_l` per band, i.e.
        :math:`(d_l z_l + (H^\top r)_l)/\max d`: the gradient step already divided by
        :math:`r` for :meth:`prox` (``out`` may not be ``z``).  The weights :math:`1/r_l`
        on :math:`z` go to the operator's gradient step (``base_weights``), which a fused
        kernel applies as it writes ``out``: no pass of its own over the cube."""
        return op.adjoint_add(r, z, self.step, out=out, base_weights=self._w)

    def prox(self, prior, v_scaled: np.ndarray, out: np.ndarray) -> np.ndarray:
        r"""``out`` :math:`= \mathrm{prox}^D_\varphi(v)` from ``v_scaled`` :math:`= v/r`
        (:meth:`scaled_step`); ``out`` may be ``v_scaled``, which may be overwritten.
        Weighted: :math:`w^{-1}\odot\mathrm{prox}_{\sigma_0\varphi}(w\odot v)`, with
        :math:`w \odot v = \sqrt r \odot (v/r)` and :math:`w^{-1} = \sqrt r`: the prior's
        :meth:`~recon.priors.base.PriorBase.scaled_prox` with :math:`q = \sqrt r`."""
        from recon.priors.base import rescaled_prox, scaled_prox

        if self.weighted:
            return scaled_prox(prior, v_scaled, self.step, self._q, out)
        # r times the prox, scaled as the prior writes it where it can (TV).
        return rescaled_prox(prior, v_scaled, self.step, self._r_bands, out)

    def value(self, prior, x: np.ndarray, work: np.ndarray | None = None) -> float | None:
        r"""The prior's value as the loop minimises it: :math:`\varphi(x)`, or
        :math:`\varphi(w\odot x)` when weighted (:math:`w\odot x` made in ``work`` where
        given: no cube allocated an iteration); None where the prior has no value."""
        if self.weighted:
            v = prior.value(np.divide(x, self._sqrt_r, out=work))
        else:
            v = prior.value(x)
        return None if v is None else float(v)

    def kept_value(self, kept, prior, x: np.ndarray, work: np.ndarray | None = None
                   ) -> float | None:
        r""":meth:`value` of :math:`x`, a result of :meth:`prox`: ``kept(prior)``, the value
        the prior keeps of that result (:func:`~recon.priors.base.prox_value` of the last,
        :func:`~recon.priors.base.previous_value` of the one before, with the last call's
        state), where the prior is weighted (its prox's results are then :math:`w\odot x`)
        and keeps one; else :meth:`value`."""
        if self.weighted:
            v = kept(prior)
            if v is not None:
                return v
        return self.value(prior, x, work)

    def restart_dot(self, z: np.ndarray, f: np.ndarray, f_prev: np.ndarray,
                    threads: int | None = None) -> float:
        r""":math:`\langle z - f, f - f_\mathrm{prev}\rangle_D`, the restart test in the
        metric: band by band, in one pass without storing the differences where the kernels
        run (float64 sums)."""
        from recon import kernels

        fast = kernels.usable(z, f, f_prev) and all(a.flags.c_contiguous for a in (z, f, f_prev))
        total = 0.0
        for band in range(z.shape[0]):
            a, b, c = z[band].reshape(-1), f[band].reshape(-1), f_prev[band].reshape(-1)
            if fast:
                from recon.kernels import vector as kvec

                partial = np.empty(kvec.blocks(a.size), dtype=np.float64)
                with kernels.threads(threads):
                    kvec.diff_dot(a, b, c, partial)
                dot = float(partial.sum())
            else:
                dot = float(np.vdot(a - b, b - c))
            total += self.d[band] * dot
        return total
