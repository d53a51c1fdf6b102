"""The pixel integral's pieces against plain references: the vignetting area, the partition,
and the kernel against a direct sum over its pieces with closed-form weights."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.transport import pixel_integral as pi


def test_disc_fraction_matches_monte_carlo():
    rng = np.random.default_rng(0)
    u = rng.uniform(-1, 1, (2, 400_000))
    u = u[:, (u ** 2).sum(axis=0) <= 1.0]
    for _ in range(20):
        b = rng.uniform(-12, 12, 2)
        a = rng.normal(0, 4, (2, 2)) + np.diag(rng.uniform(2, 8, 2))
        got = float(pi.disc_fraction(b[:, None], a[:, :, None], 10.0)[0])
        img = b[:, None] + a @ u
        inside = np.mean(np.all(np.abs(img) <= 10.0, axis=0))
        assert abs(got - inside) < 4 * math.sqrt(max(inside * (1 - inside), 1e-6) / u.shape[1])


def test_disc_fraction_closed_cases():
    eye = np.eye(2)[:, :, None]
    assert pi.disc_fraction(np.zeros((2, 1)), eye, 5.0)[0] == 1.0          # well inside
    assert pi.disc_fraction(np.array([[20.0], [0.0]]), eye, 5.0)[0] == 0.0  # well outside
    # The square's edge through the disc's centre: half of it.
    assert pi.disc_fraction(np.array([[5.0], [0.0]]), eye, 5.0)[0] == pytest.approx(0.5)
    # A chord at distance 1/2: the segment beyond it is (π/3 − √3/4)/π of the disc.
    seg = (math.pi / 3 - math.sqrt(3) / 4) / math.pi
    assert pi.disc_fraction(np.array([[4.5], [0.0]]), eye, 5.0)[0] == pytest.approx(1 - seg)


def test_partition_holds_every_cell_and_texel_boundary():
    relay = np.array([0.3, 0.0127, 0.0, 0.0])
    xb, mcol, tcol = pi.partition(relay, 200, (10.3, 40.7), 100)
    assert xb[0] == 10.3 and xb[-1] == 40.7 and np.all(np.diff(xb) > 0)
    cells = np.arange(11, 41)
    tex = (np.arange(200) / 200 - 0.3) / 0.0127
    tex = tex[(tex > 10.3) & (tex < 40.7)]
    for b in np.concatenate([cells, tex]):
        assert np.min(np.abs(xb - b)) < 1e-9
    mid = 0.5 * (xb[1:] + xb[:-1])
    np.testing.assert_array_equal(mcol, np.floor(mid))
    t = np.floor((0.3 + 0.0127 * mid) * 200).astype(int)
    np.testing.assert_array_equal(tcol, np.where((t >= 0) & (t < 200), t, -1))
    # A flipped view (β < 0) is cut at the same kind of boundaries.
    xb2, _, t2 = pi.partition(np.array([1.2, -0.0127, 0, 0]), 200, (10.3, 40.7), 100)
    assert np.all(np.diff(xb2) > 0) and np.all(np.diff(t2[t2 >= 0]) <= 0)


def _step_mean(x, a0, am, a1):
    """Mean over t ∈ [0, 1] of max(x − a(t), 0) for an edge on the pixel integral's path
    through a0, am, a1 (t quadratic in a, by :func:`sim.transport.pixel_integral._panel_factors`), in closed
    form: ∫ (x − a)₊ t'(a) da with t'(a) = α + β a."""
    D = a1 - a0
    if abs(D) <= pi.STILL:
        return np.maximum(x - 0.5 * (a0 + a1), 0.0)
    kappa = pi._panel_factors(a0, am, a1)[1]
    alpha, beta = 1.0 / D - kappa * (a0 + a1), 2.0 * kappa
    lo, hi = min(a0, a1), max(a0, a1)
    u = np.clip(x, lo, hi)

    def F(a):
        return alpha * (x * a - 0.5 * a * a) + beta * (0.5 * x * a * a - a ** 3 / 3.0)

    return np.sign(D) * (F(u) - F(lo))


def _panels(n):
    """A band's panels (first, middle, last node) for its ``n`` nodes."""
    if n == 1:
        return [(0, 0, 0)]
    return [(2 * s, 2 * s + 1, 2 * s + 2) for s in range((n - 1) // 2)]


def _simpson_width(X, c, j0, jm, j1):
    return ((X[c + 1, j0] - X[c, j0]) + 4 * (X[c + 1, jm] - X[c, jm])
            + (X[c + 1, j1] - X[c, j1])) / 6.0


def _reference(f, code, view, relay, part, geom, tau, r):
    """Row ``r`` of one view and band by a direct sum over the partition's pieces, each
    weighted by the closed-form integral of the pixel's footprint kernel over it (no running
    integrals, no shared edges)."""
    w = geom.w
    n = geom.cx.shape[0]
    X = np.empty((n, w + 1))
    Y0, Y1, XC = np.empty(w), np.empty(w), np.empty(w)
    pi._row_edges(r, geom.prc, geom.pre, geom.pceT, geom.pccT, geom.cx, geom.cy, X, Y0, Y1, XC)
    X = X.T
    H = f.shape[0]
    pmax = pi.max_pieces(relay, H)
    plen = np.zeros((w + 1, pmax))
    pmr = np.zeros(pmax, np.int64)
    ptr = np.zeros(pmax, np.int64)
    ng = pi._row_pieces(Y0, Y1, relay[2], relay[3], H, code.shape[0], plen, pmr, ptr,
                        np.empty(pmax + 1), np.empty(w, np.int64), np.empty(w, np.int64))
    xb, mcol, tcol = part
    # The row's mean of M f on every piece, its y span interpolated between the pixel centres.
    xm = 0.5 * (xb[1:] + xb[:-1])
    share = np.stack([np.interp(xm, XC, plen[:w, p]) for p in range(ng)], axis=1)
    g = np.zeros(xm.size)
    for i in range(xm.size):
        if mcol[i] < 0 or tcol[i] < 0:
            continue
        for p in range(ng):
            if pmr[p] >= 0 and ptr[p] >= 0 and code[pmr[p], mcol[i]] == view:
                g[i] += share[i, p] * f[ptr[p], tcol[i]]
    out = np.zeros(w)
    panels = _panels(n)
    for c in range(w):
        acc = 0.0
        for j0, jm, j1 in panels:
            # ∫ over a piece of the footprint's coverage: the difference of two steps' means.
            phi = (_step_mean(xb, X[c, j0], X[c, jm], X[c, j1])
                   - _step_mean(xb, X[c + 1, j0], X[c + 1, jm], X[c + 1, j1]))
            acc += float(np.sum(g * np.diff(phi))) / _simpson_width(X, c, j0, jm, j1)
        out[c] = tau[r, c] * acc / len(panels)
    return out


def test_step_mean_is_the_mean_over_the_path():
    """The reference's closed form against the mean over many t of a step on the path whose t
    is quadratic in its position (solved for the position), straight and still paths too."""
    t = (np.arange(20000) + 0.5) / 20000
    x = np.linspace(-1.0, 6.0, 57)
    for a0, am, a1 in ((1.0, 2.6, 4.0), (4.0, 2.2, 1.0), (1.0, 2.5, 4.0), (2.0, 2.0, 2.0)):
        D = a1 - a0
        if abs(D) <= pi.STILL:
            a = np.full_like(t, a0)
        else:
            k = pi._panel_factors(a0, am, a1)[1]
            # t = (a − a0)/D + k (a − a0)(a − a1): the root in [a0, a1].
            A, B, C = k, 1.0 / D - k * (a0 + a1), -a0 / D + k * a0 * a1 - t
            a = (-B + np.sign(D) * np.sqrt(B * B - 4 * A * C)) / (2 * A) if k else -C / B
        want = np.maximum(x[:, None] - a[None, :], 0.0).mean(axis=1)
        np.testing.assert_allclose(_step_mean(x, a0, am, a1), want, atol=1e-7)



def test_panel_factors_match_their_formula():
    """1/D and κ from one reciprocal equal the two divisions they replace (and κ = 0 on a
    panel shorter than STRAIGHT, where 1/D is still the plain reciprocal)."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        x0 = rng.uniform(-50, 50)
        D = rng.choice([-1.0, 1.0]) * 10 ** rng.uniform(-2.9, 1.0)
        xm, x1 = x0 + D * rng.uniform(0.3, 0.7), x0 + D
        D, a = x1 - x0, xm - x0          # as the kernel forms them
        inv_d, kap = pi._panel_factors(x0, xm, x1)
        assert inv_d == pytest.approx(1.0 / D, rel=1e-14)
        assert kap == pytest.approx((0.5 * D - a) / (D * a * (a - D)), rel=1e-14)
    for D in (5e-4, -9e-4):
        inv_d, kap = pi._panel_factors(1.0, 1.0 + 0.4 * D, 1.0 + D)
        assert kap == 0.0 and inv_d == 1.0 / ((1.0 + D) - 1.0)


@pytest.mark.mitsuba
def test_kernel_matches_a_direct_sum_over_its_pieces(small_transport):
    tr = small_transport
    rng = np.random.default_rng(1)
    for shape, k, l in (((158, 158), 0, 1), ((316, 301), 1, 5), ((97, 211), 3, 10)):
        f = rng.random(shape).astype(np.float32)
        out = tr.view_band(f, k, l)
        geom, part, tau = tr.geometry(k, l), tr.partition(k, shape[1]), tr.throughput(k, l)
        for r in rng.integers(0, geom.h, 3):
            ref = _reference(f, tr.code, tr.views[k], tr.maps.relay[k], part, geom, tau, int(r))
            np.testing.assert_allclose(out[r], ref, rtol=2e-5, atol=2e-6 * float(np.abs(ref).max()))


def _plain_rows(f, code, view, relay, part, geom, tau):
    """The kernel's own algorithm written plainly with NumPy, row by row: the pieces' weights
    by a binary search for each piece's pixel bracket, G, GG and GGG as cumulative sums over
    the whole partition, every edge's GG and GGG by a binary search."""
    h, w = geom.h, geom.w
    n = geom.cx.shape[0]
    H = f.shape[0]
    pmax = pi.max_pieces(relay, H)
    xb, mcol, tcol = part
    xm = 0.5 * (xb[1:] + xb[:-1])
    L = np.diff(xb)
    valid = (mcol >= 0) & (tcol >= 0)
    mc, tc = np.where(valid, mcol, 0), np.where(valid, tcol, 0)
    out = np.zeros((h, w))
    panels = _panels(n)
    for r in range(h):
        X = np.empty((n, w + 1))
        Y0, Y1, XC = np.empty(w), np.empty(w), np.empty(w)
        pi._row_edges(r, geom.prc, geom.pre, geom.pceT, geom.pccT, geom.cx, geom.cy, X, Y0, Y1,
                      XC)
        plen = np.zeros((w + 1, pmax))
        pmr, ptr = np.zeros(pmax, np.int64), np.zeros(pmax, np.int64)
        ng = pi._row_pieces(Y0, Y1, relay[2], relay[3], H, code.shape[0], plen, pmr, ptr,
                            np.empty(pmax + 1), np.empty(w, np.int64), np.empty(w, np.int64))
        c = np.clip(np.searchsorted(XC, xm, side="right") - 1, 0, max(w - 2, 0))
        t = np.clip((xm - XC[c]) / (XC[c + 1] - XC[c]), 0.0, 1.0) if w > 1 else 0.0 * xm
        g = np.zeros(xm.size)
        for p in range(ng):
            if pmr[p] < 0 or ptr[p] < 0:
                continue
            share = plen[c, p] + t * (plen[c + 1, p] - plen[c, p])
            g += np.where(valid & (code[pmr[p], mc] == view), share * f[ptr[p], tc], 0.0)
        G = np.concatenate([[0.0], np.cumsum(g * L)])
        GG = np.concatenate([[0.0], np.cumsum(G[:-1] * L + 0.5 * g * L * L)])
        GGG = np.concatenate([[0.0], np.cumsum(GG[:-1] * L + 0.5 * G[:-1] * L * L
                                               + g * L ** 3 / 6.0)])
        k = np.clip(np.searchsorted(xb, X, side="right") - 1, 0, xm.size - 1)
        d = X - xb[k]
        ggx = GG[k] + d * (G[k] + 0.5 * d * g[k])
        g3x = GGG[k] + d * (GG[k] + d * (0.5 * G[k] + d * g[k] / 6.0))
        acc = np.zeros(w)
        for j0, jm, j1 in panels:
            D = X[j1] - X[j0]
            still = ~(np.abs(D) > pi.STILL)
            a = X[jm] - X[j0]
            with np.errstate(divide="ignore", invalid="ignore"):
                kappa = np.where(np.abs(D) > pi.STRAIGHT, (0.5 * D - a) / (D * a * (a - D)), 0.0)
                dGG = ggx[j1] - ggx[j0]
                mG = dGG / D + kappa * (2 * (D * ggx[j1] - (g3x[j1] - g3x[j0])) - D * dGG)
            xh = 0.5 * (X[j0] + X[j1])
            kh = np.clip(np.searchsorted(xb, xh, side="right") - 1, 0, xm.size - 1)
            mG = np.where(still, G[kh] + (xh - xb[kh]) * g[kh], mG)
            wid = (np.diff(X[j0]) + 4 * np.diff(X[jm]) + np.diff(X[j1])) / 6.0
            acc += np.diff(mG) / wid
        out[r] = tau[r] * acc / len(panels)
    return out


@pytest.mark.mitsuba
def test_kernel_matches_its_algorithm_written_plainly(small_transport):
    """The kernel's walks, gap ranges and running integrals against binary searches and
    cumulative sums: the same numbers to float32 rounding, forward and (dot test) adjoint."""
    tr = small_transport
    rng = np.random.default_rng(2)
    for shape, k, l in (((158, 158), 0, 0), ((316, 316), 2, 6), ((120, 260), 4, 10)):
        f = rng.random(shape).astype(np.float32)
        geom, part, tau = tr.geometry(k, l), tr.partition(k, shape[1]), tr.throughput(k, l)
        ref = _plain_rows(f, tr.code, tr.views[k], tr.maps.relay[k], part, geom, tau)
        out = tr.view_band(f, k, l)
        assert float(np.abs(out - ref).max()) <= 1e-6 * float(np.abs(ref).max())
        e = rng.standard_normal((geom.h, geom.w)).astype(np.float32)
        lhs = np.vdot(out.astype(np.float64), e.astype(np.float64))
        rhs = np.vdot(f.astype(np.float64), tr.view_band_adjoint(e, k, l, shape))
        # The forward's output is float32 (6·10⁻⁸ a term at worst): its rounding is measured
        # against Σ|out e|, not against the sum, which random signs cancel to 10⁻⁴ of that.
        assert abs(lhs - rhs) <= 1e-7 * float(np.abs(out.astype(np.float64) * e).sum())


def test_node_weights_are_simpsons_rule_on_each_panel():
    np.testing.assert_allclose(pi.node_weights(1), [1.0])
    np.testing.assert_allclose(pi.node_weights(3), [1 / 6, 4 / 6, 1 / 6])
    np.testing.assert_allclose(pi.node_weights(5), np.array([1, 4, 2, 4, 1]) / 12)
    # Exact for a cubic across the band, as Simpson's rule is.
    t = np.linspace(0.0, 1.0, 7)
    assert float(pi.node_weights(7) @ (t ** 3 - 2 * t)) == pytest.approx(0.25 - 1.0)
    for n in (2, 4, 0):
        with pytest.raises(ValueError):
            pi.node_weights(n)


@pytest.mark.parametrize("D", [6, 4])
def test_row_polynomial_matches_numpy(D):
    """The kernels' polynomial along a row (the maps' degree 5 by Horner's rule in the
    monomial basis; any other degree from the tabulated values): Σ_b (Σ_a rv[a] c[a, b]) P_b(u),
    as numpy's Legendre series computes it, at columns' u in [-1, 1]."""
    from sim.transport.maps import legendre_values

    rng = np.random.default_rng(D)
    rv, c = rng.normal(size=D), rng.normal(size=(D, D))
    u = np.concatenate([[-1.0, 1.0], rng.uniform(-1, 1, 55)])
    colT = np.ascontiguousarray(legendre_values(u, D - 1).T)
    out = np.full(u.size, np.nan)
    pi.poly_row(rv, c, colT, out)
    want = np.polynomial.legendre.legval(u, rv @ c)
    np.testing.assert_allclose(out, want, rtol=1e-13, atol=1e-13 * np.abs(rv @ c).sum())


@pytest.mark.parametrize("ay, by, H, ylo, yhi", [
    (0.0, 0.25 / 40, 40, 3.3, 11.7),                 # every fourth mask row a texel row
    # `paper`'s views: the scene's far offset makes each texel boundary the round-off of a
    # large difference, which once left a 10⁻⁹ sliver gap after most texel rows.
    (-3.263504752305342, 0.002228244376807608, 1800, 1706.31, 1713.94),
    (3.262572144935613, -0.0022282449994869176, 1800, 1300.31, 1307.94)])
def test_row_gaps_cut_once_at_every_boundary(ay, by, H, ylo, yhi):
    """A row's gaps end at every mask-row and texel-row boundary inside its y range and nowhere
    else: no sliver after a gap that ended on a texel boundary, one cut where a texel boundary
    lies on a mask boundary; each gap's rows are those of its middle."""
    n_mask, pmax = 1720, 128
    pmr, ptr = np.zeros(pmax, np.int64), np.zeros(pmax, np.int64)
    bounds = np.empty(pmax + 1)
    ng = pi.row_gaps(ylo, yhi, ay, by, H, n_mask, pmr, ptr, bounds)
    t = np.sort((ay + by * np.array([ylo, yhi])) * H)
    texel = (np.arange(np.floor(t[0]), np.ceil(t[1]) + 1) / H - ay) / by
    cuts = np.concatenate([np.arange(np.ceil(ylo), yhi), texel])
    cuts = np.unique(np.round(cuts[(cuts > ylo) & (cuts < yhi)], 8))
    assert ng == cuts.size + 1
    np.testing.assert_allclose(bounds[1:ng], cuts, rtol=0, atol=1e-8)
    assert bounds[0] == ylo and bounds[ng] == yhi
    mid = 0.5 * (bounds[:ng] + bounds[1:ng + 1])
    mr = np.floor(mid).astype(np.int64)
    tr = np.floor((ay + by * mid) * H).astype(np.int64)
    np.testing.assert_array_equal(pmr[:ng], np.where(mr < n_mask, mr, -1))
    np.testing.assert_array_equal(ptr[:ng], np.where((tr >= 0) & (tr < H), tr, -1))
