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
- A :class:`DisplacementField` (a smooth 2-D polynomial) corrects a homography for what it
  cannot hold, such as the curvature a prism's field-dependent deviation gives the image;
  :class:`HomographyWarp` takes one for each side of the map.

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

    def share_csr(self, forward=None, adjoint=None) -> None:
        r"""Hold ``forward`` (:math:`W`) and ``adjoint`` (:math:`W^\top`), each a CSR triple
        ``(indptr, indices, data)`` with the values of :meth:`sparse_pair`'s, in place of the
        warp's own arrays: a caller that copied them (the one-pass kernels of
        :class:`~recon.operators.CalibratedCassi` join every view's into one array) then
        holds one copy, not two.  A warp that keeps no matrix has nothing to give up."""
        return None

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


class DisplacementField:
    r"""A smooth displacement of image coordinates, a 2-D polynomial of total degree ``deg``:

    .. math:: d(x, y) = \sum_{i + j \le \deg} c_{ij}\, \xi^i \eta^j, \qquad
              \xi = (x - x_c)/s_x,\ \eta = (y - y_c)/s_y,

    one coefficient row for :math:`d_x` and one for :math:`d_y`.

    Parameters
    ----------
    coeffs : (2, T) array_like
        :math:`c_{ij}` of :math:`d_x` and :math:`d_y`, in the order of :meth:`terms`;
        ``T = (deg + 1)(deg + 2) / 2``.
    frame : (4,) array_like
        :math:`(x_c, y_c, s_x, s_y)`, scales positive.
    """

    def __init__(self, coeffs, frame):
        c = np.array(coeffs, dtype=np.float64)
        f = np.array(frame, dtype=np.float64)
        if c.ndim != 2 or c.shape[0] != 2 or not np.all(np.isfinite(c)):
            raise InputError(f"coeffs must be a finite (2, T) array, got shape {c.shape}")
        deg = int(round((np.sqrt(8 * c.shape[1] + 1) - 3) / 2))
        if len(self.terms(deg)) != c.shape[1]:
            raise InputError(f"{c.shape[1]} coefficients are no full 2-D polynomial")
        if f.shape != (4,) or not np.all(np.isfinite(f)) or f[2] <= 0 or f[3] <= 0:
            raise InputError(f"frame must be finite (x_c, y_c, s_x > 0, s_y > 0), got {frame!r}")
        self.coeffs, self.frame, self.degree = c, f, deg

    @staticmethod
    def terms(deg: int) -> list[tuple[int, int]]:
        r"""The exponents (i, j) of :math:`\xi^i \eta^j`, in coefficient order."""
        return [(i, t - i) for t in range(deg + 1) for i in range(t, -1, -1)]

    @classmethod
    def fit(cls, points, shifts, deg: int = 2, frame=None) -> "DisplacementField":
        """Least-squares field through ``shifts`` (N, 2) measured at ``points`` (N, 2) (x, y);
        ``frame`` defaults to the points' centre and half-extent."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        d = np.asarray(shifts, dtype=np.float64).reshape(-1, 2)
        n_terms = len(cls.terms(deg))
        if p.shape != d.shape or p.shape[0] < n_terms or not np.all(np.isfinite(p) & np.isfinite(d)):
            raise InputError(f"need at least {n_terms} finite points and shifts of the same "
                             f"shape, got {p.shape} and {d.shape}")
        if frame is None:
            lo, hi = p.min(axis=0), p.max(axis=0)
            frame = (*(0.5 * (lo + hi)), *np.maximum(0.5 * (hi - lo), 1.0))
        field = cls(np.zeros((2, n_terms)), frame)
        a = field._design(p[:, 0], p[:, 1])
        coef, *_ = np.linalg.lstsq(a, d, rcond=None)
        field.coeffs = np.ascontiguousarray(coef.T)
        return field

    def _design(self, x, y) -> np.ndarray:
        xc, yc, sx, sy = self.frame
        xi = (np.asarray(x, dtype=np.float64) - xc) / sx
        eta = (np.asarray(y, dtype=np.float64) - yc) / sy
        return np.stack([xi ** i * eta ** j for i, j in self.terms(self.degree)], axis=-1)

    def __call__(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """:math:`(d_x, d_y)` at points ``x``, ``y`` (any matching shapes)."""
        a = self._design(x, y)
        return a @ self.coeffs[0], a @ self.coeffs[1]

    def bend(self) -> "DisplacementField":
        """The field without its affine part (its terms of degree ≤ 1)."""
        c = self.coeffs.copy()
        c[:, :3] = 0.0          # 1, xi, eta (:meth:`terms`)
        return DisplacementField(c, self.frame)

    def moved(self, dx: float) -> "DisplacementField":
        """The same field in coordinates whose x origin lies ``dx`` further left
        (:math:`x' = x + dx`)."""
        xc, yc, sx, sy = self.frame
        return DisplacementField(self.coeffs, (xc + dx, yc, sx, sy))

    def __repr__(self):
        return f"DisplacementField(degree {self.degree}, frame {tuple(self.frame)})"


class HomographyWarp(Warp):
    r"""Bilinear resampling through a 3×3 homography, precomputed as a sparse CSR matrix.

    The view pixel :math:`p = (x_v, y_v)` reads the centre image at
    :math:`q = \pi(\mathrm{matrix}^{-1} (x_v, y_v, 1)^\top)` (:math:`\pi` divides by the third
    coordinate) with bilinear weights; neighbours outside the centre image count as zero.

    With displacement fields (:class:`DisplacementField`) the map is
    :math:`p = H(q - d_c(q)) + d_v(H(q - d_c(q)))` — the centre image's own distortion
    :math:`d_c` taken out, the homography, the view's distortion :math:`d_v` put in — and the
    view pixel reads the centre image at its inverse to first order in the fields (they are
    smooth and below a pixel):

    .. math:: q = q' + d_c(q'), \qquad q' = \pi\big(H^{-1}(p - d_v(p))\big).

    Parameters
    ----------
    matrix : (3, 3) array_like
        Centre → view map (as for ``cv2.warpPerspective``), invertible and finite.
    in_shape : (H, W)
        Centre image shape.
    out_shape : (Hv, Wv), optional
        View image shape (default ``in_shape``).
    view_field, centre_field : DisplacementField, optional
        :math:`d_v` in view coordinates, :math:`d_c` in centre coordinates (default none).
    """

    def __init__(self, matrix, in_shape, out_shape=None, view_field=None, centre_field=None):
        m = np.array(matrix, dtype=np.float64)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise InputError(f"homography must be a finite 3x3 matrix, got shape {m.shape}")
        if abs(np.linalg.det(m)) < 1e-12 * max(1.0, np.abs(m).max() ** 3):
            raise InputError("homography matrix is singular")
        for name, f in (("view_field", view_field), ("centre_field", centre_field)):
            if f is not None and not isinstance(f, DisplacementField):
                raise InputError(f"{name} must be a DisplacementField, got {type(f).__name__}")
        self.H = m
        self.view_field, self.centre_field = view_field, centre_field
        self.in_shape = _image_shape(in_shape)
        self.out_shape = self.in_shape if out_shape is None else _image_shape(out_shape)
        xs, ys, ok = _source_points(np.linalg.inv(m), self.out_shape, view_field, centre_field)
        self._m = _bilinear_matrix(xs, ys, ok, self.in_shape, self.out_shape)
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

    def share_csr(self, forward=None, adjoint=None):
        for name, csr in (("_m", forward), ("_mt", adjoint)):
            if csr is None:
                continue
            own = getattr(self, name)
            indptr, indices, data = csr
            # The caller's arrays replace the warp's own only if they hold the same matrix.
            if not (np.array_equal(indptr, own.indptr) and np.array_equal(indices, own.indices)
                    and np.array_equal(data, own.data)):
                raise InputError("share_csr: the arrays are not this warp's matrix")
            # In place: SciPy's constructor would copy them.
            own.indptr, own.indices, own.data = indptr, indices, data

    def norm_parts(self):
        if self._n_c is None:
            self._n_c = super().norm_parts()
        return self._n_c

    def __repr__(self):
        fields = "" if self.view_field is None and self.centre_field is None else ", with fields"
        return f"HomographyWarp({self.in_shape} -> {self.out_shape}{fields})"


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


def _source_points(inv: np.ndarray, out_shape, view_field=None, centre_field=None):
    """Where every view pixel reads the centre image: (xs, ys, ok) flat over the view
    (:class:`HomographyWarp`); ``ok`` False where the homography sends it to infinity."""
    hv, wv = out_shape
    yv, xv = np.mgrid[0:hv, 0:wv]
    px, py = xv.ravel().astype(np.float64), yv.ravel().astype(np.float64)
    if view_field is not None:
        dx, dy = view_field(px, py)
        px, py = px - dx, py - dy
    q = inv @ np.stack([px, py, np.ones(hv * wv)])
    ok = q[2] > 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        xs = np.where(ok, q[0] / np.where(ok, q[2], 1.0), -2.0)
        ys = np.where(ok, q[1] / np.where(ok, q[2], 1.0), -2.0)
    if centre_field is not None:
        dx, dy = centre_field(xs, ys)
        xs, ys = np.where(ok, xs + dx, -2.0), np.where(ok, ys + dy, -2.0)
    return xs, ys, ok


def _bilinear_matrix(xs: np.ndarray, ys: np.ndarray, ok: np.ndarray, in_shape,
                     out_shape) -> sp.csr_matrix:
    """CSR matrix (Hv*Wv, H*W), float32, of bilinear sampling at the points (xs, ys) (flat,
    one per view pixel; none where ``ok`` is False).

    Made as CSR directly: a pixel's four taps, (y0, x0), (y0, x0 + 1), (y0 + 1, x0),
    (y0 + 1, x0 + 1), are already in the order of their columns, so the entries kept, read
    pixel by pixel, are the CSR arrays (:func:`_bilinear_matrix_coo`, the COO build and
    SciPy's conversion it replaces, gives the same arrays: tests/recon/operators/test_warp.py).
    """
    h, w = in_shape
    x0, y0, fx, fy = _bilinear_parts(xs, ys)
    n = out_shape[0] * out_shape[1]
    cols = np.empty((n, 4), np.int64)
    vals = np.empty((n, 4), np.float32)
    keep = np.empty((n, 4), np.bool_)
    for k, (dy, wy, dx, wx) in enumerate(_taps(fx, fy)):
        yy, xx = y0 + dy, x0 + dx
        wgt = wy * wx
        kk = keep[:, k]
        np.logical_and(ok, wgt > 0, out=kk)
        kk &= (yy >= 0) & (yy < h) & (xx >= 0) & (xx < w)
        with np.errstate(invalid="ignore", over="ignore"):   # far points are not kept
            cols[:, k] = np.where(kk, yy * w + xx, 0.0)
        vals[:, k] = wgt
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(keep.sum(axis=1), out=indptr[1:])
    index = np.int32 if h * w < 2 ** 31 and indptr[-1] < 2 ** 31 else np.int64
    return sp.csr_matrix((vals[keep], cols[keep].astype(index), indptr.astype(index)),
                         shape=(n, h * w))


def _bilinear_parts(xs, ys):
    """``x0, y0, fx, fy``: the integer parts and fractions of the points, positions within
    :data:`_WEIGHT_TOL` of an integer snapped to it (exact permutations stay exact)."""
    x0 = np.floor(xs)
    y0 = np.floor(ys)
    fx = xs - x0
    fy = ys - y0
    for f, base in ((fx, x0), (fy, y0)):
        up = f > 1.0 - _WEIGHT_TOL
        base[up] += 1.0
        f[up] = 0.0
        f[f < _WEIGHT_TOL] = 0.0
    return x0, y0, fx, fy


def _taps(fx, fy):
    """``(dy, wy, dx, wx)`` of the four bilinear taps, in the order of their columns."""
    return [(dy, wy, dx, wx) for dy, wy in ((0, 1.0 - fy), (1, fy))
            for dx, wx in ((0, 1.0 - fx), (1, fx))]


def _bilinear_matrix_coo(xs: np.ndarray, ys: np.ndarray, ok: np.ndarray, in_shape,
                         out_shape) -> sp.csr_matrix:
    """:func:`_bilinear_matrix` through a COO matrix and SciPy's conversion (the reference)."""
    h, w = in_shape
    hv, wv = out_shape
    x0, y0, fx, fy = _bilinear_parts(xs, ys)
    rows, cols, vals = [], [], []
    row = np.arange(hv * wv)
    for dy, wy, dx, wx in _taps(fx, fy):
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
