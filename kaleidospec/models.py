r"""The calibrated forward models, in one place: their names, the default, the radiometric
gains of each and the grid each reconstructs on.

A calibration (:class:`recon.calibration.Calibration`) always holds the **shifted** model,
the per-band mask images times the shifted scene (:class:`recon.operators.CalibratedCassi`),

.. math:: g_k = \sum_l C_{k,l} \odot S_{o_{k,l}}\big(W_k f_l\big);

it may also hold the **smeared** model, mask then shift and smear
(:class:`recon.operators.SmearedCassi`), and the **footprint** model, every pixel's weights on
the comb target's texels (:mod:`recon.calibration.footprint`), each with gains of its own.
Where the lens's diffraction spreads over more than a pixel (``paper``), the mask images are
deconvolved and the shifted and smeared models blur their measurement again with the
calibration's PSF (:class:`recon.operators.blur.BlurredOperator`); the footprint model
measures the blur with the rest.

Adding a model takes: its name in :data:`MODELS` and its gains field in :data:`GAINS` (and in
:data:`RUN_MODELS` if ``kaleidospec run --model`` offers it), the step that measures it in
:data:`kaleidospec.calibrate.STEPS`, its fields in :class:`recon.calibration.Calibration` and
its operator in :func:`recon.calibration.operator_from_calibration`.

Grids.  The shifted and smeared models reconstruct on the calibration's grid: the centre view's
box, with column 0 where the shortest band puts the view's first column, and only the part of
the view that the mask codes (the guard stripe's columns are never measured).
:func:`truth_on_grid` moves a ground truth onto it: exact area means (:func:`box_means`) over
the cells where the calibrated views put the grid's pixels on the scene
(:func:`kaleidospec.instrument.grid_on_scene`).  :func:`grid_offset` is the same grid taken for
the design's grid translated by the design's dispersion (the lenses' distortion left out, up to
1.1 px at the edges of `paper`'s centre view): good enough to find the ColorChecker's patches,
not to score a reconstruction.  The footprint model reconstructs on the comb target's texel
grid, which is the scenes' grid: no translation.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError

__all__ = ["MODELS", "DEFAULT_MODEL", "RUN_MODELS", "GAINS", "SMEAR_SAMPLES", "check_model",
           "holds", "model_of", "model_gains", "cube_grid", "grid_offset", "shifted_area_weights",
           "truth_on_grid", "truth_mover", "box_means", "box_means_reference"]

#: Every calibrated model a calibration can hold; the first (shifted) is in every calibration.
MODELS = ("shifted", "smeared", "footprint")
#: The model used when none is named: the one every design can calibrate in minutes.  The
#: footprint model is the more accurate where it fits in memory (not on ``paper``), the smeared
#: one no better than the shifted one (docs/calibration.md).
DEFAULT_MODEL = "shifted"
#: The models ``kaleidospec run`` and ``demo`` offer (``--model``); ``run`` calibrates each
#: itself.
RUN_MODELS = ("shifted", "footprint")
#: The :class:`recon.calibration.Calibration` field of each model's radiometric gains.
GAINS = {"shifted": "gains", "smeared": "smear_gains", "footprint": "footprint_gains"}
#: Wavelengths sampled across each band for its smear (the smeared model's kernels, every
#: band's mean position, and the design's counterpart :func:`grid_offset` compares it with).
SMEAR_SAMPLES = 32


def check_model(model: str) -> None:
    """Raise :class:`recon.errors.InputError` unless ``--model`` names one of
    :data:`RUN_MODELS`."""
    if model not in RUN_MODELS:
        raise InputError(f"--model must be one of {', '.join(RUN_MODELS)}, got {model!r}")


def holds(cal, model: str) -> bool:
    """Whether the calibration ``cal`` holds ``model`` (the shifted model always)."""
    from recon.calibration.operator import resolve_model

    try:
        resolve_model(cal, model)
    except InputError:
        return False
    return True


def model_of(cal, model: str | None = None) -> str:
    """The calibrated model that ``model`` names for ``cal``; ``None`` names
    :data:`DEFAULT_MODEL` (were that ``"smeared"``: the best model the calibration holds).
    A model the calibration lacks raises :class:`recon.errors.InputError`."""
    from recon.calibration.operator import resolve_model

    if model is None:
        model = "auto" if DEFAULT_MODEL == "smeared" else DEFAULT_MODEL
    return resolve_model(cal, model)


def model_gains(cal, model: str | None = None) -> np.ndarray:
    """(L,) the radiometric gains of the calibrated ``model``."""
    own = getattr(cal, GAINS[model_of(cal, model)])
    return cal.gains if own is None else own


def cube_grid(cal, model: str | None = None) -> tuple[int, int]:
    """(H, W) of the cubes the calibrated ``model`` reconstructs."""
    if model_of(cal, model) == "footprint":
        return tuple(int(v) for v in cal.footprint_grid)
    return tuple(cal.cube_shape[:2])


def grid_offset(design, cal, model: str | None = None) -> tuple[float, float]:
    r"""Where the reconstruction grid sits on the ground-truth grid: truth pixel
    :math:`(y_v + o_y,\ x_v + o_x)` is reconstruction pixel :math:`(y_v, x_v)`.

    The footprint model's grid is the comb target's, the scenes' own grid: :math:`(0, 0)`.
    Otherwise:

    The centre view's cube column :math:`x` lands, in band :math:`l`, on sensor column
    :math:`c_0 + x + \bar\varphi_l` on average over the band (design,
    :func:`kaleidospec.instrument.band_mean_dispersion`); the calibration puts reconstruction
    column :math:`x_v` on box column :math:`x_v + o_{0,l}` (the band's measured mean
    position), i.e. sensor column :math:`b_0 + x_v + o_{0,l}`.  So :math:`o_x = b_0 - c_0 +
    \overline{o_{0,l} - \bar\varphi_l}` (mean over bands), and :math:`o_y = b_{0,y} - r_0`.
    """
    from kaleidospec.instrument import band_mean_dispersion

    if model_of(cal, model) == "footprint":
        return 0.0, 0.0
    if 0 not in cal.view_ids:
        raise InputError("the calibration has no centre view")
    i = cal.view_ids.index(0)
    by, bx = (float(x) for x in cal.view_boxes[i, :2])
    r0, c0 = design.code_region_px(0)[:2]
    phi = band_mean_dispersion(design, cal.wavelengths, SMEAR_SAMPLES)
    ox = bx - c0 + float(np.mean(cal.offsets[i] - phi))
    return by - r0, ox


def shifted_area_weights(n_in: int, n_out: int, offset: float, scale: float) -> np.ndarray:
    r"""(n_out, n_in) weights of an exact area mean over shifted cells along one axis.

    Output cell :math:`i` covers :math:`[(i + o)\,s,\ (i + 1 + o)\,s]` in input texels
    (:math:`o` the offset in output cells, :math:`s` input texels per output cell); its weight
    on texel :math:`j` is the overlap with :math:`[j, j + 1]` over :math:`s`.  The parts of a
    cell beyond the input's ends count as the edge texel (edge padding), so every row sums
    to 1.
    """
    lo = (np.arange(n_out, dtype=np.float64) + offset) * scale
    hi = lo + scale
    a = np.arange(n_in + 1, dtype=np.float64)
    w = np.clip(np.minimum(hi[:, None], a[None, 1:]) - np.maximum(lo[:, None], a[None, :-1]),
                0.0, None)
    w[:, 0] += np.clip(np.minimum(hi, 0.0) - lo, 0.0, None)
    w[:, -1] += np.clip(hi - np.maximum(lo, float(n_in)), 0.0, None)
    return w / scale


def truth_on_grid(truth, design, cal, model: str | None = None, view_ids=None, *,
                  corners=None) -> np.ndarray:
    r"""The ground truth moved onto the grid of the calibrated ``model`` (:func:`cube_grid`) as
    the views ``view_ids`` (default: all the calibration's) see it, (H, W, L) float32.

    ``truth`` (Ht, Wt, L) covers the centre view's :math:`v \times v` square at any resolution
    (:func:`sim.optics.diffuser.cube_region`): a built-in scene at its own, finer resolution
    (:func:`kaleidospec.instrument.scene_cube`), or its mean on the design's grid
    (:func:`sim.frame.ground_truth`).  Every grid pixel is the exact area mean of the truth
    (piecewise constant on its texels, edge-padded) over the part of the scene the pixel
    covers:

    - footprint model: its grid is the comb target's, the design's grid (:func:`grid_offset`
      is zero);
    - shifted and smeared models: every calibrated view says where a grid pixel lies on the
      scene (its homography, displacement field and offsets, through the simulator's exact
      optics: :func:`kaleidospec.instrument.grid_on_scene`), and the pixel's cell is the mean
      of the answers of the views a reconstruction uses, the box through the midpoints of its
      sides (the cells are squares to 10⁻³ px).  Before, the truth was the design grid
      translated by :func:`grid_offset`, which is off by up to 1.1 px at the edges of the
      `paper` centre view: it charged the models with the lenses' distortion (a placement
      every view agrees on) as if it were a model error.  Where the views disagree, no
      registration pleases them all: on `small`, without displacement fields, the views
      mirrored along x put the grid 0.8 px (rms) away from where the centre puts it.

    Pass the scene at its own resolution wherever it exists: the :math:`v \times v` mean has
    lost the detail within a pixel (a truth that flatters a smooth reconstruction).

    ``corners``, :func:`kaleidospec.instrument.grid_on_scene`'s ``(x, y)`` for these
    ``design``, ``cal`` and ``view_ids`` when already computed (:func:`truth_mover`: the
    frames of a video share them).
    """
    t = np.asarray(truth, dtype=np.float32)
    (h, w), n = cube_grid(cal, model), cal.n_bands
    if t.ndim != 3 or t.shape[2] != n:
        raise InputError(f"truth shape {t.shape} does not have the calibration's {n} bands")
    v = design.view_size_px
    if model_of(cal, model) == "footprint":
        wy = shifted_area_weights(t.shape[0], h, 0.0, t.shape[0] / v).astype(np.float32)
        wx = shifted_area_weights(t.shape[1], w, 0.0, t.shape[1] / v).astype(np.float32)
        out = np.einsum("ij,jkl,mk->iml", wy, t, wx, optimize=True)
        return np.ascontiguousarray(out, dtype=np.float32)
    if corners is None:
        from kaleidospec.instrument import grid_on_scene

        corners = grid_on_scene(design, cal, view_ids)
    x, y = corners
    sx, sy = t.shape[1] / v, t.shape[0] / v
    return box_means(t, 0.5 * (x[:-1, :-1] + x[1:, :-1]) * sx, 0.5 * (x[:-1, 1:] + x[1:, 1:]) * sx,
                     0.5 * (y[:-1, :-1] + y[:-1, 1:]) * sy, 0.5 * (y[1:, :-1] + y[1:, 1:]) * sy)


def truth_mover(design, cal, model: str | None = None, view_ids=None):
    """``move(truth)`` = :func:`truth_on_grid` ``(truth, design, cal, model, view_ids)``, with
    where the grid lies on the scene (:func:`kaleidospec.instrument.grid_on_scene`, the
    simulator's maps evaluated for every view) computed on the first call only: the same
    cubes for every truth of one design, as a video's frames are."""
    corners = []

    def move(truth):
        if not corners and model_of(cal, model) != "footprint":
            from kaleidospec.instrument import grid_on_scene

            corners.append(grid_on_scene(design, cal, view_ids))
        return truth_on_grid(truth, design, cal, model, view_ids,
                             corners=corners[0] if corners else None)

    return move


def box_means(image, x0, x1, y0, y1) -> np.ndarray:
    r"""Exact means of a piecewise-constant image (H, W, L) over the boxes
    :math:`[x_0, x_1] \times [y_0, y_1]` (texel units, texel :math:`(i, j)` covers
    :math:`[j, j+1) \times [i, i+1)`; arrays of one shape S), (*S, L) float32.

    The integral image :math:`I(x, y) = \int_0^y\!\int_0^x f` is bilinear inside every texel,
    so bilinear interpolation of its values at the texel corners is exact, and a box's integral
    is :math:`I(x_1, y_1) - I(x_0, y_1) - I(x_1, y_0) + I(x_0, y_0)`.  Beyond the image the edge
    texels extend (edge padding).
    """
    f = np.asarray(image, dtype=np.float32)
    hh, ww, n = f.shape
    x0, x1, y0, y1 = (np.asarray(a, dtype=np.float64) for a in (x0, x1, y0, y1))
    lo = min(float(x0.min()), float(x1.min()), float(y0.min()), float(y1.min()), 0.0)
    hi = max(float(x1.max()) - ww, float(x0.max()) - ww, float(y1.max()) - hh,
             float(y0.max()) - hh, 0.0)
    pad = int(np.ceil(max(-lo, hi))) + 1
    # A box narrower than 10⁻³ texel becomes one that wide around its middle (the texel's
    # value): the integral image's differences over less would lose their digits.
    width = np.maximum(np.abs(x1 - x0), 1e-3)
    height = np.maximum(np.abs(y1 - y0), 1e-3)
    xa = 0.5 * (x0 + x1 - width) + pad
    ya = 0.5 * (y0 + y1 - height) + pad
    corners = [(xa + width, ya + height, 1.0), (xa, ya + height, -1.0),
               (xa + width, ya, -1.0), (xa, ya, 1.0)]
    wp = ww + 2 * pad + 1
    area = (width * height).ravel()
    from recon import kernels

    if kernels.enabled():
        # The same operations in the same order, compiled, without fast-math: the same bits
        # as the NumPy loop below (box_means_reference; tests/kaleidospec/test_models.py).
        cx = np.stack([c[0].ravel() for c in corners])
        cy = np.stack([c[1].ravel() for c in corners])
        signs = np.array([c[2] for c in corners])
        out = np.empty((area.size, n), dtype=np.float32)
        _box_means_kernel(f, pad, cx, cy, signs, area, out)
        return out.reshape(x0.shape + (n,))
    return _box_means_numpy(f, corners, pad, wp, area).reshape(x0.shape + (n,))


def box_means_reference(image, x0, x1, y0, y1) -> np.ndarray:
    """:func:`box_means` in NumPy alone (the reference its compiled path is tested against)."""
    from recon import kernels

    with kernels.numpy_only():
        return box_means(image, x0, x1, y0, y1)


def _box_means_numpy(f, corners, pad, wp, area):
    hh, ww, n = f.shape
    out = np.empty((area.size, n), dtype=np.float32)
    for l in range(n):
        sat = np.zeros((hh + 2 * pad + 1, wp))
        sat[1:, 1:] = np.pad(f[:, :, l], pad, mode="edge").astype(np.float64).cumsum(0).cumsum(1)
        flat = sat.ravel()
        acc = np.zeros(area.size)
        # The taps are recomputed per band: kept for all bands they would hold 16 index and
        # weight arrays of the grid's size (0.2 GB on `paper`).
        for cx, cy, sign in corners:
            ix = np.floor(cx).astype(np.int64).ravel()
            iy = np.floor(cy).astype(np.int64).ravel()
            tx, ty = cx.ravel() - ix, cy.ravel() - iy
            i = iy * wp + ix
            acc += sign * ((1 - ty) * ((1 - tx) * flat[i] + tx * flat[i + 1])
                           + ty * ((1 - tx) * flat[i + wp] + tx * flat[i + wp + 1]))
        out[:, l] = acc / area
    return out


def _box_means_kernel(f, pad, cx, cy, signs, area, out):
    from numba import njit, prange

    global _BOX_KERNEL
    if _BOX_KERNEL is None:
        @njit(cache=True, parallel=True)
        def kernel(f, pad, cx, cy, signs, area, out):
            hh, ww, n = f.shape
            hp, wp = hh + 2 * pad + 1, ww + 2 * pad + 1
            for l in prange(n):
                # The edge-padded band, its cumulative sums down the rows then along them
                # (NumPy's cumsum(0).cumsum(1): each a running sum in index order).
                sat = np.zeros((hp, wp))
                for r in range(1, hp):
                    rr = min(max(r - 1 - pad, 0), hh - 1)
                    for c in range(1, wp):
                        sat[r, c] = np.float64(f[rr, min(max(c - 1 - pad, 0), ww - 1), l])
                for r in range(2, hp):
                    for c in range(1, wp):
                        sat[r, c] = sat[r - 1, c] + sat[r, c]
                for r in range(1, hp):
                    for c in range(2, wp):
                        sat[r, c] = sat[r, c - 1] + sat[r, c]
                flat = sat.ravel()
                for j in range(area.size):
                    acc = 0.0
                    for k in range(signs.size):
                        ix = np.int64(np.floor(cx[k, j]))
                        iy = np.int64(np.floor(cy[k, j]))
                        tx = cx[k, j] - ix
                        ty = cy[k, j] - iy
                        i = iy * wp + ix
                        acc = acc + signs[k] * ((1 - ty) * ((1 - tx) * flat[i] + tx * flat[i + 1])
                                                + ty * ((1 - tx) * flat[i + wp]
                                                        + tx * flat[i + wp + 1]))
                    out[j, l] = np.float32(acc / area[j])
        _BOX_KERNEL = kernel
    _BOX_KERNEL(f, pad, cx, cy, signs, area, out)


_BOX_KERNEL = None
