r"""Geometric maps :math:`W_k` from centre-view coordinates to one view's coordinates.

A warp maps a centre-view image of shape ``in_shape`` = (H, W) to a view image of shape
``out_shape`` = (Hv, Wv), and is applied to a whole band-major stack (..., H, W) at once.

- :class:`Identity` and :class:`Flip` are permutations: they are applied as NumPy views
  (negative strides, no copy), their adjoint is their inverse, and the adjoint of a sum can be
  accumulated straight into a flipped view of the output (:meth:`Warp.accumulate_view`).
- :class:`HomographyWarp` resamples with bilinear interpolation through a precomputed
  ``scipy.sparse`` CSR matrix :math:`W \in \mathbb{R}^{H_vW_v \times HW}` (four entries per row);
  samples that fall outside the centre image read zeros.
- :class:`Translate` is a homography with a pure translation.

Coordinates are pixel indices, ``x`` along columns and ``y`` along rows, pixel centres at
integers (the OpenCV convention).  A homography ``matrix`` maps centre coordinates
:math:`(x, y, 1)` to view coordinates, exactly like the matrix passed to
``cv2.warpPerspective(centre, matrix, (Wv, Hv))``: the view pixel :math:`p` reads the centre
image at :math:`\mathrm{matrix}^{-1} p`.

Warps without shapes (``Identity()``, ``Flip(1)``, ``Translate(dy, dx)``) are bound to concrete
shapes by :meth:`Warp.bind`, which :class:`~recon.operators.cassi.CassiOperator` calls.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.operators.dispersion import _image_shape, work_dtype

#: Interpolation weights closer than this to 0 or 1 are rounded, so that a homography that is
#: an exact permutation (a flip written as a matrix) gives a permutation matrix.
_WEIGHT_TOL = 1e-6


class Warp:
    """Base class of the geometric maps; see the module docstring.

    Attributes
    ----------
    in_shape, out_shape : (int, int) or None
        Centre-view and view image shapes (``None`` until bound).
    is_permutation : bool
        True when the map only reorders pixels (then it is applied as a view).
    """

    in_shape: tuple[int, int] | None = None
    out_shape: tuple[int, int] | None = None
    is_permutation = False

    def bind(self, in_shape, out_shape=None) -> "Warp":
        """Return this warp with concrete shapes (``out_shape`` defaults to ``in_shape``).

        Raises
        ------
        InputError
            If the shapes are incompatible with this warp.
        """
        raise NotImplementedError

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Warp a stack ``(..., H, W) -> (..., Hv, Wv)``; may return a read-only view."""
        raise NotImplementedError

    def apply_adjoint(self, y: np.ndarray) -> np.ndarray:
        """The exact adjoint ``(..., Hv, Wv) -> (..., H, W)``."""
        raise NotImplementedError

    def accumulate_view(self, out: np.ndarray) -> np.ndarray | None:
        r"""For a permutation, a view ``V`` of ``out`` (..., H, W) such that ``V += z`` adds
        :math:`W^\top z` to ``out``; ``None`` for other warps."""
        return None

    def matrix(self) -> sp.csr_matrix:
        """The map as a sparse (Hv*Wv, H*W) float64 matrix (tests, row norms)."""
        h, w = self._need_shapes()
        eye = np.arange(h * w, dtype=np.float64).reshape(h, w)
        # A permutation (possibly with dropped pixels) is read off by warping pixel indices.
        idx = np.asarray(self.apply(eye + 1.0)).ravel()
        rows = np.nonzero(idx)[0]
        cols = (idx[rows] - 1.0).astype(np.int64)
        return sp.csr_matrix((np.ones(rows.size), (rows, cols)),
                             shape=(int(np.prod(self.out_shape)), h * w))

    def sparse_pair(self) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        r""":math:`W` and :math:`W^\top` as float32 CSR matrices, the same weights in both (the
        fused kernels gather along the rows of each, :mod:`recon.kernels.calibrated`)."""
        m = self.matrix().astype(np.float32).tocsr()
        return m, m.T.tocsr()

    def norm_parts(self) -> tuple[np.ndarray, np.ndarray | None]:
        r"""Row statistics of the matrix used for closed-form row norms.

        Returns
        -------
        n : (Hv, Wv) float64
            :math:`\|W_p\|^2` for every view pixel :math:`p`.
        c : (Hv, Wv-1) float64 or None
            :math:`\langle W_p, W_{p+\hat x}\rangle` for horizontal neighbours; ``None`` when
            those rows are always orthogonal (permutations).
        """
        m = self.matrix()
        hv, wv = self.out_shape
        n = np.asarray(m.multiply(m).sum(axis=1)).reshape(hv, wv)
        if self.is_permutation:
            return n, None
        if wv < 2:
            return n, np.zeros((hv, 0))
        left = np.arange(hv * wv).reshape(hv, wv)[:, :-1].ravel()
        c = np.asarray(m[left].multiply(m[left + 1]).sum(axis=1)).reshape(hv, wv - 1)
        return n, c

    def _need_shapes(self) -> tuple[int, int]:
        if self.in_shape is None or self.out_shape is None:
            raise InputError(f"{self!r} has no shapes yet; call .bind(in_shape, out_shape)")
        return self.in_shape

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.in_shape} -> {self.out_shape})"


def _equal_shapes(in_shape, out_shape, what: str, hint: str = "") -> tuple[int, int]:
    """``in_shape`` for a permutation warp, which needs ``out_shape`` (default: the same) equal."""
    in_shape = _image_shape(in_shape)
    out_shape = in_shape if out_shape is None else _image_shape(out_shape)
    if in_shape != out_shape:
        raise InputError(f"{what} needs equal shapes, got {in_shape} -> {out_shape}{hint}")
    return in_shape


class Identity(Warp):
    """The identity map (the centre view)."""

    is_permutation = True

    def __init__(self, shape=None):
        if shape is not None:
            self.in_shape = self.out_shape = _image_shape(shape)

    def bind(self, in_shape, out_shape=None):
        return Identity(_equal_shapes(in_shape, out_shape, "an identity warp",
                                      " (give the view a HomographyWarp/Translate to change size)"))

    def apply(self, x):
        return x

    def apply_adjoint(self, y):
        return y

    def accumulate_view(self, out):
        return out


class Flip(Warp):
    """Mirror image: ``axis=0`` reverses rows (top/bottom views), ``axis=1`` reverses columns
    (left/right views), ``axis=(0, 1)`` both (corner views)."""

    is_permutation = True

    def __init__(self, axis, shape=None):
        axes = (axis,) if np.isscalar(axis) else tuple(axis)
        try:
            axes = tuple(sorted({int(a) for a in axes}))
        except (TypeError, ValueError):
            raise InputError(f"Flip axis must be 0, 1 or (0, 1), got {axis!r}") from None
        if not axes or any(a not in (0, 1) for a in axes):
            raise InputError(f"Flip axis must be 0, 1 or (0, 1), got {axis!r}")
        self.axes = axes
        # Index into the last two axes of a stack, as negative-stride slices.
        self._index = (Ellipsis,) + tuple(slice(None, None, -1) if a in axes else slice(None)
                                          for a in (0, 1))
        if shape is not None:
            self.in_shape = self.out_shape = _image_shape(shape)

    def bind(self, in_shape, out_shape=None):
        return Flip(self.axes, _equal_shapes(in_shape, out_shape, "a flip"))

    def apply(self, x):
        return x[self._index]

    apply_adjoint = apply
    accumulate_view = apply

    def __repr__(self):
        return f"Flip(axis={self.axes}, shape={self.in_shape})"


class HomographyWarp(Warp):
    r"""Bilinear resampling through a 3×3 homography, precomputed as a sparse CSR matrix.

    The view pixel :math:`p = (x_v, y_v)` reads the centre image at
    :math:`q = \pi(\mathrm{matrix}^{-1} (x_v, y_v, 1)^\top)` (:math:`\pi` divides by the third
    coordinate) with bilinear weights; neighbours outside the centre image count as zero.

    Parameters
    ----------
    matrix : (3, 3) array_like
        Centre → view map (as for ``cv2.warpPerspective``), invertible and finite.
    in_shape : (H, W)
        Centre image shape.
    out_shape : (Hv, Wv), optional
        View image shape (default ``in_shape``).
    """

    def __init__(self, matrix, in_shape, out_shape=None):
        m = np.array(matrix, dtype=np.float64)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise InputError(f"homography must be a finite 3x3 matrix, got shape {m.shape}")
        if abs(np.linalg.det(m)) < 1e-12 * max(1.0, np.abs(m).max() ** 3):
            raise InputError("homography matrix is singular")
        self.H = m
        self.in_shape = _image_shape(in_shape)
        self.out_shape = self.in_shape if out_shape is None else _image_shape(out_shape)
        self._m = _bilinear_matrix(np.linalg.inv(m), self.in_shape, self.out_shape)
        self._mt = self._m.T.tocsr()
        self._n_c = None

    def bind(self, in_shape, out_shape=None):
        in_shape = _image_shape(in_shape)
        if in_shape != self.in_shape or (out_shape is not None
                                         and _image_shape(out_shape) != self.out_shape):
            raise InputError(f"homography warp was built for {self.in_shape} -> {self.out_shape},"
                             f" asked for {in_shape} -> {out_shape}")
        return self

    def apply(self, x):
        return _sparse_stack(self._m, x, self.out_shape)

    def apply_adjoint(self, y):
        return _sparse_stack(self._mt, y, self.in_shape)

    def matrix(self):
        return self._m.astype(np.float64)

    def sparse_pair(self):
        return self._m, self._mt

    def norm_parts(self):
        if self._n_c is None:
            self._n_c = super().norm_parts()
        return self._n_c

    def __repr__(self):
        return f"HomographyWarp({self.in_shape} -> {self.out_shape})"


class Translate(Warp):
    r"""Shift the image content by ``(dy, dx)`` pixels (sub-pixel allowed, bilinear):
    :math:`v(y, x) = f(y - d_y, x - d_x)`, zeros where it reads outside."""

    def __init__(self, dy: float, dx: float):
        d = np.array([dy, dx], dtype=np.float64)
        if not np.all(np.isfinite(d)):
            raise InputError(f"translation must be finite, got ({dy}, {dx})")
        self.dy, self.dx = float(d[0]), float(d[1])

    def bind(self, in_shape, out_shape=None):
        m = np.array([[1.0, 0.0, self.dx], [0.0, 1.0, self.dy], [0.0, 0.0, 1.0]])
        return HomographyWarp(m, in_shape, out_shape)

    def __repr__(self):
        return f"Translate(dy={self.dy}, dx={self.dx})"


class WarpOperator(LinearOperator):
    """A warp applied to every band of a band-major cube, ``(L, H, W) -> (L, Hv, Wv)``."""

    def __init__(self, warp: Warp, n_bands: int, in_shape=None, out_shape=None):
        if warp.in_shape is None or in_shape is not None:
            warp = warp.bind(in_shape if in_shape is not None else warp.in_shape, out_shape)
        self.warp = warp
        super().__init__((n_bands,) + warp.in_shape, (n_bands,) + warp.out_shape)

    def _forward(self, x):
        return np.ascontiguousarray(self.warp.apply(x.astype(work_dtype(x), copy=False)))

    def _adjoint(self, y):
        return np.ascontiguousarray(self.warp.apply_adjoint(y.astype(work_dtype(y), copy=False)))

    def row_norms_sq(self):
        n, _ = self.warp.norm_parts()
        return np.broadcast_to(n, self.oshape).copy()


def as_warp(warp, name: str = "warp") -> Warp:
    """``None`` → :class:`Identity`; a :class:`Warp` passes; anything else is an InputError."""
    if warp is None:
        return Identity()
    if not isinstance(warp, Warp):
        raise InputError(f"{name} must be None, Identity, Flip, Translate or HomographyWarp, "
                         f"got {type(warp).__name__}")
    return warp


def as_warps(warps, n_views: int, what: str = "the masks") -> list[Warp]:
    """One :class:`Warp` per view: ``None`` → identities, each entry through :func:`as_warp`.

    Raises
    ------
    InputError
        An entry that is not a warp, or not exactly ``n_views`` of them (``what`` names the
        array that fixes the number of views, for the message).
    """
    if warps is None:
        warps = [None] * n_views
    out = [as_warp(w, name=f"warps[{i}]") for i, w in enumerate(list(warps))]
    if len(out) != n_views:
        raise InputError(f"warps has {len(out)} entries, {what} has {n_views} views")
    return out


def cube_shape_of(cube_shape, n_bands: int, warps, default_hw) -> tuple[int, int, int]:
    """The band-major cube shape ``(L, H, W)`` of a multi-view operator.

    ``cube_shape`` when given (checked), else ``(L,)`` + the input shape of the first warp
    that has one, else ``(L,) + default_hw``.

    Raises
    ------
    InputError
        Not three positive integers, or not ``n_bands`` bands.
    """
    if cube_shape is None:
        known = [w.in_shape for w in warps if w.in_shape is not None]
        return (int(n_bands),) + tuple(int(s) for s in (known[0] if known else default_hw))
    try:
        cs = tuple(int(s) for s in cube_shape)
    except (TypeError, ValueError):
        raise InputError(f"cube_shape must be (L, H, W), got {cube_shape!r}") from None
    if len(cs) != 3 or min(cs) < 1:
        raise InputError(f"cube_shape must be three positive ints (L, H, W), got {cube_shape!r}")
    if cs[0] != n_bands:
        raise InputError(f"cube_shape {cs} is band-major (L, H, W) but the operator has "
                         f"{n_bands} bands")
    return cs


def _bilinear_matrix(inv: np.ndarray, in_shape, out_shape) -> sp.csr_matrix:
    """CSR matrix (Hv*Wv, H*W), float32, of bilinear sampling at ``inv @ (x, y, 1)``."""
    h, w = in_shape
    hv, wv = out_shape
    yv, xv = np.mgrid[0:hv, 0:wv]
    p = np.stack([xv.ravel(), yv.ravel(), np.ones(hv * wv)]).astype(np.float64)
    q = inv @ p
    ok = q[2] > 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = np.where(ok, q[0] / np.where(ok, q[2], 1.0), -2.0)
        ys = np.where(ok, q[1] / np.where(ok, q[2], 1.0), -2.0)
    x0 = np.floor(xs)
    y0 = np.floor(ys)
    fx = xs - x0
    fy = ys - y0
    # Snap near-integer positions so that exact permutations stay exact.
    for f, base in ((fx, x0), (fy, y0)):
        up = f > 1.0 - _WEIGHT_TOL
        base[up] += 1.0
        f[up] = 0.0
        f[f < _WEIGHT_TOL] = 0.0
    rows, cols, vals = [], [], []
    row = np.arange(hv * wv)
    for dy, wy in ((0, 1.0 - fy), (1, fy)):
        for dx, wx in ((0, 1.0 - fx), (1, fx)):
            yy = y0 + dy
            xx = x0 + dx
            wgt = wy * wx
            keep = ok & (wgt > 0) & (yy >= 0) & (yy < h) & (xx >= 0) & (xx < w)
            rows.append(row[keep])
            cols.append((yy[keep] * w + xx[keep]).astype(np.int64))
            vals.append(wgt[keep])
    m = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(hv * wv, h * w)).tocsr()
    m.sum_duplicates()
    return m.astype(np.float32)


def _sparse_stack(m: sp.csr_matrix, x: np.ndarray, out_shape) -> np.ndarray:
    """Apply ``m`` to every image of a stack (..., h, w) -> (..., *out_shape)."""
    lead = x.shape[:-2]
    x2 = np.ascontiguousarray(x).reshape(-1, x.shape[-2] * x.shape[-1])
    dt = work_dtype(x2)
    mm = m if dt == np.float32 else m.astype(np.float64)
    out = np.empty((x2.shape[0], mm.shape[0]), dtype=dt)
    for i in range(x2.shape[0]):
        out[i] = mm @ x2[i]
    return out.reshape(lead + tuple(out_shape))
