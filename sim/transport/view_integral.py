r"""The pixel integral of every band of one view in one pass over its rows.

:mod:`sim.transport.pixel_integral` integrates one view in one band (:func:`~sim.transport.pixel_integral.
band_forward`, with its exact adjoint for the exact operator).  A frame needs every band, and
most of what a band's pass computes does not depend on the band: the row's cut into y gaps at
mask-row and texel-row boundaries, which mask cells are open, the scene's texel under each
piece, and where each pixel edge lies among the pieces at each wavelength node.  This kernel
computes those once per row and carries all bands along (the same maths as
:mod:`sim.transport.pixel_integral`; its notes give it):

1. *Rows* (stage 1).  For each piece of the row's x partition and each band :math:`l`, the
   mean over the footprint's height :math:`[y_0^l, y_1^l]` of :math:`M_k f_l`, summed over
   the gaps :math:`[b_g, b_{g+1}]` that the piece's footprint meets,

   .. math:: g_l(x) = \sum_g \frac{\big(\min(b_{g+1}, y_1^l) - \max(b_g, y_0^l)\big)_+}
             {y_1^l - y_0^l}\, M_k(g, x)\, f_l(g, x),

   the footprint's bounds at the piece taken from knots every :data:`KNOT` mask units (on the
   line between the pixel centres, then linear between knots: a bound moves by ~10⁻⁴ px from
   pixel to pixel; beyond a band's end pixels, their bounds).  The inner loop runs over the
   bands, the scene being stored band-last; each band's :math:`g` and its running integrals
   :math:`G`, :math:`GG`, :math:`GGG` at the piece's start go straight into a band-major
   table.  A piece whose footprint meets no cell open to the view has :math:`g = 0` in every
   band: it is only carried through the running integrals.
2. *Edges* (stage 2).  Every pixel edge is located among the pieces at every panel's ends
   (a node at a band's end serves both bands; the panels' middles only shape the path): in a
   block's first row by a bucket table (buckets narrower than half the texel pitch and a
   quarter mask unit hold at most three breakpoints, so three comparisons added replace a
   walk whose branches mispredict), in the next rows by stepping from the piece it was in a
   row above (an edge moves by a small fraction of a piece from row to row: the step is
   almost always none), as the first band that reads the node there reads the table.  Each
   band then takes its mean of :math:`G` over each panel from :math:`GG` and :math:`GGG` at
   the panel's ends (:func:`sim.transport.pixel_integral.panel_mean`).  The table is indexed by piece,
   not from the row's first piece, so an edge's piece is its row of the table: no clamp and
   no offset an edge, where the edges are in order along the row (every design's are,
   :meth:`sim.transport.exact.Transport.edges_ordered`; elsewhere each row checks them).

Each row's lower pixel edge is the next row's upper one, so the footprints' y bounds are
evaluated once per edge in a block of rows, not twice.

The result equals :func:`~sim.transport.pixel_integral.band_forward` band by band to a few 10⁻⁵ of the
view's peak (the footprints' y bounds are interpolated where that kernel interpolates the
shares; both are exact to the maps' 10⁻⁴ px; ``tests/sim/transport/test_view_integral.py``); what
it costs against the band-by-band kernel is measured by ``tools/bench_transport.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit, uint64

from sim.transport.pixel_integral import (CONTRACT, SIXTH, STILL, cell_open, max_pieces,
                                          mean_width, panel_mean_d, panel_nodes, poly_row,
                                          row_gaps, row_span)

__all__ = ["KNOT", "Buckets", "buckets", "view_forward", "kernel_address"]

#: Mask units between the knots at which every band's footprint bounds are interpolated.
KNOT = 2.0


class Buckets:
    """A bucket table for locating points among the breakpoints ``xb`` of a partition.

    ``start[b]`` is how many breakpoints lie at or below bucket ``b``'s left end
    ``x0 + b / inv`` (less round-off); at most three more lie up to its right end, and ``xbp``
    is ``xb`` followed by +∞, so that ``start[b] + Σ_{i<3} [xbp[start[b] + i] <= x]`` counts
    the breakpoints at or below any ``x`` in the bucket.
    """

    def __init__(self, xbp, start, x0, inv):
        self.xbp, self.start, self.x0, self.inv = xbp, start, float(x0), float(inv)


def buckets(xb, texel_pitch: float) -> Buckets:
    """:class:`Buckets` for the breakpoints ``xb`` (sorted) of a partition whose texel columns
    are ``texel_pitch`` mask units wide."""
    xb = np.asarray(xb, np.float64)
    width = min(0.25, 0.5 * abs(float(texel_pitch)))
    while True:
        x0 = float(xb[0]) - width     # one bucket before the first breakpoint: start[0] = 0
        n = int((float(xb[-1]) - x0) / width) + 3
        # A point's bucket is computed in floating point and may be the next one when the
        # point lies within round-off below a bucket's end: each bucket's start leaves out
        # the breakpoints within ``eps`` below its left end, and counts them by comparison.
        eps = 1e-7 * width
        left = x0 + width * np.arange(n + 1)
        start = np.searchsorted(xb, left - eps, side="right")
        inside = np.searchsorted(xb, left[1:] + eps, side="right") - start[:-1]
        if inside.max(initial=0) <= 3:
            break
        width *= 0.5                  # breakpoints bunched closer than the pitches suggest
        if width < 1e-6:
            raise ValueError("the partition's breakpoints are too bunched for a bucket table")
    xbp = np.concatenate([xb, np.full(4, np.inf)])
    return Buckets(xbp, start[:-1].astype(np.int64), x0, 1.0 / width)


@njit(cache=True, nogil=True, inline="always")
def _count(x, xbp, start, x0, inv):
    """How many breakpoints lie at or below ``x`` (:class:`Buckets`)."""
    b = min(max(int((x - x0) * inv), 0), start.shape[0] - 1)
    p = start[b]
    return p + (xbp[p] <= x) + (xbp[p + 1] <= x) + (xbp[p + 2] <= x)


@njit(cache=True, nogil=True, inline="always")
def _table_ggg(Tl, p, d):
    """(GG, GGG) at ``d`` past the start of a band's table row ``p`` (g, G, GG, GGG there),
    as :func:`sim.transport.pixel_integral._ggg` evaluates its own arrays."""
    return (Tl[p, 2] + d * (Tl[p, 1] + 0.5 * d * Tl[p, 0]),
            Tl[p, 3] + d * (Tl[p, 2] + d * (0.5 * Tl[p, 1] + d * Tl[p, 0] * SIXTH)))


@njit(cache=True, nogil=True, inline="always")
def _span(YE0, YE1, l, c):
    """Band ``l``'s footprint bounds (low, high) at pixel ``c`` from its two edges' bounds."""
    a = YE0[l, c]
    b = YE1[l, c]
    return (a if a < b else b), (b if a < b else a)


@njit(cache=True, nogil=True, inline="always")
def _extremes(Y, rows, mn, mx):
    """(min, max) of the rows ``rows`` of ``Y`` (an edge row's bounds over the bands, the
    pixel edges at some nodes), column by column over the rows first (into the scratch
    ``mn``, ``mx``), then over the columns: one chain of comparisons, not one a row (a chain
    runs at its latency).  Selects, not min/max: Numba's NaN-aware min and max keep the loop
    from vectorising (the values are polynomials of finite coefficients: never NaN)."""
    w = Y.shape[1]
    for c in range(w):
        mn[c] = Y[rows[0], c]
        mx[c] = Y[rows[0], c]
    for i in range(1, rows.shape[0]):
        j = rows[i]
        for c in range(w):
            v = Y[j, c]
            mn[c] = v if v < mn[c] else mn[c]
            mx[c] = v if v > mx[c] else mx[c]
    lo = np.inf
    hi = -np.inf
    for c in range(w):
        lo = min(lo, mn[c])
        hi = max(hi, mx[c])
    return lo, hi


@njit(cache=True, nogil=True, inline="always")
def _within(X, ends, mn, mx, a, b):
    """Whether every edge ``X[j]`` of the nodes ``ends`` lies in [a, b) (:func:`_extremes`
    with the scratch ``mn``, ``mx``)."""
    lo, hi = _extremes(X, ends, mn, mx)
    return lo >= a and hi < b


@njit(cache=True, nogil=True, inline="always")
def _step(u, x, xlim):
    """The index ``u`` of ``xlim`` (the breakpoints between −∞ and +∞) with
    ``xlim[u] <= x < xlim[u + 1]``, stepped from ``u`` (unsigned)."""
    one = uint64(1)
    while xlim[u + one] <= x:
        u += one
    while xlim[u] > x:
        u -= one
    return u


@njit(cache=True, nogil=True, inline="always")
def _locate(X, P, xlim):
    """Each edge ``X[e]``'s row of the table, ``P[e]``, stepped from the row above's."""
    for e in range(X.shape[0]):
        P[e] = np.int64(_step(uint64(P[e]), X[e], xlim))


@njit(cache=True, nogil=True, error_model="numpy", fastmath=set(CONTRACT))
def _kernel(f, code, view, relay, H, xb, mcol, tcol, xbp, start, x0, inv, prc, pre, pceT,
            pccT, cxn, cyl, boff, bnodes, ends, bands, tau, out, r_start, r_end, pmax, stats,
            ordered):
    w = pccT.shape[1]
    N = cxn.shape[0]
    L = cyl.shape[0]
    nint = mcol.shape[0]
    ay, by = relay[2], relay[3]
    X = np.empty((N, w + 1))
    YE0 = np.empty((L, w))
    YE1 = np.empty((L, w))
    XC = np.empty(w)
    ymn = np.empty(w)
    ymx = np.empty(w)
    e_lo = 0.0      # the extremes of the upper pixel edge's bounds (the row above's lower)
    e_hi = 0.0
    nk = int((xb[nint] - xb[0]) / KNOT) + 3
    yk0 = np.empty((nk, L))
    yk1 = np.empty((nk, L))
    gk_lo = np.zeros(nk, np.int64)
    gk_hi = np.zeros(nk, np.int64)
    kmin = np.empty(nk)
    kmax = np.empty(nk)
    xc_first = np.empty(L)
    xc_last = np.empty(L)
    y0 = np.empty(L)
    y1 = np.empty(L)
    inv_h = np.empty(L)
    acc = np.empty(L)
    G = np.zeros(L)
    GG = np.zeros(L)
    GGG = np.zeros(L)
    # The table's row p + 1 holds piece p's start; row 0 a piece before the partition's.
    T = np.empty((L, nint + 3, 4))
    # Each edge's row of the table (xlim's index of its piece's start).
    PA = np.zeros((N, w + 1), np.int32)
    # The breakpoints between −∞ and +∞: piece p spans [xlim[p + 1], xlim[p + 2]).
    xlim = np.empty(nint + 4)
    xlim[0] = -np.inf
    xlim[1:nint + 2] = xb
    xlim[nint + 2:] = np.inf
    # The start of each row of the table, finite: a row of zeros before the partition's first
    # piece is evaluated at a finite offset (inf · 0 would be NaN).
    xs = xlim.copy()
    xs[0] = 0.0
    # The row (of the block) in which each node's edges were last located.
    stamp = np.full(N, -1, np.int64)
    counted = False
    band_rows = np.arange(L)
    emn = np.empty(w + 1)
    emx = np.empty(w + 1)
    # Walked indices (a knot's pixel, an edge's piece) are unsigned: Numba tests a signed index
    # for wrap-around (a negative one counts from the end) at every read, and LLVM cannot drop
    # the test for an index it cannot bound.  Unsigned arithmetic stays unsigned only with
    # unsigned operands (with a signed one Numba goes to float), hence these constants.
    one = uint64(1)
    zero = uint64(0)
    wm1 = uint64(max(w - 1, 0))
    wm2 = uint64(max(w - 2, 0))
    mG = np.empty(w + 1)
    dGG = np.empty(w + 1)
    GG1 = np.empty(w + 1)
    dG3 = np.empty(w + 1)
    accv = np.empty(w)
    bounds = np.empty(pmax + 1)
    pmr = np.zeros(pmax, np.int64)
    ptr_ = np.zeros(pmax, np.int64)
    n_mask = code.shape[0]
    for r in range(r_start, r_end):
        # The pixel edges' mask x at every node, every band's footprint bounds in mask y at
        # the pixel centres, and the row's y gaps (shared by every band and pixel).
        for j in range(N):
            poly_row(prc[r], cxn[j], pceT, X[j])
        # A row's lower pixel edge is the next row's upper one: each edge's bounds, and
        # their extremes, are evaluated once per block of rows.
        if r == r_start:
            for l in range(L):
                poly_row(pre[r], cyl[l], pccT, YE1[l])
            e_lo, e_hi = _extremes(YE1, band_rows, ymn, ymx)
        YE0, YE1 = YE1, YE0
        for l in range(L):
            poly_row(pre[r + 1], cyl[l], pccT, YE1[l])
        n_lo, n_hi = _extremes(YE1, band_rows, ymn, ymx)
        ylo = min(e_lo, n_lo)
        yhi = max(e_hi, n_hi)
        e_lo, e_hi = n_lo, n_hi
        ng = row_gaps(ylo, yhi, ay, by, H, n_mask, pmr, ptr_, bounds)
        if ng > 0 and bounds[ng] < yhi:
            stats[1] += 1             # more gaps than the scratch holds (a caller's error)
        stats[0] = max(stats[0], ng)
        lo, hi = row_span(X, xb)
        if hi < lo:
            # No piece under the row: dark.  (Every other row writes every pixel at its end.)
            for l in range(L):
                for c in range(w):
                    out[l, r, c] = 0.0
            continue
        # Knots along mask x: every band's bounds there, and the gaps any band meets between
        # two knots.  They count from the partition's start, not the row's, so that a band's
        # bounds do not depend on which other bands are integrated with it.
        xk = xb[0]
        qa = int((xb[lo] - xk) / KNOT)
        nq = min(int((xb[hi + 1] - xk) / KNOT) + 2, nk)
        for l in range(L):
            n = boff[l + 1] - boff[l]
            jm = bnodes[boff[l] + n // 2]          # the band's middle node (n is odd)
            for c in range(w):
                XC[c] = 0.5 * (X[jm, c] + X[jm, c + 1])
            # Knots carry the line through the end pixels' centres beyond them (not clamped),
            # so that interpolating between knots keeps it; the clamp to the end pixels'
            # bounds is applied piece by piece, where the per-band kernel applies it.  A knot's
            # bracket is walked from the last (knots are ~3 px apart) and its fraction taken
            # with one division a knot, not one a pixel.
            c = uint64(0)
            for q in range(qa, nq):
                xq = xk + q * KNOT
                while c < wm2 and XC[c + one] <= xq:
                    c += one
                while c > zero and XC[c] > xq:
                    c -= one
                c1 = min(c + one, wm1)
                t = (xq - XC[c]) / (XC[c1] - XC[c]) if c1 > c else 0.0
                lo0, hi0 = _span(YE0, YE1, l, c)
                lo1, hi1 = _span(YE0, YE1, l, c1)
                yk0[q, l] = lo0 + t * (lo1 - lo0)
                yk1[q, l] = hi0 + t * (hi1 - hi0)
            xc_first[l] = XC[0]
            xc_last[l] = XC[w - 1]
        xf_max = -np.inf
        xl_min = np.inf
        e0lo = np.inf
        e0hi = -np.inf
        e1lo = np.inf
        e1hi = -np.inf
        for l in range(L):
            xf_max = max(xf_max, xc_first[l])
            xl_min = min(xl_min, xc_last[l])
            lo0, hi0 = _span(YE0, YE1, l, 0)
            lo1, hi1 = _span(YE0, YE1, l, w - 1)
            e0lo = min(e0lo, lo0)
            e0hi = max(e0hi, hi0)
            e1lo = min(e1lo, lo1)
            e1hi = max(e1hi, hi1)
        # Each knot's y extremes over the bands, then the gaps met between two knots.  Near
        # the row's ends every band's end-pixel bounds are included, not only those of the
        # bands whose end lies there: a gap too many adds zeros, not a different sum.
        for q in range(qa, nq):
            a = np.inf
            b = -np.inf
            for l in range(L):
                a = min(a, yk0[q, l])
                b = max(b, yk1[q, l])
            kmin[q] = a
            kmax[q] = b
        for q in range(qa, nq - 1):
            xa = xk + q * KNOT
            a = min(kmin[q], kmin[q + 1])
            b = max(kmax[q], kmax[q + 1])
            if xa <= xf_max:
                a = min(a, e0lo)
                b = max(b, e0hi)
            if xa + KNOT >= xl_min:
                a = min(a, e1lo)
                b = max(b, e1hi)
            first = ng
            last = -1
            for p in range(ng):
                if bounds[p + 1] > a and bounds[p] < b:
                    first = min(first, p)
                    last = p
            gk_lo[q] = first
            gk_hi[q] = last + 1
        # Stage 1: every band's g on every piece, and its running G, GG and GGG, written
        # straight into the band-major table that stage 2 reads (T[l, i + 1] = g, G, GG, GGG
        # at piece i's start).
        for l in range(L):
            G[l] = 0.0
            GG[l] = 0.0
            GGG[l] = 0.0
        for i in range(lo, hi + 1):
            mc = mcol[i]
            tc = tcol[i]
            lit = False
            if mc >= 0 and tc >= 0:
                xm = 0.5 * (xb[i] + xb[i + 1])
                u = (xm - xk) / KNOT
                q = min(max(int(u), qa), nq - 2)
                t = u - q
                # A piece whose footprint meets no cell open to this view adds nothing: its
                # bands' bounds and heights are not needed (two pieces in five on `paper`).
                for p in range(gk_lo[q], gk_hi[q]):
                    if cell_open(code, view, pmr[p], ptr_[p], mc):
                        lit = True
                        break
                if lit:
                    for l in range(L):
                        acc[l] = 0.0
                    for l in range(L):
                        y0[l] = yk0[q, l] + t * (yk0[q + 1, l] - yk0[q, l])
                        y1[l] = yk1[q, l] + t * (yk1[q + 1, l] - yk1[q, l])
                    if xm <= xf_max or xm >= xl_min:
                        # Beyond a band's end pixel centres its bounds are the end pixel's.
                        for l in range(L):
                            if xm <= xc_first[l]:
                                y0[l], y1[l] = _span(YE0, YE1, l, 0)
                            if xm >= xc_last[l]:
                                y0[l], y1[l] = _span(YE0, YE1, l, w - 1)
                    for l in range(L):
                        inv_h[l] = 1.0 / (y1[l] - y0[l]) if y1[l] > y0[l] else 0.0
                    for p in range(gk_lo[q], gk_hi[q]):
                        mr = pmr[p]
                        tr = ptr_[p]
                        if cell_open(code, view, mr, tr, mc):
                            ba = bounds[p]
                            bb = bounds[p + 1]
                            for l in range(L):
                                s = min(bb, y1[l]) - max(ba, y0[l])
                                acc[l] += max(s, 0.0) * inv_h[l] * f[tr, tc, l]
            Lp = xb[i + 1] - xb[i]
            k = i + 1
            if lit:
                for l in range(L):
                    Gl = G[l]
                    GGl = GG[l]
                    GGGl = GGG[l]
                    T[l, k, 0] = acc[l]
                    T[l, k, 1] = Gl
                    T[l, k, 2] = GGl
                    T[l, k, 3] = GGGl
                    GGG[l] = GGGl + Lp * (GGl + Lp * (0.5 * Gl + Lp * acc[l] * SIXTH))
                    GG[l] = GGl + Gl * Lp + 0.5 * acc[l] * Lp * Lp
                    G[l] = Gl + acc[l] * Lp
            else:
                # g = 0: the same sums with its terms left out (adding 0 changes no bit).
                for l in range(L):
                    Gl = G[l]
                    GGl = GG[l]
                    GGGl = GGG[l]
                    T[l, k, 0] = 0.0
                    T[l, k, 1] = Gl
                    T[l, k, 2] = GGl
                    T[l, k, 3] = GGGl
                    GGG[l] = GGGl + Lp * (GGl + Lp * (0.5 * Gl))
                    GG[l] = GGl + Gl * Lp
        # Every edge is located at the panels' ends, as its row of the table.  An edge moves
        # by a small fraction of a piece from one row to the next, so in a block's first row
        # it is counted by the bucket table and after it found by stepping from where it was
        # in the row above (almost always no step, a branch that predicts well), in stage 2.
        if not counted:
            for j in ends:
                for e in range(w + 1):
                    PA[j, e] = _count(X[j, e], xbp, start, x0, inv)
                stamp[j] = r
            counted = True
        # The table's ends: row lo before the row's pieces (all 0), row hi + 2 past them (the
        # integrals carried on, g = 0).  Edges in order along the row lie between them; where
        # a row's may not (``ordered`` false), each is located now and clamped to them.
        top = hi + 2
        for l in range(L):
            T[l, lo, 0] = 0.0
            T[l, lo, 1] = 0.0
            T[l, lo, 2] = 0.0
            T[l, lo, 3] = 0.0
            T[l, top, 0] = 0.0
            T[l, top, 1] = G[l]
            T[l, top, 2] = GG[l]
            T[l, top, 3] = GGG[l]
        if not ordered and not _within(X, ends, emn, emx, xlim[lo], xlim[top + 1]):
            stats[2] += 1
            for j in ends:
                if stamp[j] != r:
                    _locate(X[j], PA[j], xlim)
                    stamp[j] = r
                for e in range(w + 1):
                    PA[j, e] = min(max(PA[j, e], lo), top)
        # Stage 2, band by band and panel by panel: GG and GGG at every edge at the panel's
        # ends, its mean G over the panel, the pixels' sums.
        for l in range(L):
            b0 = boff[l]
            n = boff[l + 1] - b0
            npan = max((n - 1) // 2, 1)
            bl = bands[l]
            if npan > 1:
                for c in range(w):
                    accv[c] = 0.0
            for s in range(npan):
                i0, im, i1 = panel_nodes(s, n)
                j0, jm, j1 = bnodes[b0 + i0], bnodes[b0 + im], bnodes[b0 + i1]
                if stamp[j0] != r:
                    _locate(X[j0], PA[j0], xlim)
                    stamp[j0] = r
                # The panel's far end is located in the loop that reads the table there (it
                # is the next band's near end): one pass over its edges, not two.
                walk = stamp[j1] != r
                stamp[j1] = r
                # The gathers from the table (in a loop of their own: the divisions after
                # them vectorise), then each edge's mean over the panel.  The loop is written
                # twice, with the far end's step and without (LLVM left the test in one
                # loop), over the band's rows of the table and the nodes' rows taken once
                # (fewer addresses kept: 2-3 % of a view).
                Tl = T[l]
                Xa = X[j0]
                Xe = X[j1]
                Pa = PA[j0]
                Pe = PA[j1]
                if walk:
                    for e in range(w + 1):
                        xa = Xa[e]
                        xe = Xe[e]
                        pa = uint64(Pa[e])
                        pe = uint64(Pe[e])
                        pe = _step(pe, xe, xlim)
                        Pe[e] = np.int64(pe)
                        GGa, G3a = _table_ggg(Tl, pa, xa - xs[pa])
                        GGe, G3e = _table_ggg(Tl, pe, xe - xs[pe])
                        dGG[e] = GGe - GGa
                        GG1[e] = GGe
                        dG3[e] = G3e - G3a
                else:
                    for e in range(w + 1):
                        xa = Xa[e]
                        xe = Xe[e]
                        pa = uint64(Pa[e])
                        pe = uint64(Pe[e])
                        GGa, G3a = _table_ggg(Tl, pa, xa - xs[pa])
                        GGe, G3e = _table_ggg(Tl, pe, xe - xs[pe])
                        dGG[e] = GGe - GGa
                        GG1[e] = GGe
                        dG3[e] = G3e - G3a
                n_still = 0
                for e in range(w + 1):
                    mG[e] = panel_mean_d(X[j0, e], X[jm, e], X[j1, e], dGG[e], GG1[e], dG3[e])
                    n_still += not abs(X[j1, e] - X[j0, e]) > STILL
                if n_still:
                    # An edge that stands still (a monochromatic band's): G at the edge.
                    for e in range(w + 1):
                        if not abs(X[j1, e] - X[j0, e]) > STILL:
                            xm = 0.5 * (X[j0, e] + X[j1, e])
                            p = min(max(_count(xm, xbp, start, x0, inv), lo), top)
                            mG[e] = T[l, p, 1] + (xm - xs[p]) * T[l, p, 0]
                if npan == 1:
                    # One panel: the pixels' sums written straight out (0 + v: the same bits
                    # as summed into zeros).
                    for c in range(w):
                        v = 0.0 + (mG[c + 1] - mG[c]) / mean_width(X, j0, jm, j1, c)
                        out[l, r, c] = tau[bl, r, c] * v
                else:
                    for c in range(w):
                        accv[c] += (mG[c + 1] - mG[c]) / mean_width(X, j0, jm, j1, c)
            if npan > 1:
                inv_n = 1.0 / npan
                for c in range(w):
                    out[l, r, c] = tau[bl, r, c] * accv[c] * inv_n


def view_forward(f, code, view, relay, part, bucket: Buckets, geom, cxn, cyl, band_nodes,
                 bands, tau, out, rows=None, ordered: bool = False, report=None):
    """Irradiance (La, h, w) float32 of one view in the bands ``bands`` (rows ``rows``).

    Parameters
    ----------
    f : (H, W, La) float32
        The scene's bands ``bands``, band-last.
    code : (n, n) int8
        The view owning each open mask cell (−1 chrome).
    view : int
    relay : (4,)
        The view's mask → scene map (:func:`sim.transport.pixel_integral.partition`).
    part : (xb, mcol, tcol)
        :func:`sim.transport.pixel_integral.partition` of the view for the cube's width.
    bucket : Buckets
        :func:`buckets` of ``xb``.
    geom : sim.transport.pixel_integral.RowGeometry
        Of the view (its row and column polynomials; its band's own fields are not read).
    cxn : (N, D, D)
        The mask-x polynomial at the nodes the bands use.
    cyl : (La, D, D)
        Each band's mask-y polynomial averaged over its nodes
        (:func:`sim.transport.pixel_integral.node_weights`).
    band_nodes : list of int arrays
        Each band's nodes, as indices into ``cxn``.
    bands : (La,) int
        Each band's index into ``tau``.
    tau : (L, h, w) float32
        The view's throughput in every band.
    out : (La, ≥ h, ≥ w) float32
        Written at ``rows`` (all rows by default), in its first ``w`` columns.
    ordered : bool
        The caller knows that every node's pixel edges are in order along every row
        (:meth:`sim.transport.exact.Transport.edges_ordered`), so no row checks that its edges lie
        among its pieces.
    report : dict, optional
        Given, its ``"rows clamped"`` is set to how many rows had edges beyond their pieces
        (clamped to them).
    """
    xb, mcol, tcol = part
    f = np.asarray(f)
    if f.dtype != np.float32 or not f.flags.c_contiguous or f.ndim != 3:
        raise ValueError("f must be a C-contiguous (H, W, L) float32 array")
    r0, r1 = (0, geom.h) if rows is None else (int(rows[0]), int(rows[1]))
    boff = np.concatenate([[0], np.cumsum([len(b) for b in band_nodes])]).astype(np.int64)
    bnodes = np.concatenate([np.asarray(b, np.int64) for b in band_nodes])
    # The nodes where edges are located: every panel's ends (a band's nodes at even places).
    ends = np.unique(np.concatenate([np.asarray(b, np.int64)[::2] for b in band_nodes]))
    stats = np.zeros(3, np.int64)
    pmax = max_pieces(relay, f.shape[0]) + 16
    _kernel(f, code, int(view), np.asarray(relay, np.float64), f.shape[0], xb, mcol, tcol,
            bucket.xbp, bucket.start, bucket.x0, bucket.inv, geom.prc, geom.pre, geom.pceT,
            geom.pccT, np.ascontiguousarray(cxn, np.float64),
            np.ascontiguousarray(cyl, np.float64), boff, bnodes, ends,
            np.asarray(bands, np.int64), tau, out, r0, r1, pmax, stats, bool(ordered))
    if report is not None:
        report["rows clamped"] = int(stats[2])
    if stats[1]:
        raise RuntimeError(f"{int(stats[1])} rows have more y gaps than the {pmax} expected")
    return out


def kernel_address() -> int:
    """Where the compiled kernel of :func:`view_forward` starts in memory (its machine code,
    for a profiler that maps samples to its loops); :func:`view_forward` must have run once in
    this process."""
    if not _kernel.signatures:
        raise RuntimeError("the view kernel is not compiled yet: run view_forward first")
    compiled = _kernel.overloads[_kernel.signatures[0]]
    return compiled.library.get_pointer_to_function(compiled.fndesc.llvm_func_name)
