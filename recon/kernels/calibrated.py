r"""Calibrated CASSI kernels: warp, per-band mask image and dispersion shift of one view.

For one view of :class:`~recon.operators.calibrated.CalibratedCassi`, with :math:`v_l = W f_l`
the warped band (view width :math:`W_v`), :math:`C_l` the band's mask image on the sensor crop
(width :math:`W_m`), the band's offset :math:`\varphi_l = a_l + t_l` and the weights
:math:`c^0_l = s_l(1-t_l)`, :math:`c^1_l = s_l t_l` (:math:`s_l` the band's scale),

.. math::

    g[i, x] &= \sum_l C_l[i, x]\,\bigl(c^0_l\, v_l[i, x-a_l] + c^1_l\, v_l[i, x-a_l-1]\bigr),
    \\
    z_l[i, j] &= c^0_l\, C_l[i, a_l+j]\, y[i, a_l+j] + c^1_l\, C_l[i, a_l+1+j]\, y[i, a_l+1+j],
    \qquad (H^\top y)_l = W^\top z_l .

:math:`W` is a sparse matrix (rows: view pixels, columns: cube pixels; bilinear resampling has
up to four entries a row), given in CSR form together with its transpose, so that both the
forward map (:math:`v = Wf`, a gather along the rows of :math:`W`) and the adjoint
(:math:`W^\top z`, a gather along the rows of :math:`W^\top`) read scattered and write
contiguously: rows run in parallel without two threads ever writing one element, and the
result does not depend on the number of threads.  The same float32 weights serve both
directions, so the adjoint is exact up to rounding.  A view whose warp is the identity skips
the gather (``ident``).

Forward: :func:`forward_views` makes every view in one pass over the cube.  A task lays a
block of cube rows out pixel-major in a scratch that stays in cache (the L bands of a pixel
side by side), then makes every view's rows whose warp reads only those cube rows.  A view
row is gathered into a (W_v, L) scratch, each entry of :math:`W` adding one pixel's L
contiguous bands (:func:`_gather_row_pixels`, a vector operation, where the band-major cube
would need L loads from L rows far apart), turned band-major in cache, then added, masked
and shifted, into the measurement row, so one row of every mask image and the measurement
row stay in cache.  An identity view reads the cube's row in place.  The view-by-view
kernels it replaces stay for warps whose rows reach over too many cube rows: the whole cube
laid out pixel-major once (:func:`bands_last`), then :func:`forward_view` a view, each view
row a task; both make each row with the same sums in the same order.

Adjoint: :func:`adjoint_views` makes every view's :math:`z` and gathers :math:`W_k^\top z`
into the cube in one pass over it, pixel-major in cache likewise.  The view-by-view kernels
it replaces stay for warps that spread a cube row over too many view rows:
:func:`shift_adjoint` makes :math:`z` (or, for an identity view, adds it to the output
directly) and :func:`warp_adjoint` gathers :math:`W^\top z` into the cube, one cube row of
all bands a task; both take the same ``mode`` that says how the view's part combines with the
output (see :func:`warp_adjoint`), so that a sum over views, and the solvers'
:math:`b + sH^\top y`, need no extra pass.

The gathers read each entry of :math:`W` once for all bands, not once a band, and the bands
of a pixel as one vector (figures in ``docs/speed_product.md``).
"""

from __future__ import annotations

import numpy as np
from numba import prange

from recon.kernels import jit

__all__ = ["bands_last", "forward_view", "forward_views", "forward_rows", "shift_adjoint",
           "warp_adjoint", "adjoint_views", "adjoint_rows", "FORWARD_TASK_BYTES",
           "FORWARD_MAX_SPAN", "ADJOINT_TASK_BYTES", "ADJOINT_MAX_ZROWS"]

#: Rows per parallel task: enough to amortise the scratch allocation, few enough to balance.
_ROWS = 8
#: Pixels per parallel task of :func:`bands_last`.
_PIXELS = 64
#: Pixels per block of :func:`_to_band_major`: a block's bands (8 x L floats) stay in the
#: first-level cache while each band's run of 8 is written.
_BLOCK = 8
#: Bytes of a task's cube rows laid out pixel-major in :func:`forward_views`
#: (:func:`forward_rows`): about a core's L2 cache, with the rows the views' warps reach
#: past the task's own.
FORWARD_TASK_BYTES = 1 << 20
#: The most cube rows past the first that one view row's warp may read for
#: :func:`forward_views` (warps that reach over more, e.g. a strong rotation, take the
#: view-by-view kernels).
FORWARD_MAX_SPAN = 16
#: Bytes of a task's rows of every band in :func:`adjoint_views` (:func:`adjoint_rows`): about
#: a core's L2 cache (1 MiB on the machine measured).  A task remakes the view rows it shares
#: with the next, so taller tasks remake a smaller share of them (docs/speed_product.md).
ADJOINT_TASK_BYTES = 1 << 20
#: The most view rows a task of :func:`adjoint_views` may need (warps that spread a cube row
#: over more, e.g. a strong rotation, take the view-by-view kernels).
ADJOINT_MAX_ZROWS = 32


@jit(refcount=False)
def _gather_row(x, indptr, indices, data, i, v):
    r"""``v[l, :]`` :math:`= (W x_l)` on view row ``i``, every band: each row of :math:`W` (its
    column indices and weights) is read once for all bands, not once a band."""
    n_bands, wv = v.shape
    base = i * wv
    for j in range(wv):
        r = base + j
        for l in range(n_bands):
            v[l, j] = 0
        for e in range(indptr[r], indptr[r + 1]):
            d = data[e]
            c = indices[e]
            for l in range(n_bands):
                v[l, j] += d * x[l, c]


@jit(refcount=False)
def _shift_add(vl, cr, al, b0, b1, sub, acc):
    r"""``acc[x]`` :math:`\mathrel{+}= C[x]\,(c^0 v[x-a] + c^1 v[x-a-1])`, one band of one row;
    columns ``x`` outside the row are dropped."""
    wv = vl.shape[0]
    if al < 0 or al + wv + sub > acc.shape[0]:
        _clipped_tap(vl, cr, al, b0, acc)
        if sub:
            _clipped_tap(vl, cr, al + 1, b1, acc)
        return
    if not sub:
        o, c = acc[al:al + wv], cr[al:al + wv]
        for j in range(wv):
            o[j] += c[j] * (b0 * vl[j])
        return
    acc[al] += cr[al] * (b0 * vl[0])
    o, c = acc[al + 1:al + wv], cr[al + 1:al + wv]
    v1, v0 = vl[1:], vl[:wv - 1]
    for j in range(wv - 1):
        o[j] += c[j] * (b0 * v1[j] + b1 * v0[j])
    acc[al + wv] += cr[al + wv] * (b1 * vl[wv - 1])


@jit(refcount=False)
def _clipped_tap(vl, cr, al, b, acc):
    r"""``acc[x]`` :math:`\mathrel{+}= C[x]\, b\, v[x-a]` for the ``x`` inside the row (a band
    whose image reaches past an edge of the crop)."""
    j0 = max(0, -al)
    j1 = min(vl.shape[0], acc.shape[0] - al)
    if j1 <= j0:
        return
    o, c, v = acc[al + j0:al + j1], cr[al + j0:al + j1], vl[j0:j1]
    for j in range(j1 - j0):
        o[j] += c[j] * (b * v[j])


@jit(parallel=True)
def bands_last(x, out):
    r"""``out[n, l] = x[l, n]``: the cube pixel-major, every band of a pixel side by side, for
    the forward's gathers (:func:`forward_view`).

    Parameters
    ----------
    x : ndarray, shape (L, N)
        The cube, each band flattened.
    out : ndarray, shape (N, L)
    """
    n = x.shape[1]
    # Each task writes its block of ``out`` contiguously and reads L short runs of ``x``.
    n_tasks = (n + _PIXELS - 1) // _PIXELS
    for task in prange(n_tasks):
        lo = task * _PIXELS
        _lay_out(x, lo, out[lo:min(n, lo + _PIXELS)])


@jit(refcount=False)
def _lay_out(x, p0, out):
    r"""``out[p, l] = x[l, p0 + p]`` for every row ``p`` of ``out``: pixels ``p0 ..`` of the
    cube ``x`` (L, N), pixel-major."""
    n_bands = x.shape[0]
    for p in range(out.shape[0]):
        o = out[p]
        for l in range(n_bands):
            o[l] = x[l, p0 + p]


@jit(refcount=False)
def _gather_row_pixels(xt, indptr, indices, data, shift, i, vt):
    r"""``vt[j, :]`` :math:`= (W x)` at pixel ``j`` of view row ``i``, every band, from the
    pixel-major cube ``xt`` (N, L) or a block of its rows: each entry of :math:`W` adds one
    pixel's L bands.  Cube pixel ``c`` is row ``c - shift`` of ``xt`` (a block that starts at
    pixel ``shift``)."""
    wv, n_bands = vt.shape
    r0 = i * wv
    for j in range(wv):
        r = r0 + j
        acc = vt[j]
        e0, e1 = indptr[r], indptr[r + 1]
        if e1 - e0 == 4:
            # A bilinear tap's four entries (almost every row) in one expression: the pixel's
            # bands are written once, where adding entry by entry loads and stores them four
            # times.  The same sum, in the same order.
            d0, d1, d2, d3 = data[e0], data[e0 + 1], data[e0 + 2], data[e0 + 3]
            s0, s1 = xt[indices[e0] - shift], xt[indices[e0 + 1] - shift]
            s2, s3 = xt[indices[e0 + 2] - shift], xt[indices[e0 + 3] - shift]
            for l in range(n_bands):
                acc[l] = d0 * s0[l] + d1 * s1[l] + d2 * s2[l] + d3 * s3[l]
            continue
        for l in range(n_bands):
            acc[l] = 0
        for e in range(e0, e1):
            d = data[e]
            src = xt[indices[e] - shift]
            for l in range(n_bands):
                acc[l] += d * src[l]


@jit(refcount=False)
def _to_band_major(vt, v):
    r"""``v[l, j] = vt[j, l]``: a warped row from pixel-major (as gathered) to band-major.

    In blocks of :data:`_BLOCK` pixels: each band's values of a block are read from the
    block's few cache lines and written as one contiguous run, where a band at a time over
    the whole row reads a value from every line of the row (docs/speed_product.md)."""
    wv, n_bands = vt.shape
    whole = wv - wv % _BLOCK
    for j0 in range(0, whole, _BLOCK):
        block = vt[j0:j0 + _BLOCK]
        for l in range(n_bands):
            run = v[l, j0:j0 + _BLOCK]
            for j in range(_BLOCK):
                run[j] = block[j, l]
    for j in range(whole, wv):
        for l in range(n_bands):
            v[l, j] = vt[j, l]


@jit(refcount=False)
def _forward_row(x, xt, cm, a, c0, c1, sub, ident, indptr, indices, data, shift, i, vt, v, acc):
    r"""``acc`` :math:`= g[i, :]`: every band of view row ``i`` (see the module docstring);
    ``vt`` (Wv, L) and ``v`` (L, Wv) are scratch for the warped row, pixel-major as gathered
    (from ``xt``, ``shift`` as for :func:`_gather_row_pixels`) and band-major
    (unused by an identity view, which reads the cube's row in place)."""
    n_bands, wv = v.shape
    wm = acc.shape[0]
    for x_ in range(wm):
        acc[x_] = 0
    if not ident:
        _gather_row_pixels(xt, indptr, indices, data, shift, i, vt)
        _to_band_major(vt, v)
    base = i * wv
    for l in range(n_bands):
        vl = x[l, base:base + wv] if ident else v[l]
        _shift_add(vl, cm[l, i], a[l], c0[l], c1[l], sub[l], acc)


@jit(parallel=True)
def forward_view(x, xt, cm, a, c0, c1, sub, ident, indptr, indices, data, wv, out):
    r"""One view's measurement :math:`g` (overwrites ``out``).

    Parameters
    ----------
    x : ndarray, shape (L, H*W)
        The cube, each band flattened (float32; ``xt``, ``cm``, ``c0``, ``c1``, ``data`` and
        ``out`` in the same precision).
    xt : ndarray, shape (H*W, L)
        The same cube pixel-major (:func:`bands_last`; not read by an identity view).
    cm : ndarray, shape (L, Hv, Wm)
        The view's mask images :math:`C_l`.
    a : ndarray of int64, shape (L,)
        Integer parts of the offsets.
    c0, c1 : ndarray, shape (L,)
        The taps :math:`c^0_l, c^1_l` (the band scale folded in).
    sub : ndarray of bool, shape (L,)
        Whether band ``l`` has a second tap (:math:`t_l \ne 0`).
    ident : bool
        The warp is the identity (then ``indptr``, ``indices``, ``data`` are not read).
    indptr, indices : ndarray of int32
    data : ndarray
        :math:`W` in CSR form, ``(Hv*Wv, H*W)``.
    wv : int
        :math:`W_v`.
    out : ndarray, shape (Hv, Wm)
    """
    hv, wm = out.shape
    n_tasks = (hv + _ROWS - 1) // _ROWS
    for task in prange(n_tasks):
        vt = np.empty((wv, x.shape[0]), dtype=out.dtype)
        v = np.empty((x.shape[0], wv), dtype=out.dtype)
        for i in range(task * _ROWS, min(hv, (task + 1) * _ROWS)):
            _forward_row(x, xt, cm, a, c0, c1, sub, ident, indptr, indices, data, 0, i, vt, v,
                         out[i])


def forward_rows(n_bands: int, h: int, w: int, cores: int, reach: int) -> int:
    """Cube rows per task of :func:`forward_views`: with the ``reach`` rows past them that the
    views' warps read, as many as :data:`FORWARD_TASK_BYTES` holds pixel-major (at least 4),
    while every core still gets four tasks."""
    return _task_rows(FORWARD_TASK_BYTES // max(1, 4 * n_bands * w) - max(0, reach), 4, h,
                      cores)


def _task_rows(fit: int, least: int, h: int, cores: int) -> int:
    """``fit`` cube rows a task, or ``least`` if fewer, but no more than give every core four
    tasks (unless that is below ``least``), and at most ``h``."""
    share = -(-h // (4 * max(1, cores)))
    return int(max(1, min(max(least, fit), max(least, share), h)))


@jit(parallel=True)
def forward_views(x, cm, a, c0, c1, sub, ident, wvs, indptr, indices, data, s0, s1, ilo, ihi,
                  w, out):
    r"""The measurement :math:`g` of every view in one pass over the cube (overwrites ``out``).

    Task ``t`` lays the cube rows ``s0[t] .. s1[t] - 1`` out pixel-major in a scratch that
    stays in cache, then makes every view's rows ``ilo[k, t] .. ihi[k, t] - 1`` (the view
    rows whose warp reads those cube rows only) from it, each as :func:`forward_view` makes
    it: the same sums in the same order, so the same bits.  Where the view-by-view kernels
    lay the whole cube out pixel-major and every view's gather reads all of it from memory,
    this reads the cube once (the rows a task shares with the next, twice).

    Parameters
    ----------
    x : ndarray, shape (L, H*W)
    cm : ndarray, shape (K, L, Hv, Wm)
    a, c0, c1, sub : ndarray, shape (K, L)
        As for :func:`forward_view`, one row a view.
    ident : ndarray of bool, shape (K,)
    wvs : ndarray of int64, shape (K,)
        The views' widths :math:`W_v`.
    indptr : ndarray of int64, shape (K, n)
        Each view's :math:`W_k` CSR row pointers (``Hv W_v + 1`` of them, the rest unused) into
        the shared ``indices``/``data``.
    indices : ndarray of int32
    data : ndarray
    s0, s1 : ndarray of int64, shape (tasks,)
        The cube rows each task lays out.
    ilo, ihi : ndarray of int64, shape (K, tasks)
        The view rows each task makes.
    w : int
        The cube's width :math:`W`.
    out : ndarray, shape (K, Hv, Wm)
    """
    n_views = cm.shape[0]
    n_bands = x.shape[0]
    for task in prange(s0.shape[0]):
        r0, r1 = s0[task], s1[task]
        p0 = r0 * w
        n = (r1 - r0) * w
        xt = np.empty((n, n_bands), dtype=out.dtype)
        _lay_out(x, p0, xt)
        for k in range(n_views):
            if ihi[k, task] <= ilo[k, task]:
                continue
            wv = wvs[k]
            vt = np.empty((wv, n_bands), dtype=out.dtype)
            v = np.empty((n_bands, wv), dtype=out.dtype)
            for i in range(ilo[k, task], ihi[k, task]):
                _forward_row(x, xt, cm[k], a[k], c0[k], c1[k], sub[k], ident[k], indptr[k],
                             indices, data, p0, i, vt, v, out[k, i])


@jit(refcount=False)
def _combine(o, s, mode, b, scale):
    """``o`` (=, +=, base + scale·(o + ·), base + scale·) ``s`` by ``mode``, one row."""
    n = o.shape[0]
    if mode == 0:
        for j in range(n):
            o[j] = s[j]
    elif mode == 1:
        for j in range(n):
            o[j] += s[j]
    elif mode == 2:
        for j in range(n):
            o[j] = b[j] + scale * (o[j] + s[j])
    else:
        for j in range(n):
            o[j] = b[j] + scale * s[j]


@jit(refcount=False)
def _band_z_row(cr, yr, al, b0, b1, sub, lo, cy, zr):
    r"""One row of one band's :math:`z_l`: ``cy[lo:]`` :math:`= C_{k,l}\,y` on the row
    (``cr`` the mask image's row, ``yr`` the measurement's), then ``zr`` the two taps
    ``b0 cy[al + j] + b1 cy[al + j + 1]`` (``b1`` only where ``sub``)."""
    wm = yr.shape[0]
    cyr = cy[lo:lo + wm]
    for x_ in range(wm):
        cyr[x_] = cr[x_] * yr[x_]
    wv = zr.shape[0]
    p0 = cy[al:al + wv]
    if sub:
        p1 = cy[al + 1:al + 1 + wv]
        for j in range(wv):
            zr[j] = b0 * p0[j] + b1 * p1[j]
    else:
        for j in range(wv):
            zr[j] = b0 * p0[j]


@jit(parallel=True)
def shift_adjoint(y, cm, a, c0, c1, sub, mode, base, scale, out):
    r""":math:`z_l[i, :]` of one view for every band and row, combined into ``out`` by ``mode``.

    Parameters
    ----------
    y : ndarray, shape (Hv, Wm)
        The view's measurement.
    cm, a, c0, c1, sub
        As for :func:`forward_view`.
    mode, base, scale
        As for :func:`warp_adjoint`; ``base`` of ``out``'s shape (read for modes 2 and 3).
    out : ndarray, shape (L, Hv, Wv)
        :math:`z` itself (``mode`` 0) or, for an identity view, the cube.
    """
    n_bands, hv, wv = out.shape
    wm = y.shape[1]
    # C y on the row with zeros on either side, as far as any band's image reaches past the
    # crop (and one column for the second tap of the last band).
    lo = max(0, -np.min(a))
    hi = max(1, np.max(a) + wv + 1 - wm)
    n_tasks = (hv + _ROWS - 1) // _ROWS
    for task in prange(n_tasks):
        cy = np.zeros(lo + wm + hi, dtype=out.dtype)
        z = np.empty(wv, dtype=out.dtype)
        for i in range(task * _ROWS, min(hv, (task + 1) * _ROWS)):
            yr = y[i]
            for l in range(n_bands):
                _band_z_row(cm[l, i], yr, a[l] + lo, c0[l], c1[l], sub[l], lo, cy, z)
                _combine(out[l, i], z, mode, base[l, i], scale)


@jit(parallel=True)
def warp_adjoint(z, indptr, indices, data, mode, base, scale, out):
    r""":math:`W^\top z_l` for every band, combined into ``out``.

    Parameters
    ----------
    z : ndarray, shape (L, Hv*Wv)
    indptr, indices : ndarray of int32
    data : ndarray
        :math:`W^\top` in CSR form, ``(H*W, Hv*Wv)``.
    mode : int
        0: ``out`` :math:`= W^\top z`; 1: ``out`` :math:`\mathrel{+}= W^\top z`;
        2: ``out`` :math:`= b + s\,(\mathrm{out} + W^\top z)`; 3: ``out`` :math:`= b + s\,W^\top
        z` (the first view, the next ones, the last one of a sum added to a base, a single
        view added to a base).
    base : ndarray, shape (L, H, W)
        :math:`b` (modes 2 and 3); must not be ``out`` unless ``mode`` is 3.
    scale : float
        :math:`s`, in the working precision.
    out : ndarray, shape (L, H, W)
    """
    n_bands, h, w = out.shape
    n_tasks = (h + _ROWS - 1) // _ROWS
    for task in prange(n_tasks):
        s = np.empty((n_bands, w), dtype=out.dtype)
        for yy in range(task * _ROWS, min(h, (task + 1) * _ROWS)):
            # Every band's cube row yy at once: each row of W^T read once, not once a band.
            _gather_row(z, indptr, indices, data, yy, s)
            for l in range(n_bands):
                _combine(out[l, yy], s[l], mode, base[l, yy], scale)


def adjoint_rows(n_bands: int, h: int, w: int, cores: int) -> int:
    """Cube rows per task of :func:`adjoint_views`: as many as :data:`ADJOINT_TASK_BYTES`
    holds (at least 8: a task remakes the one or two view rows it shares with the next, so
    fewer rows would remake a larger share), while every core still gets four tasks."""
    return _task_rows(ADJOINT_TASK_BYTES // max(1, 4 * n_bands * w), 8, h, cores)


@jit(refcount=False)
def _view_z_rows(y, cm, a, c0, c1, sub, r0, r1, wv, lo, cy, z):
    r""":math:`z_l` of one view on its rows ``r0 .. r1 - 1`` into ``z``, pixel-major
    (``(n, L)``, row ``i`` from ``(i - r0) wv`` on), as :func:`shift_adjoint` makes them;
    ``cy`` a zero-padded row scratch (``lo`` zeros before the crop)."""
    n_bands = a.shape[0]
    for i in range(r0, r1):
        yr = y[i]
        o = (i - r0) * wv
        for l in range(n_bands):
            _band_z_row(cm[l, i], yr, a[l] + lo, c0[l], c1[l], sub[l], lo, cy, z[o:o + wv, l])


@jit(refcount=False)
def _gather_add(z, shift, indptr, indices, data, yy, w, acc, t):
    r"""``acc[t, x, :]`` :math:`\mathrel{+}= (W^\top z)` at every pixel ``x`` of cube row
    ``yy``, every band, ``z`` (pixel-major) holding the view's flat pixels from ``shift`` on:
    each entry of :math:`W^\top` adds one pixel's L bands."""
    n_bands = z.shape[1]
    base = yy * w
    for x_ in range(w):
        r = base + x_
        dst = acc[t, x_]
        for e in range(indptr[r], indptr[r + 1]):
            d = data[e]
            src = z[indices[e] - shift]
            for l in range(n_bands):
                dst[l] += d * src[l]


@jit(parallel=True)
def adjoint_views(y, cm, a, c0, c1, sub, ident, wvs, indptr, indices, data, vlo, vhi, rows,
                  zrows, lo, hi, has_base, base, weights, scale, out):
    r""":math:`H^\top y` of every view in one pass over the cube (overwrites ``out``), or
    :math:`b + s H^\top y` with ``has_base`` (:math:`q_l b_l + s (H^\top y)_l` with
    ``weights`` :math:`q`).

    Each task is ``rows`` cube rows: for every view it makes :math:`z` on the view rows that
    those cube rows gather from (``vlo[k, task] .. vhi[k, task] - 1``, at most ``zrows``) into a
    scratch that stays in cache, gathers :math:`W_k^\top z` (an identity view: :math:`z`
    itself) into the task's rows, and writes them once.  Both scratches are pixel-major, so
    that each entry of :math:`W_k^\top` adds the L bands of a pixel as one vector.  Where
    :func:`shift_adjoint` and :func:`warp_adjoint` view by view write every view's :math:`z`
    to memory and read it back and read and write the whole cube once a view, this reads the
    mask images and the measurement once and writes the cube once (view rows shared by two
    tasks are made twice).

    Parameters
    ----------
    y : ndarray, shape (K, Hv, Wm)
    cm : ndarray, shape (K, L, Hv, Wm)
    a, c0, c1, sub : ndarray, shape (K, L)
        As for :func:`forward_view`, one row a view.
    ident : ndarray of bool, shape (K,)
        Identity views (their view image is the cube's grid; no CSR read).
    wvs : ndarray of int64, shape (K,)
        The views' widths :math:`W_v`.
    indptr : ndarray of int64, shape (K, H*W + 1)
        Each view's :math:`W_k^\top` CSR row pointers into the shared ``indices``/``data``.
    indices : ndarray of int32
    data : ndarray
    vlo, vhi : ndarray of int64, shape (K, tasks)
        The view rows each task needs.
    rows, zrows : int
        Cube rows a task, and the most view rows a task needs.
    lo, hi : int
        Zero columns before and after the crop in the row scratch (as :func:`shift_adjoint`).
    has_base : bool
    base : ndarray, shape (L, H, W)
        :math:`b` (read with ``has_base``).
    weights : ndarray, shape (L,) or (0,)
        :math:`q`, a factor per band of the base (the band metric's weighted base); empty:
        none (the base as it is, not multiplied by ones, so that the sums are unchanged).
    scale : float
    out : ndarray, shape (L, H, W)
        May be ``base``: each task reads its rows of ``base`` before it writes them.
    """
    n_views = y.shape[0]
    n_bands, h, w = out.shape
    wm = y.shape[2]
    weighted = weights.shape[0] > 0
    wmax = 1
    for k in range(n_views):
        wmax = max(wmax, wvs[k])
    n_tasks = (h + rows - 1) // rows
    for task in prange(n_tasks):
        y0 = task * rows
        y1 = min(h, y0 + rows)
        acc = np.zeros((rows, w, n_bands), dtype=out.dtype)
        z = np.empty((zrows * wmax, n_bands), dtype=out.dtype)
        cy = np.zeros(lo + wm + hi, dtype=out.dtype)
        for k in range(n_views):
            r0, r1 = vlo[k, task], vhi[k, task]
            if r1 <= r0:
                continue
            wv = wvs[k]
            _view_z_rows(y[k], cm[k], a[k], c0[k], c1[k], sub[k], r0, r1, wv, lo, cy, z)
            if ident[k]:
                for yy in range(y0, y1):
                    ar, zr = acc[yy - y0], z[(yy - r0) * wv:(yy - r0) * wv + w]
                    for x_ in range(w):
                        for l in range(n_bands):
                            ar[x_, l] += zr[x_, l]
            else:
                for yy in range(y0, y1):
                    _gather_add(z, r0 * wv, indptr[k], indices, data, yy, w, acc, yy - y0)
        # Back to band-major rows, in cache.
        for yy in range(y0, y1):
            ar = acc[yy - y0]
            for l in range(n_bands):
                o = out[l, yy]
                if has_base and weighted:
                    b = base[l, yy]
                    q = weights[l]
                    for x_ in range(w):
                        o[x_] = q * b[x_] + scale * ar[x_, l]
                elif has_base:
                    b = base[l, yy]
                    for x_ in range(w):
                        o[x_] = b[x_] + scale * ar[x_, l]
                else:
                    for x_ in range(w):
                        o[x_] = ar[x_, l]
