"""Test problems shared by several test modules (importable: `pythonpath = ["tests"]`)."""

import numpy as np


def piecewise_cube(l=8, h=32, w=32, seed=0):
    """Piecewise-constant band-major cube: a background and four rectangles, flat spectra."""
    rng = np.random.default_rng(seed)
    x = np.empty((l, h, w), np.float32)
    x[:] = 0.3 * rng.uniform(0.5, 1, (l, 1, 1))
    for _ in range(4):
        y0, x0 = rng.integers(0, h - 8), rng.integers(0, w - 8)
        x[:, y0:y0 + rng.integers(6, 14), x0:x0 + rng.integers(6, 14)] = \
            rng.uniform(0.2, 1, (l, 1, 1))
    return x


def reference_subspace(v, rank):
    """The plain NumPy (float64) reference of the subspace priors' projection: the ``rank``
    leading eigenvectors E of the band Gram matrix of ``v`` (L, H, W), signed so that each
    sums to a positive value, and the coefficient images Eᵀ v, shape (rank, H, W)."""
    m = v.reshape(v.shape[0], -1).astype(np.float64)
    _, vecs = np.linalg.eigh(m @ m.T)
    e = vecs[:, ::-1][:, :rank]
    e *= np.sign(e.sum(axis=0))
    return e, (e.T @ m).reshape((rank,) + v.shape[1:])


class DriftingTV:
    """TV whose value carries a state that moves at every prox (an offset growing by
    ``drift`` a call), as a basis re-estimated from each iterate moves a subspace prior's
    value; the prox, and so the minimiser, are TV's."""

    band_scalable = True

    def __init__(self, tau, drift, reports_state):
        from recon.priors.tv import TVPrior

        self.tv = TVPrior(tau)
        self.drift, self.reports_state, self.calls = drift, reports_state, 0

    def prox(self, v, step, out=None):
        self.calls += 1
        return self.tv.prox(v, step, out=out)

    def value(self, x):
        return self.tv.value(x) + self.drift * self.calls

    def reset(self):
        self.tv.reset()

    def state_change(self):
        return 1e-6 if self.reports_state and self.calls > 1 else None
