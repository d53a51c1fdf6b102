"""CalibratedCassi: per-band sensor masks C_kl, g_k = sum_l C_kl * S_kl(W_k f_l)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from dense import assert_matches_dense, flip_matrix, shift_matrix
from recon.errors import InputError
from recon.operators import (
    CalibratedCassi, Flip, Translate, dot_test, kaleidoscope_cassi,
)

SETTINGS = settings(max_examples=30, deadline=None, derandomize=True, database=None)


def dense_calibrated(cmasks, offsets, warp_mats, shape):
    k_, l_, hv, wm = cmasks.shape
    wv = warp_mats[0].shape[0] // hv
    rows = []
    for k in range(k_):
        rows.append(np.hstack([
            np.diag(cmasks[k, l].astype(np.float64).ravel())
            @ np.kron(np.eye(hv), shift_matrix(offsets[k, l], wv, wm)) @ warp_mats[k]
            for l in range(l_)]))
    return np.vstack(rows)


@SETTINGS
@given(k=st.integers(1, 4), l_=st.integers(1, 3), h=st.integers(1, 4), w=st.integers(1, 5),
       extra=st.integers(1, 4), data=st.data(), seed=st.integers(0, 2**16))
def test_matches_dense_reference(k, l_, h, w, extra, data, seed):
    rng = np.random.default_rng(seed)
    wm = w + extra
    # Absolute offsets that fit: 0 <= phi and ceil(phi) + W <= Wm.
    offsets = np.array([[data.draw(st.floats(0.0, float(extra)).map(lambda v: round(v, 3)))
                         for _ in range(l_)] for _ in range(k)])
    kinds = [data.draw(st.sampled_from([None, (0,), (1,), (0, 1)])) for _ in range(k)]
    warps = [None if a is None else Flip(a) for a in kinds]
    mats = [np.eye(h * w) if a is None else flip_matrix((h, w), a) for a in kinds]
    cm = rng.random((k, l_, h, wm)).astype(np.float32)
    op = CalibratedCassi(cm, offsets, warps, (l_, h, w))
    a = dense_calibrated(cm, offsets, mats, (l_, h, w))
    assert op.ishape == (l_, h, w) and op.oshape == (k, h, wm)
    assert_matches_dense(op, a, rng)


@SETTINGS
@given(k=st.integers(1, 3), l_=st.integers(1, 3), h=st.integers(1, 3), w=st.integers(1, 6),
       wm=st.integers(1, 8), data=st.data(), seed=st.integers(0, 2**16))
def test_bands_past_the_crop_edges(k, l_, h, w, wm, data, seed):
    # A view image that starts before the crop (negative offsets) or ends after it: the
    # columns outside [0, Wm) are dropped, in the NumPy path as in the dense reference.
    rng = np.random.default_rng(seed)
    offsets = np.array([[data.draw(st.floats(-w + 0.01, wm - 0.01).map(lambda v: round(v, 2)))
                         for _ in range(l_)] for _ in range(k)])
    kinds = [data.draw(st.sampled_from([None, (0,), (1,)])) for _ in range(k)]
    cm = rng.random((k, l_, h, wm)).astype(np.float32)
    op = CalibratedCassi(cm, offsets, [None if a is None else Flip(a) for a in kinds],
                         (l_, h, w))
    a = dense_calibrated(cm, offsets, [np.eye(h * w) if a is None else flip_matrix((h, w), a)
                                       for a in kinds], (l_, h, w))
    assert_matches_dense(op, a, rng)


def test_translate_warp_dot_and_row_norms():
    rng = np.random.default_rng(7)
    cm = rng.random((2, 3, 4, 9)).astype(np.float32)
    op = CalibratedCassi(cm, [[0, 1.5, 2.25], [3, 2, 0.5]], [Translate(0.4, -0.7), None],
                         (3, 4, 5))
    assert dot_test(op, rng) < 1e-6
    n = int(np.prod(op.oshape))
    dense_rows = np.array([np.sum(op.adjoint(np.eye(n)[i].reshape(op.oshape))**2)
                           for i in range(n)])
    np.testing.assert_allclose(op.row_norms_sq().ravel(), dense_rows, rtol=1e-5, atol=1e-6)


def test_equals_mask_and_shift_for_integer_offsets():
    # With C_kl = S_kl(M_k) (the ideal shifted masks), C * S(Wf) = S(M * Wf) for integer shifts.
    rng = np.random.default_rng(8)
    h, w, l_ = 5, 6, 4
    masks = (rng.random((5, h, w)) > 0.5).astype(np.float32)
    offsets = np.array([0.0, 1.0, 3.0, 4.0])
    ideal = kaleidoscope_cassi(masks, offsets, 5)
    wm = ideal.oshape[2]
    cm = np.zeros((5, l_, h, wm), dtype=np.float32)
    for k in range(5):
        for l, a in enumerate(offsets.astype(int)):
            cm[k, l, :, a:a + w] = masks[k]
    cal = CalibratedCassi(cm, offsets, [v.warp for v in ideal.views], (l_, h, w))
    f = rng.random(ideal.ishape).astype(np.float32)
    y = rng.random(ideal.oshape).astype(np.float32)
    np.testing.assert_allclose(cal.forward(f), ideal.forward(f), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(cal.adjoint(y), ideal.adjoint(y), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(cal.row_norms_sq(), ideal.row_norms_sq(), rtol=1e-12)


def test_default_cube_shape_and_3d_masks():
    cm = np.ones((3, 4, 10), dtype=np.float32)
    op = CalibratedCassi(cm, [0, 1.5, 3])
    assert op.ishape == (3, 4, 7) and op.oshape == (1, 4, 10)  # W = Wm - ceil(max phi)
    assert op.forward(np.ones(op.ishape, dtype=np.float32)).dtype == np.float32


@pytest.mark.parametrize("make", [
    # A band whose image misses the crop: wholly right of it, wholly left of it.
    lambda: CalibratedCassi(np.ones((1, 2, 3, 6)), [0, 6], cube_shape=(2, 3, 3)),
    lambda: CalibratedCassi(np.ones((1, 2, 3, 6)), [0, -3], cube_shape=(2, 3, 3)),
    lambda: CalibratedCassi(np.ones((1, 2, 3, 6)), [-3.5, 0], cube_shape=(2, 3, 2)),
    lambda: CalibratedCassi(np.ones((1, 2, 3, 6)), [0, 1, 2], cube_shape=(2, 3, 3)),
    lambda: CalibratedCassi(np.ones((1, 2, 3, 6)), [0, np.nan], cube_shape=(2, 3, 3)),
    lambda: CalibratedCassi(np.full((1, 2, 3, 6), np.nan), [0, 1], cube_shape=(2, 3, 3)),
    lambda: CalibratedCassi(np.ones((3, 3, 6)), [0, 1], cube_shape=(3, 3, 3)),        # L mismatch
    lambda: CalibratedCassi(np.ones((2, 2, 3, 6)), [0, 1], [None], (2, 3, 3)),
    lambda: CalibratedCassi(np.ones((1, 2, 3, 6)), [0, 1], cube_shape=(3, 3, 3)),
    lambda: CalibratedCassi(np.ones((1, 2, 3, 6)), [0, 1], cube_shape=(2, 4, 3)),     # height
    lambda: CalibratedCassi(np.ones((3, 6)), [0, 1]),
])
def test_bad_input(make):
    with pytest.raises(InputError):
        make()
