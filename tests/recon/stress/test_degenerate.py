"""Degenerate problems, every solver: finite outputs, or a clear InputError if ill-posed.

Decision (documented in the solvers): an operator that is zero (an all-closed mask in every
view) gives ``InputError("the operator is zero ...")`` from every solver — any cube fits the
data, so there is nothing to reconstruct, and returning the start (zeros) silently would hide
a calibration mistake.  A closed mask in *some* views is fine (those rows carry no data).

For the other cases the output must be finite and fit the data at least as well as the zero
cube, ``||Hx - g|| <= ||g||`` (no solver may make things worse than doing nothing).
"""

import numpy as np
import pytest

from recon.errors import InputError
from recon.operators import CassiOperator, View, kaleidoscope_cassi, standard_cassi
from recon.solvers import SOLVERS, solve

NAMES = sorted(SOLVERS)
L, H, W = 4, 16, 16
ITERS = 30


def _cube(l=L, h=H, w=W, seed=0):
    rng = np.random.default_rng(seed)
    x = np.full((l, h, w), 0.3, np.float32) * rng.uniform(0.5, 1.0, (l, 1, 1)).astype(np.float32)
    x[:, h // 4:3 * h // 4 + 1, w // 4:3 * w // 4 + 1] = 0.9
    return x


def _mask(h=H, w=W, seed=0):
    m = (np.random.default_rng(seed).random((h, w)) < 0.5).astype(np.float32)
    m[0, 0] = 1.0  # never all closed, even at 1×1
    return m


def _check(name, op, g, **kw):
    if "prior" not in kw:
        kw.setdefault("tau", 0.1)
    res = solve(name, op, g, iters=ITERS, **kw)
    x = res.x
    assert x.shape == op.ishape and np.all(np.isfinite(x))
    r = np.linalg.norm(op.forward(x) - g)
    assert r <= np.linalg.norm(g) * (1 + 1e-6) + 1e-12, (r, np.linalg.norm(g))
    return x


@pytest.mark.parametrize("name", NAMES)
def test_all_zero_measurement_gives_zero_cube(name):
    op = standard_cassi(_mask(), 1, L)
    x = _check(name, op, np.zeros(op.oshape, np.float32))
    assert np.all(x == 0)


@pytest.mark.parametrize("name", NAMES)
def test_constant_measurement(name):
    op = standard_cassi(_mask(), 1, L)
    x = _check(name, op, np.full(op.oshape, 0.7, np.float32))
    assert x.min() > -0.5 and x.max() < 2.0  # bounded: 0.7 over ~L/2 open bands


@pytest.mark.parametrize("name", NAMES)
def test_saturated_measurement(name):
    op = kaleidoscope_cassi(np.stack([_mask(seed=s) for s in range(3)]), np.arange(L), 3)
    g = op.forward(_cube())
    g = np.minimum(g, np.percentile(g, 60)).astype(np.float32)  # 40 % of pixels clipped
    _check(name, op, g)


@pytest.mark.parametrize("name", NAMES)
def test_all_open_mask(name):
    op = standard_cassi(np.ones((H, W)), 1, L)
    _check(name, op, op.forward(_cube()))


@pytest.mark.parametrize("name", NAMES)
def test_all_closed_mask_is_an_input_error(name):
    op = standard_cassi(np.zeros((H, W)), 1, L)
    with pytest.raises(InputError, match="operator is zero"):
        solve(name, op, np.zeros(op.oshape, np.float32), iters=5, tau=0.1)
    op3 = kaleidoscope_cassi(np.zeros((3, H, W)), np.arange(L), 3)
    with pytest.raises(InputError, match="operator is zero"):
        solve(name, op3, np.ones(op3.oshape, np.float32), iters=5, tau=0.1)


@pytest.mark.parametrize("name", NAMES)
def test_one_closed_view_among_three_is_fine(name):
    masks = np.stack([_mask(seed=0), np.zeros((H, W), np.float32), _mask(seed=2)])
    op = kaleidoscope_cassi(masks, np.arange(L), 3)
    _check(name, op, op.forward(_cube()))


@pytest.mark.parametrize("name", NAMES)
def test_identical_views_rank_deficient(name):
    """H2 = [H; H] repeats every row.  For the objective ½||[g; g] - H2 x||² = 2·½||g - Hx||²,
    tau on two copies is tau/2 on one; TwIST and FISTA scale their step with ||H2||² = 2||H||²
    (the power iteration sees exactly the doubled operator), so from the same start the
    iterates coincide.  So do ADMM's, its penalty scaled with ||H2||² too, when both take the
    conjugate-gradient x step (invariant to the system's scale; the exact step needs a
    diagonal H Hᵀ, which the repeated rows break)."""
    mask, offs = _mask(), np.arange(L, dtype=np.float64)
    one = CassiOperator([View(mask, offs)])
    two = CassiOperator([View(mask, offs), View(mask, offs)])
    g = one.forward(_cube())
    x0 = one.adjoint(g)  # TwIST starts from H^T g, which the duplication would double
    x2 = _check(name, two, np.concatenate([g, g]), tau=0.1, x0=x0)
    if name != "gap-tv":  # GAP-TV's diagonal preconditioner does not see the duplication
        kw = {"exact": False} if name == "admm" else {}
        x1 = solve(name, one, g, iters=ITERS, tau=0.05, x0=x0, **kw).x
        np.testing.assert_allclose(x2, x1, rtol=0, atol=1e-4 * np.abs(x1).max())


@pytest.mark.parametrize("name", NAMES)
def test_identical_masks_in_every_kaleidoscope_view(name):
    op = kaleidoscope_cassi(np.stack([_mask()] * 5), np.arange(L), 5)
    _check(name, op, op.forward(_cube()))


@pytest.mark.parametrize("name", NAMES)
def test_single_band(name):
    op = standard_cassi(_mask(), 2, 1)
    assert op.oshape == (1, H, W)
    truth = _cube(l=1)
    x = _check(name, op, op.forward(truth))
    # One band, no dispersion: where the mask is open the data is the scene itself.
    open_ = _mask() > 0
    assert np.abs(x[0][open_] - truth[0][open_]).mean() < 0.1


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("shape", [(H, 1), (1, W), (1, 1)], ids=["1px-wide", "1px-tall", "1px"])
def test_one_pixel_images(name, shape):
    h, w = shape
    op = standard_cassi(_mask(h, w), 1, L)
    _check(name, op, op.forward(_cube(L, h, w)))
    op3 = kaleidoscope_cassi(np.stack([_mask(h, w, s) for s in range(3)]), np.arange(L), 3)
    _check(name, op3, op3.forward(_cube(L, h, w)))


@pytest.mark.parametrize("name", NAMES)
def test_zero_dispersion(name):
    op = standard_cassi(_mask(), 0, L)
    assert op.oshape == (1, H, W)
    _check(name, op, op.forward(_cube()))
    op3 = kaleidoscope_cassi(np.stack([_mask(seed=s) for s in range(3)]), np.zeros(L), 3)
    _check(name, op3, op3.forward(_cube()))


@pytest.mark.parametrize("measurement", ["zero", "constant"])
@pytest.mark.parametrize("prior", ["subspace-tv", "subspace-nlr"])
def test_spectral_priors_on_flat_measurements(prior, measurement):
    """The spectral priors in FISTA on measurements without structure: finite, and no worse
    than the zero cube.  A flat iterate hands the non-local denoiser patches that all tie
    (it returned NaN there before each group kept its reference patch)."""
    from recon.priors import make_prior

    op = kaleidoscope_cassi(np.stack([_mask(seed=s) for s in range(3)]), np.arange(L), 3)
    g = np.zeros(op.oshape, np.float32) if measurement == "zero" else \
        np.full(op.oshape, 0.7, np.float32)
    # A counted warm-up: the denoiser runs inside the 30 iterations.
    options = {"warmup": 2} if prior == "subspace-nlr" else {}
    p = make_prior(prior, shape=op.ishape, dtype=np.float32, weight=0.1, solver="fista",
                   **options)
    x = _check("fista-tv", op, g, prior=p)
    if measurement == "zero":
        assert np.all(x == 0)
