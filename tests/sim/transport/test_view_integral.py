"""sim.transport.view_integral: every band of a view in one pass equals the per-band kernel, band by band;
its bucket search counts breakpoints as a sorted search does."""

from __future__ import annotations

import numpy as np
import pytest

from recon.errors import InputError
from sim.transport import pixel_integral as pi
from sim.transport import view_integral as vi

#: Agreement with :func:`sim.transport.pixel_integral.band_forward`, as a fraction of the view's peak:
#: the two interpolate the footprints' y bounds differently (bounds between knots here, shares
#: between pixel centres there); at most 3.5·10⁻⁵ is measured on ``paper`` and ``small``, with
#: random and natural scenes, at the view grid and twice it.
AGREE = 1e-4


def test_bucket_count_is_a_sorted_search():
    rng = np.random.default_rng(0)
    # Mask boundaries at the integers and texel boundaries at another pitch, as a partition
    # has them, with near-coincidences; then a bunch closer than either pitch.
    xb = np.unique(np.concatenate([np.arange(3.0, 60.0), 2.7 + 0.4987 * np.arange(120),
                                   [10.0 + 1e-9, 10.0 + 2e-9, 20.5, 20.5000001]]))
    xb = xb[(xb >= 2.7) & (xb <= 59.9)]
    for data in (xb, np.unique(np.concatenate([xb, 30.0 + 0.01 * np.arange(12)]))):
        b = vi.buckets(data, 0.4987)
        x = np.concatenate([rng.uniform(data[0] - 3, data[-1] + 3, 5000), data,
                            np.nextafter(data, -np.inf), [-1e9, 1e9]])
        got = np.array([vi._count(v, b.xbp, b.start, b.x0, b.inv) for v in x])
        np.testing.assert_array_equal(got, np.searchsorted(data, x, side="right"))


def _per_band(tr, f_hwl, k, bands):
    return np.stack([tr.view_band(np.ascontiguousarray(f_hwl[:, :, i]), k, l)
                     for i, l in enumerate(bands)])


@pytest.mark.mitsuba
@pytest.mark.parametrize("shape", [(158, 158), (316, 301)])
def test_all_bands_match_the_per_band_kernel(small_transport, shape):
    tr = small_transport
    rng = np.random.default_rng(2)
    f = rng.random(shape + (tr.n_bands,)).astype(np.float32)
    for k in range(len(tr.views)):
        got = tr.view_bands(f, k)
        want = _per_band(tr, f, k, range(tr.n_bands))
        peak = float(np.abs(want).max())
        assert peak > 0
        np.testing.assert_allclose(got, want, rtol=0, atol=AGREE * peak)
        # Where the views look through chrome both are 0 alike; elsewhere they agree pixel by
        # pixel, not only at the peak's scale.
        lit = want > 1e-3 * peak
        assert np.median(np.abs(got[lit] - want[lit]) / want[lit]) < 1e-6


@pytest.mark.mitsuba
def test_a_subset_of_bands_and_blocks_of_rows(small_transport):
    """Some bands only (their nodes only; one band alone), and rows in blocks: each band comes
    out as it does among all, and blocks of rows as the whole."""
    tr = small_transport
    rng = np.random.default_rng(3)
    f = rng.random((200, 180, tr.n_bands)).astype(np.float32)
    full = tr.view_bands(f, 2)
    for bands in ([0, 4, 10], [7]):
        sub = tr.view_bands(np.ascontiguousarray(f[:, :, bands]), 2, bands)
        # The same sums, started at the first piece the bands' own edges reach.
        np.testing.assert_allclose(sub, full[bands], rtol=1e-6,
                                   atol=1e-9 * float(full.max()))
    from sim.transport.view_integral import view_forward

    k, bands = 1, list(range(tr.n_bands))
    geom = tr.geometry(k, 0)
    mask = tr.maps.mask[k]
    args = (f, tr.code, tr.views[k], tr.maps.relay[k], tr.partition(k, f.shape[1]),
            tr.buckets(k, f.shape[1]), geom, mask[:, 0],
            np.stack([pi.node_weights(len(b)) @ mask[b, 1].reshape(len(b), -1)
                      for b in tr.band_nodes]).reshape(-1, *mask.shape[-2:]), tr.band_nodes, bands,
            tr.throughput(k))
    whole = view_forward(*args, np.full((len(bands), geom.h, geom.w), np.nan, np.float32))
    # Blocks of one row locate every edge by the bucket table; longer blocks step from the row
    # above after their first: the same pieces, so the same sums to the bit.
    for step in (37, 1):
        blocks = np.full_like(whole, np.nan)
        for r in range(0, geom.h, step):
            view_forward(*args, blocks, (r, min(r + step, geom.h)))
        np.testing.assert_array_equal(blocks, whole)
    np.testing.assert_array_equal(whole, tr.view_bands(f, k))
    with pytest.raises(ValueError):
        view_forward(f.astype(np.float64), *args[1:], whole)
    # Into a larger buffer (the blurs' zero-padded transforms): its top-left (h, w) of each
    # band, the same bits, and nothing else touched.
    big = np.full((len(bands), geom.h + 5, geom.w + 7), np.nan, np.float32)
    tr.view_bands(f, k, out=big)
    np.testing.assert_array_equal(big[:, :geom.h, :geom.w], whole)
    assert np.isnan(big[:, geom.h:]).all() and np.isnan(big[:, :, geom.w:]).all()
    for bad in (big[:, :-6], big[1:], big.astype(np.float64)):
        with pytest.raises(InputError):
            tr.view_bands(f, k, out=bad)
    # A partition that no row reaches (moved far down mask x): every row dark, written as 0.
    xb, mcol, tcol = args[4]
    far = (xb - 1e4, mcol, tcol)
    dark = np.full_like(whole, np.nan)
    view_forward(*args[:4], far, vi.buckets(far[0], 1.0 / (f.shape[1] * tr.maps.relay[k][1])),
                 *args[6:], dark)
    assert not dark.any() and not np.isnan(dark).any()


@pytest.mark.mitsuba
def test_a_monochromatic_band(shared_cache):
    """One node (a band-pass capture at one wavelength): G at the edges, no segments."""
    pytest.importorskip("mitsuba")
    from sim.optics.design import get_design
    from sim.transport.exact import load_or_build

    d = get_design("small")
    tr = load_or_build(d, intervals=[[552.0, 552.0]], seed=0)
    assert len(tr.band_nodes[0]) == 1
    f = np.random.default_rng(4).random((158, 158, 1)).astype(np.float32)
    for k in (0, 3):
        want = _per_band(tr, f, k, [0])
        np.testing.assert_allclose(tr.view_bands(f, k), want, rtol=0,
                                   atol=AGREE * float(want.max()))


@pytest.mark.mitsuba
def test_bands_cut_into_panels():
    """A tolerance finer than the shipped one cuts `small`'s bluer bands into several panels
    (5 or 7 nodes): the all-bands pass still equals the per-band kernel, which still equals
    its direct sum over the pieces and passes its dot test."""
    pytest.importorskip("mitsuba")
    from sim.bands import band_intervals
    from sim.optics.design import get_design
    from sim.transport.maps import band_nodes, trace_maps
    from sim.transport.exact import TRACE, Transport

    from .test_pixel_integral import _reference

    d = get_design("small")
    iv = band_intervals(d)
    nodes, index = band_nodes(d, iv, 2e-4)
    assert max(len(i) for i in index) >= 5
    maps = trace_maps(d, nodes, seed=0, degree=TRACE["degree"],
                      aperture_rays=TRACE["aperture_rays"])
    tr = Transport(d, maps, iv, index)
    rng = np.random.default_rng(5)
    f = rng.random((158, 158, tr.n_bands)).astype(np.float32)
    k = 1
    got = tr.view_bands(f, k)
    want = _per_band(tr, f, k, range(tr.n_bands))
    np.testing.assert_allclose(got, want, rtol=0, atol=AGREE * float(np.abs(want).max()))
    l = int(np.argmax([len(i) for i in index]))
    band = np.ascontiguousarray(f[:, :, l])
    geom, part, tau = tr.geometry(k, l), tr.partition(k, 158), tr.throughput(k, l)
    for r in (17, 80):
        ref = _reference(band, tr.code, tr.views[k], tr.maps.relay[k], part, geom, tau, r)
        np.testing.assert_allclose(want[l, r], ref, rtol=2e-5,
                                   atol=2e-6 * float(np.abs(ref).max()))
    e = rng.standard_normal(want.shape[1:]).astype(np.float32)
    lhs = np.vdot(want[l].astype(np.float64), e.astype(np.float64))
    rhs = np.vdot(band.astype(np.float64), tr.view_band_adjoint(e, k, l, band.shape))
    assert abs(lhs - rhs) <= 1e-7 * float(np.abs(want[l].astype(np.float64) * e).sum())


@pytest.mark.mitsuba
def test_edges_out_of_order_are_clamped_to_their_rows_pieces(small_transport):
    """Stage 2 reads the table at each edge's piece unclamped where the transport vouches that
    the edges are in order along every row (every design's are); a map that folds back
    (bent by hand here) is not vouched for, and each of its rows clamps the edges that leave
    its pieces, as the per-band kernel does, instead of reading rows of the table that the
    row never wrote."""
    import copy

    from sim.transport.exact import Transport

    tr = small_transport
    assert all(tr.edges_ordered(k) for k in range(len(tr.views)))
    k = 1
    maps = copy.copy(tr.maps)
    maps.mask = tr.maps.mask.copy()
    # A column-quadratic term as large as half the slope: the edges of a row's first sixth
    # of columns run backwards, past its first piece.
    maps.mask[k, :, 0, 0, 2] += 0.5 * maps.mask[k, :, 0, 0, 1]
    from sim.optics.design import get_design

    bent = Transport(get_design("small"), maps, tr.intervals, tr.band_nodes)
    assert not bent.edges_ordered(k) and bent.edges_ordered(0)
    # Every mask cell open and a scene alike down each column, so that both kernels'
    # footprints (interpolated differently in y) integrate the same g.
    code = np.full_like(bent.code, bent.views[k])
    row = np.random.default_rng(6).random((1, 158, bent.n_bands)).astype(np.float32)
    f = np.ascontiguousarray(np.broadcast_to(row, (158, 158, bent.n_bands)))
    bands = list(range(bent.n_bands))
    geom = bent.geometry(k, 0)
    args = (f, code, bent.views[k], maps.relay[k], bent.partition(k, 158),
            bent.buckets(k, 158), geom, maps.mask[k, :, 0],
            np.stack([pi.band_mean(maps.mask[k, :, 1], b) for b in bent.band_nodes]),
            bent.band_nodes, bands, bent.throughput(k))
    report = {}
    got = vi.view_forward(*args, np.zeros((len(bands), geom.h, geom.w), np.float32),
                          report=report)
    assert report["rows clamped"] > 0.5 * geom.h
    want = np.stack([pi.band_forward(np.ascontiguousarray(f[:, :, l]), code, bent.views[k],
                                     maps.relay[k], bent.partition(k, 158),
                                     bent.geometry(k, l), bent.throughput(k, l))
                     for l in bands])
    peak = float(np.abs(want).max())
    assert np.isfinite(got).all() and float(np.abs(got).max()) <= peak * (1 + AGREE)
    # Past the fold (pixels whose edges all lie beyond any x the folded edges reach, and a
    # knot's spacing more) the two kernels agree as they do on any map.
    xs = np.stack([geom.prc @ c @ geom.pce.T for c in maps.mask[k, :, 0]])
    back = np.diff(xs, axis=2) <= 0
    turn = int(np.flatnonzero(back.any(axis=(0, 1))).max()) + 1
    reach = xs[:, :, :turn + 1].max(axis=(0, 2))
    clear = xs[:, :, :-1].min(axis=0) > reach[:, None] + vi.KNOT
    assert clear.sum() > 0.3 * clear.size
    np.testing.assert_allclose(np.where(clear, got, 0), np.where(clear, want, 0), rtol=0,
                               atol=AGREE * peak)
    # On a map in order the row check changes nothing.
    g2 = tr.geometry(k, 0)
    a2 = (f, tr.code, tr.views[k], tr.maps.relay[k], tr.partition(k, 158),
          tr.buckets(k, 158), g2, tr.maps.mask[k, :, 0],
          np.stack([pi.band_mean(tr.maps.mask[k, :, 1], b) for b in tr.band_nodes]),
          tr.band_nodes, bands, tr.throughput(k))
    checked = vi.view_forward(*a2, np.zeros_like(got), report=report)
    assert report["rows clamped"] == 0
    np.testing.assert_array_equal(checked, vi.view_forward(*a2, np.zeros_like(got), None, True))
