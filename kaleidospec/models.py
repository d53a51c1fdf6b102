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
:func:`truth_on_grid` moves a ground truth onto it (an exact area mean over cells translated by
:func:`grid_offset`, from the design and the calibrated box and offsets).  The footprint model
reconstructs on the comb target's texel grid, which is the scenes' grid: no translation.
"""

from __future__ import annotations

import numpy as np

from recon.errors import InputError

__all__ = ["MODELS", "DEFAULT_MODEL", "RUN_MODELS", "GAINS", "SMEAR_SAMPLES", "check_model",
           "holds", "model_of", "model_gains", "cube_grid", "grid_offset", "shifted_area_weights",
           "truth_on_grid"]

#: Every calibrated model a calibration can hold; the first (shifted) is in every calibration.
MODELS = ("shifted", "smeared", "footprint")
#: The model used when none is named: the one every design can calibrate in minutes.  On
#: ``small`` (FISTA-TV, 5 views, ``tools/exp_views.py``) the footprint model is the most
#: accurate (within 0.07 dB of the exact operator at 1–9 views) and the smeared one is no
#: better than the shifted one (24.36 against 24.61 dB ColorChecker, 22.69 against 22.77
#: natural); on ``paper`` the footprint matrix does not fit in memory.
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


def truth_on_grid(truth, design, cal, model: str | None = None) -> np.ndarray:
    r"""The ground truth moved onto the grid of the calibrated ``model`` (:func:`cube_grid`),
    (H, W, L) float32.

    ``truth`` (Ht, Wt, L) covers the centre view's :math:`v \times v` square at any resolution
    (:func:`sim.diffuser.cube_region`): a built-in scene at its own, finer resolution
    (:func:`kaleidospec.instrument.scene_cube`), or its mean on the design's grid
    (:func:`sim.frame.ground_truth`).  Grid pixel :math:`(y_v, x_v)` is the exact area mean of
    the truth over the design-grid cell :math:`[y_v + o_y, y_v + 1 + o_y] \times [x_v + o_x,
    x_v + 1 + o_x]` (:func:`grid_offset`; :func:`shifted_area_weights`, edge-padded).

    Pass the scene at its own resolution wherever it exists.  From the :math:`v \times v` mean
    this is a linear interpolation between neighbouring grid means, which has lost the detail
    within a pixel and then smooths by the fractional offset: a truth that flatters a smooth
    reconstruction (FISTA-TV, shifted model: by 0.05–0.35 dB on ``small``, 0.02–0.05 dB on
    ``paper``).
    """
    t = np.asarray(truth, dtype=np.float32)
    (h, w), n = cube_grid(cal, model), cal.n_bands
    if t.ndim != 3 or t.shape[2] != n:
        raise InputError(f"truth shape {t.shape} does not have the calibration's {n} bands")
    v = design.view_size_px
    oy, ox = grid_offset(design, cal, model)
    wy = shifted_area_weights(t.shape[0], h, oy, t.shape[0] / v).astype(np.float32)
    wx = shifted_area_weights(t.shape[1], w, ox, t.shape[1] / v).astype(np.float32)
    out = np.einsum("ij,jkl,mk->iml", wy, t, wx, optimize=True)
    return np.ascontiguousarray(out, dtype=np.float32)
