r"""Plug-and-play: non-local means on the spectral subspace's eigenimages.

The FastHyDe / NGmeet idea: project the cube on its :math:`k` leading spectral basis vectors
(:mod:`recon.priors.subspace`, re-estimated from the solver's iterate), denoise the :math:`k`
eigenimages instead of the :math:`L` bands, expand back:

.. math::

    D_\sigma(v) = E\,\bigl[\mathrm{NLM}_\sigma\bigl((E^\top v)_j\bigr)\bigr]_{j=1}^{k},

with :func:`skimage.restoration.denoise_nl_means` (fast mode: 5 × 5 patches, a 13 × 13
search window, filtering parameter :math:`h = 0.8\,\sigma`) as the denoiser.  The basis is
orthonormal, so white noise of level :math:`\sigma` in the bands is white noise of level
:math:`\sigma` in each eigenimage: one strength serves all of them.

It is a denoiser, not a proximal map: ``value`` is None, and the strength follows the step as a
TV weight does, :math:`\sigma = s\,\lambda` for a step :math:`s` and weight :math:`\lambda`
(a solver's ``tau``).  Denoising ``k`` eigenimages costs :math:`k/L` of denoising every band.
"""

from __future__ import annotations

import math

import numpy as np

from recon.errors import InputError
from recon.priors.subspace import _Subspace, expand

__all__ = ["SubspaceNLM", "nl_means", "make_subspace_nlm"]

#: Patch side, search radius and h / σ of the non-local means step.
PATCH_SIZE, PATCH_DISTANCE, H_PER_SIGMA = 5, 6, 0.8


def nl_means(image: np.ndarray, sigma: float) -> np.ndarray:
    """Non-local means of one 2-D image at noise level ``sigma`` (scikit-image, fast mode)."""
    from skimage.restoration import denoise_nl_means

    return denoise_nl_means(image, patch_size=PATCH_SIZE, patch_distance=PATCH_DISTANCE,
                            h=H_PER_SIGMA * sigma, sigma=sigma, fast_mode=True,
                            preserve_range=True).astype(image.dtype, copy=False)


class SubspaceNLM(_Subspace):
    r"""Plug-and-play prior: non-local means of the subspace's eigenimages (module notes).

    Parameters
    ----------
    weight : float
        :math:`\lambda \ge 0`: the denoising strength per unit step, :math:`\sigma = s\lambda`
        (0 = projection only).
    rank : int, optional
        :math:`k`; :func:`~recon.priors.subspace.default_rank` of the bands if omitted.
    """

    name = "subspace-nlm"

    def __init__(self, weight: float, rank: int | None = None):
        super().__init__(rank)
        weight = float(weight)
        if not (math.isfinite(weight) and weight >= 0):
            raise InputError(f"weight must be >= 0, got {weight}")
        self.weight = weight

    def prox(self, v: np.ndarray, step: float, out: np.ndarray | None = None) -> np.ndarray:
        r""":math:`E\,\mathrm{NLM}_{s\lambda}(E^\top v)`, into ``out`` if given (may be ``v``)."""
        v, step, rank = self._check(v, step)
        e, z = self._coefficients(v, rank)
        sigma = step * self.weight
        if sigma > 0:
            for j in range(rank):
                z[j] = nl_means(z[j], sigma)
        return expand(e, z, out)

    def value(self, x: np.ndarray) -> None:
        """None: a denoiser defines no value."""
        return None

    def describe(self) -> dict:
        return {"prior": self.name, "weight": self.weight, "rank": self.rank}


def make_subspace_nlm(ctx, *, rank: int | None = None, tv_iters: int | None = None,
                      warm_dual: bool | None = None, isotropic: bool | None = None) -> SubspaceNLM:
    """The registry's factory: the weight is ``ctx.weight`` (the caller's TV weight), or the
    solver's default TV weight; the TV options are accepted and ignored (solvers pass them to
    any prior named)."""
    from recon.priors.tv import default_weight

    weight = ctx.weight
    if weight is None:
        weight = default_weight(ctx.solver) if ctx.solver is not None else default_weight("fista")
    return SubspaceNLM(weight, rank=rank)
