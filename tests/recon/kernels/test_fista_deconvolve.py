"""The TV deconvolution's fused passes (:mod:`recon.kernels.fista_deconvolve`) against the
NumPy expressions they replace: the same bits (they are compiled without fast-math)."""

import numpy as np
import pytest

from recon import kernels

pytestmark = pytest.mark.skipif(not kernels.enabled(), reason="Numba kernels switched off")


def _bits(a):
    return np.ascontiguousarray(a).view(np.uint32)


@pytest.mark.parametrize("shape", [(1, 1, 1), (3, 17, 9), (2, 64, 33)])
def test_spectral_step_is_numpy_to_the_bit(shape):
    from recon.kernels.fista_deconvolve import spectral_step

    rng = np.random.default_rng(1)
    spec = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)
    spec.reshape(-1)[::5] = 0
    power = rng.random(shape, dtype=np.float32)
    kd = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)).astype(np.complex64)
    ref = spec.copy()
    ref *= power
    ref -= kd
    with kernels.threads():
        spectral_step(spec, power, kd)
    assert np.array_equal(_bits(spec), _bits(ref))


@pytest.mark.parametrize("inplace", [False, True])
def test_momentum_is_numpy_to_the_bit(inplace):
    from recon.kernels.fista_deconvolve import momentum

    rng = np.random.default_rng(2)
    new, old = (rng.standard_normal((3, 21, 40)).astype(np.float32) for _ in range(2))
    c = np.float32(0.6180339)
    ref = np.empty_like(new)
    np.subtract(new, old, out=ref)
    ref *= c
    ref += new
    out = old if inplace else np.empty_like(new)
    with kernels.threads():
        momentum(new, old.copy() if not inplace else old, c, out)
    assert np.array_equal(_bits(out), _bits(ref))
