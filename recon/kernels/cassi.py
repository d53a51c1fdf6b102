r"""CASSI kernels: mask, dispersion shift and view flip of every band in one pass per row.

For the views of :class:`~recon.operators.cassi.CassiOperator` whose geometric map is a
permutation (identity or mirror flips), in the operator's *plan* coordinates (the view's mask
and offsets rewritten so that the view is computed unflipped and its measurement flipped
once, see ``_view_plan``): with :math:`u_l = M \odot f_l` on a row and the band's shift
:math:`\varphi_l = a_l + t_l`,

.. math::

    z[j] = \sum_l (1-t_l)\,u_l[j-a_l] + t_l\,u_l[j-a_l-1], \qquad
    (H^\top y)_l[x] = M[x]\,\bigl((1-t_l)\,z[x+a_l] + t_l\,z[x+a_l+1]\bigr),

then :math:`g` is :math:`z` flipped (rows and/or columns) into the view's measurement, and the
adjoint reads the measurement flipped back.  Every output row depends on one row of the input
only, so rows run in parallel; a row of every band, mask and view stays in L1/L2 cache while
it is used, and the cube is read (forward) or written (adjoint) exactly once.  The two taps of
a sub-pixel shift are written as a gather (each output element reads two input elements) so
that the inner loops vectorise.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from recon.kernels import jit

__all__ = ["forward", "adjoint"]

#: Rows per parallel task: enough to amortise the scratch allocation, few enough to balance.
_ROWS = 8


@jit(refcount=False)
def _view_row(x, masks, k, i, a, c0, c1, sub, acc):
    r"""``acc`` :math:`= \sum_l S_{k,l}(M_k \odot x_l)` on row ``i``: every band of one view.

    One call per view and row (not per band), and no reference counting of the slices (see
    :func:`recon.kernels.jit`): the per-call cost was the larger part of the kernel's time.
    """
    n_bands, h, w = x.shape
    m = masks[k, i]
    m1, m0 = m[1:], m[:w - 1]
    for j in range(acc.shape[0]):
        acc[j] = 0
    for l in range(n_bands):
        xr, al = x[l, i], a[k, l]
        if not sub[k, l]:
            o = acc[al:al + w]
            for j in range(w):
                o[j] += m[j] * xr[j]
            continue
        b0, b1 = c0[k, l], c1[k, l]
        acc[al] += b0 * (m[0] * xr[0])
        o, x1, x0 = acc[al + 1:al + w], xr[1:], xr[:w - 1]
        for j in range(w - 1):
            o[j] += b0 * (m1[j] * x1[j]) + b1 * (m0[j] * x0[j])
        acc[al + w] += b1 * (m[w - 1] * xr[w - 1])


@jit(parallel=True)
def forward(x, masks, a, c0, c1, sub, rowflip, colflip, vid, out):
    r"""Forward model of the permutation views: ``out[vid[k]]`` :math:`= g_k`.

    Parameters
    ----------
    x : ndarray, shape (L, H, W)
        The cube (float32; masks, ``c0``, ``c1`` and ``out`` in the same precision).
    masks : ndarray, shape (K, H, W)
        The views' masks in plan coordinates.
    a : ndarray of int64, shape (K, L)
        Integer parts of the plan offsets.
    c0, c1 : ndarray, shape (K, L)
        Interpolation weights :math:`1-t` and :math:`t`.
    sub : ndarray of bool, shape (K, L)
        Whether :math:`t \ne 0` (a sub-pixel shift; else one tap).
    rowflip, colflip : ndarray of bool, shape (K,)
        Whether the view's measurement is the plan image flipped upside down / left-right.
    vid : ndarray of int64, shape (K,)
        Index of each view in ``out``.
    out : ndarray, shape (K', H, Wm)
        Rows of the views ``vid`` are overwritten; other views are left alone.
    """
    n_bands, h, w = x.shape
    n_views = masks.shape[0]
    wm = out.shape[2]
    n_tasks = (h + _ROWS - 1) // _ROWS
    for task in prange(n_tasks):
        acc = np.empty(wm, dtype=out.dtype)
        for i in range(task * _ROWS, min(h, (task + 1) * _ROWS)):
            for k in range(n_views):
                _view_row(x, masks, k, i, a, c0, c1, sub, acc)
                row = out[vid[k], h - 1 - i if rowflip[k] else i]
                if colflip[k]:
                    row[:] = acc[::-1]
                else:
                    row[:] = acc


@jit(parallel=True)
def adjoint(y, masks, a, c0, c1, sub, rowflip, colflip, vid, add, base, scale, out):
    r"""Adjoint of :func:`forward`, optionally added to a cube: ``out`` :math:`= b + s
    \sum_k H_k^\top y_{\mathrm{vid}[k]}`.

    Parameters as :func:`forward`, with ``y`` of shape (K', H, Wm), and

    add : bool
        Whether to add to ``base``; if not, ``out`` is the plain adjoint and ``base`` and
        ``scale`` are not used (one compiled signature serves both).
    base : ndarray, shape (L, H, W)
        :math:`b`; may be ``out`` itself.
    scale : float
        :math:`s`, in the working precision.
    out : ndarray, shape (L, H, W)
        Overwritten.

    Adding the adjoint to a cube here (a gradient step :math:`f + s H^\top r`) saves the
    solvers a pass that reads the adjoint back and a cube-sized temporary.
    """
    n_bands, h, w = out.shape
    n_views = masks.shape[0]
    wm = y.shape[2]
    n_tasks = (h + _ROWS - 1) // _ROWS
    # With base = out, rows are updated through one slice: LLVM's run-time overlap test fails
    # on two slices of the same memory and the loop would run unvectorised (measured: 2.5x
    # slower in place than out of place).
    inplace = add and base.ctypes.data == out.ctypes.data
    for task in prange(n_tasks):
        z = np.empty((n_views, wm + 1), dtype=out.dtype)
        acc = np.empty(w, dtype=out.dtype)
        for i in range(task * _ROWS, min(h, (task + 1) * _ROWS)):
            for k in range(n_views):
                src = y[vid[k], h - 1 - i if rowflip[k] else i]
                if colflip[k]:
                    z[k, :wm] = src[::-1]
                else:
                    z[k, :wm] = src
                z[k, wm] = 0
            for l in range(n_bands):
                if add and n_views == 1:
                    # One view: the sum is one term, added to the base as it is gathered.
                    m, al, b, ol = masks[0, i], a[0, l], base[l, i], out[l, i]
                    z0, z1 = z[0, al:al + w], z[0, al + 1:al + 1 + w]
                    if sub[0, l] and inplace:
                        b0, b1 = c0[0, l], c1[0, l]
                        for j in range(w):
                            ol[j] += scale * (m[j] * (b0 * z0[j] + b1 * z1[j]))
                    elif sub[0, l]:
                        b0, b1 = c0[0, l], c1[0, l]
                        for j in range(w):
                            ol[j] = b[j] + scale * (m[j] * (b0 * z0[j] + b1 * z1[j]))
                    elif inplace:
                        for j in range(w):
                            ol[j] += scale * (m[j] * z0[j])
                    else:
                        for j in range(w):
                            ol[j] = b[j] + scale * (m[j] * z0[j])
                    continue
                o = acc if add else out[l, i]
                for k in range(n_views):
                    # Slices indexed by the bare loop counter (see _shift_add_row).
                    m, al = masks[k, i], a[k, l]
                    z0, z1 = z[k, al:al + w], z[k, al + 1:al + 1 + w]
                    if sub[k, l]:
                        b0, b1 = c0[k, l], c1[k, l]
                        if k == 0:
                            for j in range(w):
                                o[j] = m[j] * (b0 * z0[j] + b1 * z1[j])
                        else:
                            for j in range(w):
                                o[j] += m[j] * (b0 * z0[j] + b1 * z1[j])
                    elif k == 0:
                        for j in range(w):
                            o[j] = m[j] * z0[j]
                    else:
                        for j in range(w):
                            o[j] += m[j] * z0[j]
                if add and inplace:
                    ol = out[l, i]
                    for j in range(w):
                        ol[j] += scale * acc[j]
                elif add:
                    b, ol = base[l, i], out[l, i]
                    for j in range(w):
                        ol[j] = b[j] + scale * acc[j]
