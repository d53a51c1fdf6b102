r"""A non-local low-rank prior on the spectral subspace's coefficient images (plug-and-play).

The cube :math:`x \in \mathbb R^{L\times N}` is held to :math:`k` spectral basis vectors,
:math:`x = E z`, with :math:`E` re-estimated from each input as in
:mod:`recon.priors.subspace`; the :math:`k` coefficient ("eigen") images :math:`z = E^\top v`
are then denoised by a patch-based non-local low-rank denoiser (FastHyDe / NGmeet style):

1. each image :math:`z_j` is divided by its noise deviation :math:`\sigma_j` (whitened),
2. block matching on the first whitened image: for every reference patch on a grid of stride
   ``stride``, the reference and the ``group - 1`` most similar other patches within
   ``± radius`` pixels,
3. each group's matrix (a column per patch, the patch in all :math:`k` images) less its mean
   column is shrunk in its singular values by Gavish and Donoho's optimal shrinker for white
   noise of unit deviation (values inside the noise's bulk removed, those above it pulled
   back to their expected clean size), and
4. every patch estimate is put back (times :math:`\sigma_j`) and the estimates of a pixel
   averaged,

and the result is expanded, :math:`x = E\hat z`.  The kernels are in
:mod:`recon.kernels.nonlocal_lowrank`; :func:`denoise_nonlocal` has a plain NumPy path, their
reference.

The denoiser is not the proximal map of a known :math:`\varphi` (:meth:`SubspaceNLR.value` is
None): the solvers use it in place of the prox (plug-and-play).  As in DeSCI (GAP-TV, then
GAP with a weighted nuclear norm), a solve starts with the subspace-TV prox
(:class:`~recon.priors.subspace.SubspaceTV`, the same weight), which removes the coded
artefacts of the first iterates that a patch denoiser would take for structure, and then
uses the non-local denoiser with every :math:`\sigma_j` equal to ``strength`` times the
prox's step times the weight: the strength follows the caller's weight rule (in
``kaleidospec``, the measurement's noise) and the solver's step, never the scene.  The
warm-up is either a count of calls (``warmup`` an integer: GAP, whose fixed iterations the
single-view protocol counts) or a whole solve (``warmup="rule"``: FISTA's default):
:meth:`SubspaceNLR.stages` hands :func:`recon.solvers.solve` the subspace-TV prior, which
runs to the solver's stopping rule, and ``denoise_iters`` iterations of the denoiser follow
from its result.
"""

from __future__ import annotations

import math

import numpy as np

from recon import kernels
from recon.errors import InputError
from recon.priors.base import solver_algorithm
from recon.priors.subspace import SubspaceTV, expand, subspace_weight

__all__ = ["SubspaceNLR", "reference_grid", "denoise_nonlocal",
           "make_subspace_nlr", "shrink_factors", "STRENGTH", "WARMUP", "DENOISE_ITERS",
           "DENOISE_ITERS_VIEWS", "denoise_iters_for"]

#: The denoiser's strength :math:`\gamma` per solver (``"gap"``, ``"fista"``; the others take
#: GAP's), each chosen on the development scenes with that solver (docs/priors.md).  FISTA's
#: step :math:`1/L` is a fraction of GAP's unit step, hence its larger :math:`\gamma`.
STRENGTH = {"gap": 1.0, "fista": 15.0}
#: The warm-up per solver: calls of the subspace-TV prox (an integer) or ``"rule"``, a whole
#: subspace-TV solve to the solver's stopping rule (:meth:`SubspaceNLR.stages`).
WARMUP = {"gap": 60, "fista": "rule"}
#: Iterations of the denoiser after a ``"rule"`` warm-up: for one view, and for several (with
#: more views the gain peaks sooner; measured at one and five, docs/priors.md).
DENOISE_ITERS = 80
DENOISE_ITERS_VIEWS = 40


def denoise_iters_for(n_views: int | None) -> int:
    """The denoiser's iterations after a ``"rule"`` warm-up for ``n_views`` views (None:
    one)."""
    return DENOISE_ITERS if n_views is None or int(n_views) <= 1 else DENOISE_ITERS_VIEWS


def reference_grid(n: int, patch: int, stride: int) -> np.ndarray:
    """Top-left corners along one axis of ``n`` pixels: every ``stride``-th of
    ``0 .. n - patch``, and ``n - patch`` itself, so that the patches cover every pixel."""
    last = n - patch
    grid = list(range(0, last + 1, stride))
    if grid[-1] != last:
        grid.append(last)
    return np.asarray(grid, dtype=np.int64)


def _references(shape, patch, stride):
    ys = reference_grid(shape[0], patch, stride)
    xs = reference_grid(shape[1], patch, stride)
    ry, rx = np.meshgrid(ys, xs, indexing="ij")
    return np.ascontiguousarray(ry.ravel()), np.ascontiguousarray(rx.ravel())


def _check_geometry(shape, patch, radius, group):
    h, w = shape
    if patch > h or patch > w:
        raise InputError(f"patches of {patch} pixels do not fit images of {h}x{w}")
    # The smallest window (a corner reference) holds (min(r, H-p)+1)(min(r, W-p)+1) corners.
    corners = (min(radius, h - patch) + 1) * (min(radius, w - patch) + 1)
    return min(group, corners)


def denoise_nonlocal(z: np.ndarray, sigmas: np.ndarray, *, strength: float = 1.0,
                     patch: int = 4, radius: int = 10, group: int = 24, stride: int = 4,
                     threads: int | None = None) -> np.ndarray:
    r"""The non-local low-rank estimate of the images ``z`` ``(k, H, W)``.

    Parameters
    ----------
    z : ndarray, shape (k, H, W)
    sigmas : array of k floats > 0
        Each image's noise deviation :math:`\sigma_j`: the images are whitened by it before
        the grouping and the shrinkage, and scaled back after.
    strength : float
        The noise deviation of the whitened images the shrinkage assumes (1: as whitened).
    patch, radius, group, stride : int
        Patch side, half-width of the search window, patches per group, stride of the
        reference grid.

    Returns
    -------
    ndarray, z's shape, float32 for float32 input (the kernels) else float64 (NumPy).
    """
    z = np.ascontiguousarray(z)
    k, h, w = z.shape
    sig = np.asarray(sigmas, dtype=np.float64).reshape(-1)
    if sig.size != k or not np.all(np.isfinite(sig)) or np.any(sig <= 0):
        raise InputError(f"sigmas must be {k} finite positive values, got {sigmas!r}")
    if stride > patch:
        raise InputError(f"stride {stride} must not exceed the patch side {patch}")
    m = _check_geometry((h, w), patch, radius, group)
    scale = 1.0 / sig
    ry, rx = _references((h, w), patch, stride)
    if kernels.usable(z):
        from recon.kernels import nonlocal_lowrank as kn

        guide = np.ascontiguousarray(z[:1] * np.float32(scale[0]))
        idx_y = np.empty((ry.size, m), np.int64)
        idx_x = np.empty((ry.size, m), np.int64)
        filt = np.empty((ry.size, m, m))
        ranks = np.empty(ry.size, np.int64)
        means = np.empty((ry.size, k * patch * patch))
        acc = np.zeros((k, h, w))
        count = np.zeros((h, w))
        out = np.empty_like(z)
        with kernels.threads(threads):
            kn.match(guide, ry, rx, patch, radius, idx_y, idx_x)
            kn.group_filters(z, scale, idx_y, idx_x, patch, float(strength), filt, ranks,
                             means)
            kn.aggregate(z, scale, idx_y, idx_x, patch, filt, ranks, means, acc, count)
            kn.normalise(acc, count, out)
        return out
    return _denoise_numpy(z.astype(np.float64), scale, ry, rx, patch, radius, m,
                          float(strength))


def shrink_factors(s2: np.ndarray, d: int, m: int, sigma: float) -> np.ndarray:
    r"""NumPy's :func:`recon.kernels.nonlocal_lowrank.shrink`: the factors :math:`s_i'/s_i` of
    Gavish and Donoho's optimal shrinker (Frobenius loss) for the squared singular values
    ``s2`` of a ``d × m`` matrix with white noise of deviation ``sigma``."""
    s2 = np.asarray(s2, dtype=np.float64)
    big = max(d, m)
    beta = min(d, m) / big
    if sigma <= 0:
        return np.ones_like(s2)
    y2 = np.maximum(s2, 0.0) / (big * sigma * sigma)
    keep = np.sqrt(y2) > 1.0 + math.sqrt(beta)
    t = y2 - beta - 1.0
    root = np.sqrt(np.maximum(t * t - 4.0 * beta, 0.0))
    return np.where(keep, root / np.where(keep, y2, 1.0), 0.0)


def _denoise_numpy(z, scale, ry, rx, patch, radius, m, strength):
    """The plain NumPy reference of :func:`denoise_nonlocal` (one group at a time)."""
    k, h, w = z.shape
    zs = z * scale[:, None, None]
    # Every patch of every image: (H-p+1, W-p+1, k, p, p); the guide is the first image's.
    win = np.lib.stride_tricks.sliding_window_view(zs, (patch, patch), axis=(1, 2))
    win = np.moveaxis(win, 0, 2)
    gwin = win[:, :, 0].reshape(win.shape[0], win.shape[1], -1)
    acc = np.zeros_like(z)
    count = np.zeros((h, w))
    d = k * patch * patch
    for y0, x0 in zip(ry, rx):
        ys = np.arange(max(0, y0 - radius), min(h - patch, y0 + radius) + 1)
        xs = np.arange(max(0, x0 - radius), min(w - patch, x0 + radius) + 1)
        cand = gwin[ys[0]:ys[-1] + 1, xs[0]:xs[-1] + 1].reshape(-1, patch * patch)
        dist = ((cand - gwin[y0, x0]) ** 2).sum(axis=1)
        # The reference first, then the others by distance (ties in scan order).
        ref = (y0 - ys[0]) * xs.size + (x0 - xs[0])
        order = np.argsort(dist, kind="stable")
        best = np.concatenate(([ref], order[order != ref]))[:m]
        my, mx = ys[best // xs.size], xs[best % xs.size]
        y = win[my, mx].reshape(m, d).T                      # (d, m)
        mu = y.mean(axis=1, keepdims=True)
        yc = y - mu
        s2, v = np.linalg.eigh(yc.T @ yc)
        f = shrink_factors(s2, d, m, strength)
        est = (yc @ (v * f) @ v.T + mu).T.reshape(m, k, patch, patch)
        est = est / scale[None, :, None, None]
        for t in range(m):
            acc[:, my[t]:my[t] + patch, mx[t]:mx[t] + patch] += est[t]
            count[my[t]:my[t] + patch, mx[t]:mx[t] + patch] += 1.0
    return acc / count


def _is_count(val, least: int) -> bool:
    """Whether ``val`` is an integer (not a bool or a string) of at least ``least``."""
    return not isinstance(val, (bool, str)) and int(val) == val and val >= least


class SubspaceNLR(SubspaceTV):
    r"""Subspace prior with a non-local low-rank denoiser on the coefficient images
    (plug-and-play; module notes).

    Call :math:`t` (from 0, counted since :meth:`reset`):

    .. math::

        \mathrm{D}_s(v) = \begin{cases}
            E\,\mathrm{prox}_{s\lambda\mathrm{TV}}(E^\top v) & t < t_0 \\
            E\,\mathrm{NLR}_{\sigma}(E^\top v), \ \sigma_j = \gamma s\lambda & t \ge t_0
        \end{cases}

    with :math:`E` the :math:`k` leading eigenvectors of :math:`v v^\top`, :math:`t_0` =
    ``warmup`` and :math:`\gamma` = ``strength``.

    Parameters
    ----------
    weight : float
        :math:`\lambda \ge 0`, the TV weight a solver's ``tau`` would be (0: the projection on
        the subspace only).
    rank : int, optional
        :math:`k`; :func:`~recon.priors.subspace.default_rank` of the cube's bands if omitted.
    strength : float
        :math:`\gamma`: the denoiser's noise deviation per unit of :math:`s\lambda`.
    warmup : int or "rule"
        :math:`t_0`: calls of the subspace-TV prox before the non-local denoiser; or
        ``"rule"``: the subspace-TV prior is a first stage of its own (:meth:`stages`), and
        every call of this prior is the denoiser (:math:`t_0 = 0`).
    denoise_iters : int
        With ``warmup="rule"``, the iterations of the denoiser after the first stage.
    patch, radius, group, stride
        The denoiser's settings (:func:`denoise_nonlocal`).
    tv_iters, isotropic, threads
        As :class:`~recon.priors.subspace.SubspaceTV`.
    """

    name = "subspace-nlr"
    #: The denoiser's strength was chosen with the scalar step (σ = γ s λ with one s for every
    #: band); FISTA's band metric is for its first stage, subspace-TV.
    band_weighted = False

    def __init__(self, weight: float, rank: int | None = None, *, strength: float = 1.0,
                 warmup: int | str = 60, denoise_iters: int = DENOISE_ITERS, patch: int = 4,
                 radius: int = 10, group: int = 24, stride: int = 4, tv_iters: int = 2,
                 isotropic: bool = True, threads: int | None = None):
        super().__init__(weight, rank=rank, tv_iters=tv_iters, isotropic=isotropic,
                         threads=threads)
        strength = float(strength)
        if not (math.isfinite(strength) and strength >= 0):
            raise InputError(f"strength must be finite and >= 0, got {strength}")
        by_rule = warmup == "rule"
        if not by_rule and not _is_count(warmup, 0):
            raise InputError(f"warmup must be an integer >= 0 or rule, got {warmup!r}")
        for label, val in (("denoise_iters", denoise_iters), ("patch", patch),
                           ("radius", radius), ("group", group), ("stride", stride)):
            if not _is_count(val, 1):
                raise InputError(f"{label} must be a positive integer, got {val!r}")
        if int(group) < 2:
            raise InputError(f"group must be at least 2 patches, got {group}")
        if int(stride) > int(patch):
            raise InputError(f"stride {stride} must not exceed the patch side {patch} (the "
                             f"reference patches must cover every pixel)")
        self.strength = strength
        self.warmup = "rule" if by_rule else int(warmup)
        self.denoise_iters = int(denoise_iters)
        self.patch, self.radius = int(patch), int(radius)
        self.group, self.stride = int(group), int(stride)
        self.calls = 0

    def reset(self) -> None:
        """Forget the basis and the TV dual, and start again with the warm-up."""
        super().reset()
        self.calls = 0

    def describe(self) -> dict:
        return {"prior": self.name, "weight": self.weight, "rank": self.rank,
                "strength": self.strength, "warmup": self.warmup,
                **({"denoise_iters": self.denoise_iters} if self.warmup == "rule" else {}),
                "patch": self.patch,
                "radius": self.radius, "group": self.group, "stride": self.stride}

    def prox(self, v: np.ndarray, step: float, out: np.ndarray | None = None) -> np.ndarray:
        r"""The denoising step of call :math:`t` (class notes), into ``out`` if given (``out``
        may be ``v``)."""
        self.calls += 1
        if self.warmup != "rule" and self.calls <= self.warmup:
            return super().prox(v, step, out)
        v, step, rank = self._check(v, step)
        e, z = self._coefficients(v, rank)
        sigma = self.strength * step * self.weight
        if sigma > 0 and min(z.shape[1:]) >= self.patch:
            z = denoise_nonlocal(z, np.full(z.shape[0], sigma), patch=self.patch,
                                 radius=self.radius, group=self.group, stride=self.stride,
                                 threads=self.threads).astype(v.dtype, copy=False)
        return expand(e, np.ascontiguousarray(z), out)

    def value(self, x: np.ndarray) -> None:
        """None: a plug-and-play denoiser defines no :math:`\\varphi`."""
        return None

    def stages(self) -> tuple[SubspaceTV, int] | None:
        """With ``warmup="rule"``: the subspace-TV prior of the same weight, rank and TV
        options (the first stage, to the solver's stopping rule) and ``denoise_iters``
        iterations of this prior after it; None with a count of warm-up calls."""
        if self.warmup != "rule":
            return None
        first = SubspaceTV(self.weight, rank=self.rank, tv_iters=self.tv_iters,
                           isotropic=self.isotropic, threads=self.threads)
        return first, self.denoise_iters


def make_subspace_nlr(ctx, *, rank: int | None = None, strength: float | None = None,
                      warmup: int | str | None = None, denoise_iters: int | None = None,
                      patch: int = 4, radius: int = 10, group: int = 24, stride: int = 4,
                      tv_iters: int = 2, warm_dual: bool = True,
                      isotropic: bool = True) -> SubspaceNLR:
    """The registry's factory (:func:`recon.priors.make_prior` ``("subspace-nlr")``), with the
    weight of :func:`~recon.priors.subspace.subspace_weight` (the caller's TV weight, or the
    noise rule) and, where not given, the solver's :data:`STRENGTH` and :data:`WARMUP` and
    the views' :func:`denoise_iters_for`; ``warm_dual`` is accepted for the TV options' sake
    (the dual is kept)."""
    algo = "gap" if ctx.solver is None else solver_algorithm(ctx.solver)
    return SubspaceNLR(subspace_weight(ctx), rank=rank,
                       strength=STRENGTH.get(algo, STRENGTH["gap"]) if strength is None
                       else strength,
                       warmup=WARMUP.get(algo, WARMUP["gap"]) if warmup is None else warmup,
                       denoise_iters=denoise_iters_for(ctx.n_views) if denoise_iters is None
                       else denoise_iters, patch=patch, radius=radius, group=group,
                       stride=stride, tv_iters=tv_iters, isotropic=isotropic,
                       threads=ctx.threads)
