r"""The linear-operator contract every forward model in :mod:`recon` follows.

An operator :math:`A` maps arrays of shape ``ishape`` to arrays of shape ``oshape``;
``forward`` computes :math:`Ax`, ``adjoint`` computes :math:`A^\top y` exactly (not an
approximation), so that :math:`\langle Ax, y\rangle = \langle x, A^\top y\rangle` up to rounding.
:func:`dot_test` checks that identity and every operator's test suite calls it.
"""

from __future__ import annotations

import numpy as np


class LinearOperator:
    """Base class: a real linear map between two array shapes.

    Subclasses set ``ishape``, ``oshape`` and implement ``_forward`` and ``_adjoint``; both work
    in float32 unless the input is float64, in which case float64 is kept (for precision checks).

    Attributes
    ----------
    ishape, oshape : tuple of int
        Shapes of the domain and of the range.
    """

    ishape: tuple[int, ...]
    oshape: tuple[int, ...]

    def __init__(self, ishape, oshape):
        self.ishape = tuple(int(s) for s in ishape)
        self.oshape = tuple(int(s) for s in oshape)

    # -- public API -------------------------------------------------------------------------
    def forward(self, x: np.ndarray) -> np.ndarray:
        """Return :math:`Ax` for ``x`` of shape ``ishape``."""
        x = np.asarray(x)
        if x.shape != self.ishape:
            raise ValueError(f"{type(self).__name__}: input shape {x.shape} != {self.ishape}")
        return self._forward(x)

    def adjoint(self, y: np.ndarray) -> np.ndarray:
        """Return :math:`A^\\top y` for ``y`` of shape ``oshape``."""
        y = np.asarray(y)
        if y.shape != self.oshape:
            raise ValueError(f"{type(self).__name__}: input shape {y.shape} != {self.oshape}")
        return self._adjoint(y)

    def adjoint_add(self, y: np.ndarray, base: np.ndarray, scale: float = 1.0,
                    out: np.ndarray | None = None,
                    base_weights: np.ndarray | None = None) -> np.ndarray:
        r"""Return :math:`b + s\,A^\top y`, the gradient step of the solvers, or
        :math:`q \odot b + s\,A^\top y` with ``base_weights``.

        Parameters
        ----------
        y : ndarray, shape ``oshape``
        base : ndarray, shape ``ishape``
            :math:`b`; the result has its dtype.
        scale : float
            :math:`s`.
        out : ndarray, shape ``ishape``, optional
            Where to write the result; may be ``base``.
        base_weights : ndarray, shape ``(ishape[0],)``, optional
            :math:`q`, one factor per slice of the first axis (per band of a cube): the band
            metric's weighted base (:mod:`recon.solvers.band_metric`), which an operator with
            a fused kernel applies as it writes the result instead of in a pass of its own.

        Operators with a fused kernel override this to add the adjoint as they compute it.
        """
        base = weighted_base(base, base_weights)
        r = np.asarray(self.adjoint(y)).astype(base.dtype, copy=False)
        if scale != 1.0:
            r = np.multiply(r, scale, out=None if np.may_share_memory(r, y) else r)
        return np.add(base, r, out=out)

    __call__ = forward

    @property
    def H(self) -> "LinearOperator":
        """The adjoint as an operator."""
        return _Adjoint(self)

    def __matmul__(self, other: "LinearOperator") -> "LinearOperator":
        return _Compose(self, other)

    def row_norms_sq(self) -> np.ndarray:
        r"""Diagonal of :math:`AA^\top` (squared norm of every row), shape ``oshape``.

        Exact for any operator through :math:`\sum_j A_{ij}^2`; subclasses override it with a
        closed form.  The default here probes with unit vectors and is only for small tests.
        """
        n = int(np.prod(self.oshape))
        out = np.empty(n, dtype=np.float64)
        e = np.zeros(n, dtype=np.float64)
        for i in range(n):
            e[i] = 1.0
            out[i] = np.sum(self.adjoint(e.reshape(self.oshape)).astype(np.float64) ** 2)
            e[i] = 0.0
        return out.reshape(self.oshape)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.ishape} -> {self.oshape}>"

    # -- to implement ---------------------------------------------------------------------------
    def _forward(self, x: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _adjoint(self, y: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError


class _Adjoint(LinearOperator):
    def __init__(self, op: LinearOperator):
        super().__init__(op.oshape, op.ishape)
        self.op = op

    def _forward(self, x):
        return self.op.adjoint(x)

    def _adjoint(self, y):
        return self.op.forward(y)


class _Compose(LinearOperator):
    """``(A @ B) x = A(Bx)``."""

    def __init__(self, a: LinearOperator, b: LinearOperator):
        if a.ishape != b.oshape:
            raise ValueError(f"cannot compose {a!r} @ {b!r}")
        super().__init__(b.ishape, a.oshape)
        self.a, self.b = a, b

    def _forward(self, x):
        return self.a.forward(self.b.forward(x))

    def _adjoint(self, y):
        return self.b.adjoint(self.a.adjoint(y))


class ScaledOperator(LinearOperator):
    r"""``s·A`` for a scalar :math:`s`: forward and adjoint scaled by :math:`s`, row norms by
    :math:`s^2`.  Used to bring a measurement and its operator to a common scale."""

    def __init__(self, op: LinearOperator, s: float):
        super().__init__(op.ishape, op.oshape)
        self.inner = op
        self.scale = float(s)

    def _scaled(self, y: np.ndarray) -> np.ndarray:
        return y * y.dtype.type(self.scale)

    def _forward(self, x):
        return self._scaled(self.inner.forward(x))

    def _adjoint(self, y):
        return self._scaled(self.inner.adjoint(y))

    def adjoint_add(self, y, base, scale=1.0, out=None, base_weights=None):
        r""":math:`b + t\,(sA)^\top y = b + (ts)\,A^\top y`: the inner operator's own
        gradient step (fused where it has one) with the scales multiplied, not a scaled copy
        of :math:`A^\top y` added in two more passes."""
        return self.inner.adjoint_add(y, base, float(scale) * self.scale, out,
                                      base_weights=base_weights)

    def row_norms_sq(self):
        rn = np.asarray(self.inner.row_norms_sq())
        return rn * rn.dtype.type(self.scale ** 2)

    def __repr__(self) -> str:
        return f"<ScaledOperator {self.scale:.4g} * {self.inner!r}>"


class MatrixOperator(LinearOperator):
    """A dense matrix as an operator on flattened arrays (a reference for tests)."""

    def __init__(self, matrix: np.ndarray, ishape=None, oshape=None):
        m = np.asarray(matrix)
        super().__init__(ishape or (m.shape[1],), oshape or (m.shape[0],))
        if m.shape != (int(np.prod(self.oshape)), int(np.prod(self.ishape))):
            raise ValueError("matrix shape does not match ishape/oshape")
        self.matrix = m

    def _forward(self, x):
        return (self.matrix @ x.reshape(-1)).reshape(self.oshape)

    def _adjoint(self, y):
        return (self.matrix.T @ y.reshape(-1)).reshape(self.ishape)

    def row_norms_sq(self):
        return np.sum(self.matrix.astype(np.float64) ** 2, axis=1).reshape(self.oshape)


def dot_test(op: LinearOperator, rng: np.random.Generator | None = None,
             dtype=np.float64) -> float:
    r"""Relative mismatch of :math:`\langle Ax, y\rangle` and :math:`\langle x, A^\top y\rangle`.

    Parameters
    ----------
    op : LinearOperator
    rng : numpy.random.Generator, optional
    dtype : numpy dtype
        Precision of the random probes (float64 by default, so that the test measures the
        adjoint and not float32 rounding).

    Returns
    -------
    float
        :math:`|\langle Ax,y\rangle-\langle x,A^\top y\rangle| / \max(|\langle Ax,y\rangle|, 10^{-30})`.
    """
    rng = rng or np.random.default_rng(0)
    x = rng.standard_normal(op.ishape).astype(dtype)
    y = rng.standard_normal(op.oshape).astype(dtype)
    lhs = float(np.vdot(op.forward(x).astype(np.float64), y))
    rhs = float(np.vdot(x, op.adjoint(y).astype(np.float64)))
    return abs(lhs - rhs) / max(abs(lhs), abs(rhs), 1e-30)


def weighted_base(base: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    r""":math:`q \odot b`, ``weights`` :math:`q` one factor per slice of ``base``'s first axis
    (a new array in ``base``'s dtype), or ``base`` itself without weights: the reference of
    :meth:`LinearOperator.adjoint_add`'s ``base_weights`` that fused kernels are tested
    against."""
    if weights is None:
        return base
    base = np.asarray(base)
    q = np.asarray(weights, dtype=base.dtype).reshape(-1)
    if q.shape != base.shape[:1]:
        raise ValueError(f"base_weights: one weight per slice of the base's first axis "
                         f"({base.shape[0]}), got shape {np.shape(weights)}")
    return base * q.reshape((-1,) + (1,) * (base.ndim - 1))
