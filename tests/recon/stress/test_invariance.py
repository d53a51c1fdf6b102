r"""Invariances of the reconstruction, every solver.

- Scale: the objective :math:`\tfrac12\|sg - Hsf\|^2 + s\tau\,\mathrm{TV}(sf)` is :math:`s^2`
  times the original, TV being 1-homogeneous, so ``solve(s·g, tau=s·tau) = s·solve(g, tau)``
  (GAP-TV too: :math:`\mathrm{prox}_{s\lambda\mathrm{TV}}(sv) = s\,\mathrm{prox}_{\lambda
  \mathrm{TV}}(v)`, and every step-size rule is scale-free).  Checked in float64 to 1e-10.
- Integer shift: scene *and* masks shifted together (the whole problem translated) give the
  translated solution; the scene has a zero border so nothing crosses the edge.  Compared in
  the interior: the difference must be 20× smaller than between shifted and unshifted
  solutions.
- Sub-pixel shift: a mask coded by rows (constant along x, so it commutes with x shifts) and
  the scene shifted by a fraction of a pixel (linear interpolation) along the dispersion
  axis: of the solution shifted by 0, 0.25, ..., 2 px, the one that best matches the
  solution of the shifted scene is the true shift.
"""

import numpy as np
import pytest
import scipy.ndimage as ndi

from recon.operators import kaleidoscope_cassi
from recon.solvers import SOLVERS, solve

NAMES = sorted(SOLVERS)
L, N, B = 6, 40, 10  # bands, image size, zero border
INTERIOR = (slice(None), slice(B, N - B), slice(B, N - B))
OFFSETS = 0.9 * np.arange(L)


@pytest.fixture(scope="module")
def scene(stress):
    truth = np.zeros((L, N, N))
    truth[:, B:N - B, B:N - B] = stress.piecewise_cube(L, N - 2 * B, N - 2 * B, seed=3)
    return truth


def _norm(a):
    return float(np.linalg.norm(a[INTERIOR]))


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("s", [1e-3, 7.0, 1e3])
def test_scaling_the_measurement_scales_the_solution(stress, name, s):
    op = stress.kaleido_op(3)
    g = stress.add_noise(op.forward(stress.piecewise_cube()), 30.0, seed=1).astype(np.float64)
    x1 = solve(name, op, g, iters=40, tau=stress.TAU[name]).x
    xs = solve(name, op, s * g, iters=40, tau=s * stress.TAU[name]).x
    assert stress.rel_err(xs / s, x1) < 1e-10


# Mirror views see the scene flipped: a scene shift (dy, dx) is a shift of the view's mask
# in view coordinates by (±dy, ±dx), the sign flipped along each mirrored axis.
_FLIPS = {0: (False, False), 1: (False, True), 2: (False, True), 3: (True, False),
          4: (True, False)}


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("n_views", [1, 3, 5])
def test_integer_shift_of_scene_and_masks_shifts_the_solution(stress, scene, name, n_views):
    dy, dx = 3, -2
    masks = stress.random_masks(9, N, N, seed=0)
    moved = np.stack([np.roll(masks[k], (-dy if _FLIPS[k][0] else dy, -dx if _FLIPS[k][1] else dx),
                              (0, 1)) for k in range(n_views)])
    op = kaleidoscope_cassi(masks, OFFSETS, n_views)
    op_s = kaleidoscope_cassi(moved, OFFSETS, n_views)
    shifted = np.roll(scene, (dy, dx), (1, 2))
    x = solve(name, op, op.forward(scene), iters=40, tau=stress.TAU[name]).x
    xs = solve(name, op_s, op_s.forward(shifted), iters=40, tau=stress.TAU[name]).x
    moved_with = _norm(xs - np.roll(x, (dy, dx), (1, 2)))
    stayed = _norm(xs - x)
    assert moved_with < 0.05 * stayed, (moved_with, stayed)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("n_views", [1, 3])
@pytest.mark.parametrize("d", [0.5, 1.25])
def test_subpixel_shift_of_the_scene_shifts_the_solution(stress, scene, name, n_views, d):
    rows = (np.random.default_rng(0).random((N, 1)) < 0.5) * np.ones((1, N))
    op = kaleidoscope_cassi(np.stack([rows] * 9), OFFSETS, n_views)
    shifted = ndi.shift(scene, (0, 0, d), order=1, mode="constant")
    x = solve(name, op, op.forward(scene), iters=40, tau=stress.TAU[name]).x
    xs = solve(name, op, op.forward(shifted), iters=40, tau=stress.TAU[name]).x
    grid = np.arange(0.0, 2.01, 0.25)
    miss = [_norm(xs - ndi.shift(x, (0, 0, t), order=1, mode="constant")) for t in grid]
    assert grid[int(np.argmin(miss))] == d, dict(zip(grid.tolist(), np.round(miss, 4)))
    assert min(miss) < 0.7 * miss[0]  # clearly better than "did not move"
