r"""A plain NumPy GAP-TV for standard CASSI, written the way public codes are: the reference
that ``tools/bench_recon.py`` times side by side with :mod:`recon`.

It follows PnP-CASSI (Zheng et al., Photonics Research 2021: ``gap_denoise`` with
``denoiser='tv'``) and the classic GAP-TV of Yuan (ICIP 2016): the sheared cube :math:`x`
(H × W+s(L−1) × L) with the shifted masks :math:`\Phi`, :math:`A x = \sum_l \Phi_l x_l`,
:math:`A^\top y = \Phi \odot y`, the accelerated update

.. math::

    y_1 \leftarrow y_1 + (y - Ax), \qquad
    x \leftarrow x + A^\top\bigl((y_1 - Ax) / \textstyle\sum_l \Phi_l\bigr),

then the TV denoiser on the unsheared cube: scikit-image's ``denoise_tv_chambolle`` band by
band (``channel_axis=-1``) with 5 iterations from a zero dual at every outer step, as the
public code calls it.  Everything is float64 whole-array NumPy (the public code's ``A``/``At``
by broadcasting, ``shift_back`` by ``np.roll``), no fused kernels, no warm starts: what the
public code costs, not a strawman.

Cubes here are (H, W, L), as in the public code.
"""

from __future__ import annotations

import numpy as np

__all__ = ["shifted_masks", "shift", "shift_back", "A", "At", "tv_denoise", "gap_tv"]


def shift(x: np.ndarray, step: int) -> np.ndarray:
    """(H, W, L) → (H, W+step·(L−1), L): band l moved right by step·l, zeros elsewhere."""
    h, w, n = x.shape
    out = np.zeros((h, w + step * (n - 1), n))
    for i in range(n):
        out[:, i * step:i * step + w, i] = x[:, :, i]
    return out


def shift_back(x: np.ndarray, step: int) -> np.ndarray:
    """Inverse of :func:`shift` on its support: (H, Wm, L) → (H, Wm−step·(L−1), L), each band
    rolled back in place, then cropped (as the public code)."""
    h, wm, n = x.shape
    for i in range(n):
        x[:, :, i] = np.roll(x[:, :, i], -step * i, axis=1)
    return x[:, :wm - step * (n - 1), :]


def shifted_masks(mask: np.ndarray, step: int, n_bands: int) -> np.ndarray:
    r""":math:`\Phi`, (H, W+step·(L−1), L): the mask shifted with each band."""
    return shift(np.repeat(np.asarray(mask, np.float64)[:, :, None], n_bands, axis=2), step)


def A(x: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Forward model on the sheared cube."""
    return np.sum(x * phi, axis=2)


def At(y: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Adjoint of :func:`A`."""
    return np.repeat(y[:, :, None], phi.shape[2], axis=2) * phi


def tv_denoise(x: np.ndarray, weight: float, n_iter: int) -> np.ndarray:
    """scikit-image's Chambolle TV denoiser on every band of an (H, W, L) cube, as PnP-CASSI
    calls it (``max_num_iter`` iterations, each band on its own)."""
    from skimage.restoration import denoise_tv_chambolle

    return denoise_tv_chambolle(x, weight=weight, max_num_iter=n_iter, channel_axis=-1)


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
        TV weight of the per-band Chambolle denoiser (scikit-image's ``weight``).
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
        x = shift(tv_denoise(shift_back(x, step), weight, tv_iters), step)
    return shift_back(x, step)
