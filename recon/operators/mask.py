r"""Coded-aperture modulation: every band multiplied by the same mask, :math:`y_l = M \odot x_l`.

The operator is diagonal, so it is self-adjoint and its row norms are :math:`M^2`.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator
from recon.operators.dispersion import work_dtype


def as_mask(mask, shape: tuple[int, ...] | None = None, name: str = "mask", ndim: int = 2) -> np.ndarray:
    """Validate a finite float mask (C-contiguous float32) of ``ndim`` dimensions.

    Raises
    ------
    InputError
        Wrong number of dimensions, wrong shape, empty, or non-finite values.
    """
    try:
        m = np.ascontiguousarray(mask, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a numeric array: {exc}") from None
    if m.ndim != ndim:
        raise InputError(f"{name} must be {ndim}-D, got shape {m.shape}")
    if m.size == 0:
        raise InputError(f"{name} is empty (shape {m.shape})")
    if shape is not None and m.shape != tuple(shape):
        raise InputError(f"{name} has shape {m.shape}, expected {tuple(shape)}")
    # The extremes carry any NaN (np.min/np.max propagate it) and any infinity: two
    # reductions instead of a boolean array the size of the masks.
    if not (np.isfinite(m.min()) and np.isfinite(m.max())):
        raise InputError(f"{name} contains non-finite values")
    return m


class InPrecision:
    """Float32 masks, and their float64 copies made on first use and then kept.

    The operators compute in their input's precision (:func:`~.dispersion.work_dtype`):
    float32 in the solvers, float64 in dot tests and stress tests.  Masks are stored in
    float32; a float64 input reads the kept copies instead of converting the masks per call.

    Parameters
    ----------
    masks : ndarray or list of ndarray
        Float32.
    """

    def __init__(self, masks):
        self._f32 = masks
        self._f64 = None

    def __call__(self, dtype):
        """The masks in ``dtype`` (float32 or float64)."""
        if np.dtype(dtype) == np.float32:
            return self._f32
        if self._f64 is None:
            self._f64 = ([m.astype(np.float64) for m in self._f32]
                         if isinstance(self._f32, list) else self._f32.astype(np.float64))
        return self._f64


class MaskModulation(LinearOperator):
    r"""Multiply every band of a band-major cube by a mask: :math:`(L,H,W)\to(L,H,W)`.

    .. math:: (Mx)_{l,y,x} = M_{y,x}\, x_{l,y,x}

    Parameters
    ----------
    mask : (H, W) array_like
        Transmission, finite (values in [0, 1] for a physical mask).
    n_bands : int
    """

    def __init__(self, mask, n_bands: int):
        self.mask = as_mask(mask)
        n_bands = int(n_bands)
        if n_bands < 1:
            raise InputError(f"n_bands must be >= 1, got {n_bands}")
        shape = (n_bands,) + self.mask.shape
        super().__init__(shape, shape)

    def _forward(self, x):
        return np.multiply(x.astype(work_dtype(x), copy=False), self.mask)

    _adjoint = _forward

    def row_norms_sq(self):
        m2 = self.mask.astype(np.float64) ** 2
        return np.broadcast_to(m2, self.oshape).copy()
