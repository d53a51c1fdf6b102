r"""The pixel integral: each pixel's footprint integrated exactly over mask cells and texels.

A pixel :math:`p` of view :math:`k` records in band :math:`l` (interval :math:`[\lambda_0,
\lambda_1]`) the mean, over its area and the band, of what it sees through the optics
(:mod:`sim.transport.maps`):

.. math:: E_l(p) = \tau_l(p)\; \frac{1}{\lambda_1 - \lambda_0} \int_{\lambda_0}^{\lambda_1}
          \frac{1}{|p|} \int_p M_k\big(m(s, \lambda)\big)\, f_l\big(\alpha_k + \beta_k\,
          m(s, \lambda)\big)\; ds\, d\lambda,

with :math:`m` the mask-plane point a sensor point sees, :math:`M_k` the mask restricted to the
cells of view :math:`k`'s code region (0/1), :math:`f_l` the scene's band (piecewise constant
on texels) and :math:`\tau_l` the band's throughput at the pixel (vignetting and losses,
:func:`throughput_image`).  Within a pixel the map :math:`m` is affine and axis-aligned (its
shear and rotation across one pixel are below 10⁻³ px), so the footprint at one wavelength is a
rectangle :math:`[a, b] \times [y_0, y_1]` in mask coordinates, and as λ runs through the band
its x-edges move along the prism's smooth dispersion curve.  The integral then separates:

1. *Rows* (stage 1).  Along the footprint's height, :math:`g(x) = \frac{1}{y_1 - y_0}
   \int_{y_0}^{y_1} M_k f\, dy` is piecewise constant on the *partition* of the mask's x axis by
   the mask-cell and texel column boundaries (:func:`partition`); each piece of
   :math:`[y_0, y_1]` between mask-row and texel-row boundaries contributes its length exactly.
2. *Columns and wavelength* (stage 2).  With :math:`G = \int g`, :math:`GG = \int G` and
   :math:`GGG = \int GG` (exact: piecewise linear, quadratic and cubic), the mean of
   :math:`G` over a band at an edge that moves from :math:`x_0` through :math:`x_m` to
   :math:`x_1` is a closed form in :math:`GG` and :math:`GGG` at the path's two ends
   (:func:`panel_mean`): the path is the one whose band parameter :math:`t \in [0, 1]` is
   quadratic in :math:`x` through :math:`(x_0, 0)`, :math:`(x_m, \tfrac12)`, :math:`(x_1, 1)`,

   .. math:: \overline{G} = \int_{x_0}^{x_1} G(x)\, t'(x)\, dx, \qquad
             t'(x) = \frac{1}{D} + \kappa\,(2x - x_0 - x_1), \quad D = x_1 - x_0,

   so that :math:`\overline{G} = \Delta GG / D + \kappa\,\big(2 (D\, GG(x_1) - \Delta GGG)
   - D\, \Delta GG\big)`.  A band is cut into :math:`S` equal *panels* (wavelength nodes
   at their ends and middles, :func:`sim.transport.maps.band_nodes`; one on the designs shipped), and

   .. math:: E_l(p) = \tau_l(p)\, \frac{1}{S} \sum_{s=1}^{S}
             \frac{\overline{G}_s(b) - \overline{G}_s(a)}{\bar w_s},

   with :math:`\bar w_s` the footprint's mean width over panel :math:`s` (Simpson's rule over
   its three nodes; the edges of neighbouring pixels are shared).  The prism's dispersion is
   a smooth curve in λ, which a quadratic follows across a whole band to 2·10⁻⁴ px on
   ``paper`` (9·10⁻⁴ on ``small``) where straight lines between nodes needed 2–5 nodes a band
   for 3·10⁻³: the edges are located at the panels' ends only.

Nothing is sampled: the result is the integral itself, up to the maps' fit (~10⁻³ px) and the
quadratic path of an edge across a panel (≤ ``tolerance_px`` of :func:`sim.transport.maps.band_nodes`).
:func:`band_forward` and its exact adjoint :func:`band_adjoint` (a dot test checks it) are
Numba kernels for one view and one band (the exact operator's); :mod:`sim.transport.view_integral` takes
every band of a view in one pass (the frames').
:math:`G`, :math:`GG` and :math:`GGG` are float64: they accumulate over a whole row (~2000
pieces on ``paper``) and the differences taken between neighbouring edges would lose every
digit in float32.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["disc_fraction", "throughput_images", "node_weights", "band_mean", "partition",
           "panel_mean", "band_forward", "band_adjoint", "RowGeometry", "COARSE_PX", "STILL",
           "STRAIGHT",
           # The kernels' pieces that the view integral (sim.transport.view_integral) shares.
           "CONTRACT", "SIXTH", "cell_open", "max_pieces", "mean_width", "panel_mean_d",
           "panel_nodes", "poly_row", "row_gaps", "row_span"]


# ------------------------------------------------------------------------------ vignetting
@njit(cache=True, nogil=True)
def _triangle_disc(ax, ay, bx, by):
    """Signed area of the unit disc ∩ triangle (0, a, b)."""
    dx, dy = bx - ax, by - ay
    qa = dx * dx + dy * dy
    qb = ax * dx + ay * dy
    qc = ax * ax + ay * ay - 1.0
    ts = np.empty(4)
    n = 0
    ts[n] = 0.0
    n += 1
    if qa > 0.0:
        disc = qb * qb - qa * qc
        if disc > 0.0:
            sq = math.sqrt(disc)
            for t in ((-qb - sq) / qa, (-qb + sq) / qa):
                if 0.0 < t < 1.0:
                    ts[n] = t
                    n += 1
    ts[n] = 1.0
    n += 1
    total = 0.0
    for i in range(n - 1):
        px, py = ax + ts[i] * dx, ay + ts[i] * dy
        qx, qy = ax + ts[i + 1] * dx, ay + ts[i + 1] * dy
        mx, my = 0.5 * (px + qx), 0.5 * (py + qy)
        cross = px * qy - py * qx
        if mx * mx + my * my <= 1.0:
            total += 0.5 * cross
        else:
            total += 0.5 * math.atan2(cross, px * qx + py * qy)
    return total


@njit(cache=True, nogil=True)
def _disc_fraction(bx, by, a00, a10, a01, a11, half):
    """Fraction of the unit disc u whose image b + A u lies in the square [-half, half]²."""
    n0 = math.hypot(a00, a01)     # reach of row 0 of A over the disc
    n1 = math.hypot(a10, a11)
    if abs(bx) + n0 <= half and abs(by) + n1 <= half:
        return 1.0
    if abs(bx) - n0 >= half or abs(by) - n1 >= half:
        return 0.0
    det = a00 * a11 - a01 * a10
    if abs(det) < 1e-300:
        return 0.0
    # The square's corners pulled back into disc coordinates: a parallelogram, counter-clockwise
    # when det > 0.
    cx = np.array([-half, half, half, -half])
    cy = np.array([-half, -half, half, half])
    ux = np.empty(4)
    uy = np.empty(4)
    for i in range(4):
        rx, ry = cx[i] - bx, cy[i] - by
        ux[i] = (a11 * rx - a01 * ry) / det
        uy[i] = (-a10 * rx + a00 * ry) / det
    area = 0.0
    for i in range(4):
        j = (i + 1) % 4
        area += _triangle_disc(ux[i], uy[i], ux[j], uy[j])
    return min(max(abs(area) / math.pi, 0.0), 1.0)


@njit(cache=True, nogil=True)
def _disc_fraction_grid(ex, half, out):
    h, w = out.shape
    for i in range(h):
        for j in range(w):
            out[i, j] = _disc_fraction(ex[0, i, j], ex[1, i, j], ex[2, i, j], ex[3, i, j],
                                       ex[4, i, j], ex[5, i, j], half)


def disc_fraction(b, a, half: float) -> np.ndarray:
    """Fraction of the unit disc :math:`u` with :math:`b + A u` in :math:`[-h, h]^2`.

    Parameters
    ----------
    b : array_like (2, ...)
        Image of the disc's centre.
    a : array_like (2, 2, ...)
        The affine map's matrix (``a[:, 0]``, ``a[:, 1]``: images of the disc's unit vectors).
    half : float
        Half the square's side (the tube's exit).

    Exact: the square pulled back into disc coordinates is a parallelogram, and the disc ∩
    polygon area is a sum of disc ∩ triangle areas over its edges.
    """
    b = np.asarray(b, np.float64)
    a = np.asarray(a, np.float64)
    shape = b.shape[1:]
    ex = np.stack([b[0], b[1], a[0, 0], a[1, 0], a[0, 1], a[1, 1]]).reshape(6, 1, -1)
    out = np.empty((1, ex.shape[2]))
    _disc_fraction_grid(np.ascontiguousarray(ex), float(half), out)
    return out.reshape(shape)


#: Spacing (px) of the coarse grid on which the smooth throughput T is interpolated.
COARSE_PX = 8


@njit(cache=True, nogil=True)
def _bilinear(coarse, step, h, w, out):
    """Bilinear interpolation of ``coarse`` (values at pixel centres 0.5 + step·i) to (h, w)."""
    nr, nc = coarse.shape
    for i in range(h):
        y = i / step
        iy = min(int(y), nr - 2)
        fy = y - iy
        for j in range(w):
            x = j / step
            ix = min(int(x), nc - 2)
            fx = x - ix
            out[i, j] = ((1 - fy) * ((1 - fx) * coarse[iy, ix] + fx * coarse[iy, ix + 1])
                         + fy * ((1 - fx) * coarse[iy + 1, ix] + fx * coarse[iy + 1, ix + 1]))


@njit(cache=True, nogil=True)
def _exact_tau(pr, pc, coef_t, coef_e, wts, half, todo, out):
    """τ = Σ_j w_j V_j T_j at the pixels flagged in ``todo`` (polynomials folded per row)."""
    h, w = todo.shape
    n, D = coef_t.shape[0], coef_t.shape[1]
    rt = np.zeros((n, D))
    re = np.zeros((n, 6, D))
    for i in range(h):
        any_ = False
        for j in range(w):
            if todo[i, j]:
                any_ = True
                break
        if not any_:
            continue
        for k in range(n):
            for b in range(D):
                acc = 0.0
                for a in range(D):
                    acc += pr[i, a] * coef_t[k, a, b]
                rt[k, b] = acc
                for q in range(6):
                    acc = 0.0
                    for a in range(D):
                        acc += pr[i, a] * coef_e[k, q, a, b]
                    re[k, q, b] = acc
        for j in range(w):
            if not todo[i, j]:
                continue
            tot = 0.0
            for k in range(n):
                t = 0.0
                for b in range(D):
                    t += rt[k, b] * pc[j, b]
                ex = np.zeros(6)
                for q in range(6):
                    for b in range(D):
                        ex[q] += re[k, q, b] * pc[j, b]
                v = _disc_fraction(ex[0], ex[1], ex[2], ex[3], ex[4], ex[5], half)
                tot += wts[k] * v * max(t, 0.0)
            out[i, j] = tot


def node_weights(n: int) -> np.ndarray:
    """Weights of a band's ``n`` = 2S + 1 equally spaced nodes for its mean: Simpson's rule on
    each of its S panels (1, 4, 1)/6, averaged (one node: 1)."""
    if n == 1:
        return np.ones(1)
    if n < 3 or n % 2 == 0:
        raise ValueError(f"a band has one node or 2S + 1 (panels' ends and middles), not {n}")
    w = np.ones(n)
    w[1::2] = 4.0
    w[2:-1:2] = 2.0
    return w / w.sum()


def band_mean(values, nodes) -> np.ndarray:
    """The band's mean of a quantity traced at its ``nodes`` (``values`` indexed by node along
    its first axis, e.g. a map's coefficients), by :func:`node_weights`."""
    nodes = [int(j) for j in nodes]
    return np.tensordot(node_weights(len(nodes)), np.asarray(values)[nodes], 1)


def throughput_images(maps, k: int, band_nodes) -> np.ndarray:
    r"""Every band's throughput τ at the pixel centres of view ``k``: (L, h, w) float32.

    τ is the mean over the band's wavelength nodes (:func:`node_weights`) of :math:`V\,T`
    (:mod:`sim.transport.maps`).  T is smooth (a low-order polynomial) and is interpolated bilinearly
    from a grid every :data:`COARSE_PX` pixels (error < 10⁻⁵ of T); V is 1 away from the
    stop's shadow, and wherever a coarse cell may be partly vignetted at any node of the band
    (its corners' disc images within the cell's variation of the square's edge) τ is evaluated
    exactly at every pixel.
    """
    from sim.transport.maps import evaluate, legendre_values

    r0, c0, h, w = (int(v) for v in maps.rects[k])
    rc, sr, cc, sc = maps.norm[k]
    D = maps.degree
    pr = legendre_values((np.arange(h) + r0 + 0.5 - rc) / sr, D)
    pc = legendre_values((np.arange(w) + c0 + 0.5 - cc) / sc, D)
    s = COARSE_PX
    gr = np.arange(0, h - 1 + s, s, dtype=np.float64)
    gc = np.arange(0, w - 1 + s, s, dtype=np.float64)
    gpr = legendre_values((gr + r0 + 0.5 - rc) / sr, D)
    gpc = legendre_values((gc + c0 + 0.5 - cc) / sc, D)
    used = sorted({int(j) for b in band_nodes for j in b})
    t_coarse = {j: evaluate(maps.throughput[k, j], gpr, gpc) for j in used}
    clean = {}
    stop = maps.has_stop and np.all(np.isfinite(maps.exit[k]))
    for j in used:
        if not stop:
            clean[j] = np.ones((gr.size - 1, gc.size - 1), bool)
            continue
        e = [evaluate(maps.exit[k, j, q], gpr, gpc) for q in range(6)]
        slack = maps.stop_half - np.maximum(np.abs(e[0]) + np.hypot(e[2], e[4]),
                                            np.abs(e[1]) + np.hypot(e[3], e[5]))
        # A cell is clean when its corners clear the square by more than the slack changes
        # between neighbouring corners (the maps are smooth over 8 px).
        var = max(float(np.abs(np.diff(slack, axis=0)).max(initial=0.0)),
                  float(np.abs(np.diff(slack, axis=1)).max(initial=0.0)))
        ok = slack > 2.0 * var
        clean[j] = ok[:-1, :-1] & ok[1:, :-1] & ok[:-1, 1:] & ok[1:, 1:]
    out = np.empty((len(band_nodes), h, w), np.float32)
    fine = np.empty((h, w))
    for l, nodes in enumerate(band_nodes):
        nodes = [int(j) for j in nodes]
        wts = node_weights(len(nodes))
        tavg = sum(wt * np.maximum(t_coarse[j], 0.0) for j, wt in zip(nodes, wts))
        _bilinear(tavg, float(s), h, w, fine)
        cell_ok = np.logical_and.reduce([clean[j] for j in nodes])
        todo = ~np.repeat(np.repeat(cell_ok, s, axis=0), s, axis=1)[:h, :w]
        if todo.any():
            _exact_tau(pr, pc, np.ascontiguousarray(maps.throughput[k, nodes]),
                       np.ascontiguousarray(np.nan_to_num(maps.exit[k, nodes])), wts,
                       maps.stop_half, np.ascontiguousarray(todo), fine)
        out[l] = fine
    return out


# ------------------------------------------------------------------------------ partition
def partition(relay, width: int, x_range, n_cells: int):
    """The mask's x axis cut at every mask-cell and texel column boundary.

    Parameters
    ----------
    relay : (4,) α_x, β_x, α_y, β_y
        Texel column of mask column coordinate m: floor((α_x + β_x m) · width).
    width : int
        The cube's columns.
    x_range : (lo, hi)
        The mask-x span to cover.
    n_cells : int
        Mask cells per side.

    Returns
    -------
    xb : (n+1,) float64 breakpoints; mcol, tcol : (n,) int64 the mask and texel column of each
    piece (−1 outside the mask or the cube).
    """
    ax, bx = float(relay[0]), float(relay[1])
    lo, hi = float(x_range[0]), float(x_range[1])
    cells = np.arange(math.floor(lo), math.ceil(hi) + 1, dtype=np.float64)
    t_lo, t_hi = sorted(((ax + bx * lo) * width, (ax + bx * hi) * width))
    ts = np.arange(math.floor(t_lo), math.ceil(t_hi) + 1, dtype=np.float64)
    tex = (ts / width - ax) / bx
    xb = np.unique(np.concatenate([cells, tex, [lo, hi]]))
    xb = xb[(xb >= lo) & (xb <= hi)]
    mid = 0.5 * (xb[1:] + xb[:-1])
    mcol = np.floor(mid).astype(np.int64)
    mcol[(mcol < 0) | (mcol >= n_cells)] = -1
    tcol = np.floor((ax + bx * mid) * width).astype(np.int64)
    tcol[(tcol < 0) | (tcol >= width)] = -1
    return xb, mcol, tcol


# ------------------------------------------------------------------------------ row geometry
class RowGeometry:
    """What the kernels need of one view and one band, as plain arrays.

    ``cx`` (n, D, D): the mask-x polynomial at each of the band's nodes; ``cy`` (D, D): the
    mask-y polynomial averaged over them (:func:`node_weights`); ``pre``/``prc`` (h+1, D)/(h, D):
    row polynomials at the pixel rows' edges and centres; ``pce``/``pcc`` (w+1, D)/(w, D):
    column polynomials at the pixel columns' edges and centres (``pceT``/``pccT``: the same,
    transposed).
    """

    def __init__(self, maps, k: int, nodes):
        from sim.transport.maps import legendre_values

        r0, c0, h, w = (int(v) for v in maps.rects[k])
        rc, sr, cc, sc = maps.norm[k]
        D = maps.degree
        self.h, self.w = h, w
        self.pre = legendre_values((np.arange(h + 1) + r0 - rc) / sr, D)
        self.prc = legendre_values((np.arange(h) + r0 + 0.5 - rc) / sr, D)
        self.pce = legendre_values((np.arange(w + 1) + c0 - cc) / sc, D)
        self.pcc = legendre_values((np.arange(w) + c0 + 0.5 - cc) / sc, D)
        # Column-major copies for the kernels' inner loops along a row.
        self.pceT = np.ascontiguousarray(self.pce.T)
        self.pccT = np.ascontiguousarray(self.pcc.T)
        self.cx = np.ascontiguousarray(maps.mask[k, list(nodes), 0])
        self.cy = np.ascontiguousarray(band_mean(maps.mask[k, :, 1], nodes))

    def x_range(self, margin: float = 2.0):
        """The mask-x span of the view's pixel edges at the band's nodes, widened by ``margin``."""
        from sim.transport.maps import evaluate

        xs = np.stack([evaluate(c, self.prc[[0, -1]], self.pce[[0, -1]]) for c in self.cx])
        return float(xs.min()) - margin, float(xs.max()) + margin


@njit(cache=True, nogil=True, inline="always")
def _fold(rv, c, b):
    """``Σ_a rv[a] c[a, b]``: column ``b`` of a polynomial folded with one row's values."""
    s = 0.0
    for a in range(c.shape[0]):
        s += rv[a] * c[a, b]
    return s


@njit(cache=True, nogil=True, inline="always")
def poly_row(rv, c, colT, out):
    r"""``out[e] = Σ_b (Σ_a rv[a] c[a, b]) P_b(u_e)``: a Legendre polynomial folded with one
    row's values ``rv`` first, then evaluated along the row, where ``colT[b, e]`` holds
    :math:`P_b(u_e)` (as :class:`RowGeometry`'s ``pceT`` and ``pccT``; ``colT[1]`` is
    :math:`u` itself).

    The maps' degree 5 (D = 6) is evaluated by Horner's rule in the monomial basis,

    .. math:: \sum_b c_b P_b(u) = m_0 + u(m_1 + u(m_2 + u(m_3 + u(m_4 + u\, m_5)))),

    with :math:`m_0 = c_0 - c_2/2 + 3c_4/8`, :math:`m_1 = c_1 - 3c_3/2 + 15c_5/8`,
    :math:`m_2 = 3c_2/2 - 15c_4/4`, :math:`m_3 = 5c_3/2 - 35c_5/4`, :math:`m_4 = 35c_4/8`,
    :math:`m_5 = 63c_5/8`: one load per column instead of six (|u| ≤ 1 and the coefficients
    of degree ≥ 2 are small, so the round-off is that of the sum, ~10⁻¹³ mask units).  Any
    other degree sums the tabulated values."""
    D = c.shape[0]
    if D == 6:
        c0, c1, c2 = _fold(rv, c, 0), _fold(rv, c, 1), _fold(rv, c, 2)
        c3, c4, c5 = _fold(rv, c, 3), _fold(rv, c, 4), _fold(rv, c, 5)
        m0 = c0 - 0.5 * c2 + 0.375 * c4
        m1 = c1 - 1.5 * c3 + 1.875 * c5
        m2 = 1.5 * c2 - 3.75 * c4
        m3 = 2.5 * c3 - 8.75 * c5
        m4 = 4.375 * c4
        m5 = 7.875 * c5
        for e in range(out.shape[0]):
            u = colT[1, e]
            out[e] = m0 + u * (m1 + u * (m2 + u * (m3 + u * (m4 + u * m5))))
        return
    for e in range(out.shape[0]):
        out[e] = 0.0
    for b in range(D):
        cb = _fold(rv, c, b)
        for e in range(out.shape[0]):
            out[e] += cb * colT[b, e]


@njit(cache=True, nogil=True)
def _row_edges(r, prc, pre, pceT, pccT, cx, cy, X, Y0, Y1, XC):
    """Mask-x of every pixel edge at every node (X, (n, w+1)), the footprints' y bounds (Y0, Y1)
    and the pixels' centres in mask-x at the band's middle node (XC)."""
    n = cx.shape[0]
    w = pccT.shape[1]
    for j in range(n):
        poly_row(prc[r], cx[j], pceT, X[j])
    poly_row(pre[r], cy, pccT, Y0)
    poly_row(pre[r + 1], cy, pccT, Y1)
    for c in range(w):
        if Y1[c] < Y0[c]:
            Y0[c], Y1[c] = Y1[c], Y0[c]
    jm = n // 2
    for c in range(w):
        if n % 2 == 1:
            XC[c] = 0.5 * (X[jm, c] + X[jm, c + 1])
        else:
            XC[c] = 0.25 * (X[jm - 1, c] + X[jm - 1, c + 1] + X[jm, c] + X[jm, c + 1])


#: The kernels' fast-math: fused multiply-adds (one rounding where a product and a sum had two)
#: and nothing else, so every sum keeps its order and NaN and infinity keep their meaning.
CONTRACT = frozenset({"contract"})

#: 1/6, multiplied where the kernels' sums take a sixth: a division by a constant stays a
#: division without reassociation (CONTRACT), and a vector division costs several multiplies.
SIXTH = 1.0 / 6.0

#: Boundaries of a row's gaps closer than this (texels, or mask units) are one line.
SLIVER = 1e-7


@njit(cache=True, nogil=True, inline="always")
def row_gaps(ylo, yhi, ay, by, H, n_mask, pmr, ptr_, bounds):
    """Cut [ylo, yhi] at the mask-row and texel-row boundaries: each gap's mask row and texel
    row (−1 outside the mask or the cube) and its edges (``bounds``).  Returns the number of
    gaps (at most ``pmr.shape[0]``)."""
    pmax = pmr.shape[0]
    k = 0
    y = ylo
    bounds[0] = ylo
    while y < yhi and k < pmax:
        nb = math.floor(y) + 1.0
        t = (ay + by * y) * H
        # The next texel boundary past y.  A gap that ended on a texel boundary puts y on it
        # within round-off, either side: that boundary is behind, not next (else a 10⁻⁹ sliver
        # gap would follow every texel row, each costing a gap's work for nothing).
        if by > 0.0:
            n = math.floor(t) + 1.0
            if n - t < SLIVER:
                n += 1.0
        else:
            n = math.ceil(t) - 1.0
            if t - n < SLIVER:
                n -= 1.0
        yt = (n / H - ay) / by
        # A texel boundary within round-off of a mask boundary is the same line.
        ye = max(nb, yt) if abs(nb - yt) < SLIVER else min(nb, yt)
        ye = min(ye, yhi)
        if ye <= y:
            ye = min(y + 1e-9, yhi)
        ym = 0.5 * (y + ye)
        mr = int(math.floor(ym))
        tr = int(math.floor((ay + by * ym) * H))
        pmr[k] = mr if 0 <= mr < n_mask else -1
        ptr_[k] = tr if 0 <= tr < H else -1
        k += 1
        bounds[k] = ye
        y = ye
    return k


@njit(cache=True, nogil=True)
def _row_pieces(Y0, Y1, ay, by, H, n_mask, plen, pmr, ptr_, bounds, pfirst, plast):
    """Cut the row's y band at its mask-row and texel-row boundaries (lines shared by all its
    pixels, :func:`row_gaps`), and every pixel's share of its own span [Y0, Y1] in each gap,
    and the first and last gap it meets (``pfirst``, ``plast``; its shares are 0 outside
    them); ``bounds`` (pmax + 1): scratch for the gaps' edges.  Returns the number of gaps."""
    w = Y0.shape[0]
    ylo = Y0[0]
    yhi = Y1[0]
    for c in range(w):
        ylo = min(ylo, Y0[c])
        yhi = max(yhi, Y1[c])
    k = row_gaps(ylo, yhi, ay, by, H, n_mask, pmr, ptr_, bounds)
    for c in range(w):
        y0, y1 = Y0[c], Y1[c]
        inv = 1.0 / (y1 - y0) if y1 > y0 else 0.0
        first, last = k, -1
        for g in range(k):
            a = max(bounds[g], y0)
            b = min(bounds[g + 1], y1)
            v = (b - a) * inv if b > a else 0.0
            plen[c, g] = v
            if v != 0.0:
                first = min(first, g)
                last = g
        pfirst[c] = first
        plast[c] = last
    return k


@njit(cache=True, nogil=True, inline="always")
def row_span(X, xb):
    """(lo, hi): the pieces of the partition ``xb`` that the row's edges ``X`` (n, w+1) reach
    at any node (hi < lo: none)."""
    w = X.shape[1] - 1
    xmin = X[0, 0]
    xmax = X[0, w]
    for j in range(X.shape[0]):
        xmin = min(xmin, X[j, 0])
        xmax = max(xmax, X[j, w])
    lo = max(np.searchsorted(xb, xmin, side="right") - 1, 0)
    hi = min(np.searchsorted(xb, xmax, side="left"), xb.shape[0] - 2)
    return lo, hi


def max_pieces(relay, height: int) -> int:
    """Most pieces a pixel's y span can be cut into (texel rows it meets, a mask-row boundary
    and rounding), for the kernels' scratch arrays."""
    return 2 * int(math.ceil(abs(float(relay[3])) * height)) + 8


@njit(cache=True, nogil=True, inline="always")
def _bracket(x, XC, IXC, c):
    """(c, t): x lies between pixel centres XC[c] and XC[c+1], a fraction t of the way (c from
    0 to w − 2, t clamped to [0, 1]; IXC[c] = 1/(XC[c+1] − XC[c])); ``c`` starts the walk."""
    w = XC.shape[0]
    if w < 2:
        return 0, 0.0
    c = min(max(c, 0), w - 2)
    while c < w - 2 and XC[c + 1] <= x:
        c += 1
    while c > 0 and XC[c] > x:
        c -= 1
    t = (x - XC[c]) * IXC[c]
    return c, min(max(t, 0.0), 1.0)


@njit(cache=True, nogil=True, inline="always")
def _locate(x, xb, lo, hi, ptr):
    """Index k in [lo, hi] with xb[k] <= x < xb[k+1] (hi + 1: past the end; lo − 1: before),
    walked from ``ptr`` (the previous edge's piece: edges advance by a piece or two)."""
    if x < xb[lo]:
        return lo - 1
    if x >= xb[hi + 1]:
        return hi + 1
    if ptr < lo or ptr > hi:
        ptr = lo
    while ptr > lo and xb[ptr] > x:
        ptr -= 1
    while ptr < hi and xb[ptr + 1] <= x:
        ptr += 1
    return ptr


#: Below this |x₁ − x₀| (mask units) an edge does not move across a panel: G at its midpoint.
STILL = 1e-9
#: Below this |x₁ − x₀| (mask units) a panel's path is taken straight (κ = 0): its sag, ~D²
#: times the dispersion's relative curvature, is then far below the maps' round-off.
STRAIGHT = 1e-3


@njit(cache=True, nogil=True, inline="always")
def cell_open(code, view, mr, tr, mc):
    """Whether the gap of mask row ``mr`` and texel row ``tr`` (−1: none) lets the scene
    through mask column ``mc`` into ``view``: a cell of the view's code, over the scene."""
    return mr >= 0 and tr >= 0 and code[mr, mc] == view


@njit(cache=True, nogil=True, inline="always")
def panel_nodes(s, n):
    """Panel ``s`` of a band with ``n`` nodes: the places of its first, middle and last node
    among them (all 0 for a monochromatic band's one node)."""
    return 2 * s, min(2 * s + 1, n - 1), min(2 * s + 2, n - 1)


@njit(cache=True, nogil=True, inline="always")
def _panel_factors(x0, xm, x1):
    r"""(:math:`1/D`, :math:`\kappa`) of the path through :math:`(x_0, 0), (x_m, \frac12),
    (x_1, 1)` whose :math:`t` is quadratic in :math:`x`,
    :math:`t = (x - x_0)/D + \kappa (x - x_0)(x - x_1)`, :math:`D = x_1 - x_0`:

    .. math:: \kappa = \frac{D/2 - a}{D\, a\, (a - D)}, \quad a = x_m - x_0,

    both from one reciprocal :math:`r = 1/(D a (a - D))` (:math:`1/D = a (a - D)\, r`), written
    with selects so that a loop over edges stays vectorised: every band and edge takes one
    division here, not two.  :math:`\kappa = 0` where :math:`|D| \le` :data:`STRAIGHT`."""
    D = x1 - x0
    a = xm - x0
    bent = abs(D) > STRAIGHT
    q = a * (a - D)
    r = 1.0 / (D * q if bent else D)
    return (q * r if bent else r), ((0.5 * D - a) * r if bent else 0.0)


@njit(cache=True, nogil=True, inline="always")
def panel_mean(x0, xm, x1, GG0, GG1, GGG0, GGG1):
    r"""Mean over a panel of :math:`G` at an edge on the path through :math:`x_0, x_m, x_1`
    (module notes), from :math:`GG` and :math:`GGG` at its ends (:math:`|x_1 - x_0|` >
    :data:`STILL`):

    .. math:: \overline{G} = \frac{\Delta GG}{D} + \kappa\,\big(2 (D\, GG_1 - \Delta GGG)
              - D\, \Delta GG\big),

    the integral of :math:`G\, t'` written so that the large running integrals cancel first.
    """
    return panel_mean_d(x0, xm, x1, GG1 - GG0, GG1, GGG1 - GGG0)


@njit(cache=True, nogil=True, inline="always")
def panel_mean_d(x0, xm, x1, dGG, GG1, dGGG):
    """:func:`panel_mean` from the differences ΔGG, ΔGGG and GG₁."""
    inv_d, kap = _panel_factors(x0, xm, x1)
    D = x1 - x0
    return dGG * inv_d + kap * (2.0 * (D * GG1 - dGGG) - D * dGG)


@njit(cache=True, nogil=True, error_model="numpy", fastmath=set(CONTRACT))
def _kernel(f, code, view, relay, H, W, xb, mcol, tcol, prc, pre, pceT, pccT, cx, cy, tau,
            out, fbar, adjoint, pmax):
    h = prc.shape[0]
    w = pccT.shape[1]
    n = cx.shape[0]
    npan = max((n - 1) // 2, 1)
    inv_n = 1.0 / npan
    nint = mcol.shape[0]
    ay, by = relay[2], relay[3]
    X = np.empty((n, w + 1))
    Y0 = np.empty(w)
    Y1 = np.empty(w)
    XC = np.empty(w)
    g = np.zeros(nint)
    G = np.zeros(nint + 1)
    GG = np.zeros(nint + 1)
    GGG = np.zeros(nint + 1)
    ag = np.zeros(nint)
    aG = np.zeros(nint + 1)
    aGG = np.zeros(nint + 1)
    aGGG = np.zeros(nint + 1)
    GN = np.zeros((n, w + 1))   # GG of every edge at the panels' ends (forward)
    GN3 = np.zeros((n, w + 1))  # and GGG
    an = np.empty(n)            # the adjoint at one edge: of GG
    an3 = np.empty(n)           # and of GGG
    ptrs = np.zeros(n, np.int64)
    mG = np.empty((npan, w + 1))
    amG = np.zeros((npan, w + 1))
    accv = np.empty(w)
    plen = np.zeros((w + 1, pmax))
    bounds = np.empty(pmax + 1)
    IXC = np.zeros(w)
    pmr = np.zeros(pmax, np.int64)
    ptr_ = np.zeros(pmax, np.int64)
    pfirst = np.zeros(w, np.int64)
    plast = np.zeros(w, np.int64)
    pa = np.zeros(w, np.int64)
    pb = np.zeros(w, np.int64)
    n_mask = code.shape[0]
    for r in range(h):
        _row_edges(r, prc, pre, pceT, pccT, cx, cy, X, Y0, Y1, XC)
        ng = _row_pieces(Y0, Y1, ay, by, H, n_mask, plen, pmr, ptr_, bounds, pfirst, plast)
        # A piece between centres c and c + 1 takes its y shares from both pixels: only the
        # gaps either of them meets can weigh (2-4 of a row's 4-6).
        for c in range(w - 1):
            IXC[c] = 1.0 / (XC[c + 1] - XC[c])
            pa[c] = min(pfirst[c], pfirst[c + 1])
            pb[c] = max(plast[c], plast[c + 1]) + 1
        if w < 2:
            pa[0] = 0
            pb[0] = ng
        lo, hi = row_span(X, xb)
        if hi < lo:
            continue
        if not adjoint:
            # Stage 1: the rows' mean of M f on every piece, then its integrals G, GG, GGG.
            G[lo] = 0.0
            GG[lo] = 0.0
            GGG[lo] = 0.0
            c = 0
            for i in range(lo, hi + 1):
                acc = 0.0
                mc = mcol[i]
                tc = tcol[i]
                if mc >= 0 and tc >= 0:
                    # The y span at this piece: linear between the neighbouring pixels' centres
                    # (it moves by ~1e-4 px from pixel to pixel).
                    xm = 0.5 * (xb[i] + xb[i + 1])
                    c, t = _bracket(xm, XC, IXC, c)
                    for p in range(pa[c], pb[c]):
                        mr = pmr[p]
                        tr = ptr_[p]
                        if cell_open(code, view, mr, tr, mc):
                            a = plen[c, p]
                            acc += (a + t * (plen[c + 1, p] - a)) * f[tr, tc]
                g[i] = acc
                L = xb[i + 1] - xb[i]
                GGG[i + 1] = GGG[i] + L * (GG[i] + L * (0.5 * G[i] + L * acc * SIXTH))
                GG[i + 1] = GG[i] + G[i] * L + 0.5 * acc * L * L
                G[i + 1] = G[i] + acc * L
            # Stage 2: every edge's GG and GGG at the panels' ends (one walk along the row per
            # node: an edge moves on by a piece or two), then its mean G over each panel.
            for j in range(0, n, 2):
                ptr = lo
                for e in range(w + 1):
                    k = _locate(X[j, e], xb, lo, hi, ptr)
                    ptr = max(k, lo)
                    GN[j, e], GN3[j, e] = _ggg(X[j, e], k, xb, g, G, GG, GGG, lo, hi)
            for s in range(npan):
                j0, jm, j1 = panel_nodes(s, n)
                ptr = lo
                for e in range(w + 1):
                    x0, x1 = X[j0, e], X[j1, e]
                    if n > 1 and abs(x1 - x0) > STILL:
                        mG[s, e] = panel_mean(x0, X[jm, e], x1, GN[j0, e], GN[j1, e],
                                              GN3[j0, e], GN3[j1, e])
                    else:
                        # The edge stands still (a monochromatic band has one node): G there.
                        xm = 0.5 * (x0 + x1)
                        k = _locate(xm, xb, lo, hi, ptr)
                        ptr = max(k, lo)
                        mG[s, e] = _g1(xm, k, xb, g, G, lo, hi)
            for c in range(w):
                accv[c] = 0.0
            for s in range(npan):
                j0, jm, j1 = panel_nodes(s, n)
                for c in range(w):
                    wid = mean_width(X, j0, jm, j1, c)
                    accv[c] += (mG[s, c + 1] - mG[s, c]) / wid
            for c in range(w):
                out[r, c] = tau[r, c] * accv[c] * inv_n
        else:
            for i in range(lo, hi + 1):
                ag[i] = 0.0
            for i in range(lo, hi + 2):
                aG[i] = 0.0
                aGG[i] = 0.0
                aGGG[i] = 0.0
            for s in range(npan):
                for e in range(w + 1):
                    amG[s, e] = 0.0
            for s in range(npan):
                j0, jm, j1 = panel_nodes(s, n)
                for c in range(w):
                    eb = out[r, c] * tau[r, c] * inv_n
                    wid = mean_width(X, j0, jm, j1, c)
                    amG[s, c + 1] += eb / wid
                    amG[s, c] -= eb / wid
            for j in range(n):
                ptrs[j] = lo
            for e in range(w + 1):
                for j in range(n):
                    an[j] = 0.0
                    an3[j] = 0.0
                for s in range(npan):
                    a = amG[s, e]
                    if a == 0.0:
                        continue
                    j0, jm, j1 = panel_nodes(s, n)
                    x0, x1 = X[j0, e], X[j1, e]
                    if n > 1 and abs(x1 - x0) > STILL:
                        # panel_mean = (1/D + κD) GG₁ + (κD − 1/D) GG₀ − 2κ (GGG₁ − GGG₀).
                        D = x1 - x0
                        inv_d, kap = _panel_factors(x0, X[jm, e], x1)
                        an[j1] += a * (inv_d + kap * D)
                        an[j0] += a * (kap * D - inv_d)
                        an3[j1] -= a * 2.0 * kap
                        an3[j0] += a * 2.0 * kap
                    else:
                        xm = 0.5 * (x0 + x1)
                        _g1_adj(xm, _locate(xm, xb, lo, hi, ptrs[jm]), a, xb, ag, aG, lo, hi)
                for j in range(0, n, 2):
                    k = _locate(X[j, e], xb, lo, hi, ptrs[j])
                    ptrs[j] = max(k, lo)
                    aa = an[j]
                    a3 = an3[j]
                    if (aa == 0.0 and a3 == 0.0) or k < lo:
                        continue
                    # ∂(GG, GGG)(x)/∂(GGG_k, GG_k, G_k, g_k): (0, 1, d, d²/2) and
                    # (1, d, d²/2, d³/6), d = x − xb_k (past the row: g = 0).
                    kk = min(k, hi + 1)
                    dd = X[j, e] - xb[kk]
                    aGGG[kk] += a3
                    aGG[kk] += aa + a3 * dd
                    aG[kk] += dd * (aa + 0.5 * a3 * dd)
                    if k <= hi:
                        ag[k] += dd * dd * (0.5 * aa + a3 * dd * SIXTH)
            # The integrals' recursions run backwards.
            for i in range(hi, lo - 1, -1):
                L = xb[i + 1] - xb[i]
                ag[i] += L * (aG[i + 1] + L * (0.5 * aGG[i + 1] + L * aGGG[i + 1] * SIXTH))
                aG[i] += aG[i + 1] + L * (aGG[i + 1] + 0.5 * L * aGGG[i + 1])
                aGG[i] += aGG[i + 1] + aGGG[i + 1] * L
                aGGG[i] += aGGG[i + 1]
            c = 0
            for i in range(lo, hi + 1):
                mc = mcol[i]
                tc = tcol[i]
                ai = ag[i]
                if ai != 0.0 and mc >= 0 and tc >= 0:
                    xm = 0.5 * (xb[i] + xb[i + 1])
                    c, t = _bracket(xm, XC, IXC, c)
                    for p in range(pa[c], pb[c]):
                        mr = pmr[p]
                        tr = ptr_[p]
                        if cell_open(code, view, mr, tr, mc):
                            a = plen[c, p]
                            fbar[tr, tc] += ai * (a + t * (plen[c + 1, p] - a))


@njit(cache=True, nogil=True, inline="always")
def mean_width(X, j0, jm, j1, c):
    """Pixel ``c``'s footprint width over a panel: Simpson's rule over its three nodes."""
    return ((X[j0, c + 1] - X[j0, c]) + 4.0 * (X[jm, c + 1] - X[jm, c])
            + (X[j1, c + 1] - X[j1, c])) * SIXTH


@njit(cache=True, nogil=True, inline="always")
def _ggg(x, k, xb, g, G, GG, GGG, lo, hi):
    """(GG, GGG) at ``x`` in piece ``k`` (0 before the row's pieces; past them g = 0)."""
    if k < lo:
        return 0.0, 0.0
    if k > hi:
        d = x - xb[hi + 1]
        return GG[hi + 1] + d * G[hi + 1], GGG[hi + 1] + d * (GG[hi + 1] + 0.5 * d * G[hi + 1])
    d = x - xb[k]
    return (GG[k] + d * (G[k] + 0.5 * d * g[k]),
            GGG[k] + d * (GG[k] + d * (0.5 * G[k] + d * g[k] * SIXTH)))


@njit(cache=True, nogil=True, inline="always")
def _g1(x, k, xb, g, G, lo, hi):
    if k < lo:
        return 0.0
    if k > hi:
        return G[hi + 1]
    return G[k] + (x - xb[k]) * g[k]


@njit(cache=True, nogil=True, inline="always")
def _g1_adj(x, k, a, xb, ag, aG, lo, hi):
    if k < lo:
        return
    if k > hi:
        aG[hi + 1] += a
        return
    aG[k] += a
    ag[k] += a * (x - xb[k])


def band_forward(f, code, view, relay, part, geom: RowGeometry, tau, out=None):
    """Irradiance (h, w) float32 of one view in one band (module notes).

    ``f`` (H, W) float32: the scene's band; ``code`` (n, n) int8: the view owning each open
    mask cell (−1 chrome); ``part``: :func:`partition` for the view and the cube's width.
    """
    f = np.ascontiguousarray(f, np.float32)
    if out is None:
        out = np.zeros((geom.h, geom.w), np.float32)
    xb, mcol, tcol = part
    _kernel(f, code, int(view), np.asarray(relay, np.float64), f.shape[0], f.shape[1], xb, mcol,
            tcol, geom.prc, geom.pre, geom.pceT, geom.pccT, geom.cx, geom.cy, tau, out,
            np.zeros((1, 1), np.float64), False, max_pieces(relay, f.shape[0]))
    return out


def band_adjoint(e, code, view, relay, part, geom: RowGeometry, tau, shape, fbar=None):
    """The adjoint of :func:`band_forward`: (H, W) float64 accumulated into ``fbar``."""
    e = np.ascontiguousarray(e, np.float32)
    if fbar is None:
        fbar = np.zeros(shape, np.float64)
    xb, mcol, tcol = part
    _kernel(np.zeros((1, 1), np.float32), code, int(view), np.asarray(relay, np.float64),
            int(shape[0]), int(shape[1]), xb, mcol, tcol, geom.prc, geom.pre, geom.pceT,
            geom.pccT, geom.cx, geom.cy, tau, e, fbar, True, max_pieces(relay, shape[0]))
    return fbar
