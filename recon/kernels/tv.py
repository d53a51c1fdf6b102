r"""Total-variation kernels: the Chambolle prox in one pass, the TV norm per row.

Notation as in :mod:`recon.prox.tv`: a band :math:`v` (H×W), its dual :math:`p=(p^0,p^1)`,
the step :math:`\theta=1/4`, :math:`s=\theta/\lambda`, and the scaled primal
:math:`y = s v - \theta\,\mathrm{div}\,p` whose forward differences are the dual step.

**One pass for all dual iterations (a wavefront).**  Row :math:`i` of
:math:`y` depends on the dual rows :math:`i` and :math:`i-1`; the dual update of row :math:`i`
needs :math:`y` on rows :math:`i` and :math:`i+1`.  So dual iteration :math:`n+1` can update
row :math:`i` as soon as iteration :math:`n` has updated rows :math:`i` and :math:`i+1`:
iteration :math:`n` runs one row behind iteration :math:`n-1`.  Each iteration keeps the two
rows of :math:`y` it needs in a small buffer, computing row :math:`i+1` *before* it overwrites
row :math:`i` of the dual (whose old value that row still needs).  The result,
:math:`x = v - \lambda\,\mathrm{div}\,p`, is written one row behind the last iteration.
Memory traffic is one read of :math:`v`, one read and write of :math:`p` and one write of
:math:`x`, whatever the number of iterations (the NumPy path makes about 12 passes per
iteration), and the result equals that of the iterations run one after the other.

**A gradient step in the same pass.**  The solvers' prox input is a gradient step
:math:`u = v + s H^\top y`.  For CASSI each row of :math:`H^\top y` is a gather of shifted
measurement rows times a mask row, so the first iteration can make row :math:`i+1` of
:math:`u` (into ``out``) just before it reads it: one read and one write of the cube for the
step and the prox together instead of two of each.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import prange

from recon.kernels import jit

__all__ = ["chambolle", "no_gather", "tv_rows", "combine_tv_rows"]


# The row loops index slices with the bare loop counter: an index such as ``j - 1`` makes
# Numba check for negative indices, which stops LLVM from vectorising the loop.  Each band is
# seen flat (H·W), so that a row's left neighbour term :math:`p^1_{q,j-1}` at ``j = 0`` reads
# the last column of the row above, which is zero (Neumann): rows need no first-column case
# and every loop runs over the full width.  Rows of ``y`` carry one more element, a copy of
# their last, so that the horizontal difference past the last column is zero without a case.


@jit(refcount=False)
def _y_first(vb, p0, p1, w, s, theta, ybuf, k, b):
    r"""Row 0 of :math:`y = s v - \theta\,\mathrm{div}\,p` into ``ybuf[k, b, :w]`` (no row
    above and no column left of the first); ``out[w] = out[w-1]``."""
    out = ybuf[k, b]
    out[0] = s * vb[0] - theta * (p0[0] + p1[0])
    v1, a1, c1, c0, o1 = vb[1:w], p0[1:w], p1[1:w], p1[:w - 1], out[1:w]
    for j in range(w - 1):
        o1[j] = s * v1[j] - theta * (a1[j] + c1[j] - c0[j])
    out[w] = out[w - 1]


@jit(refcount=False)
def _y_row(vb, p0, p1, o, w, s, theta, ybuf, k, b):
    r"""The row at flat offset ``o > 0`` of :math:`y` into ``out = ybuf[k, b]``;
    ``out[w] = out[w-1]``.

    :math:`(\mathrm{div}\,p)_{q,j} = p^0_{q,j}-p^0_{q-1,j}+p^1_{q,j}-p^1_{q,j-1}`.
    """
    out = ybuf[k, b]
    vr, a, u = vb[o:o + w], p0[o:o + w], p0[o - w:o]
    c, cm = p1[o:o + w], p1[o - 1:o - 1 + w]
    for j in range(w):
        out[j] = s * vr[j] - theta * (a[j] - u[j] + c[j] - cm[j])
    out[w] = out[w - 1]


@jit(refcount=False)
def _dual_row(p0, p1, o, w, ybuf, k, bc, bn, isotropic, last):
    r"""Chambolle's update of the dual row at flat offset ``o`` from :math:`\nabla y` (rows
    ``ycur = ybuf[k, bc]``, ``ynext = ybuf[k, bn]``).

    Isotropic: :math:`p \leftarrow (p-\nabla y)/(1+\|\nabla y\|_2)`; anisotropic:
    :math:`p \leftarrow \Pi_{[-1,1]}(p-\nabla y)`.  On the last row (``last``) the vertical
    difference is zero and :math:`p^0` stays zero; on the last column the horizontal one is
    (``ycur[w] = ycur[w-1]``), so :math:`p^1` stays zero there.
    """
    ycur, ynext = ybuf[k, bc], ybuf[k, bn]
    one = ycur.dtype.type(1.0)
    a, b = p0[o:o + w], p1[o:o + w]
    y0, y1, yn = ycur[:w], ycur[1:w + 1], ynext[:w]
    if last:
        if isotropic:
            for j in range(w):
                gx = y1[j] - y0[j]
                b[j] = (b[j] - gx) / (one + np.abs(gx))
        else:
            for j in range(w):
                b[j] = min(max(b[j] - (y1[j] - y0[j]), -one), one)
    elif isotropic:
        for j in range(w):
            gy = yn[j] - y0[j]
            gx = y1[j] - y0[j]
            # One division instead of two (divisions bound this loop).
            d = one / (one + np.sqrt(gy * gy + gx * gx))
            a[j] = (a[j] - gy) * d
            b[j] = (b[j] - gx) * d
    else:
        for j in range(w):
            a[j] = min(max(a[j] - (yn[j] - y0[j]), -one), one)
            b[j] = min(max(b[j] - (y1[j] - y0[j]), -one), one)


@jit(refcount=False)
def _out_row(vb, p0, p1, o, w, weight, ob, inplace):
    r"""The row at flat offset ``o`` of :math:`x = v - \lambda\,\mathrm{div}\,p`.

    ``inplace``: ``ob`` is ``vb``.  The row is then updated through one slice: with two
    slices of the same memory LLVM's run-time overlap test fails and the loop runs
    unvectorised (measured: the whole prox 20 % slower in place than out of place).
    """
    if o == 0:
        o1, a1, c1, c0 = ob[1:w], p0[1:w], p1[1:w], p1[:w - 1]
        if inplace:
            ob[0] -= weight * (p0[0] + p1[0])
            for j in range(w - 1):
                o1[j] -= weight * (a1[j] + c1[j] - c0[j])
        else:
            ob[0] = vb[0] - weight * (p0[0] + p1[0])
            v1 = vb[1:w]
            for j in range(w - 1):
                o1[j] = v1[j] - weight * (a1[j] + c1[j] - c0[j])
        return
    a, u, orow = p0[o:o + w], p0[o - w:o], ob[o:o + w]
    c, cm = p1[o:o + w], p1[o - 1:o - 1 + w]
    if inplace:
        for j in range(w):
            orow[j] -= weight * (a[j] - u[j] + c[j] - cm[j])
    else:
        vr = vb[o:o + w]
        for j in range(w):
            orow[j] = vr[j] - weight * (a[j] - u[j] + c[j] - cm[j])


@jit(refcount=False)
def _input_row(vb, ob, i, w, l, z, masks, a, c0, c1, sub, inplace):
    r"""Row ``i`` of the prox input :math:`v + s H^\top y` into ``ob`` (band ``l``, flat;
    ``inplace``: ``ob`` is ``vb``).

    The gather of :func:`recon.kernels.cassi.adjoint` for one band and row, with the
    measurement already in plan coordinates and scaled (``z``, see :func:`chambolle`):

    .. math::

        \bigl(s H^\top y\bigr)_{l,i,x} = \sum_k M_{k,i,x}\,\bigl(c^0_{k,l}\, z_{k,i,x+a_{k,l}}
        + c^1_{k,l}\, z_{k,i,x+a_{k,l}+1}\bigr).

    It is here rather than imported from :mod:`recon.kernels.cassi` because Numba's disk
    cache of :func:`chambolle` is keyed on this file only: a change there would go unseen.
    """
    o = i * w
    src, dst = vb[o:o + w], ob[o:o + w]
    for k in range(masks.shape[0]):
        m, al, zr = masks[k, i], a[k, l], z[k, i]
        z0, z1 = zr[al:al + w], zr[al + 1:al + 1 + w]
        # Every view but a first one read from v adds to dst through dst itself (see
        # _out_row: two slices of one row would not vectorise).
        if sub[k, l]:
            b0, b1 = c0[k, l], c1[k, l]
            if k == 0 and not inplace:
                for j in range(w):
                    dst[j] = src[j] + m[j] * (b0 * z0[j] + b1 * z1[j])
            else:
                for j in range(w):
                    dst[j] += m[j] * (b0 * z0[j] + b1 * z1[j])
        elif k == 0 and not inplace:
            for j in range(w):
                dst[j] = src[j] + m[j] * z0[j]
        else:
            for j in range(w):
                dst[j] += m[j] * z0[j]


@functools.lru_cache(maxsize=None)
def no_gather(dtype) -> tuple:
    """The ``z, masks, a, c0, c1, sub`` arguments of :func:`chambolle` for a plain prox (no
    views, so no gradient step); the arrays are empty and never written."""
    dtype = np.dtype(dtype)
    return (np.zeros((0, 1, 1), dtype), np.zeros((0, 1, 1), dtype),
            np.zeros((0, 1), np.int64), np.zeros((0, 1), dtype), np.zeros((0, 1), dtype),
            np.zeros((0, 1), np.bool_))


@jit(refcount=False)
def _scale_row(ob, o, w, r):
    """``ob[o:o + w] *= r``: the row just written, while it is in cache.  A loop of its own,
    after the row's, so that each value is rounded as the prox's, then scaled (the bits of
    a prox followed by a pass that scales it; in one expression the fast-math licences
    would let LLVM reassociate the two)."""
    row = ob[o:o + w]
    for j in range(w):
        row[j] *= r


@jit(parallel=True)
def chambolle(v, p, weight, s, theta, n_iter, isotropic, out, z, masks, a, c0, c1, sub,
              oscale):
    r"""``n_iter`` Chambolle dual iterations on every band, then
    :math:`x = u-\lambda\,\mathrm{div}\,p`, where the prox input :math:`u` is :math:`v` or,
    fused with a CASSI gradient step, :math:`u = v + s H^\top y`.

    Parameters
    ----------
    v : ndarray, shape (L, H, W)
        The prox input, or the base of the gradient step (float32; every argument in that
        precision), C-contiguous.
    p : ndarray, shape (2, L, H, W)
        The dual, updated in place; its entries past the Neumann boundary (last row of
        :math:`p^0`, last column of :math:`p^1`) are set to zero first.
    weight : float
        :math:`\lambda`.
    s, theta : float
        :math:`\theta/\lambda` and :math:`\theta` (passed in the working precision, so that
        the scaled input :math:`s v` rounds as in the NumPy path).
    n_iter : int
    isotropic : bool
    out : ndarray, shape (L, H, W)
        The result; may be ``v`` itself (each row of ``v`` is read for the last time before
        that row of ``out`` is written).
    z : ndarray, shape (K, H, Wm + 1)
        The gradient step's :math:`s\,y` in the CASSI plan coordinates of
        :mod:`recon.kernels.cassi` (each view's measurement flipped as its plan, scaled, one
        zero column appended), from
        :meth:`CassiOperator.adjoint_gather <recon.operators.cassi.CassiOperator.adjoint_gather>`.
        With ``K = 0`` there is no gradient step: :math:`u = v`.
    masks, a, c0, c1, sub : ndarray
        The plan's masks (K, H, W), integer offsets (K, L), tap weights (K, L) and sub-pixel
        flags (K, L), as for :func:`recon.kernels.cassi.adjoint`.
    oscale : ndarray, shape (L,) or (0,)
        A factor per band the result is multiplied by as it is written (FISTA's band metric
        scales the prox's result back per band), or none.

    Bands are independent and run in parallel.  With a gradient step, row :math:`i` of
    :math:`u` is gathered into ``out`` just before the first dual iteration reaches it and
    is read back from there, while in cache: the cube is read and written once for the step
    and the prox together, where :func:`recon.kernels.cassi.adjoint` then this kernel would
    read it twice and write it twice.
    """
    n_bands, h, w = v.shape
    gather = masks.shape[0] > 0
    scaled = oscale.shape[0] > 0
    # In place, rows are updated through one slice (see _out_row).
    inplace = v.ctypes.data == out.ctypes.data
    for l in prange(n_bands):
        ob, vl = out[l].reshape(-1), v[l].reshape(-1)
        # With a gradient step the prox input is made in ob and read back from there.
        vb = ob if gather else vl
        p0, p1 = p[0, l].reshape(-1), p[1, l].reshape(-1)
        p0[(h - 1) * w:] = 0
        for i in range(h):
            p1[i * w + w - 1] = 0
        # ybuf[k, i % 2] is row i of iteration k's y.
        ybuf = np.empty((max(n_iter, 1), 2, w + 1), dtype=v.dtype)
        for r in range(h + n_iter):
            if gather:
                # The first iteration reaches row r at this step and needs rows r and r + 1
                # of the input; with no iteration the result needs row r.
                if n_iter == 0:
                    if r < h:
                        _input_row(vl, ob, r, w, l, z, masks, a, c0, c1, sub, inplace)
                else:
                    if r == 0:
                        _input_row(vl, ob, 0, w, l, z, masks, a, c0, c1, sub, inplace)
                    if r + 1 < h:
                        _input_row(vl, ob, r + 1, w, l, z, masks, a, c0, c1, sub, inplace)
            for k in range(n_iter):
                q = r - k
                if q < 0 or q >= h:
                    continue
                bc, bn = q % 2, (q + 1) % 2
                if q == 0:
                    _y_first(vb, p0, p1, w, s, theta, ybuf, k, bc)
                if q + 1 < h:
                    _y_row(vb, p0, p1, (q + 1) * w, w, s, theta, ybuf, k, bn)
                _dual_row(p0, p1, q * w, w, ybuf, k, bc, bn, isotropic, q == h - 1)
            # The last iteration has finished row r - n_iter + 1 (and all above it).
            q = r - n_iter + 1 if n_iter > 0 else r
            if 0 <= q < h:
                _out_row(vb, p0, p1, q * w, w, weight, ob, inplace or gather)
                if scaled:
                    _scale_row(ob, q * w, w, oscale[l])


@jit(refcount=False)
def _tv_row(x, l, i, isotropic):
    r""":math:`\sum_j \|(\nabla x)_{l,i,j}\|` in float64 (see :func:`tv_rows`)."""
    h, w = x.shape[1], x.shape[2]
    r = x[l, i]
    r0, r1 = r[:w - 1], r[1:]
    acc = 0.0
    if i < h - 1:
        d = x[l, i + 1]
        d0 = d[:w - 1]
        if isotropic:
            for j in range(w - 1):
                gy = d0[j] - r0[j]
                gx = r1[j] - r0[j]
                acc += np.sqrt(gy * gy + gx * gx)
        else:
            for j in range(w - 1):
                acc += np.abs(d0[j] - r0[j]) + np.abs(r1[j] - r0[j])
        acc += np.abs(d[w - 1] - r[w - 1])
    else:
        for j in range(w - 1):
            acc += np.abs(r1[j] - r0[j])
    return acc


@jit(parallel=True)
def tv_rows(x, isotropic, out):
    r"""Total variation of every row: ``out[l, i]`` :math:`=\sum_j \|(\nabla x)_{l,i,j}\|`.

    Forward differences, Neumann boundary (the vertical difference of the last row and the
    horizontal one of the last column are zero); :math:`\|\cdot\|_2` if ``isotropic``, else
    :math:`\|\cdot\|_1`.  Each row is summed in float64 on its own, so that the total, summed
    in a fixed order by the caller, does not depend on how rows were spread over threads.

    Parameters
    ----------
    x : ndarray, shape (L, H, W)
    isotropic : bool
    out : ndarray, shape (L, H), float64
    """
    n_bands, h, w = x.shape
    for k in prange(n_bands * h):
        out[k // h, k % h] = _tv_row(x, k // h, k % h, isotropic)


@jit(refcount=False)
def _combine_row(a, u, b, v, c, w, out, l, i):
    """Row ``i`` of band ``l``: ``out = a u + b v + c w``."""
    o, uu, vv, ww = out[l, i], u[l, i], v[l, i], w[l, i]
    for j in range(o.shape[0]):
        o[j] = a * uu[j] + b * vv[j] + c * ww[j]


@jit(parallel=True)
def combine_tv_rows(a, u, b, v, c, w, out, isotropic, rows):
    r"""``out`` :math:`= a u + b v + c w` and its total variation per row, in one pass.

    TwIST's two-step candidate and the TV term of its objective: each row of ``out`` is
    measured while it and the row below are still in cache, instead of reading the cube
    back.  ``rows`` (L, H) float64 receives what :func:`tv_rows` would give for ``out``.
    ``out`` must alias no input.  Bands run in parallel.
    """
    n_bands, h = out.shape[0], out.shape[1]
    for l in prange(n_bands):
        _combine_row(a, u, b, v, c, w, out, l, 0)
        for i in range(1, h):
            _combine_row(a, u, b, v, c, w, out, l, i)
            rows[l, i - 1] = _tv_row(out, l, i - 1, isotropic)
        rows[l, h - 1] = _tv_row(out, l, h - 1, isotropic)
