"""The exact operator: adjoint, agreement with rendered frames, independence, no-inversion
variant."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.operators.base import dot_test
from sim.optics.design import get_design
from sim.transport.oracle import oracle_measurements, oracle_operator

OVR = {"band_step_nm": 50.0}


@pytest.fixture(scope="module", autouse=True)
def cache(shared_cache):
    return shared_cache


@pytest.fixture(scope="module")
def scene():
    from scenes.registry import get_scene
    from sim.frame import simulate_frame

    d = get_design("small", OVR)
    v = d.view_size_px
    cube, wl = get_scene("colorchecker", (v, v), d.wavelengths)
    frame, meta = simulate_frame(d, cube, wl, noise=False)
    return d, cube, frame, meta


def test_dot_test_and_shapes(scene):
    d = scene[0]
    op = oracle_operator(d, 3)
    v = d.view_size_px
    assert op.ishape == (d.n_bands, v, v) and op.oshape == (3, v, v)
    assert dot_test(op, np.random.default_rng(0)) < 1e-5


def test_row_norms_are_exact_and_their_mean_is_estimated():
    """Coloured probing gives every row's norm exactly (checked against unit probes); the
    mean over the measured rows, estimated with a few probes, agrees with it (3 bands, one
    view, to keep the probing short)."""
    d = get_design("small", {"band_step_nm": 125.0})
    op = oracle_operator(d, 1)
    rn = op.row_norms_sq()
    assert rn.shape == op.oshape and np.all(rn >= 0)
    rng = np.random.default_rng(2)
    v = d.view_size_px
    lit = np.argwhere(rn[0, 20:v - 20, 20:v - 20] > 0.1 * rn.max()) + 20
    for i, j in lit[rng.choice(len(lit), 4, replace=False)]:
        e = np.zeros(op.oshape)
        e[0, i, j] = 1.0
        assert rn[0, i, j] == pytest.approx(float(np.sum(op.adjoint(e) ** 2)), rel=1e-4)
    assert op.mean_row_norm_sq() == pytest.approx(float(rn[rn > 0].mean()), rel=0.01)


def test_forward_predicts_the_rendered_frame(scene):
    """With the scene frames' own trace the operator is the frame's expectation (blur
    included): only quantisation separates them.  The oracle's own trace is another
    realisation of the same optics: within 3·10⁻⁴ of it."""
    from sim.transport.exact import SEEDS

    d, cube, frame, meta = scene
    assert meta["trace_seed"] == SEEDS["scene"] != SEEDS["oracle"]
    g = oracle_measurements(frame, meta, d, 5)
    x = np.ascontiguousarray(np.moveaxis(cube, 2, 0))
    model = oracle_operator(d, 5, seed=SEEDS["scene"]).forward(x)
    for k in range(5):
        err = np.abs(model[k] - g[k]).max() * meta["radiance_scale"]
        assert err <= 0.51, (k, err)
    own = oracle_operator(d, 5).forward(x)
    assert np.linalg.norm(own - model) / np.linalg.norm(model) < 3e-4
    assert not np.array_equal(own, model)


def test_fewer_measured_views_measure_the_same_light(scene):
    """Only the views whose blur reaches a measured rectangle are integrated: measuring the
    centre alone gives what it gives among five, the neighbours' blurred light included."""
    d, cube, frame, meta = scene
    x = np.ascontiguousarray(np.moveaxis(cube, 2, 0))
    one, five = oracle_operator(d, 1), oracle_operator(d, 5)
    assert 0 in one.lit_views and set(one.lit_views) <= set(five.lit_views)
    a, b = one.forward(x)[0], five.forward(x)[0]
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-6 * float(b.max()))
    # A view far from the measured ones is left out: its light never reaches them.
    far = oracle_operator(d, 1, diffraction=False)
    assert far.lit_views == [0]


def test_no_inversion_is_another_valid_operator(scene):
    d, cube, frame, meta = scene
    a = oracle_operator(d, 2)
    b = oracle_operator(d, 2, inversion=False)
    assert dot_test(b, np.random.default_rng(1)) < 1e-5
    x = np.ascontiguousarray(np.moveaxis(cube, 2, 0))
    np.testing.assert_allclose(a.forward(x)[0], b.forward(x)[0])   # the centre is unchanged
    # The left view of the no-inversion system is the real one seeing a mirrored scene.
    np.testing.assert_allclose(b.forward(x)[1], a.forward(np.ascontiguousarray(x[:, :, ::-1]))[1],
                               rtol=1e-5, atol=1e-3)


def test_bad_input(scene):
    d, cube, frame, meta = scene
    with pytest.raises(InputError, match="not traced"):
        oracle_operator(d, 9)
    with pytest.raises(InputError, match="design"):
        oracle_measurements(frame, dict(meta, design_hash="0000000000000000"), d, 1)
    with pytest.raises(InputError):
        oracle_operator(d, 0)
