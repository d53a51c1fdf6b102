"""Multi-view CASSI: dense references, the MST/TSA-Net convention, kaleidoscope geometry."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from dense import assert_matches_dense, flip_matrix, shift_matrix
from recon.errors import InputError
from recon.operators import (
    CassiOperator, Flip, HomographyWarp, Identity, Translate, View, dot_test,
    kaleidoscope_cassi, standard_cassi,
)

SETTINGS = settings(max_examples=30, deadline=None, derandomize=True, database=None)


# -- independent dense references ------------------------------------------------------------


def translate_matrix(shape, dy, dx):
    """v(y, x) = f(y - dy, x - dx), bilinear, zeros outside (loops)."""
    h, w = shape
    a = np.zeros((h * w, h * w))
    for y in range(h):
        for x in range(w):
            ys, xs = y - dy, x - dx
            y0, x0 = math.floor(ys), math.floor(xs)
            fy, fx = ys - y0, xs - x0
            for yy, wy in ((y0, 1 - fy), (y0 + 1, fy)):
                for xx, wx in ((x0, 1 - fx), (x0 + 1, fx)):
                    if 0 <= yy < h and 0 <= xx < w and wy * wx > 1e-9:
                        a[y * w + x, yy * w + xx] += wy * wx
    return a


def dense_cassi(masks, offsets, warp_mats, shape):
    """H = [H_1; ...; H_K], H_k = [S_kl diag(M_k) W_k]_l with globally normalised offsets."""
    l_, h, w = shape
    hv, wv = masks[0].shape
    phi = np.asarray(offsets, dtype=np.float64)
    lo = math.floor(phi.min())
    wm = wv + math.ceil(phi.max()) - lo
    rows = []
    for k, m in enumerate(masks):
        blocks = [np.kron(np.eye(hv), shift_matrix(phi[k, l] - lo, wv, wm))
                  @ np.diag(m.astype(np.float64).ravel()) @ warp_mats[k] for l in range(l_)]
        rows.append(np.hstack(blocks))
    return np.vstack(rows), wm


warp_choice = st.sampled_from(["id", "fx", "fy", "fxy", "tr"])
offset = st.one_of(st.integers(-4, 4).map(float),
                   st.floats(-4.0, 4.0, allow_nan=False).map(lambda v: round(v, 3)))


def make_warp(kind, shape, rng):
    if kind == "id":
        return None, np.eye(shape[0] * shape[1])
    if kind == "tr":
        dy, dx = (round(float(v), 2) for v in rng.uniform(-1.5, 1.5, 2))
        return Translate(dy, dx), translate_matrix(shape, dy, dx)
    axes = {"fx": (1,), "fy": (0,), "fxy": (0, 1)}[kind]
    return Flip(axes), flip_matrix(shape, axes)


@SETTINGS
@given(k=st.integers(1, 9), l_=st.integers(1, 3), h=st.integers(1, 4), w=st.integers(1, 5),
       data=st.data(), seed=st.integers(0, 2**16))
def test_matches_dense_reference(k, l_, h, w, data, seed):
    rng = np.random.default_rng(seed)
    offsets = np.array([[data.draw(offset) for _ in range(l_)] for _ in range(k)])
    kinds = [data.draw(warp_choice) for _ in range(k)]
    masks = rng.random((k, h, w)).astype(np.float32)
    warps, mats = zip(*(make_warp(kind, (h, w), rng) for kind in kinds))
    op = CassiOperator([View(masks[i], offsets[i], warps[i]) for i in range(k)], (l_, h, w))
    a, wm = dense_cassi(masks, offsets, mats, (l_, h, w))
    assert op.ishape == (l_, h, w) and op.oshape == (k, h, wm)
    assert op.n_views == k and op.n_bands == l_
    x = rng.standard_normal(op.ishape)
    y = rng.standard_normal(op.oshape)
    # (1e-6: Translate stores its bilinear weights in float32; the reference is exact.)
    np.testing.assert_allclose(op.forward(x).ravel(), a @ x.ravel(), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(op.adjoint(y).ravel(), a.T @ y.ravel(), rtol=1e-6, atol=1e-6)
    # Closed-form row norms = diag(H H^T) of the dense matrix.
    np.testing.assert_allclose(op.row_norms_sq().ravel(), np.diag(a @ a.T), rtol=1e-6, atol=1e-6)
    assert dot_test(op, rng) < 1e-6
    # float32 in, float32 out, same values to float32 precision.
    g32 = op.forward(x.astype(np.float32))
    assert g32.dtype == np.float32 and op.adjoint(y.astype(np.float32)).dtype == np.float32
    np.testing.assert_allclose(g32.ravel(), a @ x.astype(np.float32).ravel(), atol=2e-5)


@SETTINGS
@given(seed=st.integers(0, 2**16), l_=st.integers(1, 3), hv=st.integers(2, 5),
       wv=st.integers(2, 5), offs=st.lists(offset, min_size=3, max_size=3))
def test_homography_view_matches_dense(seed, l_, hv, wv, offs):
    rng = np.random.default_rng(seed)
    h, w = 4, 4
    m = np.array([[1.1, 0.1, -0.4], [-0.05, 0.9, 0.6], [0.01, -0.02, 1.0]])
    hw = HomographyWarp(m, (h, w), (hv, wv))
    masks = rng.random((2, hv, wv)).astype(np.float32)
    offsets = np.array([offs[:l_], offs[-l_:]])
    op = CassiOperator([View(masks[0], offsets[0], hw), View(masks[1], offsets[1], hw)])
    assert op.ishape == (l_, h, w)
    mats = [hw.matrix().toarray()] * 2
    a, _ = dense_cassi(masks, offsets, mats, (l_, h, w))
    assert_matches_dense(op, a, rng, norms_atol=1e-6)


# -- the standard single-view convention (MST / TSA-Net) -----------------------------------
def mst_reference(mask, f_hwl, step):
    """Loop-free MST-style reference: shifted mask Phi (H, W+step(L-1), L) and
    g = sum_l Phi_l * shift(f_l), with cubes in the benchmark's (H, W, L) layout."""
    h, w, l_ = f_hwl.shape
    wm = w + step * (l_ - 1)
    phi = np.zeros((h, wm, l_), dtype=np.float64)
    fs = np.zeros((h, wm, l_), dtype=np.float64)
    cols = np.arange(w)[None, :] + step * np.arange(l_)[:, None]  # (L, W)
    phi[:, cols.T, np.arange(l_)[None, :]] = mask[:, :, None]
    fs[:, cols.T, np.arange(l_)[None, :]] = f_hwl
    return np.sum(phi * fs, axis=2), phi


@pytest.mark.parametrize("h, w, l_, step", [(8, 8, 28, 2), (5, 9, 4, 1), (6, 7, 3, 3), (4, 4, 1, 2)])
def test_standard_cassi_is_mst_convention(h, w, l_, step):
    rng = np.random.default_rng(h * w + l_)
    mask = (rng.random((h, w)) > 0.5).astype(np.float32)
    f = rng.random((h, w, l_)).astype(np.float32)
    op = standard_cassi(mask, step, l_)
    assert op.ishape == (l_, h, w) and op.oshape == (1, h, w + step * (l_ - 1))
    g_ref, phi = mst_reference(mask, f, step)
    g = op.forward(np.ascontiguousarray(f.transpose(2, 0, 1)))
    np.testing.assert_allclose(g[0], g_ref, rtol=1e-6, atol=1e-6)
    # MST's adjoint (the "At" of their code): f_l = Phi_l * unshift(g).
    y = rng.random(op.oshape).astype(np.float32)
    cols = np.arange(w)[None, :] + step * np.arange(l_)[:, None]
    at_ref = (phi * y[0][:, :, None])[:, cols.T, np.arange(l_)[None, :]]  # (H, W, L)
    np.testing.assert_allclose(op.adjoint(y).transpose(1, 2, 0), at_ref, rtol=1e-6, atol=1e-6)
    # Row norms: MST's Phi_s = sum_l Phi_l^2.
    np.testing.assert_allclose(op.row_norms_sq()[0], np.sum(phi**2, axis=2), rtol=1e-12)


def test_standard_cassi_is_a_one_view_cassi_operator():
    mask = np.random.default_rng(0).random((5, 6))
    op = standard_cassi(mask, 2, 4)
    assert isinstance(op, CassiOperator) and op.n_views == 1
    np.testing.assert_array_equal(op.offsets, [[0, 2, 4, 6]])


# -- the kaleidoscope -----------------------------------------------------------------------
def test_kaleidoscope_views_are_mirror_images():
    rng = np.random.default_rng(2)
    h, w, l_ = 6, 8, 3
    f = rng.random((l_, h, w))
    op = kaleidoscope_cassi(np.ones((9, h, w)), np.zeros(l_), 9)
    g = op.forward(f)
    c = g[0]
    np.testing.assert_allclose(c, f.sum(0))
    for k in (1, 2):          # left, right: horizontal mirror of the centre
        np.testing.assert_allclose(g[k], c[:, ::-1])
    for k in (3, 4):          # top, bottom: vertical mirror
        np.testing.assert_allclose(g[k], c[::-1, :])
    for k in range(5, 9):     # corners: both
        np.testing.assert_allclose(g[k], c[::-1, ::-1])
    flat = kaleidoscope_cassi(np.ones((9, h, w)), np.zeros(l_), 9, inversion=False).forward(f)
    for k in range(9):
        np.testing.assert_allclose(flat[k], c)


def _registered_positions(op, h, w, l_, y0, c0):
    """Column of each band's image of a point at (y0, c0), per view, after registering the
    view to the centre (undoing the view's mirror on the measurement)."""
    pos = np.zeros((op.n_views, l_))
    for l in range(l_):
        f = np.zeros((l_, h, w))
        f[l, y0, c0] = 1.0
        g = op.forward(f)
        for k in range(op.n_views):
            axes = op.views[k].warp.axes if isinstance(op.views[k].warp, Flip) else ()
            img = g[k][::-1] if 0 in axes else g[k]
            ys, xs = np.nonzero(img)
            assert len(xs) == 1 and ys[0] == y0
            # Registration: the view's column u maps back to centre column (W-1) - u.
            pos[k, l] = (w - 1) - xs[0] if 1 in axes else xs[0]
    return pos


@pytest.mark.parametrize("inversion", [True, False])
def test_dispersion_inversion(inversion):
    h, w, l_ = 5, 9, 4
    offsets = 2.0 * np.arange(l_)     # the sensor disperses every view towards +x
    op = kaleidoscope_cassi(np.ones((5, h, w)), offsets, 5, inversion=inversion)
    pos = _registered_positions(op, h, w, l_, y0=1, c0=4)
    step = np.diff(pos, axis=1)
    np.testing.assert_array_equal(step[0], 2.0)       # centre: +x
    np.testing.assert_array_equal(step[3:5], 2.0)     # top/bottom: never inverted
    np.testing.assert_array_equal(step[1:3], -2.0 if inversion else 2.0)


def test_kaleidoscope_view_order_and_subsets():
    rng = np.random.default_rng(4)
    masks = rng.random((9, 4, 5)).astype(np.float32)
    full = kaleidoscope_cassi(masks, [0.0, 1.5], 9)
    expected = [Identity, Flip, Flip, Flip, Flip] + [Flip] * 4
    axes = [None, (1,), (1,), (0,), (0,)] + [(0, 1)] * 4
    for v, cls, ax in zip(full.views, expected, axes):
        assert isinstance(v.warp, cls)
        if ax is not None:
            assert v.warp.axes == ax
    f = rng.random(full.ishape)
    for n in (1, 2, 3, 5):
        sub = kaleidoscope_cassi(masks, [0.0, 1.5], n)
        np.testing.assert_allclose(sub.forward(f), full.forward(f)[:n], rtol=1e-6)
    # Calibrated warps replace the ideal maps (None keeps the ideal one).
    t = Translate(0.5, 0.25)
    op = kaleidoscope_cassi(masks, [0.0, 1.5], 3, warps=[None, t, None])
    assert isinstance(op.views[0].warp, Identity) and isinstance(op.views[2].warp, Flip)
    assert isinstance(op.views[1].warp, HomographyWarp)
    assert dot_test(op) < 1e-6


def test_kaleidoscope_dot_tests_all_view_counts():
    rng = np.random.default_rng(5)
    masks = rng.random((9, 6, 7)).astype(np.float32)
    offsets = [-1.25, 0.0, 0.4, 2.6]
    for n in range(1, 10):
        for inv in (True, False):
            assert dot_test(kaleidoscope_cassi(masks, offsets, n, inversion=inv), rng) < 1e-6


# -- bad input ------------------------------------------------------------------------------
@pytest.mark.parametrize("make", [
    lambda: CassiOperator([]),
    lambda: CassiOperator([View(np.ones((3, 4)), [0, 1]), View(np.ones((3, 5)), [0, 1])]),
    lambda: CassiOperator([View(np.ones((3, 4)), [0, 1]), View(np.ones((3, 4)), [0, 1, 2])]),
    lambda: CassiOperator([View(np.ones((3, 4)), [0, 1])], (2, 3, 5)),   # identity, size change
    lambda: CassiOperator([View(np.ones((3, 4)), [0, 1])], (3, 4, 2)),   # (H, W, L) by mistake
    lambda: CassiOperator(["not a view"]),
    lambda: View(np.ones((3, 4)), [0, np.nan]),
    lambda: View(np.full((3, 4), np.inf), [0, 1]),
    lambda: View(np.ones((3, 4)), [0, 1], warp="flip"),
    lambda: standard_cassi(np.ones((3, 4)), np.nan, 4),
    lambda: standard_cassi(np.ones((3, 4)), 2, 0),
    lambda: standard_cassi(np.ones(4), 2, 3),
    lambda: kaleidoscope_cassi(np.ones((5, 3, 4)), [0, 1], 10),
    lambda: kaleidoscope_cassi(np.ones((2, 3, 4)), [0, 1], 3),
    lambda: kaleidoscope_cassi(np.ones((3, 3, 4)), [[0, 1]], 3),
    lambda: kaleidoscope_cassi(np.ones((3, 3, 4)), [0, 1], 3, warps=[None]),
])
def test_bad_input(make):
    with pytest.raises(InputError):
        make()


def test_shape_checks_on_apply():
    op = standard_cassi(np.ones((3, 4)), 1, 2)
    with pytest.raises(ValueError):
        op.forward(np.ones((3, 4, 2)))
    with pytest.raises(ValueError):
        op.adjoint(np.ones((3, 5)))

