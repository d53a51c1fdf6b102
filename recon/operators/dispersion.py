r"""Per-band horizontal shift (the prism's dispersion), integer or sub-pixel, either direction.

A band image :math:`v` of width :math:`W` shifted by :math:`\varphi = a + t` pixels
(:math:`a = \lfloor\varphi\rfloor`, :math:`0 \le t < 1`) is sampled by linear interpolation at
:math:`x - \varphi`:

.. math::

    (S_\varphi v)[x] = (1-t)\, v[x-a] + t\, v[x-a-1],

so a positive :math:`\varphi` moves content towards larger :math:`x`.  The adjoint gathers
:math:`(S_\varphi^\top y)[u] = (1-t)\, y[u+a] + t\, y[u+a+1]`.  For :math:`t = 0` only the
first term exists, so integer shifts are exact copies.

Offsets are normalised so that the smallest shift starts at column 0; the output width is then
:math:`W_m = W + \lceil\max\varphi\rceil - \lfloor\min\varphi\rfloor`.  The helpers here work
band by band on contiguous (H, W) images with slice arithmetic into preallocated buffers, which
is what :class:`~recon.operators.cassi.CassiOperator` calls in its hot loop.
"""

from __future__ import annotations

import math

import numpy as np

from recon.errors import InputError
from recon.operators.base import LinearOperator

#: Offsets closer than this to an integer are treated as integers, so that e.g. ``0.1 * 30``
#: does not create a needless extra output column and an interpolation pass.
SNAP_TOL = 1e-6


def work_dtype(x: np.ndarray):
    """float64 stays float64 (precision checks); everything else computes in float32."""
    return np.float64 if x.dtype == np.float64 else np.float32


def as_offsets(offsets, n: int | None = None, name: str = "offsets") -> np.ndarray:
    """Validate a 1-D table of finite shifts (float64), snapping near-integers.

    Raises
    ------
    InputError
        If it is not 1-D, has the wrong length or holds non-finite values.
    """
    try:
        phi = np.array(offsets, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numbers: {exc}") from None
    if phi.ndim != 1 or phi.size == 0:
        raise InputError(f"{name} must be a non-empty 1-D array, got shape {phi.shape}")
    if n is not None and phi.size != n:
        raise InputError(f"{name} has {phi.size} entries, expected {n} (one per band)")
    if not np.all(np.isfinite(phi)):
        raise InputError(f"{name} must be finite, got {phi}")
    return snap(phi)


def snap(phi: np.ndarray) -> np.ndarray:
    """Round values within :data:`SNAP_TOL` of an integer to that integer."""
    r = np.round(phi)
    return np.where(np.abs(phi - r) < SNAP_TOL, r, phi)


def split(phi: float) -> tuple[int, float]:
    """Return ``(a, t)`` with ``phi = a + t``, ``a`` integer, ``0 <= t < 1``."""
    a = math.floor(phi)
    return int(a), float(phi - a)


def span(phi: np.ndarray) -> tuple[int, int]:
    r"""Return ``(lo, extra)``: :math:`\lfloor\min\varphi\rfloor` and the extra width
    :math:`\lceil\max\varphi\rceil - \lfloor\min\varphi\rfloor` the shifts add."""
    lo = math.floor(float(np.min(phi)))
    hi = math.ceil(float(np.max(phi)))
    return int(lo), int(hi - lo)


def shift_add(v: np.ndarray, dst: np.ndarray, a: int, t: float, buf: np.ndarray) -> None:
    r"""Accumulate :math:`S_{a+t} v` into ``dst`` (in place).

    Parameters
    ----------
    v : (H, W) array
        Band image; it is not modified.
    dst : (H, Wm) array
        Accumulator; columns ``a .. a+W`` (``a+W-1`` when ``t == 0``) must exist.
    a, t : int, float
        Integer and fractional parts of the shift, ``0 <= t < 1``.
    buf : (H, W) array
        Scratch space of ``dst``'s dtype.
    """
    w = v.shape[-1]
    d0 = dst[..., a:a + w]
    if t == 0.0:
        np.add(d0, v, out=d0)
        return
    # (1-t) v into [a, a+W) and t v into [a+1, a+W+1): written as d0 += v - t v, d1 += t v
    # so that only one scaled copy is made.
    d1 = dst[..., a + 1:a + 1 + w]
    np.multiply(v, t, out=buf)
    np.add(d0, v, out=d0)
    np.subtract(d0, buf, out=d0)
    np.add(d1, buf, out=d1)


def shift_gather(y: np.ndarray, a: int, t: float, w: int, out: np.ndarray,
                 dy: np.ndarray | None = None) -> np.ndarray:
    r"""Write :math:`S_{a+t}^\top y` (width ``w``) into ``out`` and return it.

    Parameters
    ----------
    y : (H, Wm) array
    a, t, w : int, float, int
    out : (H, w) array
    dy : (H, Wm - 1) array, optional
        The forward difference ``y[:, 1:] - y[:, :-1]``; with it a sub-pixel gather is
        ``y[a:a+w] + t * dy[a:a+w]`` (two passes instead of three).  Callers that gather many
        bands from the same ``y`` compute it once.
    """
    y0 = y[..., a:a + w]
    if t == 0.0:
        np.copyto(out, y0)
        return out
    if dy is None:
        np.subtract(y[..., a + 1:a + 1 + w], y0, out=out)
    else:
        np.copyto(out, dy[..., a:a + w])
    np.multiply(out, t, out=out)
    np.add(out, y0, out=out)
    return out


def shift_row_norms(n: np.ndarray, c: np.ndarray | None, a: int, t: float, dst: np.ndarray) -> None:
    r"""Accumulate the squared row norms of :math:`S_{a+t} A` into ``dst``.

    Row :math:`x` of :math:`S A` is :math:`(1-t) A_{x-a} + t A_{x-a-1}`, so its squared norm is

    .. math::

        (1-t)^2 n[x-a] + t^2 n[x-a-1] + 2t(1-t)\, c[x-a-1],

    with :math:`n[u] = \|A_u\|^2` and :math:`c[u] = \langle A_u, A_{u+1}\rangle` (horizontal
    neighbours).  ``c`` is ``None`` when those rows are orthogonal (masks on permutations).

    Parameters
    ----------
    n : (H, W) array
    c : (H, W-1) array or None
    a, t : int, float
    dst : (H, Wm) float64 array
    """
    w = n.shape[-1]
    if t == 0.0:
        dst[..., a:a + w] += n
        return
    dst[..., a:a + w] += (1.0 - t) ** 2 * n
    dst[..., a + 1:a + 1 + w] += t * t * n
    if c is not None:
        dst[..., a + 1:a + w] += 2.0 * t * (1.0 - t) * c


class Dispersion(LinearOperator):
    r"""Shift band :math:`l` of a band-major cube horizontally by :math:`\varphi_l` pixels.

    :math:`(L, H, W) \to (L, H, W_m)` with :math:`W_m = W + \lceil\max\varphi\rceil -
    \lfloor\min\varphi\rfloor`; band :math:`l` lands at :math:`\varphi_l - \lfloor\min\varphi
    \rfloor` (see the module docstring for the interpolation).  Bands are not summed: this is
    the "sheared cube"; :class:`~recon.operators.cassi.CassiOperator` fuses the shift with the
    mask and the band sum.

    Parameters
    ----------
    offsets : (L,) array_like of float
        Shifts in pixels, + towards larger x; any sign, integer or not.
    image_shape : (H, W)

    Attributes
    ----------
    offsets : (L,) float64
        The normalised shifts (smallest floor at 0).
    """

    def __init__(self, offsets, image_shape):
        phi = as_offsets(offsets)
        h, w = _image_shape(image_shape)
        lo, extra = span(phi)
        self.offsets = phi - lo
        self._parts = [split(p) for p in self.offsets]
        super().__init__((phi.size, h, w), (phi.size, h, w + extra))

    def _forward(self, x):
        dt = work_dtype(x)
        x = x.astype(dt, copy=False)
        out = np.zeros(self.oshape, dtype=dt)
        buf = np.empty(self.ishape[1:], dtype=dt)
        for l, (a, t) in enumerate(self._parts):
            shift_add(x[l], out[l], a, t, buf)
        return out

    def _adjoint(self, y):
        dt = work_dtype(y)
        y = y.astype(dt, copy=False)
        out = np.empty(self.ishape, dtype=dt)
        w = self.ishape[2]
        for l, (a, t) in enumerate(self._parts):
            shift_gather(y[l], a, t, w, out[l])
        return out

    def row_norms_sq(self):
        out = np.zeros(self.oshape, dtype=np.float64)
        ones = np.ones(self.ishape[1:], dtype=np.float64)
        for l, (a, t) in enumerate(self._parts):
            shift_row_norms(ones, None, a, t, out[l])
        return out


def _image_shape(shape) -> tuple[int, int]:
    try:
        h, w = (int(s) for s in shape)
    except (TypeError, ValueError):
        raise InputError(f"image shape must be (H, W), got {shape!r}") from None
    if h < 1 or w < 1:
        raise InputError(f"image shape must be positive, got {shape!r}")
    return h, w
