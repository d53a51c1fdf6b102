"""The slab-wise probe draws (:mod:`recon.probes`) against NumPy's single draws, to the bit."""

import numpy as np
import pytest

from recon import probes


@pytest.mark.parametrize("shape", [(3, 5, 7), (2, 300, 500), (1,)])
def test_standard_normal_is_the_single_draw(shape):
    # (2, 300, 500) spans slabs and ends inside one.
    want = np.random.default_rng(4).standard_normal(shape).astype(np.float32)
    got = probes.standard_normal(np.random.default_rng(4), shape)
    assert got.dtype == np.float32 and np.array_equal(got, want)


@pytest.mark.parametrize("shape", [(3, 5, 7), (2, 300, 500)])
def test_rademacher_is_choice_and_the_stream_goes_on_alike(shape):
    signs = np.array([-1.0, 1.0], np.float32)
    ref, rng = np.random.default_rng(9), np.random.default_rng(9)
    out = np.empty(shape, np.float32)
    for _ in range(3):      # successive probes continue one stream, as in the row-norm estimate
        want = ref.choice(signs, size=shape)
        assert np.array_equal(probes.rademacher(rng, shape, out=out), want)
    assert ref.standard_normal() == rng.standard_normal()


def test_rademacher_refuses_an_output_it_cannot_fill():
    rng = np.random.default_rng(0)
    for out in (np.empty((4, 5), np.float64), np.empty((5, 4), np.float32),
                np.empty((4, 10), np.float32)[:, ::2]):
        with pytest.raises(ValueError):
            probes.rademacher(rng, (4, 5), out=out)
