r"""Spectral subspace priors: the cube held to :math:`k` spectral basis vectors.

A natural scene's spectra lie close to a low-dimensional subspace, so the cube
:math:`x \in \mathbb R^{L\times N}` (``L`` bands, ``N = H W`` pixels) is written
:math:`x = E z` with an orthonormal basis :math:`E \in \mathbb R^{L\times k}` and coefficient
("eigen") images :math:`z \in \mathbb R^{k\times N}`.  The basis is re-estimated from each input
:math:`v` of the proximal map as the :math:`k` leading eigenvectors of the band Gram matrix
:math:`v v^\top` (:math:`L\times L`, one pass over the cube), so the prior never sees anything
but the solver's iterate.

For a fixed :math:`E` the regulariser

.. math::

    \varphi(x) = \lambda\,\mathrm{TV}(E^\top x) + \iota_{\mathrm{span}\,E}(x)

has the exact proximal map :math:`\mathrm{prox}_{s\varphi}(v) = E\,\mathrm{prox}_{s\lambda
\mathrm{TV}}(E^\top v)`, because :math:`\|x - v\|^2 = \|z - E^\top v\|^2 + \|(I - EE^\top) v\|^2`
for :math:`x = Ez`.  TV is thus paid on :math:`k` images instead of :math:`L` bands.

The basis, the projection and the expansion are Numba kernels
(:mod:`recon.kernels.subspace`) on float32 cubes, NumPy otherwise.
"""

from __future__ import annotations

import math

import numpy as np

from recon import kernels
from recon.errors import InputError
from recon.priors.base import PriorBase, solver_algorithm
from recon.prox.tv import TVProx, tv_norm

__all__ = ["SubspaceTV", "band_gram", "symmetric_eigh", "leading_basis", "basis_change",
           "project", "expand", "default_rank", "subspace_weight", "make_subspace_tv"]


def default_rank(n_bands: int) -> int:
    r"""The subspace dimension used when none is given: :math:`k = \lceil L/4 \rceil`, at
    least 4 and at most :math:`L` (8 for CAVE's 31 bands, 7 for 28, 4 for 11).

    The floor of 4 rather than 3: three basis vectors are exactly an RGB-lifted scene's rank,
    and measured spectra need more (docs/priors.md, "The subspace dimension k")."""
    n_bands = int(n_bands)
    return max(1, min(n_bands, max(4, -(-n_bands // 4))))


def band_gram(v: np.ndarray) -> np.ndarray:
    r"""The band Gram matrix :math:`v v^\top` (``(L, L)`` float64) of a cube ``(L, H, W)``."""
    n_bands = v.shape[0]
    m = v.reshape(n_bands, -1)
    if kernels.usable(m) and m.flags.c_contiguous:
        from recon.kernels import subspace as ks

        partial = np.empty((ks.blocks(m.shape[1]), n_bands, n_bands))
        with kernels.threads():
            ks.gram(m, partial)
        return partial.sum(axis=0)
    m = m.astype(np.float64)
    return m @ m.T


def symmetric_eigh(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigenvectors of a small symmetric matrix: cyclic Jacobi
    (:func:`recon.kernels.subspace.jacobi_eigh`) where the kernels run, else
    :func:`numpy.linalg.eigh`."""
    if kernels.enabled():
        from recon.kernels import subspace as ks

        w, vecs = ks.jacobi_eigh(np.array(a, dtype=np.float64), 1e-12, 50)
        order = np.argsort(w, kind="stable")
        return w[order], vecs[:, order]
    return np.linalg.eigh(a)


def leading_basis(v: np.ndarray, rank: int, previous: np.ndarray | None = None,
                  weights: np.ndarray | None = None) -> np.ndarray:
    r"""The ``rank`` leading eigenvectors of the band Gram matrix :math:`v v^\top`.

    Parameters
    ----------
    v : ndarray, shape (L, H, W)
    rank : int
        :math:`1 \le k \le L`.
    previous : ndarray, shape (L, k), optional
        The basis of the previous call: each new vector takes the sign that agrees with its
        predecessor, so coefficient images (and any warm state kept on them) do not flip.
    weights : ndarray, shape (L,), optional
        A factor :math:`q_l` per band: the basis of the weighted cube :math:`q \odot v`,
        whose Gram matrix :math:`Q v v^\top Q` is taken from :math:`v`'s (no weighted copy).

    Returns
    -------
    ndarray, shape (L, k), float64
        Orthonormal columns, by decreasing eigenvalue.  Without ``previous`` each column's
        sign makes its sum non-negative.
    """
    gram = band_gram(v)
    if weights is not None:
        q = np.asarray(weights, dtype=np.float64).reshape(-1)
        gram = gram * np.outer(q, q)
    _, vecs = symmetric_eigh(gram)
    basis = np.ascontiguousarray(vecs[:, ::-1][:, :rank])
    if previous is not None and previous.shape == basis.shape:
        signs = np.sign(np.einsum("lk,lk->k", basis, previous))
    else:
        signs = np.sign(basis.sum(axis=0))
    signs[signs == 0] = 1.0
    basis *= signs
    return basis


def project(e: np.ndarray, v: np.ndarray) -> np.ndarray:
    r""":math:`z = E^\top v`, shape ``(k, H, W)``, for a basis ``e`` ``(L, k)`` in ``v``'s dtype."""
    m = v.reshape(v.shape[0], -1)
    if kernels.usable(e, m) and m.flags.c_contiguous:
        from recon.kernels import subspace as ks

        z = np.empty((e.shape[1], m.shape[1]), dtype=m.dtype)
        with kernels.threads():
            ks.mix(np.ascontiguousarray(e.T), m, z)
    else:
        z = e.T @ m
    return z.reshape((e.shape[1],) + v.shape[1:])


def expand(e: np.ndarray, z: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    r""":math:`x = E z`, shape ``(L, H, W)``, into ``out`` if given (``out`` may not be ``z``)."""
    shape = (e.shape[0],) + z.shape[1:]
    zf = z.reshape(z.shape[0], -1)
    if out is None:
        out = np.empty(shape, dtype=z.dtype)
    if kernels.usable(e, zf, out) and zf.flags.c_contiguous and out.flags.c_contiguous:
        from recon.kernels import subspace as ks

        with kernels.threads():
            ks.mix(np.ascontiguousarray(e), zf, out.reshape(e.shape[0], -1))
        return out
    np.copyto(out, (e @ zf).reshape(shape))
    return out


def basis_change(previous: np.ndarray | None, basis: np.ndarray) -> float | None:
    r"""How far the spanned subspace moved: :math:`\|EE^\top - E'E'^\top\|_F /
    \|E'E'^\top\|_F = \|EE^\top - E'E'^\top\|_F / \sqrt{k}` for the previous basis
    :math:`E'` and the new :math:`E` (orthonormal, ``(L, k)``); signs and the order within
    the span do not count.  None without a previous basis, infinity when the rank changed.

    Why the solvers' rule needs it (docs/priors.md, "The stopping rule waits for the
    basis"): while the basis turns, the iterate can travel with the momentum at a small
    relative change per iteration and a PSNR still rising; the basis moves several times as
    much as the iterate then, and settles when the iterate does.
    """
    if previous is None:
        return None
    if previous.shape != basis.shape:
        return math.inf
    d = basis @ basis.T - previous @ previous.T
    return float(np.sqrt(np.sum(d * d)) / math.sqrt(basis.shape[1]))


class _Subspace(PriorBase):
    """The projection shared by the subspace priors."""

    def __init__(self, rank: int | None):
        if rank is not None and (isinstance(rank, bool) or int(rank) != rank or rank < 1):
            raise InputError(f"rank must be a positive integer, got {rank!r}")
        self.rank = None if rank is None else int(rank)
        self.basis: np.ndarray | None = None
        self._previous_basis: np.ndarray | None = None     # the basis of the call before
        self._change: float | None = None

    def _check(self, v: np.ndarray, step: float) -> tuple[np.ndarray, float, int]:
        v = np.asarray(v)
        if v.ndim != 3 or min(v.shape) < 1:
            raise InputError(f"a prior takes (L, H, W) cubes, got shape {v.shape}")
        if v.dtype not in (np.float32, np.float64):
            v = v.astype(np.float32)
        step = float(step)
        if not (math.isfinite(step) and step >= 0):
            raise InputError(f"step must be >= 0, got {step}")
        rank = default_rank(v.shape[0]) if self.rank is None else self.rank
        if rank > v.shape[0]:
            raise InputError(f"rank {rank} exceeds the {v.shape[0]} bands")
        return v, step, rank

    def _coefficients(self, v: np.ndarray, rank: int, weights=None
                      ) -> tuple[np.ndarray, np.ndarray]:
        """(E, z): the re-estimated basis (v's dtype) and z = Eᵀ v, shape (k, H, W); with a
        factor q per band (``weights``) the basis E of q ⊙ v (:func:`leading_basis`), and
        (QE, (QE)ᵀ v) in its place."""
        v = np.ascontiguousarray(v)
        previous = self._previous_basis = self.basis
        self.basis = leading_basis(v, rank, previous, weights)
        self._change = basis_change(previous, self.basis)
        e = self.basis if weights is None else \
            self.basis * np.asarray(weights, dtype=np.float64).reshape(-1, 1)
        e = e.astype(v.dtype)
        return e, project(e, v)

    def state_change(self) -> float | None:
        """:func:`basis_change` of the last call (None before a second one)."""
        return self._change

    def reset(self) -> None:
        self.basis = None
        self._previous_basis = None
        self._change = None


class SubspaceTV(_Subspace):
    r"""Subspace prior with total variation on the coefficient images.

    .. math::

        \varphi(x) = \lambda\,\mathrm{TV}(E^\top x) + \iota_{\mathrm{span}\,E}(x),
        \qquad \mathrm{prox}_{s\varphi}(v) = E\,\mathrm{prox}_{s\lambda\mathrm{TV}}(E^\top v),

    with :math:`E` the :math:`k` leading eigenvectors of :math:`v v^\top`
    (:func:`leading_basis`), re-estimated at every call.

    Parameters
    ----------
    weight : float
        :math:`\lambda \ge 0` (the TV weight a solver's ``tau`` would be; 0 = projection only).
    rank : int, optional
        :math:`k`; :func:`default_rank` of the cube's bands if omitted.
    tv_iters : int
        Chambolle iterations per call, warm-started from the previous call's dual (a solver
        calls the prox once per iteration, as GAP-TV does with 2).
    isotropic : bool
        Isotropic (default) or anisotropic TV.
    threads : int, optional
        Threads of the TV prox (:class:`~recon.prox.TVProx`).
    """

    name = "subspace-tv"
    #: In FISTA's band metric the prior is taken on the band-weighted cube
    #: (:mod:`recon.solvers.band_metric`; measured in docs/priors.md).
    band_weighted = True

    def __init__(self, weight: float, rank: int | None = None, tv_iters: int = 2,
                 isotropic: bool = True, threads: int | None = None):
        super().__init__(rank)
        weight = float(weight)
        if not (math.isfinite(weight) and weight >= 0):
            raise InputError(f"weight must be >= 0, got {weight}")
        if int(tv_iters) < 1:
            raise InputError(f"tv_iters must be >= 1, got {tv_iters}")
        self.weight = weight
        self.tv_iters = int(tv_iters)
        self.isotropic = bool(isotropic)
        self.threads = threads
        self._tv: TVProx | None = None
        self._coeffs: np.ndarray | None = None   # the last prox's coefficient images
        self._previous_coeffs: np.ndarray | None = None     # and the call's before
        self._turned: np.ndarray | None = None   # scratch of previous_value

    def describe(self) -> dict:
        return {"prior": self.name, "weight": self.weight, "rank": self.rank,
                "tv_iters": self.tv_iters}

    def prox(self, v: np.ndarray, step: float, out: np.ndarray | None = None) -> np.ndarray:
        r""":math:`E\,\mathrm{prox}_{s\lambda\mathrm{TV}}(E^\top v)`, into ``out`` if given
        (``out`` may be ``v``)."""
        return self.scaled_prox(v, step, None, out)

    def scaled_prox(self, v: np.ndarray, step: float, weights, out: np.ndarray | None = None
                    ) -> np.ndarray:
        r""":math:`q \odot \mathrm{prox}_{s\varphi}(q \odot v)` for a factor :math:`q_l` per
        band (``weights``; None: the plain prox), into ``out`` if given (``out`` may be ``v``).

        With :math:`Q = \mathrm{diag}(q)` and :math:`E` the basis of :math:`Qv` (from
        :math:`Q v v^\top Q`), it is :math:`(QE)\,\mathrm{prox}_{s\lambda\mathrm{TV}}
        \bigl((QE)^\top v\bigr)`: the factors ride on the :math:`L \times k` basis, and no
        pass over the cube weighs it (the band metric, :mod:`recon.solvers.band_metric`)."""
        v, step, rank = self._check(v, step)
        e, z = self._coefficients(v, rank, weights)
        if self.weight > 0 and step > 0:
            if self._tv is None or self._tv.shape != z.shape or self._tv.dtype != z.dtype:
                self._tv = TVProx(z.shape, z.dtype, self.isotropic, self.threads)
            z = self._tv(z, step * self.weight, self.tv_iters, warm=True, out=z)
        self._previous_coeffs, self._coeffs = self._coeffs, z
        return expand(e, z, out)

    def prox_value(self) -> float | None:
        r""":math:`\lambda\,\mathrm{TV}(z)` of the last prox's coefficient images :math:`z`:
        the value of its result :math:`Ez` (whose projection :math:`E^\top E z` is :math:`z`,
        the basis orthonormal), without projecting the cube again; None before a call."""
        if self._coeffs is None:
            return None
        return self.weight * tv_norm(self._coeffs, self.isotropic)

    def previous_value(self) -> float | None:
        r""":math:`\lambda\,\mathrm{TV}(E^\top E' z')`: the value of the previous prox's
        result :math:`E'z'` (basis :math:`E'`, coefficients :math:`z'`) with the last call's
        basis :math:`E`, from the coefficients through the :math:`k\times k` matrix
        :math:`E^\top E'`, without a pass over the cube; None before two calls, or when the
        rank changed.  With a factor per band (:meth:`scaled_prox`) it is the value of
        :math:`q^{-1}\odot` that result, the factors being the same at both calls, which is
        how the band metric takes the prior."""
        if self._previous_coeffs is None or self._previous_basis is None or \
                self.basis is None or self._previous_basis.shape != self.basis.shape:
            return None
        z = self._previous_coeffs
        turn = (self.basis.T @ self._previous_basis).astype(z.dtype)
        if self._turned is None or self._turned.shape != z.shape or \
                self._turned.dtype != z.dtype:
            self._turned = np.empty_like(z)
        return self.weight * tv_norm(expand(turn, z, self._turned), self.isotropic)

    def value(self, x: np.ndarray) -> float:
        r""":math:`\lambda\,\mathrm{TV}(E^\top x)` with the basis of the last call (of ``x``
        itself before any); the indicator is left out (the solvers evaluate it on iterates
        that the prox put in the subspace)."""
        x = np.asarray(x)
        rank = default_rank(x.shape[0]) if self.rank is None else self.rank
        basis = self.basis if self.basis is not None else leading_basis(x, rank)
        x = np.ascontiguousarray(x, dtype=x.dtype if x.dtype in (np.float32, np.float64)
                                 else np.float32)
        z = project(basis.astype(x.dtype), x)
        return self.weight * tv_norm(np.ascontiguousarray(z), self.isotropic)

    def reset(self) -> None:
        """Forget the basis, the TV dual and the last coefficients (a new problem begins)."""
        super().reset()
        self._coeffs = self._previous_coeffs = self._turned = None
        if self._tv is not None:
            self._tv.reset()


#: The subspace prior's weight relative to the TV weight the caller would use (its ``tau``):
#: the coefficient images carry the same noise per pixel as the bands (the basis is
#: orthonormal), so TV's strength serves; docs/priors.md measures it so.
WEIGHT_PER_TV_WEIGHT = 1.0

#: Weight per view and per unit of the measurement's rms noise (unit-row-norm units) for the
#: least-squares solvers, :math:`\lambda = \kappa\, n\, \bar\sigma`, where no weight is given:
#: the constant of the application's TV rule (``kaleidospec.reconstruct.TAU_PER_NOISE``), with
#: which docs/priors.md measured this prior.
WEIGHT_PER_NOISE = {"fista": 0.15, "twist": 0.15, "admm": 0.15}


def subspace_weight(ctx) -> float:
    r"""The weight :func:`make_subspace_tv` uses: ``ctx.weight`` (the caller's TV weight) times
    :data:`WEIGHT_PER_TV_WEIGHT`; else :math:`\kappa\, n\, \bar\sigma`
    (:data:`WEIGHT_PER_NOISE`) where the solver, the noise and the views are known; else the
    solver's default TV weight (:func:`recon.priors.tv.default_weight`)."""
    from recon.priors.tv import default_weight

    if ctx.weight is not None:
        return float(ctx.weight) * WEIGHT_PER_TV_WEIGHT
    solver = "fista" if ctx.solver is None else ctx.solver
    algo = solver_algorithm(solver)
    if ctx.noise is not None and ctx.n_views and algo in WEIGHT_PER_NOISE:
        noise = float(ctx.noise)
        if not (math.isfinite(noise) and noise > 0):
            raise InputError(f"the measurement's noise must be positive, got {ctx.noise}")
        return WEIGHT_PER_NOISE[algo] * int(ctx.n_views) * noise
    return default_weight(solver)


def make_subspace_tv(ctx, *, rank: int | None = None, tv_iters: int = 2,
                     warm_dual: bool = True, isotropic: bool = True) -> SubspaceTV:
    """The registry's factory (:func:`recon.priors.make_prior` ``("subspace-tv")``), with the
    weight of :func:`subspace_weight`; ``warm_dual`` is accepted for the TV options' sake (the
    dual is always kept: the basis changes little between calls)."""
    return SubspaceTV(subspace_weight(ctx), rank=rank, tv_iters=tv_iters, isotropic=isotropic,
                      threads=ctx.threads)
