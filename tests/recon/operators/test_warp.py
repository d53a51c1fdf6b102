"""Geometric maps: permutations as views, bilinear homographies against loops and OpenCV."""

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from dense import flip_matrix
from recon.errors import InputError
from recon.operators import (
    Flip, HomographyWarp, Identity, Translate, WarpOperator, dot_test,
)

SETTINGS = settings(max_examples=25, deadline=None, derandomize=True, database=None)


def dense_homography(matrix, in_shape, out_shape):
    """Loop reference: view pixel (xv, yv) reads the centre image bilinearly at inv(matrix) p."""
    h, w = in_shape
    hv, wv = out_shape
    inv = np.linalg.inv(np.asarray(matrix, dtype=np.float64))
    a = np.zeros((hv * wv, h * w))
    for yv in range(hv):
        for xv in range(wv):
            q = inv @ np.array([xv, yv, 1.0])
            if q[2] <= 0:
                continue
            xs, ys = q[0] / q[2], q[1] / q[2]
            x0, y0 = math.floor(xs), math.floor(ys)
            fx, fy = xs - x0, ys - y0
            for yy, wy in ((y0, 1 - fy), (y0 + 1, fy)):
                for xx, wx in ((x0, 1 - fx), (x0 + 1, fx)):
                    if 0 <= yy < h and 0 <= xx < w and wy * wx > 1e-9:
                        a[yv * wv + xv, yy * w + xx] += wy * wx
    return a


def check_operator(op, dense, rng):
    x = rng.standard_normal(op.ishape)
    y = rng.standard_normal(op.oshape)
    l = op.ishape[0]
    big = np.kron(np.eye(l), dense)
    np.testing.assert_allclose(op.forward(x).ravel(), big @ x.ravel(), atol=1e-6)
    np.testing.assert_allclose(op.adjoint(y).ravel(), big.T @ y.ravel(), atol=1e-6)
    np.testing.assert_allclose(op.row_norms_sq().ravel(), np.sum(big**2, axis=1), atol=1e-6)
    assert dot_test(op, rng) < 1e-6


@pytest.mark.parametrize("axes", [(0,), (1,), (0, 1)])
def test_flip_matches_permutation_and_is_a_view(axes):
    rng = np.random.default_rng(0)
    warp = Flip(axes).bind((3, 5))
    op = WarpOperator(warp, 2)
    check_operator(op, flip_matrix((3, 5), axes), rng)
    x = rng.random((2, 3, 5), dtype=np.float32)
    v = warp.apply(x)
    assert np.shares_memory(v, x)  # negative strides, no copy
    np.testing.assert_array_equal(warp.apply_adjoint(v), x)  # an involution


def test_identity():
    rng = np.random.default_rng(1)
    warp = Identity().bind((4, 3))
    check_operator(WarpOperator(warp, 2), np.eye(12), rng)
    with pytest.raises(InputError):
        Identity().bind((4, 3), (4, 4))


@SETTINGS
@given(h=st.integers(1, 5), w=st.integers(1, 5), hv=st.integers(1, 5), wv=st.integers(1, 5),
       params=st.lists(st.floats(-1.0, 1.0), min_size=8, max_size=8), seed=st.integers(0, 999))
def test_homography_matches_loop_reference(h, w, hv, wv, params, seed):
    p = np.asarray(params)
    matrix = np.array([[1 + 0.3 * p[0], 0.3 * p[1], 2 * p[2]],
                       [0.3 * p[3], 1 + 0.3 * p[4], 2 * p[5]],
                       [0.02 * p[6], 0.02 * p[7], 1.0]])
    warp = HomographyWarp(matrix, (h, w), (hv, wv))
    dense = dense_homography(matrix, (h, w), (hv, wv))
    np.testing.assert_allclose(warp.matrix().toarray(), dense, atol=1e-5)
    check_operator(WarpOperator(warp, 2), warp.matrix().toarray(), np.random.default_rng(seed))
    n, c = warp.norm_parts()
    np.testing.assert_allclose(n.ravel(), np.sum(dense**2, axis=1), atol=1e-5)
    rows = np.arange(hv * wv).reshape(hv, wv)
    expect_c = np.sum(dense[rows[:, :-1].ravel()] * dense[rows[:, 1:].ravel()], axis=1)
    np.testing.assert_allclose(c.ravel(), expect_c, atol=1e-5)


@pytest.mark.parametrize("axes", [(0,), (1,), (0, 1)])
def test_flip_written_as_homography_is_the_flip(axes):
    h, w = 4, 6
    sx, sy = (-1.0 if 1 in axes else 1.0), (-1.0 if 0 in axes else 1.0)
    m = np.array([[sx, 0, (w - 1) if sx < 0 else 0], [0, sy, (h - 1) if sy < 0 else 0], [0, 0, 1]])
    a = HomographyWarp(m, (h, w)).matrix().toarray()
    np.testing.assert_array_equal(a, flip_matrix((h, w), axes))


def test_homography_agrees_with_opencv():
    h, w = 40, 52
    yy, xx = np.mgrid[0:h, 0:w]
    img = (0.5 + 0.25 * np.sin(xx / 7.0) * np.cos(yy / 5.0)).astype(np.float32)
    m = np.array([[0.97, 0.05, 1.3], [-0.04, 1.02, -0.7], [2e-4, -1e-4, 1.0]])
    ours = HomographyWarp(m, (h, w), (h, w)).apply(img[None])[0]
    ref = cv2.warpPerspective(img, m, (w, h), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    # OpenCV quantises bilinear weights to 1/32; compare away from the border.
    inner = (slice(3, -3), slice(3, -3))
    err = np.abs(ours - ref)[inner]
    assert err.max() < 0.01 and err.mean() < 2e-3


def test_translate():
    rng = np.random.default_rng(3)
    img = rng.random((1, 5, 7))
    # Integer: plain slicing with zero fill.
    v = Translate(1, -2).bind((5, 7)).apply(img)
    expect = np.zeros_like(img)
    expect[:, 1:, :5] = img[:, :4, 2:]
    np.testing.assert_allclose(v, expect, atol=1e-7)
    # Sub-pixel on an affine image: exact inside, v(y, x) = f(y - dy, x - dx).
    yy, xx = np.mgrid[0:5, 0:7]
    aff = (2.0 * xx + 3.0 * yy)[None].astype(np.float64)
    v = Translate(0.25, 0.5).bind((5, 7)).apply(aff)
    np.testing.assert_allclose(v[0, 1:, 1:], (2.0 * (xx - 0.5) + 3.0 * (yy - 0.25))[1:, 1:],
                               atol=1e-5)
    check_operator(WarpOperator(Translate(0.3, -1.6), 2, (4, 5)),
                   dense_homography([[1, 0, -1.6], [0, 1, 0.3], [0, 0, 1]], (4, 5), (4, 5)), rng)


@pytest.mark.parametrize("make", [
    lambda: Flip(2),
    lambda: Flip("x"),
    lambda: Flip(()),
    lambda: Flip(1).bind((3, 4), (4, 3)),
    lambda: HomographyWarp(np.zeros((3, 3)), (3, 3)),
    lambda: HomographyWarp(np.eye(2), (3, 3)),
    lambda: HomographyWarp([[1, 0, np.nan], [0, 1, 0], [0, 0, 1]], (3, 3)),
    lambda: HomographyWarp(np.eye(3), (3, 3)).bind((4, 4)),
    lambda: Translate(np.inf, 0),
    lambda: Identity().bind((0, 2)),
])
def test_bad_input(make):
    with pytest.raises(InputError):
        make()


# ------------------------------------------------------------------ displacement fields
def _field(rng, scale=0.4, frame=(25.0, 20.0, 25.0, 20.0)):
    from recon.operators import DisplacementField

    return DisplacementField(scale * rng.uniform(-1, 1, (2, 6)), frame)


def test_displacement_field_is_fitted_and_moved():
    from recon.operators import DisplacementField

    rng = np.random.default_rng(4)
    f = _field(rng)
    pts = rng.uniform(0, 50, (30, 2))
    g = DisplacementField.fit(pts, np.stack(f(pts[:, 0], pts[:, 1]), axis=1), 2,
                              frame=f.frame)
    np.testing.assert_allclose(g.coeffs, f.coeffs, atol=1e-12)
    # The frame only reparametrises: a fit in the points' own frame is the same field.
    h = DisplacementField.fit(pts, np.stack(f(pts[:, 0], pts[:, 1]), axis=1), 2)
    np.testing.assert_allclose(np.stack(h(7.0, 9.0)), np.stack(f(7.0, 9.0)), atol=1e-10)
    # moved(dx): the same field in coordinates x' = x + dx.
    m = f.moved(7.5)
    np.testing.assert_allclose(np.stack(m(pts[:, 0] + 7.5, pts[:, 1])),
                               np.stack(f(pts[:, 0], pts[:, 1])), atol=1e-12)


@pytest.mark.parametrize("coeffs, frame", [(np.zeros((2, 5)), (0, 0, 1, 1)),
                                           (np.zeros((3, 6)), (0, 0, 1, 1)),
                                           (np.full((2, 6), np.nan), (0, 0, 1, 1)),
                                           (np.zeros((2, 6)), (0, 0, 0, 1))])
def test_displacement_field_bad_inputs(coeffs, frame):
    from recon.operators import DisplacementField

    with pytest.raises(InputError):
        DisplacementField(coeffs, frame)
    with pytest.raises(InputError, match="at least 6"):
        DisplacementField.fit(np.zeros((5, 2)), np.zeros((5, 2)), 2)


def test_homography_warp_with_fields_reads_where_the_fields_say():
    rng = np.random.default_rng(5)
    h = np.array([[0.98, 0.02, 3.0], [-0.01, 1.01, -2.0], [2e-4, -1e-4, 1.0]])
    dv, dc = _field(rng), _field(rng)
    in_shape, out_shape = (40, 50), (36, 44)
    warp = HomographyWarp(h, in_shape, out_shape, view_field=dv, centre_field=dc)
    # Bilinear interpolation of a linear ramp is exact: the view shows the ramp at q.
    yy, xx = np.mgrid[0:in_shape[0], 0:in_shape[1]].astype(np.float64)
    ramp = 0.3 * xx + 0.7 * yy + 1.0
    out = warp.apply(ramp[None])[0]
    py, px = np.mgrid[0:out_shape[0], 0:out_shape[1]].astype(np.float64)
    ex, ey = dv(px, py)
    q = np.linalg.inv(h) @ np.stack([(px - ex).ravel(), (py - ey).ravel(), np.ones(px.size)])
    qx, qy = q[0] / q[2], q[1] / q[2]
    cx, cy = dc(qx, qy)
    qx, qy = (qx + cx).reshape(px.shape), (qy + cy).reshape(px.shape)
    inside = (qx > 0.5) & (qx < in_shape[1] - 1.5) & (qy > 0.5) & (qy < in_shape[0] - 1.5)
    assert inside.mean() > 0.6
    np.testing.assert_allclose(out[inside], (0.3 * qx + 0.7 * qy + 1.0)[inside], atol=1e-4)
    # Zero fields are no fields; the adjoint is exact.
    from recon.operators import DisplacementField

    zero = DisplacementField(np.zeros((2, 6)), (0.0, 0.0, 1.0, 1.0))
    plain = HomographyWarp(h, in_shape, out_shape)
    with_zero = HomographyWarp(h, in_shape, out_shape, view_field=zero, centre_field=zero)
    assert (plain.matrix() != with_zero.matrix()).nnz == 0
    assert dot_test(WarpOperator(warp, 3), rng) < 1e-12
    with pytest.raises(InputError, match="DisplacementField"):
        HomographyWarp(h, in_shape, out_shape, view_field=np.zeros((2, 6)))


def test_displacement_field_bend_drops_the_affine_part():
    rng = np.random.default_rng(8)
    f = _field(rng)
    b = f.bend()
    x, y = rng.uniform(0, 50, 20), rng.uniform(0, 40, 20)
    # What is left is f minus its terms of degree <= 1 (an affine map of x, y).
    xc, yc, sx, sy = f.frame
    xi, eta = (x - xc) / sx, (y - yc) / sy
    for k in range(2):
        affine = f.coeffs[k, 0] + f.coeffs[k, 1] * xi + f.coeffs[k, 2] * eta
        np.testing.assert_allclose(b(x, y)[k], f(x, y)[k] - affine, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(h=st.integers(1, 30), w=st.integers(1, 30), hv=st.integers(1, 20), wv=st.integers(1, 20),
       seed=st.integers(0, 2 ** 31 - 1))
def test_bilinear_matrix_is_the_coo_builds_matrix(h, w, hv, wv, seed):
    # The CSR arrays made directly are those of the COO build and SciPy's conversion, to the
    # bit and in the same index types: points inside, on the edges, past them, snapped to
    # integers (within the tolerance from either side), far away, and not mapped at all.
    from recon.operators.warp import _WEIGHT_TOL, _bilinear_matrix, _bilinear_matrix_coo

    rng = np.random.default_rng(seed)
    n = hv * wv
    xs = rng.uniform(-2.5, w + 1.5, n)
    ys = rng.uniform(-2.5, h + 1.5, n)
    pick = rng.random(n)
    xs = np.where(pick < 0.2, np.round(xs) + rng.choice([-1, 1], n) * _WEIGHT_TOL / 2, xs)
    ys = np.where(pick > 0.8, np.round(ys), ys)
    xs[pick > 0.95] = 1e30
    ok = rng.random(n) > 0.1
    xs[~ok] = -2.0
    a = _bilinear_matrix(xs.copy(), ys.copy(), ok, (h, w), (hv, wv))
    b = _bilinear_matrix_coo(xs.copy(), ys.copy(), ok, (h, w), (hv, wv))
    assert a.shape == b.shape
    for name in ("indptr", "indices", "data"):
        got, want = getattr(a, name), getattr(b, name)
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)
