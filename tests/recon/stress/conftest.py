"""Shared problem builders for the numerical stress suite (small sizes, fixed seeds).

Helpers are handed out through the ``stress`` fixture (pytest runs with
``--import-mode=importlib``, so test modules cannot import this file by name).
"""

from __future__ import annotations

import types

import numpy as np
import pytest

from recon.operators import kaleidoscope_cassi
from recon.solvers import SOLVERS

#: Every solver, in a fixed order (tests are parametrised over it).
NAMES = sorted(SOLVERS)

#: TV weights for data scaled to [0, 1] (the benchmark's settings).
TAU = {"gap-tv": 0.1, "twist": 0.15, "fista-tv": 0.15, "admm": 0.15}


def piecewise_cube(l: int = 6, h: int = 24, w: int = 24, seed: int = 0,
                   dtype=np.float32) -> np.ndarray:
    """A band-major (L, H, W) piecewise-constant cube in [0, 1] with maximum 1.

    A background and four rectangles, each with its own smooth spectrum, so that a TV prior
    fits and the spectra differ from region to region.
    """
    rng = np.random.default_rng(seed)
    lam = np.linspace(0.0, 1.0, l)

    def spectrum():
        c, s = rng.uniform(0, 1), rng.uniform(0.2, 0.6)
        return 0.15 + rng.uniform(0.3, 0.85) * np.exp(-0.5 * ((lam - c) / s) ** 2)

    x = np.empty((l, h, w))
    x[:] = 0.5 * spectrum()[:, None, None]
    for _ in range(4):
        y0, x0 = rng.integers(0, max(1, h - h // 3)), rng.integers(0, max(1, w - w // 3))
        dy, dx = rng.integers(max(1, h // 5), max(2, h // 2)), rng.integers(max(1, w // 5),
                                                                          max(2, w // 2))
        x[:, y0:y0 + dy, x0:x0 + dx] = spectrum()[:, None, None]
    x /= x.max()
    return np.ascontiguousarray(x, dtype=dtype)


def random_masks(k: int, h: int, w: int, seed: int = 0, cell: int = 1) -> np.ndarray:
    """``k`` random binary masks (about half open) of ``cell``×``cell`` pixel cells."""
    rng = np.random.default_rng(seed)
    hc, wc = -(-h // cell), -(-w // cell)
    m = (rng.random((k, hc, wc)) < 0.5).astype(np.float32)
    m = np.repeat(np.repeat(m, cell, axis=1), cell, axis=2)
    return np.ascontiguousarray(m[:, :h, :w])


def kaleido_op(n_views: int, l: int = 6, h: int = 24, w: int = 24, seed: int = 0,
               offsets=None):
    """The paper's kaleidoscope with ``n_views`` views, random masks and sub-pixel dispersion
    (band l shifted by 0.9·l px: 4.5 px over 6 bands)."""
    offsets = 0.9 * np.arange(l) if offsets is None else offsets
    return kaleidoscope_cassi(random_masks(9, h, w, seed), offsets, n_views)


def add_noise(g: np.ndarray, snr_db: float, seed: int = 0, read_share: float = 0.25) -> np.ndarray:
    r"""Poisson shot noise plus Gaussian read noise at a given SNR (dB).

    The clean frame :math:`g` (arbitrary units) becomes :math:`k g` electrons.  With the read
    noise variance a fixed share :math:`c` of the mean shot-noise variance,
    :math:`\sigma_r^2 = c\,k\,\bar g`, the expected noise power is :math:`(1+c)k\bar g` and the
    signal power :math:`k^2\overline{g^2}`, so

    .. math:: \mathrm{SNR} = \frac{k\,\overline{g^2}}{(1+c)\,\bar g}
              \quad\Rightarrow\quad k = \mathrm{SNR}\,(1+c)\,\bar g / \overline{g^2}.

    The result is divided by :math:`k` again (same units as ``g``); ``snr_db = inf`` returns a
    copy of ``g``.
    """
    g = np.asarray(g, dtype=np.float64)
    if not np.isfinite(snr_db):
        return g.astype(np.float32)
    rng = np.random.default_rng(seed)
    snr = 10.0 ** (snr_db / 10.0)
    k = snr * (1.0 + read_share) * g.mean() / np.mean(g * g)
    e = rng.poisson(np.clip(k * g, 0, None)).astype(np.float64)
    e += rng.normal(0.0, np.sqrt(read_share * k * g.mean()), g.shape)
    return (e / k).astype(np.float32)


def snr_db(noisy: np.ndarray, clean: np.ndarray) -> float:
    """Measured SNR :math:`10\\log_{10}(\\|g\\|^2/\\|n-g\\|^2)` in dB."""
    clean = np.asarray(clean, np.float64)
    d = np.asarray(noisy, np.float64) - clean
    return 10.0 * np.log10(np.vdot(clean, clean) / np.vdot(d, d))


def rel_err(x: np.ndarray, truth: np.ndarray) -> float:
    """Relative error :math:`\\|x - f\\|_2 / \\|f\\|_2` (float64)."""
    d = np.asarray(x, np.float64) - truth
    return float(np.linalg.norm(d) / np.linalg.norm(np.asarray(truth, np.float64)))


@pytest.fixture(scope="session")
def stress():
    """The helpers above as one namespace."""
    return types.SimpleNamespace(NAMES=NAMES, TAU=TAU, piecewise_cube=piecewise_cube,
                                 random_masks=random_masks, kaleido_op=kaleido_op,
                                 add_noise=add_noise, snr_db=snr_db, rel_err=rel_err)
