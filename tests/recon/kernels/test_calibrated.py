"""The calibrated-CASSI kernels (:mod:`recon.kernels.calibrated`) against the NumPy path of
:class:`~recon.operators.CalibratedCassi` (float32, as in ``test_kernels.py``).

Operators mix identity, flipped and homography views (a homography whose view shape differs
from the cube's), integer and sub-pixel offsets, per-view offsets and band scales, single
bands, rows and columns, so that every branch of the kernels runs.
"""

import numpy as np
import pytest

from kernel_checks import RTOL32, assert_operator_matches_numpy, rel
from recon import kernels
from recon.errors import InputError
from recon.operators import CalibratedCassi, Flip, HomographyWarp, Translate, dot_test
from recon.operators.base import weighted_base

pytestmark = pytest.mark.skipif(not kernels.enabled(), reason="Numba kernels switched off")


def _homography(rng, shape, out_shape):
    """A mild projective map (rotation, scale, shear, perspective) of the cube onto a view."""
    a = 0.05 * rng.standard_normal()
    m = np.array([[np.cos(a) * 1.02, -np.sin(a), rng.uniform(-1, 1)],
                  [np.sin(a), np.cos(a) * 0.98, rng.uniform(-1, 1)],
                  [1e-3 * rng.standard_normal(), 1e-3 * rng.standard_normal(), 1.0]])
    return HomographyWarp(m, shape, out_shape)


def _operators():
    rng = np.random.default_rng(21)
    cm = lambda k, l, h, w: rng.random((k, l, h, w)).astype(np.float32)  # noqa: E731
    return {
        "identity-int": CalibratedCassi(cm(1, 3, 7, 12), [0, 2, 4], cube_shape=(3, 7, 8)),
        "identity-sub": CalibratedCassi(cm(1, 4, 5, 11), [0.3, 1.0, 2.5, 3.75],
                                        cube_shape=(4, 5, 7)),
        "one-band-one-column": CalibratedCassi(cm(1, 1, 6, 3), [1.5], cube_shape=(1, 6, 1)),
        "one-row": CalibratedCassi(cm(2, 3, 1, 9), [[0, 0.5, 1.25], [2, 1, 0.0]],
                                   [None, Flip(1)], (3, 1, 6)),
        "flips": CalibratedCassi(cm(4, 3, 6, 10), [[0, 1.5, 2.25], [3, 2, 0.5], [0, 0, 0],
                                                   [1.1, 2.2, 3.3]],
                                 [None, Flip(0), Flip(1), Flip((0, 1))], (3, 6, 6)),
        "translate": CalibratedCassi(cm(2, 3, 4, 9), [[0, 1.5, 2.25], [3, 2, 0.5]],
                                     [Translate(0.4, -0.7), None], (3, 4, 5)),
        # Five views as at paper size: the centre, then homographies onto smaller views.
        "homographies-5": CalibratedCassi(
            cm(5, 4, 9, 15), rng.uniform(0, 3, (5, 4)),
            [None] + [_homography(rng, (9, 11), (9, 11)) for _ in range(4)], (4, 9, 11)),
        "homography-other-shape": CalibratedCassi(
            cm(2, 3, 8, 14), [[0.2, 1.4, 2.6], [0, 1, 2]],
            [_homography(rng, (10, 12), (8, 11)), _homography(rng, (10, 12), (8, 10))],
            (3, 10, 12)),
        "band-scale": CalibratedCassi(cm(3, 4, 6, 12), rng.uniform(0, 3, (3, 4)),
                                      [None, Flip(1), _homography(rng, (6, 8), (6, 8))],
                                      (4, 6, 8), band_scale=[0.5, 2.0, 1.0, 3.25]),
        "band-scale-zero": CalibratedCassi(cm(1, 3, 5, 9), [0.5, 1.5, 2.0],
                                           cube_shape=(3, 5, 6), band_scale=[1.0, 0.0, -2.0]),
        # View images that start before the crop or end after it (columns dropped there).
        "past-the-edges": CalibratedCassi(
            cm(3, 4, 6, 10), [[-2.5, -1, 0.5, 3.25], [-4, 0, 2, 5.5], [1, 2, 3, 4]],
            [None, Flip(1), _homography(rng, (6, 8), (6, 8))], (4, 6, 8),
            band_scale=[0.5, 2.0, 1.0, 3.25]),
        "wider-than-the-crop": CalibratedCassi(cm(1, 2, 4, 5), [-1.5, -3], cube_shape=(2, 4, 9)),
    }


OPS = _operators()


@pytest.mark.parametrize("name", sorted(OPS))
def test_forward_and_adjoint_match_numpy(name):
    assert_operator_matches_numpy(OPS[name], 22)


def test_forward_gathers_rows_of_four_entries_and_the_others():
    """The forward's gather adds a row of four entries (a bilinear tap inside the cube) in one
    expression and any other row (the cube's edges) entry by entry: the homography views
    hold both kinds, and their forward matches the NumPy path, which sums entry by entry."""
    op = OPS["homographies-5"]
    lengths = set()
    for warp in op.warps[1:]:
        lengths |= set(np.diff(warp.sparse_pair()[0].indptr).tolist())
    assert 4 in lengths and lengths - {4}
    assert_operator_matches_numpy(op, 25)


@pytest.mark.parametrize("name", sorted(OPS))
def test_kernels_have_exact_adjoints(name):
    assert dot_test(OPS[name], np.random.default_rng(23), dtype=np.float32) < 1e-6


@pytest.mark.parametrize("name", sorted(OPS))
@pytest.mark.parametrize("where", ["new", "base", "other"])
@pytest.mark.parametrize("weighted", [False, True])
def test_adjoint_add_is_base_plus_scaled_adjoint(name, where, weighted):
    op = OPS[name]
    rng = np.random.default_rng(24)
    base = rng.standard_normal(op.ishape).astype(np.float32)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    # The band metric's base weights (recon.solvers.band_metric), applied by the kernel as
    # it writes the result, against the weighted base made first.
    q = rng.uniform(0.05, 1.0, op.ishape[0]).astype(np.float32) if weighted else None
    with kernels.numpy_only():
        want = weighted_base(base, q) + np.float32(0.37) * op.adjoint(y)
    b = base.copy()
    out = {"new": None, "base": b, "other": np.empty_like(b)}[where]
    got = op.adjoint_add(y, b, 0.37, out=out, base_weights=q)
    assert got.dtype == np.float32
    assert got is out if out is not None else got is not b
    assert rel(got, want) < RTOL32
    if where != "base":
        assert np.array_equal(b, base)          # the base is only read


def test_band_scale_is_the_scaled_mask_images():
    rng = np.random.default_rng(25)
    cm = rng.random((2, 3, 6, 12)).astype(np.float32)
    s = np.array([0.25, 4.0, 1.5])
    args = ([[0.5, 1.0, 2.5], [0, 3.5, 1.25]], [None, Translate(0.3, 0.6)], (3, 6, 8))
    scaled = CalibratedCassi(cm, *args, band_scale=s)
    copied = CalibratedCassi(cm * s.astype(np.float32)[None, :, None, None], *args)
    assert scaled.mask_images is cm                 # no scaled copy is made
    x = rng.standard_normal(scaled.ishape).astype(np.float32)
    y = rng.standard_normal(scaled.oshape).astype(np.float32)
    for ctx in (kernels.threads, kernels.numpy_only):
        with ctx():
            assert rel(scaled.forward(x), copied.forward(x)) < RTOL32
            assert rel(scaled.adjoint(y), copied.adjoint(y)) < RTOL32
    np.testing.assert_allclose(scaled.row_norms_sq(), copied.row_norms_sq(), rtol=1e-6)


def test_float64_takes_the_numpy_path():
    op = OPS["homographies-5"]
    rng = np.random.default_rng(26)
    x = rng.standard_normal(op.ishape)
    assert op.forward(x).dtype == np.float64
    with kernels.numpy_only():
        ref = op.forward(x)
    assert np.array_equal(op.forward(x), ref)


def test_kernels_do_not_depend_on_threads():
    op = OPS["homographies-5"]
    rng = np.random.default_rng(27)
    x = rng.standard_normal(op.ishape).astype(np.float32)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    outs = []
    for n in (1, 2, 3):
        with kernels.threads(n):
            outs.append((op.forward(x), op.adjoint(y), op.adjoint_add(y, x, 0.5)))
    for other in outs[1:]:
        for a, b in zip(outs[0], other):
            assert np.array_equal(a, b)


@pytest.mark.parametrize("name", sorted(OPS))
def test_band_forward_is_the_forward_of_one_band_to_the_bit(name):
    """One band's model through the kernels alone equals the full forward of the cube that
    is that image in that band and zero elsewhere, bit for bit (the other bands add exact
    zeros), and the NumPy path's (float32 rounding)."""
    op = OPS[name]
    rng = np.random.default_rng(31)
    for band in range(op.ishape[0]):
        img = rng.random(op.ishape[1:], dtype=np.float32)
        x = np.zeros(op.ishape, np.float32)
        x[band] = img
        got = op.band_forward(band, img)
        assert got.dtype == np.float32 and got.shape == op.oshape
        assert np.array_equal(got, op.forward(x))
        with kernels.numpy_only():
            ref = op.forward(x)
            assert np.array_equal(op.band_forward(band, img), ref)
        assert rel(got, ref) < RTOL32


def test_band_forward_rejects_bad_band_and_shape():
    from recon.errors import InputError

    op = OPS["flips"]
    for band in (-1, op.ishape[0], 1.5, True):
        with pytest.raises(InputError):
            op.band_forward(band, np.ones(op.ishape[1:], np.float32))
    with pytest.raises(InputError):
        op.band_forward(0, np.ones((2, 2), np.float32))


@pytest.mark.parametrize("name", sorted(OPS))
def test_one_pass_adjoint_matches_the_view_by_view_kernels(name, monkeypatch):
    """All views in one pass over the cube (recon.kernels.calibrated.adjoint_views) against
    the view-by-view kernels it replaces, with and without a base (also in place), and the
    view-by-view path taken where a task would need too many view rows."""
    from recon.kernels import calibrated as kcal
    from recon.operators.calibrated import CalibratedCassi

    op = OPS[name]
    rng = np.random.default_rng(41)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    b = rng.standard_normal(op.ishape).astype(np.float32)
    assert op._fused_plan()
    for base, scale in ((None, 1.0), (b, -0.37)):
        ref = op._adjoint_by_view(y, base, scale, np.empty(op.ishape, np.float32))
        got = op._adjoint_kernel(y, base, scale, np.empty(op.ishape, np.float32))
        assert rel(got, ref) < RTOL32
    inplace = b.copy()
    op._adjoint_kernel(y, inplace, -0.37, inplace)
    assert rel(inplace, op._adjoint_by_view(y, b, -0.37, np.empty_like(b))) < RTOL32
    monkeypatch.setattr(kcal, "ADJOINT_MAX_ZROWS", 0)
    narrow = CalibratedCassi(op.mask_images, op.offsets, op.warps, op.ishape, op.band_scale)
    assert narrow._fused_plan() is False
    assert rel(narrow.adjoint(y), op.adjoint(y)) < RTOL32
    out = narrow.adjoint_add(y, b, -0.37, out=b.copy())
    assert rel(out, op.adjoint_add(y, b, -0.37)) < RTOL32
    # Base weights: the view-by-view path weighs the base first, the one-pass kernel as it
    # writes.
    q = rng.uniform(0.05, 1.0, op.ishape[0]).astype(np.float32)
    out = narrow.adjoint_add(y, b, -0.37, out=b.copy(), base_weights=q)
    assert rel(out, op.adjoint_add(y, b, -0.37, base_weights=q)) < RTOL32


def test_bands_last_is_the_transpose():
    from recon.kernels import calibrated as kcal

    rng = np.random.default_rng(51)
    for shape in ((1, 7), (3, 1), (26, 64 * 3 + 5)):
        x = rng.standard_normal(shape).astype(np.float32)
        out = np.empty(shape[::-1], np.float32)
        kcal.bands_last(x, out)
        assert np.array_equal(out, x.T)


def test_a_warped_row_goes_band_major_in_blocks_and_its_tail():
    from recon.kernels import calibrated as kcal

    rng = np.random.default_rng(52)
    # Widths below, at and between multiples of the block (the tail alone, whole blocks,
    # blocks and a tail), and one band.
    for wv, n_bands in ((1, 26), (7, 26), (8, 26), (8 * 3, 1), (8 * 4 + 5, 26), (867, 26)):
        vt = rng.standard_normal((wv, n_bands)).astype(np.float32)
        v = np.full((n_bands, wv), np.nan, np.float32)
        kcal._to_band_major(vt, v)
        assert np.array_equal(v, vt.T)


def _view_by_view(op, monkeypatch):
    """A fresh copy of ``op`` whose forward takes the view-by-view kernels (no view row may
    reach past its task's cube rows, so the one-pass plan is refused)."""
    from recon.kernels import calibrated as kcal

    with monkeypatch.context() as m:
        m.setattr(kcal, "FORWARD_MAX_SPAN", -1)
        copy = CalibratedCassi(op.mask_images, op.offsets, op.warps, op.ishape, op.band_scale)
        assert copy._forward_plan() is False
    return copy


@pytest.mark.parametrize("small_tasks", [False, True])
@pytest.mark.parametrize("name", sorted(OPS))
def test_one_pass_forward_is_the_view_by_view_kernels_to_the_bit(name, small_tasks,
                                                                  monkeypatch):
    """All views in one pass over the cube (recon.kernels.calibrated.forward_views) against the
    view-by-view kernels it replaces (bands_last, then forward_view a view), bit for bit: with
    the tasks of the operator's own plan, and with tasks of a few rows, so that view rows
    read cube rows past their task's own."""
    from recon.kernels import calibrated as kcal

    if small_tasks:
        monkeypatch.setattr(kcal, "FORWARD_TASK_BYTES", 1)
    op = OPS[name]
    fused = CalibratedCassi(op.mask_images, op.offsets, op.warps, op.ishape, op.band_scale)
    plan = fused._forward_plan()
    assert plan
    if small_tasks and op.ishape[1] > 4:
        assert plan["s0"].size > 1
    ref = _view_by_view(op, monkeypatch)
    rng = np.random.default_rng(53)
    for _ in range(2):
        x = rng.standard_normal(op.ishape).astype(np.float32)
        assert np.array_equal(fused.forward(x), ref.forward(x))


def test_one_pass_forward_refuses_warps_that_reach_far():
    """A view turned by 90 degrees reads a cube column on each of its rows: the plan is
    refused and the view-by-view kernels give the forward (still the NumPy path's)."""
    rng = np.random.default_rng(54)
    h = 40
    turn = HomographyWarp(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
                          (h, h), (h, h))
    op = CalibratedCassi(rng.random((2, 3, h, h + 4)).astype(np.float32),
                         [[0, 1, 2], [0.5, 1.5, 2.5]], [None, turn], (3, h, h))
    assert op._forward_plan() is False
    assert_operator_matches_numpy(op, 56)


def test_the_operator_holds_each_warp_once():
    """Once the one-pass plans have joined the views' CSR arrays, the warps hold slices of
    the joined arrays instead of their own (one copy, not two), and every path still gives
    what it gave: the kernels, the warps' NumPy path."""
    rng = np.random.default_rng(57)
    warps = [None] + [_homography(rng, (9, 11), (9, 11)) for _ in range(3)]
    cm = rng.random((4, 3, 9, 15)).astype(np.float32)
    offsets = rng.uniform(0, 3, (4, 3))
    op = CalibratedCassi(cm, offsets, warps, (3, 9, 11))
    x = rng.standard_normal(op.ishape).astype(np.float32)
    y = rng.standard_normal(op.oshape).astype(np.float32)
    before = [w.apply(x) for w in warps[1:]]
    fwd, adj = op.forward(x), op.adjoint(y)
    fplan, aplan = op._forward_plan(), op._fused_plan()
    for w, was in zip(warps[1:], before):
        m, mt = w.sparse_pair()
        for arr, joined in ((m.indices, fplan["indices"]), (m.data, fplan["data"]),
                            (mt.indices, aplan["indices"]), (mt.data, aplan["data"])):
            assert np.shares_memory(arr, joined)
        assert np.array_equal(w.apply(x), was)
    assert np.array_equal(op.forward(x), fwd)
    assert np.array_equal(op.adjoint(y), adj)
    other = warps[2].sparse_pair()[0]
    with pytest.raises(InputError, match="not this warp's matrix"):
        warps[1].share_csr(forward=(other.indptr, other.indices, other.data))


def test_forward_reuses_its_pixel_major_buffer_safely(monkeypatch):
    """The view-by-view forward's pixel-major cube is kept between calls (a later call
    overwrites it whole), and a call that finds it taken, as a concurrent one would, makes its
    own: every result is the fresh operator's, also from two threads at once."""
    from concurrent.futures import ThreadPoolExecutor

    op = _view_by_view(OPS["homographies-5"], monkeypatch)
    rng = np.random.default_rng(52)
    xs = [rng.standard_normal(op.ishape).astype(np.float32) for _ in range(4)]
    fresh = [_view_by_view(op, monkeypatch).forward(x) for x in xs]
    assert np.array_equal(op.forward(xs[0]), fresh[0])
    buf = op._pixels
    assert np.array_equal(op.forward(xs[1]), fresh[1])
    assert op._pixels is buf
    del op._pixels                                  # taken by another call
    assert np.array_equal(op.forward(xs[2]), fresh[2])
    with ThreadPoolExecutor(2) as pool:
        for _ in range(3):
            got = list(pool.map(op.forward, xs))
            for g, want in zip(got, fresh):
                assert np.array_equal(g, want)
    ident = _view_by_view(OPS["identity-int"], monkeypatch)
    ident.forward(rng.standard_normal(ident.ishape).astype(np.float32))
    assert not hasattr(ident, "_pixels")            # identity views read the cube in place
