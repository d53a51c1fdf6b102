r"""Footprint calibration: every pixel's weights on the target's texels, from comb captures.

The shifted-mask model multiplies one mask value per pixel and band by the scene at one point.
A pixel really integrates the scene over its *footprint*: its own area, widened along the rows
by the band's dispersion (a few pixels for a 25 nm band in the blue), each point weighted by
the mask cell it crossed.  Where the scene changes inside a footprint (the ColorChecker's patch
edges) the shifted model errs; the system matrix does not.

A comb target lights texels :math:`(y, x)` with :math:`y \equiv a \pmod{P_y}`,
:math:`x \equiv b \pmod{P_x}`.  If pixel :math:`p`'s footprint fits in a window of
:math:`P_y \times P_x` texels, each phase :math:`(a, b)` shows it exactly one lit texel of the
window, so the band-pass capture :math:`R_{ab}(p)` *is* the weight
:math:`A_l(p, t)` of that texel:

.. math:: A_l(p, t) = R_{t_y \bmod P_y,\; t_x \bmod P_x}(p), \qquad t \in \text{window}(p),

in the capture's units divided by the lit texel's radiance.  The window is centred on the
footprint's circular centroid over the phases,

.. math:: c_x = \frac{P_x}{2\pi} \arg \sum_b \Big(\sum_a R_{ab}\Big) e^{2\pi i b / P_x},

known modulo :math:`P_x`; the calibrated geometry (homography, band offset and the line
capture's place on the target, :func:`predicted_positions`) picks the period, so it need be
right only to :math:`\pm P/2`.  Pixels with little light keep the geometric prediction.
Weights below ``floor`` × the band's white level (a pixel's response to a uniform white) are
noise on unlit texels and are dropped.

The result is one sparse matrix :math:`A`, rows the views' boxes (view-major, row-major),
columns the target's texels band-major: :class:`recon.operators.SparseMatrixOperator` on the
target's grid.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from recon.calibration.views import check_boxes, crop
from recon.errors import InputError

__all__ = ["FOOTPRINT_FLOOR", "comb_period", "line_anchor", "predicted_positions",
           "decode_band", "footprint_matrix"]

#: Weights below this fraction of the band's white level are dropped: a third of the weights
#: for a loss the reconstructions barely show (docs/calibration.md, "The footprint model's
#: settings").
FOOTPRINT_FLOOR = 0.002
#: Pixels whose summed comb response is below this fraction of the white level keep the
#: geometric window centre (their centroid is noise).
_CENTROID_LEVEL = 0.05


def comb_period(smear_px: float, airy_radius_px: float = 0.0) -> tuple[int, int]:
    r"""The comb's period :math:`(P_y, P_x)`: larger than any pixel's footprint.

    Along x a footprint spans the pixel, the widest band's smear :math:`s` (from the fitted
    dispersion over the band's interval) and the Airy blur on both sides; half a texel more for
    the centroid's error:

    .. math:: P_x = \lceil 1.5 + s + R 
ceil, \qquad P_y = \max(3, \lceil 2 + R 
ceil),

    :math:`R` the Airy first-zero radius (px); rows need a texel of margin for the side views'
    shear.  A shorter period lets neighbouring texels' footprints overlap and costs the
    reconstructions (docs/calibration.md, "The footprint model's settings").
    """
    s, r = float(smear_px), float(airy_radius_px)
    if not (np.isfinite(s) and np.isfinite(r)) or s < 0 or r < 0:
        raise InputError(f"smear and Airy radius must be finite and >= 0, got {s}, {r}")
    return max(3, math.ceil(2.0 + r)), math.ceil(1.5 + s + r)


def line_anchor(centroids, offsets, column: float, centre: int = 0) -> float:
    r"""The target column of the reconstruction grid's column 0: :math:`x_\text{line} -
    \operatorname{median}_l(\bar x_{0,l} - o_{0,l})`.

    The line at target column :math:`x_\text{line}` (its datasheet) appears in band :math:`l`
    of the centre view at box column :math:`\bar x_{0,l}`, and the calibrated grid puts its
    column :math:`x` at box column :math:`x + o_{0,l}`.  The median over bands, because the
    line is captured at the band centre while :math:`o` is the band's mean position (they
    differ most in the blue).
    """
    cen = np.asarray(centroids, dtype=np.float64)
    o = np.asarray(offsets, dtype=np.float64)
    if cen.shape != o.shape or cen.ndim != 2:
        raise InputError(f"line centroids {cen.shape} and offsets {o.shape} must both be (K, L)")
    if not np.all(np.isfinite(cen)) or not np.isfinite(column):
        raise InputError("line centroids and the line's column must be finite")
    return float(column) - float(np.median(cen[centre] - o[centre]))


def predicted_positions(homographies, offsets, box_shape, shift=(0.0, 0.0)) -> np.ndarray:
    r"""(K, L, Hb, Wb, 2) target coordinates (y, x) that box pixel :math:`(r, c)` sees in band
    :math:`l` according to the calibrated geometry:
    :math:`\pi\big(H_k^{-1}(c - o_{k,l},\ r,\ 1)^\top\big) + (s_y, s_x)`.

    ``homographies`` map the reconstruction grid (the centre view's) to each view,
    ``offsets`` (K, L) place the view image in its box, ``shift`` is where the grid sits on the
    target (:func:`line_anchor`).
    """
    hs = np.asarray(homographies, dtype=np.float64)
    o = np.asarray(offsets, dtype=np.float64)
    hb, wb = (int(v) for v in box_shape)
    k, n_bands = o.shape
    if hs.shape != (k, 3, 3):
        raise InputError(f"homographies {hs.shape} do not match offsets {o.shape}")
    rr, cc = np.mgrid[0:hb, 0:wb].astype(np.float64)
    out = np.empty((k, n_bands, hb, wb, 2), dtype=np.float64)
    for i in range(k):
        inv = np.linalg.inv(hs[i])
        for l in range(n_bands):
            x = cc - o[i, l]
            den = inv[2, 0] * x + inv[2, 1] * rr + inv[2, 2]
            out[i, l, ..., 1] = (inv[0, 0] * x + inv[0, 1] * rr + inv[0, 2]) / den + shift[1]
            out[i, l, ..., 0] = (inv[1, 0] * x + inv[1, 1] * rr + inv[1, 2]) / den + shift[0]
    return out


def _centre(resp, pred, period, weight):
    """Window centre along one axis: the response's circular centroid (phases on axis 0),
    unwrapped to the period nearest the prediction; the prediction where ``weight`` is low."""
    ph = np.exp(2j * np.pi * np.arange(period) / period).reshape((period,) + (1,) * pred.ndim)
    ang = np.angle(np.sum(resp * ph, axis=0)) * (period / (2 * np.pi))
    d = np.mod(ang - pred + period / 2.0, period) - period / 2.0
    return np.where(weight, pred + d, pred)


def decode_band(responses, predicted, grid, floor: float = FOOTPRINT_FLOOR):
    r"""One band's footprints from its comb responses.

    Parameters
    ----------
    responses : (Py, Px, K, Hb, Wb) array_like
        :math:`R_{ab}` per view box, in units of the lit texel's radiance.
    predicted : (K, Hb, Wb, 2) array_like
        Geometric target coordinates (y, x) of every box pixel (:func:`predicted_positions`).
    grid : (Ht, Wt)
        The target's texel grid.
    floor : float
        Relative weight floor (:data:`FOOTPRINT_FLOOR`).

    Returns
    -------
    rows, cols : int64 arrays
        Box pixel (view-major) and texel (row-major on the grid) of every kept weight.
    vals : float32 array
    """
    r = np.clip(np.asarray(responses, dtype=np.float32), 0.0, None)
    pos = np.asarray(predicted, dtype=np.float64)
    if r.ndim != 5 or pos.shape != r.shape[2:] + (2,):
        raise InputError(f"responses {r.shape} and predicted positions {pos.shape} do not match "
                         f"(Py, Px, K, Hb, Wb) and (K, Hb, Wb, 2)")
    py, px = r.shape[:2]
    ht, wt = (int(v) for v in grid)
    total = r.sum(axis=(0, 1))
    level = float(np.percentile(total, 99))
    if not level > 0:
        raise InputError("the comb captures of a band are dark")
    lit = total > _CENTROID_LEVEL * level
    cy = _centre(r.sum(axis=1), pos[..., 0], py, lit)
    cx = _centre(r.sum(axis=0), pos[..., 1], px, lit)
    ys = np.rint(cy - (py - 1) / 2.0).astype(np.int64)
    xs = np.rint(cx - (px - 1) / 2.0).astype(np.int64)
    pix = np.arange(total.size, dtype=np.int64).reshape(total.shape)
    flat = r.reshape(py * px, -1)
    rows, cols, vals = [], [], []
    for i in range(py):
        for j in range(px):
            ty, tx = ys + i, xs + j
            phase = (np.mod(ty, py) * px + np.mod(tx, px)).ravel()
            v = flat[phase, pix.ravel()].reshape(total.shape)
            keep = (ty >= 0) & (ty < ht) & (tx >= 0) & (tx < wt) & (v > floor * level)
            rows.append(pix[keep]), cols.append((ty * wt + tx)[keep]), vals.append(v[keep])
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)


def footprint_matrix(captures, view_boxes, predicted, *, floor: float = FOOTPRINT_FLOOR,
                     dark=None) -> tuple[sp.csr_matrix, tuple[int, int]]:
    r"""The system matrix from a stream of comb captures.

    Parameters
    ----------
    captures : iterable of (band, (a, b), frame, meta)
        Band-major, every phase of a band before the next band (as
        :func:`sim.captures.comb_captures` yields them); ``meta`` holds ``period``, ``phase``,
        ``grid``, ``radiance`` (the lit texel's) and ``radiance_scale`` (the exposure).
    view_boxes : (K, 4) array_like
    predicted : (K, L, Hb, Wb, 2) array_like
        :func:`predicted_positions`.
    floor : float
    dark : (H, W) array_like, optional

    Returns
    -------
    matrix : scipy.sparse.csr_matrix, (K·Hb·Wb, L·Ht·Wt) float32
        Exposure-normalised DN per unit radiance; columns band-major on the target grid.
    grid : (Ht, Wt)
    """
    pos = np.asarray(predicted, dtype=np.float64)
    k, n_bands, hb, wb = pos.shape[:4]
    boxes = check_boxes(view_boxes, n_views=k)
    if tuple(boxes[0, 2:]) != (hb, wb):
        raise InputError(f"view boxes are {tuple(boxes[0, 2:])}, predicted positions {(hb, wb)}")
    d = None if dark is None else np.asarray(dark, dtype=np.float32)
    parts, grid, period, stack, seen = [], None, None, None, set()
    current = 0

    def flush(band):
        if stack is None or len(seen) != period[0] * period[1]:
            raise InputError(f"band {band}: comb captures of {len(seen)} phases, expected "
                             f"{period[0] * period[1]}")
        rows, cols, vals = decode_band(stack, pos[:, band], grid, floor)
        parts.append((rows, cols + band * grid[0] * grid[1], vals))

    for band, phase, frame, meta in captures:
        band = int(band)
        try:
            p = tuple(int(v) for v in meta["period"])
            g = tuple(int(v) for v in meta["grid"])
            scale = float(meta["radiance_scale"]) * float(meta["radiance"])
        except (KeyError, TypeError, ValueError):
            raise InputError("a comb capture's sidecar needs period, grid, radiance and "
                             "radiance_scale") from None
        if not (np.isfinite(scale) and scale > 0):
            raise InputError(f"comb capture of band {band}: radiance x exposure must be positive")
        if period is None:
            if band != 0:
                raise InputError(f"comb captures must come band by band from band 0, got "
                                 f"band {band} first")
            period, grid = p, g
        elif (p, g) != (period, grid):
            raise InputError("comb captures of different periods or grids")
        if band != current:
            if band != current + 1:
                raise InputError(f"comb captures must come band by band: got band {band} "
                                 f"after band {current}")
            flush(current)
            current, stack, seen = band, None, set()
        a, b = (int(v) for v in phase)
        if not (0 <= a < p[0] and 0 <= b < p[1]) or (a, b) in seen:
            raise InputError(f"band {band}: bad or repeated comb phase {(a, b)}")
        f = np.asarray(frame, dtype=np.float32)
        if f.ndim != 2:
            raise InputError(f"a comb capture must be 2-D, got shape {f.shape}")
        if d is not None:
            f = f - d
        if stack is None:
            stack = np.empty(p + (k, hb, wb), dtype=np.float32)
        stack[a, b] = np.stack([crop(f, bx) for bx in boxes]) / np.float32(scale)
        seen.add((a, b))
    if period is None:
        raise InputError("no comb captures")
    flush(current)
    if current != n_bands - 1:
        raise InputError(f"comb captures of {current + 1} bands, the calibration has {n_bands}")
    rows = np.concatenate([q[0] for q in parts])
    cols = np.concatenate([q[1] for q in parts])
    vals = np.concatenate([q[2] for q in parts])
    m = sp.csr_matrix((vals, (rows, cols)), shape=(k * hb * wb, n_bands * grid[0] * grid[1]),
                      dtype=np.float32)
    return m, grid
