"""The exact operator: adjoint, agreement with rendered frames, no-inversion variant."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.operators.base import dot_test
from sim.design import get_design
from sim.oracle import oracle_measurements, oracle_operator

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
    frame, meta = simulate_frame(d, cube, wl, noise=False, diffraction=False)
    return d, cube, frame, meta


def test_dot_test_and_shapes(scene):
    d = scene[0]
    op = oracle_operator(d, 3)
    v = d.view_size_px
    assert op.ishape == (d.n_bands, v, v) and op.oshape == (3, v, v)
    assert dot_test(op, np.random.default_rng(0)) < 1e-5
    rn = op.row_norms_sq()
    assert rn.shape == op.oshape and np.all(rn >= 0)


def test_forward_predicts_the_rendered_frame(scene):
    d, cube, frame, meta = scene
    op = oracle_operator(d, 5)
    g = oracle_measurements(frame, meta, d, 5)
    model = op.forward(np.ascontiguousarray(np.moveaxis(cube, 2, 0)))
    for k in range(5):
        # Only quantisation separates the expected frame from the model (no noise, no blur).
        err = np.abs(model[k] - g[k]).max() * meta["radiance_scale"]
        assert err <= 0.51, (k, err)


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
