r"""A plain NumPy GAP-TV for standard CASSI, written the way public codes are: the reference
that ``tools/bench_recon.py`` times side by side with :mod:`recon`.

It follows PnP-CASSI (Zheng et al., Photonics Research 2021; the ``gap_denoise`` of
``dvp_linear_inv_cassi.py`` with its ``A``/``At``/``shift``/``shift_back`` helpers) and the
classic GAP-TV of Yuan (ICIP 2016): the sheared cube :math:`x` (H × W+s(L−1) × L) with the
shifted masks :math:`\Phi`, :math:`A x = \sum_l \Phi_l x_l`,
:math:`A^\top y = \Phi \odot y`, the accelerated update

.. math::

    y_1 \leftarrow y_1 + (y - Ax), \qquad
    x \leftarrow x + A^\top\bigl((y_1 - Ax) / \textstyle\sum_l \Phi_l\bigr),

then the TV denoiser on the unsheared cube, band by band: Chambolle's projection (step 1/4)
with 5 iterations from a zero dual at every outer step.  Everything is float64, whole-array
NumPy, no fused kernels, no warm starts: what the public code costs, not a strawman (no Python
loops over pixels, the same Chambolle iteration as scikit-image's ``denoise_tv_chambolle``).

Cubes here are (H, W, L), as in the public code.
"""

from __future__ import annotations

import numpy as np

__all__ = ["shifted_masks", "shift", "shift_back", "A", "At", "tv_chambolle_2d", "gap_tv"]


def shift(x: np.ndarray, step: int) -> np.ndarray:
    """(H, W, L) → (H, W+step·(L−1), L): band l moved right by step·l, zeros elsewhere."""
    h, w, n = x.shape
    out = np.zeros((h, w + step * (n - 1), n))
    for i in range(n):
        out[:, i * step:i * step + w, i] = x[:, :, i]
    return out


def shift_back(x: np.ndarray, step: int) -> np.ndarray:
    """Inverse of :func:`shift` on its support: (H, Wm, L) → (H, Wm−step·(L−1), L)."""
    h, wm, n = x.shape
    w = wm - step * (n - 1)
    out = np.empty((h, w, n))
    for i in range(n):
        out[:, :, i] = x[:, i * step:i * step + w, i]
    return out


def shifted_masks(mask: np.ndarray, step: int, n_bands: int) -> np.ndarray:
    r""":math:`\Phi`, (H, W+step·(L−1), L): the mask shifted with each band."""
    return shift(np.repeat(np.asarray(mask, np.float64)[:, :, None], n_bands, axis=2), step)


def A(x: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Forward model on the sheared cube."""
    return np.sum(x * phi, axis=2)


def At(y: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Adjoint of :func:`A`."""
    return y[:, :, None] * phi


def tv_chambolle_2d(im: np.ndarray, weight: float, n_iter: int) -> np.ndarray:
    r"""Isotropic TV denoising of one image by Chambolle's projection, ``n_iter`` dual
    iterations from a zero dual: :math:`x = v + \lambda\,\mathrm{div}\,p` (scikit-image's
    iteration and sign convention, with ``weight`` = :math:`\lambda`)."""
    p = np.zeros((2,) + im.shape)
    g = np.zeros((2,) + im.shape)
    out = im
    for _ in range(n_iter + 1):
        d = -p[0] - p[1]
        d[1:, :] += p[0, :-1, :]
        d[:, 1:] += p[1, :, :-1]
        out = im + weight * d
        if _ == n_iter:
            break
        g[0, :-1, :] = np.diff(out, axis=0)
        g[1, :, :-1] = np.diff(out, axis=1)
        norm = np.sqrt((g ** 2).sum(axis=0))
        norm *= 0.25 / weight
        norm += 1.0
        p -= (0.25 / weight) * g
        p /= norm
    return out


def gap_tv(y: np.ndarray, phi: np.ndarray, step: int, weight: float, iters: int = 50,
           tv_iters: int = 5) -> np.ndarray:
    """Accelerated GAP-TV (PnP-CASSI's ``gap_denoise`` with ``denoiser='tv'``).

    Parameters
    ----------
    y : (H, Wm) measurement
    phi : (H, Wm, L) shifted masks (:func:`shifted_masks`)
    step : int
        Pixels of dispersion per band.
    weight : float
        TV weight of the per-band Chambolle denoiser.
    iters, tv_iters : int

    Returns
    -------
    (H, W, L) float64 cube
    """
    y = np.asarray(y, np.float64)
    x = At(y, phi)
    y1 = np.zeros_like(y)
    phi_sum = np.sum(phi, axis=2)
    phi_sum[phi_sum == 0] = 1
    for _ in range(iters):
        yb = A(x, phi)
        y1 = y1 + (y - yb)
        x = x + At((y1 - yb) / phi_sum, phi)
        xb = shift_back(x, step)
        for band in range(xb.shape[2]):
            xb[:, :, band] = tv_chambolle_2d(xb[:, :, band], weight, tv_iters)
        x = shift(xb, step)
    return shift_back(x, step)
