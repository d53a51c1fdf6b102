"""Per-band dispersion shift: integer and sub-pixel, either sign, against explicit matrices."""

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from dense import shift_matrix
from recon.errors import InputError
from recon.operators import Dispersion, dot_test

SETTINGS = settings(max_examples=30, deadline=None, derandomize=True, database=None)

offset = st.one_of(st.integers(-5, 5).map(float),
                   st.floats(-5.0, 5.0, allow_nan=False).map(lambda v: round(v, 3)))


def dense_dispersion(offsets, h, w):
    phi = np.asarray(offsets, dtype=np.float64)
    lo = math.floor(phi.min())
    wm = w + math.ceil(phi.max()) - lo
    blocks = [np.kron(np.eye(h), shift_matrix(p - lo, w, wm)) for p in phi]
    out = np.zeros((len(phi) * h * wm, len(phi) * h * w))
    for l, b in enumerate(blocks):
        out[l * h * wm:(l + 1) * h * wm, l * h * w:(l + 1) * h * w] = b
    return out, wm


@SETTINGS
@given(offsets=st.lists(offset, min_size=1, max_size=4), h=st.integers(1, 4),
       w=st.integers(1, 6), seed=st.integers(0, 2**16))
def test_matches_dense(offsets, h, w, seed):
    rng = np.random.default_rng(seed)
    op = Dispersion(offsets, (h, w))
    dense, wm = dense_dispersion(offsets, h, w)
    assert op.oshape == (len(offsets), h, wm)
    x = rng.standard_normal(op.ishape)
    y = rng.standard_normal(op.oshape)
    np.testing.assert_allclose(op.forward(x).ravel(), dense @ x.ravel(), atol=1e-12)
    np.testing.assert_allclose(op.adjoint(y).ravel(), dense.T @ y.ravel(), atol=1e-12)
    np.testing.assert_allclose(op.row_norms_sq().ravel(), np.sum(dense**2, axis=1), atol=1e-12)
    assert dot_test(op, rng) < 1e-6


def test_integer_shift_is_exact_copy():
    rng = np.random.default_rng(1)
    x = rng.random((3, 4, 5), dtype=np.float32)
    op = Dispersion([-2, 0, 3], (4, 5))
    g = op.forward(x)
    assert g.shape == (3, 4, 10)
    np.testing.assert_array_equal(g[0, :, 0:5], x[0])
    np.testing.assert_array_equal(g[1, :, 2:7], x[1])
    np.testing.assert_array_equal(g[2, :, 5:10], x[2])
    np.testing.assert_array_equal(g[0, :, 5:], 0)


@pytest.mark.parametrize("phi", [0.25, 1.5, -0.75, 2.9])
def test_subpixel_shift_moves_a_ramp(phi):
    # Linear interpolation is exact on affine signals: inside, S_phi v (x) = v(x - phi).
    w = 12
    v = np.arange(w, dtype=np.float64)[None, None, :]
    op = Dispersion([0.0, phi], (1, w))
    g = op.forward(np.concatenate([v, v]))
    lo = min(0, math.floor(phi))
    x = np.arange(g.shape[2])
    inner = (x - (phi - lo) >= 0) & (x - (phi - lo) <= w - 1)
    np.testing.assert_allclose(g[1, 0, inner], (x - (phi - lo))[inner], atol=1e-12)
    # The unshifted band is exactly the ramp at column -lo.
    np.testing.assert_array_equal(g[0, 0, -lo:-lo + w], v[0, 0])


def test_near_integer_offsets_snap():
    op = Dispersion([0.0, 0.1 * 30], (2, 4))
    assert op.oshape == (2, 2, 7)
    assert op.offsets[1] == 3.0


@pytest.mark.parametrize("offsets", [[], [[0, 1]], [0.0, np.nan], [np.inf], ["a"]])
def test_bad_offsets(offsets):
    with pytest.raises(InputError):
        Dispersion(offsets, (2, 3))


def test_bad_image_shape():
    with pytest.raises(InputError):
        Dispersion([0, 1], (0, 3))
