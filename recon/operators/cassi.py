r"""The (multi-view) CASSI forward model and its exact adjoint.

For a scene cube :math:`f` in centre-view coordinates, band-major :math:`(L, H, W)`, view
:math:`k` records

.. math::

    g_k = \sum_{l=1}^{L} S_{k,l}\big(M_k \odot W_k f_l\big), \qquad g = [g_1; \dots; g_K],

with :math:`W_k` the view's geometric map (:mod:`recon.operators.warp`), :math:`M_k` its mask
(view coordinates, :math:`H_v \times W_v`) and :math:`S_{k,l}` the horizontal shift by
:math:`\varphi_{k,l}` pixels (:mod:`recon.operators.dispersion`; linear interpolation for
sub-pixel shifts).  The adjoint is

.. math::

    f_l = \sum_k W_k^\top\big(M_k \odot S_{k,l}^\top g_k\big).

All shifts are normalised together so that the smallest one starts at column 0, and the
measurement is :math:`(K, H_v, W_m)` with :math:`W_m = W_v + \lceil\max\varphi\rceil -
\lfloor\min\varphi\rfloor`.  ``row_norms_sq`` gives the diagonal of :math:`HH^\top` in closed
form (GAP-TV divides by it).

The loops run over row strips, bands and views only (never pixels), in float32 with
preallocated buffers; the comments above ``CassiOperator._forward`` explain their arrangement.
Views whose map is a permutation run, in float32, in the fused kernels of
:mod:`recon.kernels.cassi`, against which this NumPy code is the tested reference.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from recon import kernels
from recon.errors import InputError
from recon.operators.base import LinearOperator, weighted_base
from recon.operators.dispersion import (
    as_offsets, shift_row_norms, snap, span, split, work_dtype,
)
from recon.operators.mask import InPrecision, as_mask
from recon.operators.warp import Flip, Identity, Warp, as_warp, cube_shape_of

#: Ideal geometric map of each kaleidoscope view id (centre, left, right, top, bottom, corners):
#: the flip axes of the mirror image seen in that view.
KALEIDOSCOPE_FLIPS: tuple[tuple[int, ...], ...] = (
    (), (1,), (1,), (0,), (0,), (0, 1), (0, 1), (0, 1), (0, 1),
)
#: Rows per strip in the hot loops (a strip of every view's buffers fits in L2 cache).
STRIP_ROWS = 32
VIEW_NAMES = ("centre", "left", "right", "top", "bottom",
              "top-left", "top-right", "bottom-left", "bottom-right")


@dataclass
class View:
    r"""One view of the instrument.

    Parameters
    ----------
    mask : (Hv, Wv) array_like
        The view's coded-aperture transmission :math:`M_k` in view coordinates (float32,
        values in [0, 1] for a physical mask).
    offsets : (L,) array_like of float
        Dispersion shift :math:`\varphi_k(\lambda_l)` of every band in pixels; + is towards
        larger x; integer or sub-pixel, any sign.
    warp : Warp or None
        :math:`W_k`, centre image → view image; ``None`` is the identity.
    """

    mask: np.ndarray
    offsets: np.ndarray
    warp: Warp | None = None

    def __post_init__(self):
        self.mask = as_mask(self.mask)
        self.offsets = as_offsets(self.offsets)
        self.warp = as_warp(self.warp)


class CassiOperator(LinearOperator):
    r"""Multi-view CASSI :math:`H = [H_1; \dots; H_K]`, ``(L, H, W) -> (K, Hv, Wm)``.

    Parameters
    ----------
    views : sequence of View
        All with the same mask shape (Hv, Wv) and the same number of bands L.
    cube_shape : (L, H, W), optional
        The band-major scene shape (``ishape``).  Defaults to ``(L, Hv, Wv)``, or to the input
        shape of the first view whose warp has one.

    Attributes
    ----------
    views : list of View
        With warps bound to concrete shapes.
    offsets : (K, L) float64
        The normalised shifts (smallest floor at column 0).
    n_views, n_bands : int
    """

    def __init__(self, views: Sequence[View], cube_shape=None):
        if isinstance(views, View):
            views = [views]
        views = list(views)
        if not views:
            raise InputError("CassiOperator needs at least one view")
        for i, v in enumerate(views):
            if not isinstance(v, View):
                raise InputError(f"views[{i}] must be a View, got {type(v).__name__}")
        vshape = views[0].mask.shape
        n_bands = views[0].offsets.size
        for i, v in enumerate(views):
            if v.mask.shape != vshape:
                raise InputError(f"view {i} mask shape {v.mask.shape} != view 0 mask shape {vshape}")
            if v.offsets.size != n_bands:
                raise InputError(f"view {i} has {v.offsets.size} offsets, view 0 has {n_bands}")
        cube_shape = cube_shape_of(cube_shape, n_bands, [v.warp for v in views], vshape)
        hw = cube_shape[1:]
        self.views = [View(v.mask, v.offsets, v.warp.bind(hw, vshape)) for v in views]
        table = np.stack([v.offsets for v in self.views])
        lo, extra = span(table)
        self.offsets = table - lo
        self._parts = [[split(p) for p in row] for row in self.offsets]
        self.n_views = len(self.views)
        self.n_bands = n_bands
        self._plan = [_view_plan(v, row, extra) for v, row in zip(self.views, self.offsets)]
        self._masks = InPrecision([p.mask for p in self._plan])
        self._kernel_plan = _KernelPlan(self._plan)
        self._row_norms = None
        super().__init__(cube_shape, (self.n_views, vshape[0], vshape[1] + extra))

    # -- operator --------------------------------------------------------------------------
    # In float32 with Numba, the permutation views (identity or flips) run in one fused
    # kernel (recon.kernels.cassi: a pass over the cube, rows in parallel); the NumPy code
    # below is its reference and the path for float64 and resampling warps.
    # How the NumPy loops are arranged (all exact; only the order of operations changes):
    # * Flat rows: a view image is written into the left Wv columns of a zero-padded (rows, Wm)
    #   buffer, so a shift by a columns is a 1-D offset of a in the flattened measurement (the
    #   zero padding keeps rows apart because a + 1 + Wv <= Wm).  Contiguous 1-D adds are
    #   several times faster than the same adds on 2-D column slices.
    # * Flipped views are computed unflipped and flipped once per view (see _view_plan).
    # * Permutation views run in strips of STRIP_ROWS rows, bands outside views inside, so a
    #   strip of one band, of every view's measurement and of every mask stays in L2 cache.
    # * Views with a resampling warp run afterwards, one at a time (one warped cube in memory).
    def _forward(self, x):
        dt = work_dtype(x)
        x = x.astype(dt, copy=False)
        kp = self._kernel_plan
        if kp.views.size and kernels.usable(x):
            from recon.kernels import cassi as kcassi

            # The kernel overwrites the permutation views' rows; only warped views add.
            out = (np.empty if kp.views.size == self.n_views else np.zeros)(self.oshape, dt)
            with kernels.threads():
                kcassi.forward(np.ascontiguousarray(x), *kp.arrays(dt), out)
        else:
            out = np.zeros(self.oshape, dtype=dt)
            self._forward_permutations(x, out)
        self._forward_warped(x, out)
        return out

    def _forward_permutations(self, x, out):
        """The NumPy reference of :func:`recon.kernels.cassi.forward`: adds the permutation
        views' measurements into ``out`` (zeros)."""
        dt = out.dtype
        hv, wv = self.views[0].mask.shape
        wm = self.oshape[2]
        masks = self._masks(dt)
        perm = [k for k, p in enumerate(self._plan) if p.warp is None]
        # Where each view accumulates: its measurement, or a scratch image when it is flipped.
        n_flip = sum(1 for k in perm if self._plan[k].flip)
        flipped = np.zeros((n_flip, hv, wm), dtype=dt)
        acc, j = {}, 0
        for k in perm:
            if self._plan[k].flip:
                acc[k], j = flipped[j], j + 1
            else:
                acc[k] = out[k]
        # Sub-pixel shifts: sum_l [(1-t) T_a + t T_{a+1}] b_l = P - Q + T_1 Q with
        # P = sum_l T_a b_l and Q = sum_l t T_a b_l: three 1-D passes per band.
        sub = [k for k in perm if self._plan[k].subpixel]
        q = np.zeros((len(sub), hv, wm), dtype=dt)
        qk = dict(zip(sub, q))
        pad = np.zeros((STRIP_ROWS, wm), dtype=dt)
        for r0 in range(0, hv if perm else 0, STRIP_ROWS):
            r1 = min(hv, r0 + STRIP_ROWS)
            n = (r1 - r0 - 1) * wm + wv
            body, flat = pad[:r1 - r0, :wv], pad.reshape(-1)[:n]
            gs = [acc[k][r0:r1].reshape(-1) for k in perm]
            qs = [qk[k][r0:r1].reshape(-1) if k in qk else None for k in perm]
            ms = [masks[k][r0:r1] for k in perm]
            for l in range(self.n_bands):
                xs = x[l, r0:r1]
                for i, k in enumerate(perm):
                    a, t = self._plan[k].parts[l]
                    np.multiply(xs, ms[i], out=body)
                    seg = gs[i][a:a + n]
                    np.add(seg, flat, out=seg)
                    if t != 0.0:
                        flat *= t
                        seg = qs[i][a:a + n]
                        np.add(seg, flat, out=seg)
        for k in perm:
            g = acc[k].reshape(-1)
            if k in qk:
                qf = qk[k].reshape(-1)
                g -= qf
                np.add(g[1:], qf[:-1], out=g[1:])
            if self._plan[k].flip:
                np.copyto(out[k], acc[k][self._plan[k].flip])

    def _forward_warped(self, x, out):
        """Adds the measurements of the views with a resampling warp into ``out``."""
        if all(p.warp is None for p in self._plan):
            return
        dt = out.dtype
        hv, wv = self.views[0].mask.shape
        wm = self.oshape[2]
        masks = self._masks(dt)
        n = (hv - 1) * wm + wv
        pad = np.zeros((hv, wm), dtype=dt)
        body, flat = pad[:, :wv], pad.reshape(-1)[:n]
        qf = np.zeros(hv * wm, dtype=dt)
        for k, plan in enumerate(self._plan):
            if plan.warp is None:
                continue
            xv = plan.warp.apply(x)
            g = out[k].reshape(-1)
            qf.fill(0)
            for l, (a, t) in enumerate(plan.parts):
                np.multiply(xv[l], masks[k], out=body)
                seg = g[a:a + n]
                np.add(seg, flat, out=seg)
                if t != 0.0:
                    flat *= t
                    seg = qf[a:a + n]
                    np.add(seg, flat, out=seg)
            if plan.subpixel:
                g -= qf
                np.add(g[1:], qf[:-1], out=g[1:])
        return out

    def _adjoint(self, y):
        dt = work_dtype(y)
        y = np.ascontiguousarray(y, dtype=dt)
        kp = self._kernel_plan
        if kp.views.size and kernels.usable(y):
            from recon.kernels import cassi as kcassi

            out = np.empty(self.ishape, dtype=dt)
            with kernels.threads():
                kcassi.adjoint(y, *kp.arrays(dt), False, out, dt(1), out)
        else:
            out = self._adjoint_permutations(y)
        self._adjoint_warped(y, out)
        return out

    def adjoint_add(self, y, base, scale=1.0, out=None, base_weights=None):
        r""":math:`b + s H^\top y` in one pass over the cube when every view is a permutation
        (see :meth:`LinearOperator.adjoint_add <recon.operators.base.LinearOperator.adjoint_add>`;
        ``base_weights`` make the weighted base first).
        """
        kp = self._kernel_plan
        base = weighted_base(np.asarray(base), base_weights)
        dt = base.dtype
        if not (kp.views.size == self.n_views and kernels.usable(base)
                and base.shape == self.ishape and base.flags.c_contiguous
                and (out is None or (out.dtype == dt and out.flags.c_contiguous))):
            return super().adjoint_add(y, base, scale, out)
        y = np.asarray(y)
        if y.shape != self.oshape:
            raise ValueError(f"{type(self).__name__}: input shape {y.shape} != {self.oshape}")
        from recon.kernels import cassi as kcassi

        out = np.empty(self.ishape, dtype=dt) if out is None else out
        with kernels.threads():
            kcassi.adjoint(np.ascontiguousarray(y, dtype=dt), *kp.arrays(dt), True, base,
                           dt.type(scale), out)
        return out

    def adjoint_gather(self, y, scale=1.0, dtype=np.float32, max_bytes=None):
        r""":math:`s H^\top y` as the per-row gather that a fused kernel adds to a cube as it
        goes (:func:`recon.kernels.tv.chambolle`), or None.

        Returns ``(z, masks, a, c0, c1, sub)``: the plan arrays of :mod:`recon.kernels.cassi`
        (masks, integer offsets, tap weights, sub-pixel flags) and ``z``, shape
        ``(K, Hv, Wm + 1)``, :math:`s\,y` in plan coordinates (each view's measurement flipped
        as its plan, one zero column appended), such that

        .. math::

            \bigl(s H^\top y\bigr)_{l,i,x} = \sum_k M_{k,i,x}\bigl(c^0_{k,l}\,
            z_{k,i,x+a_{k,l}} + c^1_{k,l}\, z_{k,i,x+a_{k,l}+1}\bigr).

        None when a view has a resampling warp, when the kernels do not run for ``dtype``
        (float64, or switched off), or when ``masks`` and ``z`` together would take more
        than ``max_bytes``: callers then use :meth:`adjoint_add`.  The flips are made here
        once per call, on the measurement, so that the kernel can run bands in parallel and
        still gather each row contiguously.
        """
        kp = self._kernel_plan
        dt = np.dtype(dtype)
        if kp.views.size != self.n_views or not kernels.usable(np.empty(0, dt)):
            return None
        n_views, hv, wm = self.oshape
        size = n_views * hv * (self.views[0].mask.shape[1] + wm + 1) * dt.itemsize
        if max_bytes is not None and size > max_bytes:
            return None
        y = np.asarray(y)
        if y.shape != self.oshape:
            raise ValueError(f"{type(self).__name__}: input shape {y.shape} != {self.oshape}")
        masks, a, c0, c1, sub, rowflip, colflip, vid = kp.arrays(dt)
        z = np.empty((vid.size, hv, wm + 1), dtype=dt)
        for k, view in enumerate(vid):
            src = y[view]
            if rowflip[k]:
                src = src[::-1]
            if colflip[k]:
                src = src[:, ::-1]
            np.multiply(src, dt.type(scale), out=z[k, :, :wm])
        z[:, :, wm] = 0
        return z, masks, a, c0, c1, sub

    def _adjoint_permutations(self, y):
        """The NumPy reference of :func:`recon.kernels.cassi.adjoint`: the permutation
        views' part of the adjoint (zeros without such views)."""
        dt = y.dtype
        hv, wv = self.views[0].mask.shape
        wm = self.oshape[2]
        masks = self._masks(dt)
        perm = [k for k, p in enumerate(self._plan) if p.warp is None]
        # The first permutation view covers every pixel, so it assigns instead of adding.
        out = np.empty(self.ishape, dtype=dt) if perm else np.zeros(self.ishape, dtype=dt)
        # Per view: the measurement (flipped once if the view is) and, for sub-pixel shifts,
        # its forward difference, so that z[i] = (1-t) y[a+i] + t y[a+1+i] = y[a+i] + t dy[a+i].
        ys, dys = {}, {}
        for k in perm:
            plan = self._plan[k]
            ys[k] = np.ascontiguousarray(y[k][plan.flip]) if plan.flip else y[k]
            if plan.subpixel:
                d = np.zeros((hv, wm), dtype=dt)
                yf = ys[k].reshape(-1)
                np.subtract(yf[1:], yf[:-1], out=d.reshape(-1)[:-1])
                dys[k] = d
        zbuf = np.zeros(STRIP_ROWS * wm, dtype=dt)
        scratch = np.empty(STRIP_ROWS * wm, dtype=dt)
        band = np.empty((STRIP_ROWS, wv), dtype=dt)
        for r0 in range(0, hv if perm else 0, STRIP_ROWS):
            r1 = min(hv, r0 + STRIP_ROWS)
            nr = r1 - r0
            n = (nr - 1) * wm + wv
            zn, sc, b = zbuf[:n], scratch[:n], band[:nr]
            z = zbuf[:nr * wm].reshape(nr, wm)[:, :wv]
            yk = [ys[k][r0:r1].reshape(-1) for k in perm]
            dk = [dys[k][r0:r1].reshape(-1) if k in dys else None for k in perm]
            ms = [masks[k][r0:r1] for k in perm]
            for l in range(self.n_bands):
                o = out[l, r0:r1]
                for i, k in enumerate(perm):
                    a, t = self._plan[k].parts[l]
                    if t == 0.0:
                        np.copyto(zn, yk[i][a:a + n])
                    else:
                        np.multiply(dk[i][a:a + n], t, out=sc)
                        np.add(sc, yk[i][a:a + n], out=zn)
                    if i == 0:
                        np.multiply(z, ms[i], out=o)
                    else:
                        np.multiply(z, ms[i], out=b)
                        np.add(o, b, out=o)
        return out

    def _adjoint_warped(self, y, out):
        """Adds the adjoint of the views with a resampling warp into ``out``."""
        if all(p.warp is None for p in self._plan):
            return out
        dt = out.dtype
        hv, wv = self.views[0].mask.shape
        wm = self.oshape[2]
        masks = self._masks(dt)
        n = (hv - 1) * wm + wv
        zflat = np.zeros(hv * wm, dtype=dt)
        z, zn = zflat.reshape(hv, wm)[:, :wv], zflat[:n]
        dy = np.empty(hv * wm - 1, dtype=dt)
        scratch = np.empty(n, dtype=dt)
        for k, plan in enumerate(self._plan):
            if plan.warp is None:
                continue
            yk = y[k].reshape(-1)
            if plan.subpixel:
                np.subtract(yk[1:], yk[:-1], out=dy)
            tmp = np.empty((self.n_bands, hv, wv), dtype=dt)
            for l, (a, t) in enumerate(plan.parts):
                if t == 0.0:
                    np.copyto(zn, yk[a:a + n])
                else:
                    np.multiply(dy[a:a + n], t, out=scratch)
                    np.add(scratch, yk[a:a + n], out=zn)
                np.multiply(z, masks[k], out=tmp[l])
            out += plan.warp.apply_adjoint(tmp)
        return out

    def row_norms_sq(self) -> np.ndarray:
        r"""Diagonal of :math:`HH^\top`, shape ``oshape`` (float64), in closed form.

        Row :math:`(k, y, x)` collects, for each band, one interpolated row of
        :math:`\mathrm{diag}(M_k) W_k`; distinct bands touch distinct unknowns, so the squared
        norms add up over bands (see :func:`~recon.operators.dispersion.shift_row_norms`).
        """
        if self._row_norms is None:
            out = np.zeros(self.oshape, dtype=np.float64)
            for k, view in enumerate(self.views):
                m = view.mask.astype(np.float64)
                n, c = view.warp.norm_parts()
                nn = m * m * n
                cc = None if c is None else m[:, :-1] * m[:, 1:] * c
                for a, t in self._parts[k]:
                    shift_row_norms(nn, cc, a, t, out[k])
            self._row_norms = out
        return self._row_norms.copy()

    def __repr__(self):
        return (f"<CassiOperator {self.n_views} view(s), {self.n_bands} bands: "
                f"{self.ishape} -> {self.oshape}>")


@dataclass
class _Plan:
    """How the hot loops run one view: with ``warp`` None the view is computed as
    ``flip(sum_l T_parts(mask * f_l))`` (``flip`` an index into the measurement, ``()`` for
    none), else as ``sum_l T_parts(mask * warp(f)_l)``."""

    mask: np.ndarray
    parts: list
    subpixel: bool
    flip: tuple
    warp: Warp | None


class _KernelPlan:
    """The permutation views of a plan as the arrays :mod:`recon.kernels.cassi` takes.

    ``views`` holds the indices of the views without a resampling warp; ``arrays(dtype)``
    returns ``(masks, a, c0, c1, sub, rowflip, colflip, views)`` with masks and weights in
    ``dtype`` (made on first use per precision, then kept).
    """

    def __init__(self, plan: list[_Plan]):
        ids = [k for k, p in enumerate(plan) if p.warp is None]
        self.views = np.array(ids, dtype=np.int64)
        self._plan = [plan[k] for k in ids]
        self._cache: dict = {}

    def arrays(self, dtype):
        dtype = np.dtype(dtype)
        if dtype not in self._cache:
            plans = self._plan
            parts = np.array([[p for p in pl.parts] for pl in plans], dtype=np.float64)
            a = np.ascontiguousarray(parts[..., 0].astype(np.int64))
            t = parts[..., 1]
            self._cache[dtype] = (
                np.ascontiguousarray(np.stack([pl.mask for pl in plans]), dtype=dtype),
                a, (1.0 - t).astype(dtype), t.astype(dtype), t != 0.0,
                np.array([bool(pl.flip) and pl.flip[0] != slice(None) for pl in plans]),
                np.array([bool(pl.flip) and pl.flip[1] != slice(None) for pl in plans]),
                self.views)
        return self._cache[dtype]


def _view_plan(view: View, offsets: np.ndarray, extra: int) -> _Plan:
    r"""Rewrite a flipped view so that the per-band work reads and writes contiguously.

    With :math:`F_y`, :math:`F_x` the row and column reversals (of a view image, or of the
    measurement) and :math:`E = W_m - W_v`:

    - :math:`M \odot F f = F(FM \odot f)` for any flip :math:`F`;
    - :math:`T_\varphi F_x v = F_x T_{E-\varphi} v` (a shift of a mirrored image is the mirror
      of the opposite shift; linear interpolation is symmetric), and :math:`T_\varphi` commutes
      with :math:`F_y`.

    So a flipped view is the flip of an unflipped one with the flipped mask and, for column
    flips, offsets :math:`E - \varphi`: one reversal per view instead of strided passes per band.
    This is the dispersion inversion of mirrored views seen from the centre view.
    """
    warp = view.warp
    if isinstance(warp, Identity):
        return _Plan(view.mask, [split(p) for p in offsets], bool(np.any(offsets % 1)), (), None)
    if isinstance(warp, Flip):
        idx = tuple(slice(None, None, -1) if ax in warp.axes else slice(None) for ax in (0, 1))
        phi = snap(extra - offsets) if 1 in warp.axes else offsets
        return _Plan(np.ascontiguousarray(view.mask[idx]), [split(p) for p in phi],
                     bool(np.any(phi % 1)), idx, None)
    return _Plan(view.mask, [split(p) for p in offsets], bool(np.any(offsets % 1)), (), warp)


def standard_cassi(mask, step, n_bands: int) -> CassiOperator:
    r"""The standard single-view CASSI (MST / TSA-Net convention) as a one-view CassiOperator.

    Band :math:`l` (0-based) is shifted right by :math:`\mathrm{step}\cdot l` pixels:

    .. math:: g[y, x] = \sum_l M[y, x - s l]\, f_l[y, x - s l],

    so ``ishape = (L, H, W)`` and ``oshape = (1, H, W + step·(L−1))``.

    Parameters
    ----------
    mask : (H, W) array_like
    step : float
        Pixels per band (2 for the 28-band benchmark); sub-pixel or negative allowed.
    n_bands : int
    """
    n = _n_bands(n_bands)
    try:
        s = float(step)
    except (TypeError, ValueError):
        raise InputError(f"step must be a number, got {step!r}") from None
    if not np.isfinite(s):
        raise InputError(f"step must be finite, got {step!r}")
    m = as_mask(mask)
    return CassiOperator([View(m, s * np.arange(n, dtype=np.float64))], (n,) + m.shape)


def kaleidoscope_cassi(masks, offsets, n_views: int, inversion: bool = True,
                       warps=None, cube_shape=None) -> CassiOperator:
    r"""The paper's kaleidoscopic CASSI with ``n_views`` of the 3×3 views.

    Views are taken in the order centre, left, right, top, bottom, top-left, top-right,
    bottom-left, bottom-right (ids 0..8).  The sensor disperses every view the same way
    (``offsets``); a mirror view sees the scene flipped, :math:`W_k` = ``Flip(1)`` for
    left/right, ``Flip(0)`` for top/bottom, ``Flip((0, 1))`` for corners.  Expressed in centre
    coordinates a horizontal flip reverses the dispersion, so left/right (and corner) views
    disperse the other way after registration: the paper's *dispersion inversion* (Fig. 3b, 8d).

    Parameters
    ----------
    masks : (K, Hv, Wv) or (Hv, Wv) array_like
        Per-view masks in view coordinates, K >= n_views (the first n_views are used), or one
        mask shared by all views.
    offsets : (L,) or (K, L) array_like
        Dispersion shifts on the sensor in pixels, one row shared by all views or one per view.
    n_views : int
        1..9.
    inversion : bool
        ``False`` drops the flips (every :math:`W_k` is the identity): the same views and masks
        without dispersion inversion (Fig. 8c).
    warps : sequence of (Warp or None), optional
        Calibrated maps for the first n_views views, replacing the ideal ones (a ``None``
        entry keeps the ideal map of that view).
    cube_shape : (L, H, W), optional
        Passed to :class:`CassiOperator` (needed when calibrated warps change the size).
    """
    try:
        k = int(n_views)
    except (TypeError, ValueError):
        raise InputError(f"n_views must be an integer, got {n_views!r}") from None
    if not 1 <= k <= 9 or k != n_views:
        raise InputError(f"n_views must be an integer in 1..9, got {n_views!r}")
    m = np.asarray(masks)
    if m.ndim == 2:
        mlist = [as_mask(m)] * k
    elif m.ndim == 3:
        if m.shape[0] < k:
            raise InputError(f"masks has {m.shape[0]} views, need at least n_views={k}")
        mlist = [as_mask(m[i], name=f"masks[{i}]") for i in range(k)]
    else:
        raise InputError(f"masks must be (K, Hv, Wv) or (Hv, Wv), got shape {m.shape}")
    try:
        phi = np.asarray(offsets, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError("offsets must be numbers") from None
    if phi.ndim == 1:
        rows = [phi] * k
    elif phi.ndim == 2:
        if phi.shape[0] < k:
            raise InputError(f"offsets has {phi.shape[0]} rows, need at least n_views={k}")
        rows = [phi[i] for i in range(k)]
    else:
        raise InputError(f"offsets must be (L,) or (K, L), got shape {phi.shape}")
    if warps is not None:
        warps = list(warps)
        if len(warps) < k:
            raise InputError(f"warps has {len(warps)} entries, need at least n_views={k}")
    views = []
    for i in range(k):
        w = warps[i] if warps is not None else None
        if w is None:
            axes = KALEIDOSCOPE_FLIPS[i] if inversion else ()
            w = Flip(axes) if axes else Identity()
        views.append(View(mlist[i], as_offsets(rows[i], name=f"offsets of view {i}"), w))
    return CassiOperator(views, cube_shape)


def _n_bands(n_bands) -> int:
    try:
        n = int(n_bands)
    except (TypeError, ValueError):
        raise InputError(f"n_bands must be an integer, got {n_bands!r}") from None
    if n < 1 or n != n_bands:
        raise InputError(f"n_bands must be a positive integer, got {n_bands!r}")
    return n
