r"""Calibrated CASSI: measured per-band mask images on the sensor instead of mask + shift.

Standard CASSI calibration captures, band by band, the image of the coded aperture on the
sensor under uniform monochromatic light (the "shifted masks" :math:`C_{k,l}`, already
deconvolved for diffraction).  The forward model becomes

.. math::

    g_k = \sum_l C_{k,l} \odot S_{k,l}\big(W_k f_l\big), \qquad
    f_l = \sum_k W_k^\top S_{k,l}^\top\big(C_{k,l} \odot g_k\big),

where :math:`S_{k,l}` places the view image (width :math:`W_v`) at its measured dispersion
offset :math:`\varphi_{k,l}` on the sensor crop (linear interpolation for sub-pixel offsets).
Unlike :class:`~recon.operators.cassi.CassiOperator`, the offsets here are *absolute* column
positions on the crop of width :math:`W_m` the mask images were cut to, not normalised.  A
band's image may reach past either edge of the crop (a view image started before its offsets
where the view's light begins, :mod:`recon.calibration.extent`): the columns that land outside
are not measured, so :math:`S_{k,l}` keeps only the rows of the crop.

A per-band scale :math:`s_l` (``band_scale``, e.g. the inverse radiometric gains) multiplies
:math:`C_{k,l}`; it is folded into the interpolation weights, so the mask images are never
copied to apply it.

In float32 with Numba, every view runs in the fused kernels of :mod:`recon.kernels.calibrated`
(warp, mask image and shift of all bands in one pass per row, the warp gathering from the cube
laid out pixel-major once for all views; the adjoint as a gather along the rows of
:math:`W_k^\top`); the NumPy code here is their tested reference and the path for
float64.
"""

from __future__ import annotations

import numpy as np

from recon import kernels
from recon.errors import InputError
from recon.operators.base import LinearOperator, weighted_base
from recon.operators.dispersion import as_offsets, shift_row_norms, split, work_dtype
from recon.operators.mask import InPrecision, as_mask
from recon.operators.warp import as_warps, cube_shape_of


class CalibratedCassi(LinearOperator):
    r"""Multi-view CASSI from measured per-band sensor masks, ``(L, H, W) -> (K, Hv, Wm)``.

    Parameters
    ----------
    mask_images : (K, L, Hv, Wm) or (L, Hv, Wm) array_like
        :math:`C_{k,l}` on the sensor (a 3-D array is one view).
    offsets : (L,) or (K, L) array_like of float
        Absolute column where column 0 of the view image lands for each band (+ = larger x);
        one row shared by all views or one per view.  Every band's image must overlap the
        crop, :math:`-W_v < \varphi < W_m`; columns outside :math:`[0, W_m)` are dropped.
    warps : sequence of (Warp or None), optional
        :math:`W_k` per view (``None`` = identity).
    cube_shape : (L, H, W), optional
        Band-major scene shape; defaults to the input shape of the first warp that has one,
        else :math:`(L, H_v, W_m - \lceil\max\varphi\rceil)`.
    band_scale : (L,) array_like, optional
        :math:`s_l`, multiplies band ``l`` of the model (default 1): the operator is that of
        the mask images :math:`s_l C_{k,l}`, without a scaled copy of them.

    Attributes
    ----------
    mask_images : (K, L, Hv, Wm) float32
        :math:`C_{k,l}` as given (not scaled; a float32 C-contiguous input is kept, not copied).
    band_scale : (L,) float64
    offsets : (K, L) float64
    n_views, n_bands : int

    Notes
    -----
    With the float32 kernels the forward and the adjoint each take every view in one pass
    over the cube (:func:`~recon.kernels.calibrated.forward_views`,
    :func:`~recon.kernels.calibrated.adjoint_views`); they read the views' warps from arrays
    joined for all views, which the warps then hold in place of their own
    (:meth:`~recon.operators.warp.Warp.share_csr`).  Where a warp reaches too far for them,
    the view-by-view kernels run instead; their forward keeps the pixel-major copy of the
    cube that its gathers read (one cube's memory) from one call to the next.
    """

    def __init__(self, mask_images, offsets, warps=None, cube_shape=None, band_scale=None):
        c = np.asarray(mask_images)
        if c.ndim == 3:
            c = c[None]
        self.mask_images = as_mask(c, name="mask_images", ndim=4)
        k, n_bands, hv, wm = self.mask_images.shape
        phi = np.asarray(offsets, dtype=np.float64) if not isinstance(offsets, np.ndarray) \
            else offsets.astype(np.float64)
        if phi.ndim == 1:
            table = np.stack([as_offsets(phi, n_bands)] * k)
        elif phi.ndim == 2 and phi.shape[0] == k:
            table = np.stack([as_offsets(r, n_bands, name=f"offsets of view {i}")
                              for i, r in enumerate(phi)])
        else:
            raise InputError(f"offsets must be (L,) or (K={k}, L), got shape {phi.shape}")
        warps = as_warps(warps, k, "mask_images")
        cs = cube_shape_of(cube_shape, n_bands, warps, (hv, wm - int(np.ceil(np.max(table)))))
        bound = []
        for i, w in enumerate(warps):
            out_shape = w.out_shape if w.out_shape is not None else cs[1:]
            if out_shape[0] != hv:
                raise InputError(f"view {i}: warped image height {out_shape[0]} != mask image "
                                 f"height {hv}")
            bound.append(w.bind(cs[1:], out_shape))
        self.warps = bound
        self.offsets = table
        self._parts = [[split(p) for p in row] for row in table]
        for i, (w, row) in enumerate(zip(bound, self._parts)):
            wv = w.out_shape[1]
            for l, (a, t) in enumerate(row):
                if a + wv + (t > 0) <= 0 or a >= wm:
                    raise InputError(f"view {i} band {l}: at offset {table[i, l]:g} the view image"
                                     f" ({wv} columns) misses the mask image (width {wm})")
        self.n_views, self.n_bands = k, n_bands
        # Columns of zeros on either side of the crop that hold every band's whole image: the
        # NumPy path works on crops padded by them and cuts the measured columns out after.
        self._pad = (max([0] + [-a for row in self._parts for a, _ in row]),
                     max([0] + [a + w.out_shape[1] + (t > 0) - wm
                                for w, row in zip(bound, self._parts) for a, t in row]))
        scale = np.ones(n_bands) if band_scale is None else np.asarray(band_scale, np.float64)
        if scale.shape != (n_bands,) or not np.all(np.isfinite(scale)):
            raise InputError(f"band_scale must be {n_bands} finite numbers, got shape "
                             f"{scale.shape}")
        self.band_scale = scale
        # The two taps of every view and band, the scale folded in: (1-t) s and t s.
        t = np.array([[p[1] for p in row] for row in self._parts])
        self._taps = ((1.0 - t) * scale, t * scale)
        self._cmasks = InPrecision(self.mask_images)
        self._kernel_views = None
        self._plan = None
        self._forward_plan_ = None
        self._row_norms = None
        super().__init__(cs, (k, hv, wm))

    # -- operator --------------------------------------------------------------------------
    def _forward(self, x):
        dt = work_dtype(x)
        x = x.astype(dt, copy=False)
        if kernels.usable(x):
            return self._forward_kernel(np.ascontiguousarray(x))
        cm = self._cmasks(dt)
        w0, w1 = self._taps
        lo, hi = self._pad
        k_, hv, wm = self.oshape
        out = np.zeros((k_, hv, lo + wm + hi), dtype=dt)
        for k, warp in enumerate(self.warps):
            xv = warp.apply(x)
            wv = warp.out_shape[1]
            buf = np.empty(warp.out_shape, dtype=dt)
            for l, (a, t) in enumerate(self._parts[k]):
                c = self._padded(cm[k, l])
                a += lo
                d0 = out[k, :, a:a + wv]
                np.multiply(xv[l], c[:, a:a + wv], out=buf)
                if w0[k, l] != 1.0:
                    buf *= w0[k, l]
                np.add(d0, buf, out=d0)
                if t == 0.0:
                    continue
                d1 = out[k, :, a + 1:a + 1 + wv]
                np.multiply(xv[l], c[:, a + 1:a + 1 + wv], out=buf)
                buf *= w1[k, l]
                np.add(d1, buf, out=d1)
        return out if lo == hi == 0 else np.ascontiguousarray(out[:, :, lo:lo + wm])

    def _padded(self, a):
        """``a`` (..., Wm) with the zero columns of ``self._pad`` on either side (no copy when
        there are none)."""
        lo, hi = self._pad
        if lo == hi == 0:
            return a
        return np.pad(a, [(0, 0)] * (a.ndim - 1) + [(lo, hi)])

    def _adjoint(self, y):
        dt = work_dtype(y)
        y = y.astype(dt, copy=False)
        if kernels.usable(y):
            out = np.empty(self.ishape, dtype=dt)
            return self._adjoint_kernel(np.ascontiguousarray(y), None, 1.0, out)
        cm = self._cmasks(dt)
        w0, w1 = self._taps
        lo = self._pad[0]
        y = self._padded(y)
        out = np.zeros(self.ishape, dtype=dt)
        for k, warp in enumerate(self.warps):
            wv = warp.out_shape[1]
            acc = warp.accumulate_view(out)
            tmp = np.empty((self.n_bands,) + warp.out_shape, dtype=dt)
            buf = np.empty(warp.out_shape, dtype=dt)
            for l, (a, t) in enumerate(self._parts[k]):
                c = self._padded(cm[k, l])
                a += lo
                z = tmp[l]
                np.multiply(y[k, :, a:a + wv], c[:, a:a + wv], out=z)
                if w0[k, l] != 1.0:
                    z *= w0[k, l]
                if t != 0.0:
                    np.multiply(y[k, :, a + 1:a + 1 + wv], c[:, a + 1:a + 1 + wv], out=buf)
                    buf *= w1[k, l]
                    z += buf
            if acc is not None:
                acc += tmp
            else:
                out += warp.apply_adjoint(tmp)
        return out

    def adjoint_add(self, y, base, scale=1.0, out=None, base_weights=None):
        r""":math:`b + s H^\top y` (or :math:`q \odot b + s H^\top y`) with the adjoint added
        as it is computed (float32 kernels; see :meth:`LinearOperator.adjoint_add
        <recon.operators.base.LinearOperator.adjoint_add>`): in the one-pass kernel the
        weights are applied as each row of the result is written, view by view they make the
        weighted base first.
        """
        base = np.asarray(base)
        dt = base.dtype
        if not (kernels.usable(base) and base.shape == self.ishape
                and base.flags.c_contiguous
                and (out is None or (out.dtype == dt and out.flags.c_contiguous
                                     and out.shape == self.ishape))):
            return super().adjoint_add(y, base, scale, out, base_weights=base_weights)
        y = np.asarray(y)
        if y.shape != self.oshape:
            raise ValueError(f"{type(self).__name__}: input shape {y.shape} != {self.oshape}")
        weights = None
        if base_weights is not None:
            if self._fused_plan():
                weights = np.asarray(base_weights, dtype=dt).reshape(-1)
                if weights.shape != (self.n_bands,):
                    raise ValueError(f"base_weights: one weight per band ({self.n_bands}), "
                                     f"got shape {np.shape(base_weights)}")
            else:
                base = weighted_base(base, base_weights)
        target = out
        # View by view, views after the first add to the output, so the output cannot be the
        # base then (the one-pass kernel reads each row of the base before writing it).
        if out is None or (self.n_views > 1 and np.may_share_memory(out, base)
                           and not self._fused_plan()):
            target = np.empty(self.ishape, dtype=dt)
        self._adjoint_kernel(np.ascontiguousarray(y, dtype=dt), base, scale, target, weights)
        if out is not None and target is not out:
            np.copyto(out, target)
            return out
        return target

    def band_forward(self, band: int, image) -> np.ndarray:
        r""":math:`H f` for the cube :math:`f` that is ``image`` in band ``band`` and zero in
        every other band: one band's part of the sum (e.g. a flat field's model, band by band).

        In float32 with the kernels only that band is warped, masked and shifted (the other
        bands add exact zeros to the sum, so the result is :meth:`forward`'s to the bit);
        otherwise :meth:`forward` of the zero-padded cube, the reference.

        Parameters
        ----------
        band : int
        image : (H, W) array_like

        Returns
        -------
        (K, Hv, Wm) ndarray
        """
        n_bands, h, w = self.ishape
        if isinstance(band, bool) or int(band) != band or not 0 <= int(band) < n_bands:
            raise InputError(f"band must be an integer in [0, {n_bands}), got {band!r}")
        band = int(band)
        img = np.asarray(image)
        if img.shape != (h, w):
            raise InputError(f"a band image must be {(h, w)}, got {img.shape}")
        img = img.astype(work_dtype(img), copy=False)
        if not kernels.usable(img):
            x = np.zeros(self.ishape, dtype=img.dtype)
            x[band] = img
            return self.forward(x)
        from recon.kernels import calibrated as kcal

        out = np.empty(self.oshape, dtype=np.float32)
        xf = np.ascontiguousarray(img).reshape(1, -1)
        sl = slice(band, band + 1)
        with kernels.threads():
            for k, (ident, fwd, _, a, c0, c1, sub) in enumerate(self._kernel_arrays()):
                ip, ix, dv = fwd if fwd is not None else _NO_CSR
                # One band: the pixel-major cube is the same memory, (N, 1).
                kcal.forward_view(xf, xf.reshape(-1, 1), self.mask_images[k, sl], a[sl],
                                  c0[sl], c1[sl], sub[sl], ident, ip, ix, dv,
                                  self.warps[k].out_shape[1], out[k])
        return out

    def _kernel_arrays(self):
        """Per view the arrays of :mod:`recon.kernels.calibrated` (float32; made once):
        ``(ident, W, W^T, a, c0, c1, sub)`` with ``W``, ``W^T`` as CSR triples
        ``(indptr, indices, data)`` (``None`` for an identity warp)."""
        if self._kernel_views is None:
            from recon.operators.warp import Identity

            w0, w1 = self._taps
            views = []
            for k, warp in enumerate(self.warps):
                ident = isinstance(warp, Identity)
                fwd = adj = None
                if not ident:
                    fwd, adj = (_csr32(m) for m in warp.sparse_pair())
                a = np.array([p[0] for p in self._parts[k]], dtype=np.int64)
                views.append((ident, fwd, adj, a, w0[k].astype(np.float32),
                              w1[k].astype(np.float32), np.asarray(w1[k] != 0.0)))
            self._kernel_views = views
        return self._kernel_views

    def _forward_kernel(self, x):
        from recon.kernels import calibrated as kcal

        out = np.empty(self.oshape, dtype=np.float32)
        xf = x.reshape(self.n_bands, -1)
        cm = self.mask_images
        plan = self._forward_plan()
        if plan:
            with kernels.threads():
                kcal.forward_views(xf, cm, plan["a"], plan["c0"], plan["c1"], plan["sub"],
                                   plan["ident"], plan["wvs"], plan["indptr"],
                                   plan["indices"], plan["data"], plan["s0"], plan["s1"],
                                   plan["ilo"], plan["ihi"], self.ishape[2], out)
            return out
        views = self._kernel_arrays()
        with kernels.threads():
            # The warped views gather from the pixel-major cube, laid out once for all of
            # them.
            xt = _NO_PIXELS
            if not all(v[0] for v in views):
                # The buffer is kept between calls: a fresh cube-sized array costs its page
                # faults at every call.  Taken out while in use (a dict's pop is atomic), so
                # that a concurrent call makes its own.
                xt = self.__dict__.pop("_pixels", None)
                if xt is None:
                    xt = np.empty(xf.shape[::-1], dtype=np.float32)
                kcal.bands_last(xf, xt)
            for k, (ident, fwd, _, a, c0, c1, sub) in enumerate(views):
                ip, ix, dv = fwd if fwd is not None else _NO_CSR
                kcal.forward_view(xf, xt, cm[k], a, c0, c1, sub, ident, ip, ix, dv,
                                  self.warps[k].out_shape[1], out[k])
            if xt is not _NO_PIXELS:
                self._pixels = xt
        return out

    def _forward_plan(self):
        """The arrays of :func:`recon.kernels.calibrated.forward_views` (made once), or False
        where a view row is not made from one task's cube rows (a warp whose rows reach over
        more than :data:`~recon.kernels.calibrated.FORWARD_MAX_SPAN` cube rows, or whose rows
        do not follow the cube's in order).

        Every view row goes to the task that holds the first cube row its warp reads; the task
        lays out the cube rows from there to the last row any of its view rows reads."""
        if self._forward_plan_ is None:
            from recon.kernels import calibrated as kcal

            views = self._kernel_arrays()
            table = _view_table(views, self.warps)
            wvs = table["wvs"]
            n_bands, h, w = self.ishape
            hv = self.oshape[1]
            first = np.empty((self.n_views, hv), np.int64)
            last = np.empty((self.n_views, hv), np.int64)
            for k, (ident, fwd, *_) in enumerate(views):
                if ident:
                    first[k] = last[k] = np.arange(hv)
                else:
                    first[k], last[k] = _rows_read(*fwd, hv, int(wvs[k]), w)
            reach = int((last - first).max())
            order = np.diff(first, axis=1)
            monotone = all(np.all(d >= 0) or np.all(d <= 0) for d in order)
            if reach > kcal.FORWARD_MAX_SPAN or not monotone:
                self._forward_plan_ = False
                return self._forward_plan_
            rows = kcal.forward_rows(n_bands, h, w, kernels.cores(), reach)
            n_tasks = (h + rows - 1) // rows
            task = first // rows
            ilo = np.zeros((self.n_views, n_tasks), np.int64)
            ihi = np.zeros((self.n_views, n_tasks), np.int64)
            s0 = np.full(n_tasks, h, np.int64)
            s1 = np.zeros(n_tasks, np.int64)
            for k in range(self.n_views):
                # The view rows of a task are consecutive (the rows read follow the view's
                # rows, forwards or backwards).
                ts, starts, counts = np.unique(task[k], return_index=True, return_counts=True)
                ilo[k, ts], ihi[k, ts] = starts, starts + counts
                np.minimum.at(s0, task[k], first[k])
                np.maximum.at(s1, task[k], last[k] + 1)
            s0 = np.minimum(s0, s1)
            self._forward_plan_ = {**table, **_joined_csr(views, 1),
                                   "s0": s0, "s1": s1, "ilo": ilo, "ihi": ihi}
            self._hold_once(1, self._forward_plan_)
        return self._forward_plan_

    def _hold_once(self, which: int, plan: dict) -> None:
        """After a plan joined the views' CSR arrays of :math:`W_k` (``which`` 1) or
        :math:`W_k^\top` (2) into one copy: the views' arrays, here and in their warps
        (:meth:`~recon.operators.warp.Warp.share_csr`), become slices of it, so that the
        operator holds each warp once."""
        views = self._kernel_arrays()
        for k, v in enumerate(views):
            if v[which] is None:
                continue
            ip, ix, dv = v[which]
            b, m = int(plan["indptr"][k, 0]), ix.size
            shared = (ip, plan["indices"][b:b + m], plan["data"][b:b + m])
            views[k] = v[:which] + (shared,) + v[which + 1:]
            self.warps[k].share_csr(**{("forward" if which == 1 else "adjoint"): shared})

    def _fused_plan(self):
        """The arrays of :func:`recon.kernels.calibrated.adjoint_views` (made once), or False
        where a task would need more view rows than its cache-sized scratch holds."""
        if self._plan is None:
            from recon.kernels import calibrated as kcal

            views = self._kernel_arrays()
            n_bands, h, w = self.ishape
            rows = kcal.adjoint_rows(n_bands, h, w, kernels.cores())
            n_tasks = (h + rows - 1) // rows
            first = np.arange(n_tasks) * rows
            last = np.minimum(first + rows, h)
            vlo = np.zeros((self.n_views, n_tasks), np.int64)
            vhi = np.zeros((self.n_views, n_tasks), np.int64)
            for k, (ident, _, adj, a, c0, c1, sub) in enumerate(views):
                wv = self.warps[k].out_shape[1]
                if ident:
                    vlo[k], vhi[k] = first, last
                    continue
                ip, ix, dv = adj
                # The span of view rows each task's entries of W^T read: the tasks' entries
                # are consecutive runs of the CSR arrays, so a reduction from each non-empty
                # task's start to the next one's is over that task's entries exactly.
                vrow = ix.astype(np.int64) // wv
                start, stop = ip[first * w].astype(np.int64), ip[last * w].astype(np.int64)
                some = stop > start
                if some.any():
                    vlo[k, some] = np.minimum.reduceat(vrow, start[some])
                    vhi[k, some] = np.maximum.reduceat(vrow, start[some]) + 1
            zrows = int((vhi - vlo).max()) if vhi.size else 0
            if zrows > kcal.ADJOINT_MAX_ZROWS:
                self._plan = False
                return self._plan
            table = _view_table(views, self.warps)
            a, wvs = table["a"], table["wvs"]
            hi = max(1, int(max((a[k].max() + wvs[k] + 1 - self.oshape[2])
                                for k in range(self.n_views))))
            self._plan = {
                **table, **_joined_csr(views, 2),
                "vlo": vlo, "vhi": vhi, "rows": rows, "zrows": max(zrows, 1),
                "lo": max(0, -int(a.min())), "hi": hi}
            self._hold_once(2, self._plan)
        return self._plan

    def _adjoint_kernel(self, y, base, scale, out, weights=None):
        r"""``out`` :math:`= H^\top y` (``base`` None) or :math:`b + s H^\top y`, or
        :math:`q \odot b + s H^\top y` with ``weights`` :math:`q` (one a band, the one-pass
        kernel only): all views in one pass (:func:`recon.kernels.calibrated.adjoint_views`;
        ``out`` may be ``base``), or, where a warp spreads a cube row over too many view rows,
        view by view (``out`` may then be ``base`` only for one view)."""
        from recon.kernels import calibrated as kcal

        plan = self._fused_plan()
        if plan:
            b = out if base is None else np.ascontiguousarray(base, dtype=np.float32)
            q = (np.ones(0, np.float32) if weights is None
                 else np.ascontiguousarray(weights, dtype=np.float32))
            with kernels.threads():
                kcal.adjoint_views(y, self.mask_images, plan["a"], plan["c0"], plan["c1"],
                                   plan["sub"], plan["ident"], plan["wvs"], plan["indptr"],
                                   plan["indices"], plan["data"], plan["vlo"], plan["vhi"],
                                   plan["rows"], plan["zrows"], plan["lo"], plan["hi"],
                                   base is not None, b, q, np.float32(scale), out)
            return out
        if weights is not None:
            raise ValueError("base weights need the one-pass adjoint")
        return self._adjoint_by_view(y, base, scale, out)

    def _adjoint_by_view(self, y, base, scale, out):
        r"""``out`` :math:`= H^\top y` (``base`` None) or :math:`b + s H^\top y`, view by view
        (:func:`~recon.kernels.calibrated.shift_adjoint`,
        :func:`~recon.kernels.calibrated.warp_adjoint`); ``out`` may be ``base`` only for one
        view."""
        from recon.kernels import calibrated as kcal

        dt = np.float32
        cm = self.mask_images
        views = self._kernel_arrays()
        b = out if base is None else np.ascontiguousarray(base, dtype=dt)
        s = dt(scale)
        z = None
        with kernels.threads():
            for k, (ident, _, adj, a, c0, c1, sub) in enumerate(views):
                first, last = k == 0, k == len(views) - 1
                # How this view's part combines with the output (recon.kernels.calibrated).
                mode = (0 if first else 1) if base is None or not last else (3 if first else 2)
                if ident:
                    kcal.shift_adjoint(y[k], cm[k], a, c0, c1, sub, mode, b, s, out)
                    continue
                # Views may differ in width (each homography has its own view shape).
                if z is None or z.shape[1:] != self.warps[k].out_shape:
                    z = np.empty((self.n_bands,) + self.warps[k].out_shape, dtype=dt)
                kcal.shift_adjoint(y[k], cm[k], a, c0, c1, sub, 0, z, s, z)
                kcal.warp_adjoint(z.reshape(self.n_bands, -1), *adj, mode, b, s, out)
        return out

    def row_norms_sq(self) -> np.ndarray:
        r"""Diagonal of :math:`HH^\top`: :math:`\sum_l s_l^2 C_{k,l}^2 \|(S_{k,l}W_k)_i\|^2`."""
        if self._row_norms is None:
            lo, hi = self._pad
            hv, wm = self.oshape[1:]
            out = np.zeros(self.oshape, dtype=np.float64)
            q = np.empty((hv, lo + wm + hi), dtype=np.float64)
            for k, warp in enumerate(self.warps):
                n, c = warp.norm_parts()
                for l, (a, t) in enumerate(self._parts[k]):
                    q.fill(0.0)
                    shift_row_norms(n, c, a + lo, t, q)
                    out[k] += (self.band_scale[l] * self.mask_images[k, l].astype(np.float64)
                               ) ** 2 * q[:, lo:lo + wm]
            self._row_norms = out
        return self._row_norms.copy()

    def __repr__(self):
        return (f"<CalibratedCassi {self.n_views} view(s), {self.n_bands} bands: "
                f"{self.ishape} -> {self.oshape}>")


#: Placeholder CSR arrays for identity views (the kernel does not read them).
_NO_CSR = (np.zeros(1, np.int32), np.zeros(1, np.int32), np.zeros(1, np.float32))
#: Placeholder pixel-major cube where every view is an identity (the kernel does not read it).
_NO_PIXELS = np.zeros((1, 1), np.float32)


def _view_table(views, warps) -> dict:
    """The per-view arrays both one-pass kernels take, one row a view: the offsets' integer
    parts ``a``, the taps ``c0``, ``c1``, ``sub``, the identity flags and the widths ``wvs``
    of the views' ``warps``."""
    return {"a": np.stack([v[3] for v in views]), "c0": np.stack([v[4] for v in views]),
            "c1": np.stack([v[5] for v in views]), "sub": np.stack([v[6] for v in views]),
            "ident": np.array([v[0] for v in views], np.bool_),
            "wvs": np.array([wp.out_shape[1] for wp in warps], np.int64)}


def _joined_csr(views, which: int) -> dict:
    """The CSR arrays of every view's :math:`W_k` (``which`` 1) or :math:`W_k^\top` (2) joined
    for a one-pass kernel: ``indptr`` ``(K, n)`` int64, each view's row pointers into the
    shared ``indices`` and ``data`` (an identity view's all zero)."""
    csr = [v[which] for v in views]
    n = max([1] + [c[0].size for c in csr if c is not None])
    indptr = np.zeros((len(csr), n), np.int64)
    parts_i, parts_d, nnz = [], [], 0
    for k, c in enumerate(csr):
        if c is None:
            continue
        ip, ix, dv = c
        indptr[k, :ip.size] = ip.astype(np.int64) + nnz
        parts_i.append(ix)
        parts_d.append(dv)
        nnz += ix.size
    return {"indptr": indptr,
            "indices": np.concatenate(parts_i) if parts_i else np.zeros(1, np.int32),
            "data": np.concatenate(parts_d) if parts_d else np.zeros(1, np.float32)}


def _rows_read(indptr, indices, data, hv: int, wv: int, w: int):
    """The first and the last cube row that each view row's entries of :math:`W` read (a row
    without entries takes its neighbour's, so that the rows stay in order)."""
    starts = indptr[np.arange(hv) * wv].astype(np.int64)
    stops = indptr[(np.arange(hv) + 1) * wv].astype(np.int64)
    some = stops > starts
    first = np.zeros(hv, np.int64)
    last = np.zeros(hv, np.int64)
    if some.any():
        rows = indices // w
        first[some] = np.minimum.reduceat(rows, starts[some])
        last[some] = np.maximum.reduceat(rows, starts[some])
        # Rows without entries: the nearest row before them that has some (or after).
        idx = np.where(some, np.arange(hv), -1)
        np.maximum.accumulate(idx, out=idx)
        idx[idx < 0] = np.argmax(some)
        first, last = first[idx], last[idx]
    return first, last


def _csr32(m):
    """``(indptr, indices, data)`` of a CSR matrix as int32, int32, float32 (no copy when they
    already are): one compiled signature of the kernels for every warp."""
    if m.nnz >= 2 ** 31:
        raise InputError(f"a warp with {m.nnz} entries is too large for the kernels")
    return (np.ascontiguousarray(m.indptr, dtype=np.int32),
            np.ascontiguousarray(m.indices, dtype=np.int32),
            np.ascontiguousarray(m.data, dtype=np.float32))
