r"""Kernels of the non-local low-rank denoiser of the subspace's coefficient images
(:mod:`recon.priors.nonlocal_lowrank`).

The denoiser works on ``k`` images ``z`` ``(k, H, W)`` (the coefficient, or "eigen", images of
a spectral subspace) in three passes:

1. :func:`match` -- block matching: for each reference patch (``p × p``, top-left corner on a
   grid), the ``m`` patches of a guide image within ``± radius`` pixels whose sum of squared
   differences to it is smallest (the reference itself first).
2. :func:`group_filters` -- each group's matrix :math:`Y \in \mathbb R^{d\times m}` (column
   ``t``: member ``t``'s patch in the ``k`` images, each image multiplied by its ``scale``, so
   ``d = k p²``), less its mean column :math:`\mu`, is shrunk in its singular values
   :math:`s_i` by the optimal shrinker for the Frobenius loss of Gavish and Donoho (2017) for
   white noise of deviation :math:`\sigma`: with :math:`n = \max(d, m)`,
   :math:`\beta = \min(d, m)/n` and :math:`y_i = s_i/(\sqrt n\,\sigma)`,

   .. math::

       s_i' = \sqrt n\,\sigma\,\frac{\sqrt{(y_i^2 - \beta - 1)^2 - 4\beta}}{y_i}
       \quad\text{if } y_i > 1 + \sqrt\beta, \qquad s_i' = 0 \text{ otherwise}

   (a singular value inside the noise's Marchenko--Pastur bulk is removed, one above it is
   pulled back to its expected clean value), so :math:`\hat X = \mu 1^\top + U S' V^\top =
   \mu 1^\top + (Y - \mu 1^\top)\,B B^\top` with :math:`B = V_r\,\mathrm{diag}
   (s_i'/s_i)^{1/2}` over the :math:`r` values kept (from the eigenvectors of the ``m × m``
   Gram matrix by LAPACK, through Numba's ``np.linalg.eigh``, which at ``m`` = 24 is faster
   than the cyclic Jacobi rotations of :func:`recon.kernels.subspace.jacobi_eigh`:
   ``tools/bench_denoiser.py``): the kernel keeps :math:`B`, :math:`r` and :math:`\mu`.
3. :func:`aggregate` -- every member's estimate, divided back by its image's ``scale``, is added
   into its place; :func:`normalise` divides by the number of estimates of each pixel.

Each pass is parallel over independent work (groups; images in :func:`aggregate`), so the
result does not depend on the number of threads.  Distances and group algebra are float64.
"""

from __future__ import annotations

import numpy as np
from numba import prange

from recon.kernels import jit

__all__ = ["match", "group_filters", "aggregate", "normalise", "shrink"]


@jit(parallel=True)
def match(guide, ref_y, ref_x, patch, radius, idx_y, idx_x):
    r"""Block matching on ``guide`` ``(c, H, W)`` float32 (distances summed over ``c``).

    For reference ``g`` at ``(ref_y[g], ref_x[g])`` (top-left corners, int64): the reference
    itself, then the ``m - 1`` (``idx_y.shape[1]``) other corners within ``± radius``
    (clipped to the image) of smallest squared distance, in increasing order; ties keep the
    scan order (rows, then columns).  The caller makes sure that the window holds at least
    ``m`` corners.

    The reference always leads its group, so that every pixel of a reference patch gets an
    estimate: where more than ``m`` patches tie with it (a flat region of the guide) and were
    scanned before it, the group would otherwise leave it out, and a pixel no group holds
    has no estimate at all.
    """
    c, h, w = guide.shape
    n_ref, m = idx_y.shape
    hmax = h - patch
    wmax = w - patch
    for g in prange(n_ref):
        ry = ref_y[g]
        rx = ref_x[g]
        best = np.full(m, np.inf)
        by = np.zeros(m, np.int64)
        bx = np.zeros(m, np.int64)
        # The reference first, at distance 0: no candidate goes before it (the insertion
        # below moves past strictly larger distances only).
        best[0] = 0.0
        by[0] = ry
        bx[0] = rx
        for y in range(max(0, ry - radius), min(hmax, ry + radius) + 1):
            for x in range(max(0, rx - radius), min(wmax, rx + radius) + 1):
                if y == ry and x == rx:
                    continue
                worst = best[m - 1]
                d = 0.0
                for ch in range(c):
                    for a in range(patch):
                        ra = guide[ch, ry + a]
                        ca = guide[ch, y + a]
                        for b in range(patch):
                            diff = np.float64(ra[rx + b]) - np.float64(ca[x + b])
                            d += diff * diff
                    if d >= worst:
                        break
                if d < worst:
                    pos = m - 1
                    while pos > 0 and best[pos - 1] > d:
                        best[pos] = best[pos - 1]
                        by[pos] = by[pos - 1]
                        bx[pos] = bx[pos - 1]
                        pos -= 1
                    best[pos] = d
                    by[pos] = y
                    bx[pos] = x
        for t in range(m):
            idx_y[g, t] = by[t]
            idx_x[g, t] = bx[t]


@jit()
def shrink(s2, d, m, sigma2):
    r"""The factors :math:`s_i'/s_i` of the optimal singular-value shrinkage (module notes) for
    squared singular values ``s2`` (float64) of a ``d × m`` matrix, noise variance
    ``sigma2``."""
    n = s2.shape[0]
    big = max(d, m)
    beta = min(d, m) / big
    edge = 1.0 + np.sqrt(beta)
    unit2 = big * sigma2
    f = np.zeros(n)
    if unit2 <= 0.0:
        f[:] = 1.0
        return f
    for i in range(n):
        if s2[i] <= 0.0:
            continue
        y2 = s2[i] / unit2
        y = np.sqrt(y2)
        if y > edge:
            t = y2 - beta - 1.0
            f[i] = np.sqrt(max(t * t - 4.0 * beta, 0.0)) / y2
    return f


@jit(parallel=True)
def group_filters(z, scale, idx_y, idx_x, patch, sigma, filt, ranks, means):
    r"""Each group's filter factor :math:`B` (the first ``ranks[g]`` columns of ``filt[g]``,
    ``(m, m)`` float64; :math:`F = B B^\top`), its rank (``ranks`` int64) and its mean column
    (``means[g]``, ``(k p²,)`` float64), module notes; ``z`` ``(k, H, W)`` float32, ``scale``
    ``(k,)`` float64 (each image's factor), ``sigma`` the noise of the scaled images."""
    k = z.shape[0]
    n_ref, m = idx_y.shape
    p2 = patch * patch
    d = k * p2
    sigma2 = sigma * sigma
    for g in prange(n_ref):
        y = np.empty((d, m))
        for t in range(m):
            py = idx_y[g, t]
            px = idx_x[g, t]
            for j in range(k):
                s = scale[j]
                for a in range(patch):
                    row = z[j, py + a]
                    base = j * p2 + a * patch
                    for b in range(patch):
                        y[base + b, t] = row[px + b] * s
        for r in range(d):
            mu = 0.0
            for t in range(m):
                mu += y[r, t]
            mu /= m
            means[g, r] = mu
            for t in range(m):
                y[r, t] -= mu
        gm = np.zeros((m, m))
        for r in range(d):
            for t in range(m):
                yt = y[r, t]
                for u in range(t + 1):
                    gm[t, u] += yt * y[r, u]
        for t in range(m):
            for u in range(t):
                gm[u, t] = gm[t, u]
        w, v = np.linalg.eigh(gm)
        f = shrink(w, d, m, sigma2)
        r = 0
        for i in range(m):
            if f[i] > 0.0:
                root = np.sqrt(f[i])
                for t in range(m):
                    filt[g, t, r] = v[t, i] * root
                r += 1
        ranks[g] = r


@jit(parallel=True)
def aggregate(z, scale, idx_y, idx_x, patch, filt, ranks, means, acc, count):
    r"""Add every group's estimate :math:`\mu 1^\top + (Y - \mu 1^\top) B B^\top`, divided back by
    each image's ``scale``, into ``acc`` ``(k, H, W)`` float64 (zeroed by the caller), and the
    number of estimates of each pixel into ``count`` ``(H, W)`` float64.  Parallel over the
    images (each writes its own plane; image 0 also counts)."""
    k = z.shape[0]
    n_ref, m = idx_y.shape
    p2 = patch * patch
    for j in prange(k):
        s = scale[j]
        col = np.empty((p2, m))
        low = np.empty((p2, m))
        est = np.empty((p2, m))
        for g in range(n_ref):
            r_g = ranks[g]
            for t in range(m):
                py = idx_y[g, t]
                px = idx_x[g, t]
                for a in range(patch):
                    row = z[j, py + a]
                    for b in range(patch):
                        r = a * patch + b
                        col[r, t] = row[px + b] * s - means[g, j * p2 + r]
            for r in range(p2):
                for i in range(r_g):
                    e = 0.0
                    for u in range(m):
                        e += col[r, u] * filt[g, u, i]
                    low[r, i] = e
                mu = means[g, j * p2 + r]
                for t in range(m):
                    e = 0.0
                    for i in range(r_g):
                        e += low[r, i] * filt[g, t, i]
                    est[r, t] = (e + mu) / s
            for t in range(m):
                py = idx_y[g, t]
                px = idx_x[g, t]
                for a in range(patch):
                    for b in range(patch):
                        acc[j, py + a, px + b] += est[a * patch + b, t]
                if j == 0:
                    for a in range(patch):
                        for b in range(patch):
                            count[py + a, px + b] += 1.0


@jit(parallel=True)
def normalise(acc, count, out):
    """``out = acc / count`` per image (``out`` float32 ``(k, H, W)``)."""
    k, h, w = acc.shape
    for j in prange(k):
        for i in range(h):
            for x in range(w):
                out[j, i, x] = acc[j, i, x] / count[i, x]
