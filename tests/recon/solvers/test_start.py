"""Starting points (recon.solvers.start) and FISTA's start= option."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.operators import MatrixOperator
from recon.solvers import fista_tv
from recon.solvers.start import normalised_backprojection


@pytest.mark.parametrize("key", ["standard", "kaleido3"])
def test_constant_cube_is_returned_exactly(ops, key):
    # ... where the operator sees the voxel (single-view CASSI: where the mask is open); a
    # voxel it never sees starts at 0.
    op = ops[key]
    x = np.full(op.ishape, 0.37)
    x0 = normalised_backprojection(op, op.forward(x), np.float64)
    seen = op.adjoint(op.forward(np.ones(op.ishape))) > 0
    assert seen.mean() > 0.4
    np.testing.assert_allclose(x0[seen], 0.37, rtol=1e-12)
    assert np.all(x0[~seen] == 0)


@pytest.mark.parametrize("key", ["standard", "kaleido3"])
def test_mask_pattern_is_divided_out(ops, key):
    # A band-wise constant cube (a flat scene with a spectrum): on the voxels the operator
    # sees, the plain back-projection carries the mask's pattern, the normalised one is closer to
    # the cube.
    op = ops[key]
    x = np.ones(op.ishape) * np.linspace(0.2, 1.0, op.ishape[0])[:, None, None]
    g = op.forward(x)
    seen = op.adjoint(op.forward(np.ones(op.ishape))) > 0
    x0 = normalised_backprojection(op, g, np.float64)[seen]
    adj = op.adjoint(g)[seen]
    adj *= np.vdot(adj, x[seen]) / np.vdot(adj, adj)          # its best scale
    # (0.74 and 0.63 of the error here: single-view CASSI mixes the bands in each pixel.)
    assert np.linalg.norm(x0 - x[seen]) < 0.8 * np.linalg.norm(adj - x[seen])


def test_unseen_voxels_start_at_zero():
    m = np.zeros((4, 6))
    m[0, 0] = m[1, 1] = m[2, 2] = m[3, 3] = 2.0          # voxels 4 and 5 unseen
    op = MatrixOperator(m, ishape=(1, 2, 3), oshape=(4,))
    x0 = normalised_backprojection(op, np.array([2.0, 4.0, 6.0, 8.0]), np.float64)
    np.testing.assert_allclose(x0.reshape(-1), [1.0, 2.0, 3.0, 4.0, 0.0, 0.0])


def test_zero_operator_is_an_input_error():
    op = MatrixOperator(np.zeros((4, 6)), ishape=(1, 2, 3), oshape=(4,))
    with pytest.raises(InputError, match="nowhere positive"):
        normalised_backprojection(op, np.ones(4), np.float64)


def test_fista_start_option_same_minimum(ops):
    op = ops["kaleido3"]
    rng = np.random.default_rng(4)
    x = np.zeros(op.ishape)
    x[:, 8:20, 5:25] = rng.random((op.ishape[0], 1, 1))
    g = op.forward(x)
    a = fista_tv(op, g, iters=1500, tau=0.02, objective=True)
    b = fista_tv(op, g, iters=1500, tau=0.02, objective=True, start="normalised")
    assert b.objective[-1] == pytest.approx(a.objective[-1], rel=1e-5)
    # It starts closer: a lower objective after the first iteration.
    assert b.objective[0] < a.objective[0]
    with pytest.raises(InputError, match="start must be"):
        fista_tv(op, g, iters=2, tau=0.02, start="zeros")
