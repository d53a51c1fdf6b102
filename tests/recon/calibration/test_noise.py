"""The photon-transfer fit recovers a sensor's noise from pairs of frames; bad input is refused."""

import numpy as np
import pytest

from recon.calibration.noise import check_noise_model, noise_rms, photon_transfer
from recon.errors import InputError

FULL_WELL, MAX_DN, READ_E = 14000.0, 4095, 8.0
GAIN = FULL_WELL / MAX_DN              # e-/DN
TRUE = np.array([1.0 / GAIN, (READ_E / GAIN) ** 2 + 1.0 / 12.0])


def _pair(mean_e, seed=0):
    """Two raw frames of one target: Poisson shot noise, the full well, Gaussian read noise and
    a 12-bit ADC (the simulator's sensor, written again here so the test stands alone)."""
    rng = np.random.default_rng(seed)

    def read():
        e = np.minimum(rng.poisson(mean_e), FULL_WELL) + rng.normal(0.0, READ_E, mean_e.shape)
        return np.clip(np.rint(e / GAIN), 0, MAX_DN).astype(np.float32)

    return read(), read()


def _coded_target(shape=(300, 400), seed=1):
    """Every level from dark to saturated, in cells, like a coded capture."""
    rng = np.random.default_rng(seed)
    cells = rng.uniform(0.0, 1.05, (shape[0] // 4, shape[1] // 4)) * FULL_WELL
    return np.kron(cells, np.ones((4, 4)))


def test_recovers_the_sensor():
    a, b = _pair(_coded_target())
    fit = photon_transfer(a, b, MAX_DN)
    assert abs(fit[0] / TRUE[0] - 1) < 0.01, (fit, TRUE)      # the conversion gain, to 1 %
    # The intercept is extrapolated below the dark cut: loose, but the noise it gives is not.
    assert 0 <= fit[1] < 3 * TRUE[1]
    frame = a[:100]
    assert abs(noise_rms(frame, fit) / noise_rms(frame, TRUE) - 1) < 0.01


def test_the_pattern_cancels():
    """The target's pattern (and the optics') cancel in the pair's difference: a flat target
    and a coded one give the same curve."""
    flat = np.linspace(0.05, 0.85, 400)[None, :] * FULL_WELL * np.ones((300, 1))
    f1 = photon_transfer(*_pair(flat, seed=3), MAX_DN)
    f2 = photon_transfer(*_pair(_coded_target(seed=4), seed=5), MAX_DN)
    assert abs(f1[0] / f2[0] - 1) < 0.02, (f1, f2)


def test_pairs_pooled_tighten_the_fit():
    """Stacks of pairs (``a[i]``, ``b[i]``) are pooled: the same fit as the pairs one above the
    other in one frame, and over many noise draws two pairs spread the gain less than one does
    (by about √2: the groups' variances are means over twice the pixels)."""
    target = _coded_target(shape=(120, 160))
    one, two = [], []
    for seed in range(24):
        a1, b1 = _pair(target, seed=2 * seed)
        a2, b2 = _pair(target, seed=2 * seed + 1)
        pooled = photon_transfer(np.stack([a1, a2]), np.stack([b1, b2]), MAX_DN)
        above = photon_transfer(np.vstack([a1, a2]), np.vstack([b1, b2]), MAX_DN)
        np.testing.assert_array_equal(pooled, above)
        one.append(photon_transfer(a1, b1, MAX_DN)[0] / TRUE[0] - 1)
        two.append(pooled[0] / TRUE[0] - 1)
    ratio = np.std(two) / np.std(one)
    assert ratio < 0.85, ratio
    assert abs(np.mean(two)) < 3 * np.std(two) / np.sqrt(len(two))


def test_noise_rms_is_the_mean_variance():
    frame = np.array([[0.0, 100.0], [300.0, -5.0]], np.float32)  # negative: no signal
    a, b = 0.3, 5.0
    assert noise_rms(frame, [a, b]) == pytest.approx(np.sqrt(a * 100.0 + b))


def test_bad_input():
    a, b = _pair(_coded_target())
    with pytest.raises(InputError, match="one shape"):
        photon_transfer(a, b[:-1], MAX_DN)
    with pytest.raises(InputError, match="finite"):
        photon_transfer(a, np.where(b > 0, np.nan, b), MAX_DN)
    with pytest.raises(InputError, match="positive"):
        photon_transfer(a, b, 0)
    with pytest.raises(InputError, match="too few"):
        photon_transfer(a[:10, :10], b[:10, :10], MAX_DN)
    level = np.full((200, 200), 1000.0, np.float32)
    with pytest.raises(InputError, match="single level"):
        photon_transfer(level, level, MAX_DN)
    for bad in ([0.0, 1.0], [0.3, -1.0], [np.nan, 1.0], [0.3]):
        with pytest.raises(InputError, match="noise model"):
            check_noise_model(bad)
    with pytest.raises(InputError, match="non-empty"):
        noise_rms(np.zeros(0), TRUE)
