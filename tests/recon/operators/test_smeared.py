"""SmearedCassi: g_k = sum_l D_kl (M_k * W_k f_l), D_kl a multi-tap horizontal kernel."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from dense import assert_matches_dense, flip_matrix
from recon.errors import InputError
from recon.operators import (
    CalibratedCassi, Flip, SmearedCassi, Translate, dot_test, kaleidoscope_cassi,
)
from recon.operators.smeared import smear_matrix, taps_from_positions
from recon.operators.warp import HomographyWarp

SETTINGS = settings(max_examples=30, deadline=None, derandomize=True, database=None)


def dense_smeared(masks, start, weights, warp_mats, wm):
    k_, hv, wv = masks.shape
    l_ = start.shape[1]
    rows = []
    for k in range(k_):
        rows.append(np.hstack([
            np.kron(np.eye(hv), smear_matrix(start[k, l], weights[k, l], wv, wm))
            @ np.diag(masks[k].astype(np.float64).ravel()) @ warp_mats[k]
            for l in range(l_)]))
    return np.vstack(rows)


@SETTINGS
@given(k=st.integers(1, 3), l_=st.integers(1, 3), h=st.integers(1, 4), w=st.integers(1, 5),
       n_taps=st.integers(1, 4), data=st.data(), seed=st.integers(0, 2**16))
def test_matches_dense_reference(k, l_, h, w, n_taps, data, seed):
    rng = np.random.default_rng(seed)
    start = rng.integers(0, 3, size=(k, l_))
    weights = rng.random((k, l_, n_taps))
    weights[rng.random(weights.shape) < 0.2] = 0.0            # padding inside the table
    kinds = [data.draw(st.sampled_from([None, (0,), (1,), (0, 1)])) for _ in range(k)]
    warps = [None if a is None else Flip(a) for a in kinds]
    mats = [np.eye(h * w) if a is None else flip_matrix((h, w), a) for a in kinds]
    masks = rng.random((k, h, w)).astype(np.float32)
    wm = w + 2 + n_taps
    op = SmearedCassi(masks, start, weights, warps, (l_, h, w), width=wm)
    a = dense_smeared(masks, start, weights, mats, wm)
    assert op.ishape == (l_, h, w) and op.oshape == (k, h, wm)
    assert_matches_dense(op, a, rng)


@pytest.mark.parametrize("warp", [Translate(0.4, -0.7),
                                  HomographyWarp([[2.0, 0.05, 0.3], [0.02, 1.1, -0.2],
                                                  [0.001, 0.0, 1.0]], (5, 7), (4, 6))])
def test_resampling_warp_dot_and_row_norms(warp):
    # Bilinear resampling makes rows at lags >= 1 overlap: the closed form must include them
    # (a magnifying homography overlaps rows two and three columns apart too).
    rng = np.random.default_rng(7)
    masks = rng.random((2, 4, 6)).astype(np.float32)
    start = np.array([[0, 1, 2], [2, 0, 1]])
    weights = rng.random((2, 3, 4))
    homography = isinstance(warp, HomographyWarp)
    other = HomographyWarp(np.eye(3), (5, 7), (4, 6)) if homography else None
    op = SmearedCassi(masks, start, weights, [warp, other], (3, 5, 7) if homography
                      else (3, 4, 6))
    assert dot_test(op, rng) < 1e-6
    n = int(np.prod(op.oshape))
    e = np.eye(n)
    dense_rows = np.array([np.sum(op.adjoint(e[i].reshape(op.oshape)) ** 2) for i in range(n)])
    np.testing.assert_allclose(op.row_norms_sq().ravel(), dense_rows, rtol=1e-5, atol=1e-6)
    assert dot_test(op, rng, dtype=np.float32) < 1e-4


@SETTINGS
@given(n=st.integers(1, 9), seed=st.integers(0, 2**16), data=st.data())
def test_one_position_per_band_equals_cassi_operator(n, seed, data):
    # One landing position per band = two linear-interpolation taps: the CassiOperator.
    rng = np.random.default_rng(seed)
    h, w, l_ = 4, 6, 3
    masks = (rng.random((n, h, w)) > 0.5).astype(np.float32)
    offsets = np.array([data.draw(st.floats(0.0, 4.0).map(lambda v: round(v, 2)))
                        for _ in range(l_)])
    ideal = kaleidoscope_cassi(masks, offsets, n)
    # CassiOperator's offsets are normalised (smallest floor at 0) and, like these taps, apply
    # in view coordinates after the warp (flipped views included).
    start, weights = taps_from_positions(ideal.offsets[:, :, None])
    op = SmearedCassi(masks, start, weights, [v.warp for v in ideal.views], ideal.ishape,
                      width=ideal.oshape[2])
    f = rng.random(ideal.ishape).astype(np.float32)
    y = rng.random(ideal.oshape).astype(np.float32)
    np.testing.assert_allclose(op.forward(f), ideal.forward(f), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(op.adjoint(y), ideal.adjoint(y), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(op.row_norms_sq(), ideal.row_norms_sq(), rtol=1e-6, atol=1e-9)


def test_integer_positions_equal_calibrated_cassi_with_shifted_masks():
    # Integer shifts: D(M * Wf) = S(M) * S(Wf), the calibrated model with ideal mask images.
    rng = np.random.default_rng(3)
    h, w = 5, 7
    masks = rng.random((2, h, w)).astype(np.float32)
    offsets = np.array([[0.0, 2.0, 3.0], [1.0, 0.0, 4.0]])
    wm = w + 4
    cm = np.zeros((2, 3, h, wm), dtype=np.float32)
    for k in range(2):
        for l, a in enumerate(offsets[k].astype(int)):
            cm[k, l, :, a:a + w] = masks[k]
    cal = CalibratedCassi(cm, offsets, [None, Flip(0)], (3, h, w))
    start, weights = taps_from_positions(offsets[:, :, None])
    op = SmearedCassi(masks, start, weights, [None, Flip(0)], (3, h, w), width=wm)
    f = rng.random(op.ishape).astype(np.float32)
    np.testing.assert_allclose(op.forward(f), cal.forward(f), rtol=1e-6)
    np.testing.assert_allclose(op.row_norms_sq(), cal.row_norms_sq(), rtol=1e-12)


def test_taps_from_positions_is_a_smeared_hat():
    # Samples spread evenly over [2.0, 5.0): a box of width 3 convolved with the hat.
    pos = 2.0 + 3.0 * (np.arange(300) + 0.5) / 300
    start, w = taps_from_positions(pos[None, :])
    assert start[0] == 2 and w.shape == (1, 4)
    np.testing.assert_allclose(w.sum(axis=-1), 1.0)
    np.testing.assert_allclose(w[0], [1 / 6, 1 / 3, 1 / 3, 1 / 6], atol=2e-3)
    # One position: linear interpolation, and an integer is one exact tap.
    s1, w1 = taps_from_positions([[1.25], [3.0]])
    np.testing.assert_array_equal(s1, [1, 3])
    np.testing.assert_allclose(w1, [[0.75, 0.25], [1.0, 0.0]])
    with pytest.raises(InputError):
        taps_from_positions([[-0.5, 1.0]])
    with pytest.raises(InputError):
        taps_from_positions([[np.nan]])


@pytest.mark.parametrize("make", [
    lambda: SmearedCassi(np.ones((1, 3, 4)), [[0, 1]], np.ones((1, 2, 2)), width=5),   # 1+1+4 > 5
    lambda: SmearedCassi(np.ones((1, 3, 4)), [[-1, 0]], np.ones((1, 2, 1))),
    lambda: SmearedCassi(np.ones((1, 3, 4)), [[0.5, 0]], np.ones((1, 2, 1))),
    lambda: SmearedCassi(np.ones((1, 3, 4)), [[0, 1]], np.ones((1, 3, 1))),           # L mismatch
    lambda: SmearedCassi(np.ones((1, 3, 4)), [[0, 1]], np.full((1, 2, 1), np.nan)),
    lambda: SmearedCassi(np.full((1, 3, 4), np.inf), [[0, 1]], np.ones((1, 2, 1))),
    lambda: SmearedCassi(np.ones((2, 3, 4)), [[0, 1]] * 2, np.ones((2, 2, 1)), [None]),
    lambda: SmearedCassi(np.ones((1, 3, 4)), [[0, 1]], np.ones((1, 2, 1)), cube_shape=(3, 3, 4)),
    lambda: SmearedCassi(np.ones((1, 3, 4)), [[0, 1]], np.ones((1, 2, 1)), cube_shape=(2, 3, 5)),
    lambda: SmearedCassi(np.ones(4), [[0, 1]], np.ones((1, 2, 1))),
])
def test_bad_input(make):
    with pytest.raises(InputError):
        make()


def test_default_shapes_and_dtype():
    op = SmearedCassi(np.ones((3, 4), dtype=np.float32), [0, 2], [[0.5, 0.5], [1.0, 0.0]])
    assert op.ishape == (2, 3, 4) and op.oshape == (1, 3, 4 + 2)
    assert op.forward(np.ones(op.ishape, dtype=np.float32)).dtype == np.float32
    np.testing.assert_allclose(op.forward(np.ones(op.ishape)).sum(), 2 * 12)
