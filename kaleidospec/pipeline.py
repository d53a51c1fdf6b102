r"""Render, calibrate, reconstruct: the application layer, the one place that joins ``sim`` and
``recon``.

The reconstruction side sees only raw frames, their sidecars and the calibration captures, as
with real hardware:

1. :func:`calibrate` renders the calibration captures (:mod:`sim.captures`) and runs
   :mod:`recon.calibration` on them: view boxes and per-band mask images from monochromatic
   whites, the dispersion :math:`\varphi_k(\lambda)` from line captures, homographies from a
   checkerboard at 550 nm, and per-band radiometric gains :math:`c_l` from the ColorChecker.
   The result is cached by design hash (``calibration-<hash>.npz/.json`` in the cache folder).
2. :func:`render_scene` renders a scene's raw frame and keeps its ground truth.
3. :func:`reconstruct_views` cuts the first ``n`` views out of the frame and solves

   .. math:: \hat f = \arg\min_f \tfrac12 \|g/s - H\,\mathrm{diag}(c)^{-1} f\|^2
                       + \tau\,\mathrm{TV}(f),

   with :math:`s` the frame's exposure factor (``radiance_scale`` in its sidecar), so that
   :math:`\hat f` is in the scene cube's own units (comparable with the truth, and about
   [0, 1], the range the solvers' default :math:`\tau` is meant for).

The reconstruction grid is the calibration's: the centre view's box, with column 0 where the
shortest band puts the view's first column, and only the part of the view that the mask codes
(the guard stripe's columns are never measured).  :func:`truth_on_grid` moves the ground truth
onto it (a sub-pixel translation, from the design and the calibrated box and offsets) for the
metrics.  The footprint model (``model="footprint"``, calibrated with ``footprint=True``:
:mod:`recon.calibration.footprint`) reconstructs on the comb target's texel grid instead, which
is the scenes' grid: no translation.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from recon.errors import InputError
# The sRGB pictures are recon.report's, shared with kaleidospec reconstruct.
from recon.report import grid_regions, srgb_image as _srgb, write_png as _write_png

__all__ = ["VIEW_ORDER", "calibrate", "render_scene", "reconstruct_views", "oracle_operator",
           "reconstruct_oracle", "band_mean_dispersion", "solve_views", "truth_on_grid",
           "design_for_views", "run", "DEFAULTS"]

#: View ids in the order the 1/2/3/5/9-view experiments add them.
VIEW_ORDER = (0, 1, 2, 3, 4, 5, 6, 7, 8)
#: Reconstruction defaults (measured on the ``small`` design, see the README / report).
DEFAULTS = {"solver": "fista-tv", "iters": 100, "tau": None}
#: Default TV weight per solver (per view for the solvers whose data term sums over views):
#: measured on the ``small`` design, see :func:`tv_weight`.
TAU_PER_VIEW = {"fista-tv": 0.005, "twist": 0.005}
#: Calibrated mask values below this (fraction of the white level) are taken as chrome (0).
MASK_FLOOR = 0.05
#: Columns added (at most: never so many that boxes overlap) on each side of a view's lit extent:
#: a view's outermost columns are lit by one band only and fall under the box threshold.
BOX_MARGIN_X = 2
#: Views used to reconstruct the ColorChecker for the radiometric gains.
_RADIOMETRY_VIEWS = 5
#: The calibrated forward model :func:`calibrated_operator` uses by default: ``"smeared"``
#: (mask, then shift and smear: :class:`recon.operators.SmearedCassi`) or ``"shifted"`` (the
#: per-band mask images times the shifted scene, :class:`recon.operators.CalibratedCassi`).
#: Measured on ``small`` (noise-free frames, the model's prediction of the truth against the
#: frame, mean over 5 views): shifted 6.8 % (ColorChecker) / 5.7 % (natural), smeared 11.3 % /
#: 10.5 %.  The simulator's transport samples each pixel with 4 rays of random wavelength and
#: position, so every band's white capture is a random realisation of the smear that the
#: per-band mask images record exactly and a mean kernel cannot; "shifted" stays the default,
#: "smeared" is calibrated when asked (:func:`calibrate_from_captures`).
CALIBRATED_MODEL = "shifted"
#: Wavelengths sampled across each band for its smear kernel.
SMEAR_SAMPLES = 32


def _cache_dir(cache_dir=None) -> Path:
    if cache_dir is not None:
        p = Path(cache_dir)
        p.mkdir(parents=True, exist_ok=True)
        return p
    from sim.transport import cache_dir as default

    return default()


def design_for_views(design, n_views: int):
    """``design`` with its ``views`` widened to hold the first ``n_views`` views.

    The ``views`` field only says which views the simulator traces and calibration finds (the
    optics are the same), so a 9-view run uses the same design with all nine views; its hash,
    and so its caches, differ.
    """
    need = VIEW_ORDER[:int(n_views)]
    if set(need) <= set(design.views):
        return design
    return design.replace(views=tuple(sorted(set(design.views) | set(need))))


# ------------------------------------------------------------------------------- calibration
def calibrate(design, *, cache_dir=None, progress: bool = True, force: bool = False,
              repeats: int = 4, footprint: bool = False):
    """The calibration of ``design`` from rendered captures, cached by design hash.

    Parameters
    ----------
    design : sim.design.Design
    cache_dir : path, optional
        Where ``calibration-<hash>.npz/.json`` live (default: the transport cache folder,
        ``$KALEIDOSPEC_CACHE`` or ``~/.cache/kaleidospec``).
    progress : bool
        Progress bars on stderr.
    force : bool
        Recalibrate even if a cached calibration exists.
    repeats : int
        Noisy frames averaged per capture (:mod:`sim.captures`); 0 renders noise-free.
    footprint : bool
        Also measure the footprint model with the comb captures (L·P_y·P_x more captures,
        :func:`recon.calibration.footprint.comb_period`: 165 and 19 s more for ``small``); a
        cached calibration without it is redone with it.

    Returns
    -------
    recon.calibration.Calibration
        ``view_ids`` = the design's views (sorted), gains fitted on the ColorChecker.
    """
    from recon.calibration import calibration_path, load_cached, save_calibration

    cdir = _cache_dir(cache_dir)
    if not force:
        cal = load_cached(cdir, design.hash)
        if cal is not None and (cal.has_footprint or not footprint):
            return cal
    cal = calibrate_from_captures(design, repeats=repeats, progress=progress,
                                  footprint=footprint)
    save_calibration(calibration_path(cdir, design.hash), cal)
    return cal


def calibrate_from_captures(design, *, repeats: int = 4, progress: bool = False, captures=None,
                            smeared: bool | None = None, footprint: bool = False):
    """Render the captures (unless given) and run every calibration step; nothing is cached.

    ``smeared`` also calibrates the "mask, then shift and smear" model (smear kernels, view
    masks, its own gains; default: when :data:`CALIBRATED_MODEL` is ``"smeared"``).
    ``footprint`` also renders the comb captures and measures the footprint model (its system
    matrix and its own gains, :mod:`recon.calibration.footprint`).
    """
    if smeared is None:
        smeared = CALIBRATED_MODEL == "smeared"
    import dataclasses

    from recon.calibration import (airy_radius_px, build_calibration, find_view_boxes,
                                   fit_dispersion, line_centroids, mask_images,
                                   view_homographies)
    from recon.calibration.dispersion import band_mean_positions, band_positions
    from recon.calibration.footprint import comb_period
    from recon.calibration.mask import view_masks, view_stack, white_levels
    from sim.bands import band_intervals
    from sim.captures import CHECKER_NM, render_captures

    if captures is None:
        captures = render_captures(design, repeats=repeats, progress=progress)
    caps = captures
    ids = tuple(sorted(design.views))
    wl = caps.wavelengths
    steps = ["views", "dispersion", "masks", "geometry"] + (["view masks"] if smeared else []) \
        + (["footprints"] if footprint else []) + ["radiometry"]
    bar = _bar(len(steps), "calibration", progress)
    try:
        boxes = find_view_boxes(caps.white, ids, margin_x=BOX_MARGIN_X)
        _tick(bar)
        cen = line_centroids(caps.line, boxes)
        fit = fit_dispersion(wl, cen, ref_nm=CHECKER_NM, degree=min(3, wl.size - 1))
        _tick(bar)
        radii = airy_radius_px(wl, design.imaging_f_number, design.sensor_pixel_um)
        # Below ~0.75 px the Airy core stays inside one pixel: deconvolution would only add noise.
        airy = radii if float(radii.max()) >= 0.75 else None
        masks = mask_images(caps.white, boxes, airy_radius=airy)
        # Chrome cells are not perfectly dark in a capture (stray light, the sensor's blur):
        # values near zero would give measurement pixels with a tiny row norm, which GAP-TV's
        # diag(HH^T)^-1 step amplifies without bound.  They are set to exactly zero.
        masks = np.where(masks >= MASK_FLOOR, masks, np.float32(0.0))
        _tick(bar)
        # The board's layout is what a lab knows from its target: read it from the sidecar.
        pattern = tuple(caps.meta["checker"]["pattern_size"])
        hb = view_homographies(caps.checker, caps.checker_white, boxes, ids, pattern)
        _tick(bar)
        # Provisional gains from the whites (radiance E = 1 per band): the mask images are the
        # white captures divided by their white level w_l (DN at an open pixel), taken with
        # exposure s_l, so DN/s per unit radiance at an open pixel is w_l / s_l.
        levels = white_levels(view_stack(caps.white, boxes))
        expo = np.array([m["radiance_scale"] for m in caps.meta["white"]], dtype=np.float64)
        gains0 = expo / levels
        # The bands' wavelength intervals are the band-pass filters' (a lab knows them from
        # the filters' datasheet): each band smears over phi(lo)..phi(hi), and its scene sits
        # at the mean of that smear, not where its nominal wavelength lands (measured on
        # `small`: 0.8 px apart for the 450 nm band; `tools/exp_calibration_gap.py`).
        intervals = band_intervals(design, wl)
        cal = build_calibration(
            view_ids=ids, view_boxes=boxes, box_homographies=hb, mask_images=masks,
            wavelengths=wl, dispersion=band_mean_positions(fit, intervals, SMEAR_SAMPLES),
            checker_dispersion=fit.positions([CHECKER_NM])[:, 0], phase=True,
            gains=gains0, design_hash=design.hash, captures=caps.names(),
            band_positions=(band_positions(fit, intervals, SMEAR_SAMPLES)
                            if smeared else None))
        extra = {}
        if smeared:
            # The smeared model's view masks, from all the band whites jointly; its white
            # levels are those of an open mask pixel (a smear wider than a mask cell lowers
            # the captured level), hence its own provisional gains.
            vm, vlevels = view_masks(caps.white, boxes, cal.tap_start, cal.tap_weights,
                                     cal.view_shape[1], airy_radius=airy)
            vm = np.where(vm >= MASK_FLOOR, vm, np.float32(0.0))
            cal = dataclasses.replace(cal, view_masks=vm, smear_gains=expo / vlevels)
            _tick(bar)
        if footprint:
            smear = np.ptp(band_positions(fit, intervals, SMEAR_SAMPLES), axis=2).max()
            cal = _footprints(design, cal, cen, caps.meta["line"][0]["column"],
                              comb_period(smear, float(radii.max())), repeats, progress)
            _tick(bar)
        # Radiometry, per model: reconstruct the ColorChecker with the provisional gains,
        # compare its patches with their reference radiance (reflectance x D65, cube units).
        gains = _radiometry(design, caps, cal, "shifted")
        if smeared:
            extra["smear_gains"] = _radiometry(design, caps, cal, "smeared")
        if footprint:
            extra["footprint_gains"] = _radiometry(design, caps, cal, "footprint")
        _tick(bar)
    finally:
        if bar is not None:
            bar.close()
    for name, g in (("", gains), ("smeared-model ", extra.get("smear_gains", gains)),
                    ("footprint-model ", extra.get("footprint_gains", gains))):
        if not np.all(g > 0):
            raise RuntimeError(f"radiometric calibration failed: {name}gains {g.tolist()}")
    return dataclasses.replace(cal, gains=gains, **extra)


def _footprints(design, cal, line_centroids, line_column, period, repeats, progress):
    """``cal`` with the footprint model: the system matrix decoded from the comb captures of
    ``period`` (streamed, one frame at a time), provisional gains 1 (the captures are divided by
    the lit texels' radiance)."""
    import dataclasses

    from recon.calibration.footprint import footprint_matrix, line_anchor, predicted_positions
    from sim.captures import comb_captures

    i = cal.view_ids.index(0)
    shift = (0.0, line_anchor(line_centroids, cal.offsets, line_column, centre=i))
    pos = predicted_positions(cal.homographies, cal.offsets, cal.view_boxes[0, 2:], shift)
    caps = comb_captures(design, period, repeats=repeats, progress=progress)
    a, grid = footprint_matrix(caps, cal.view_boxes, pos)
    py, px = period
    names = [f"comb{py}x{px}@{w:g}nm" for w in cal.wavelengths]
    return dataclasses.replace(cal, footprint_grid=np.array(grid, np.int64),
                               footprint_indptr=a.indptr.astype(np.int64),
                               footprint_indices=a.indices,
                               footprint_data=a.data, footprint_gains=np.ones(cal.n_bands),
                               captures=list(cal.captures) + names)


def _radiometry(design, caps, cal, model) -> np.ndarray:
    """The gains of ``model`` refitted on the ColorChecker capture (per-band least squares of
    the reconstructed patches against their reference radiance)."""
    from recon.calibration import fit_gains, patch_spectra

    ids = cal.view_ids
    n = min(_RADIOMETRY_VIEWS, len(ids))
    n = max(i + 1 for i in range(n) if set(VIEW_ORDER[:i + 1]) <= set(ids))
    cube, _ = reconstruct_views(caps.colorchecker, caps.meta["colorchecker"], cal, n,
                                model=model, **_solver_defaults())
    oy, ox = grid_offset(design, cal, model)
    pb = caps.patch_boxes.astype(np.float64).copy()
    pb[:, 0] -= oy
    pb[:, 1] -= ox
    pb = np.round(pb).astype(np.int64)
    # Patches that the reconstruction grid cuts (the guard stripe's columns) are left out.
    inside = ((pb[:, 0] >= 0) & (pb[:, 1] >= 0) & (pb[:, 0] + pb[:, 2] <= cube.shape[0])
              & (pb[:, 1] + pb[:, 3] <= cube.shape[1]))
    f = patch_spectra(cube, pb[inside])
    g0 = model_gains(cal, model)
    return g0 * fit_gains(f, caps.patch_radiance[inside])


def tv_weight(solver, tau, n_views):
    """The TV weight: ``tau`` if given, else the solver's default per view × the views (the
    data term sums over the views' pixels; GAP-TV's projection step does not, so its weight
    is per view)."""
    if tau is not None:
        return tau
    from recon.app import default_tau

    base = TAU_PER_VIEW.get(solver, default_tau(solver))
    return base if solver == "gap-tv" else base * int(n_views)


def _solver_defaults():
    return {"solver": DEFAULTS["solver"], "iters": DEFAULTS["iters"], "tau": DEFAULTS["tau"]}


def _bar(total, desc, progress):
    if not progress:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="step", leave=False)


def _tick(bar):
    if bar is not None:
        bar.update(1)


# ------------------------------------------------------------------------------- scenes
def render_scene(scene, design, *, seed: int = 0, noise: bool = True, angle_deg=None,
                 radiance_scale=None, **scene_params):
    """Render the raw frame of a built-in scene or a cube file.

    The frame is independent of every calibration capture: the scene is built at
    :data:`sim.frame.SCENE_OVERSAMPLE` times the reconstruction grid (a cube file keeps its own
    resolution), so it carries detail no reconstruction grid holds, and it goes through the
    transport traced with the scene frames' own seed (:data:`sim.transport.SEEDS`).

    Parameters
    ----------
    scene : str or path
        A name from :func:`scenes.registry.list_scenes` or a cube file.
    design : sim.design.Design
    seed : int
        Sensor noise seed.
    noise : bool
        Shot and read noise.
    angle_deg : float, optional
        Rotation of the colour wheel (``colorwheel`` only; a scene parameter).
    radiance_scale : float, optional
        Fixed exposure (default: auto-exposure, brightest pixel at 80 % of the full well).
    **scene_params
        Passed to the scene builder.

    Returns
    -------
    frame : (Hs, Ws) float32, DN
    metadata : dict
        The sidecar (``design_hash``, ``radiance_scale``, ``scene``, ...).
    truth : (v, v, L) float32
        The scene averaged onto the centre view's grid (:func:`sim.frame.ground_truth`); see
        :func:`truth_on_grid` for the reconstruction grid.
    wavelengths : (L,) float64
    """
    from scenes.registry import get_scene
    from sim.frame import ground_truth, scene_grid, simulate_frame

    if angle_deg is not None:
        scene_params["angle_deg"] = angle_deg
    cube, wl = get_scene(str(scene), shape=scene_grid(design, scene),
                         wavelengths=design.wavelengths, **scene_params)
    frame, meta = simulate_frame(design, cube, wl, seed=seed, noise=noise,
                                 radiance_scale=radiance_scale)
    meta["scene"] = str(scene)
    if scene_params:
        meta["scene_params"] = {k: v_ for k, v_ in scene_params.items()}
    return frame, meta, ground_truth(design, cube), wl


# ------------------------------------------------------------------------------- grids
def model_of(cal, model: str | None = None) -> str:
    """The calibrated model that ``model`` names for ``cal`` (``None``: :data:`CALIBRATED_MODEL`;
    ``"smeared"`` falls back to ``"shifted"`` for a calibration without it)."""
    from recon.calibration.operator import resolve_model

    if model is None:
        model = "auto" if CALIBRATED_MODEL == "smeared" else CALIBRATED_MODEL
    return resolve_model(cal, model)


def model_gains(cal, model: str | None = None) -> np.ndarray:
    """(L,) the radiometric gains of the calibrated ``model``."""
    kind = model_of(cal, model)
    own = {"smeared": cal.smear_gains, "footprint": cal.footprint_gains}.get(kind)
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
    :func:`band_mean_dispersion`); the calibration puts reconstruction column :math:`x_v` on box
    column :math:`x_v + o_{0,l}` (the band's measured mean position), i.e. sensor column
    :math:`b_0 + x_v + o_{0,l}`.  So :math:`o_x = b_0 - c_0 + \overline{o_{0,l} -
    \bar\varphi_l}` (mean over bands), and :math:`o_y = b_{0,y} - r_0`.
    """
    if model_of(cal, model) == "footprint":
        return 0.0, 0.0
    if 0 not in cal.view_ids:
        raise InputError("the calibration has no centre view")
    i = cal.view_ids.index(0)
    by, bx = (float(x) for x in cal.view_boxes[i, :2])
    r0, c0 = design.code_region_px(0)[:2]
    ox = bx - c0 + float(np.mean(cal.offsets[i] - band_mean_dispersion(design, cal.wavelengths)))
    return by - r0, ox


def band_mean_dispersion(design, wavelengths) -> np.ndarray:
    r"""(L,) the design's dispersion :math:`\varphi` averaged over every band's interval (px),
    the counterpart of :func:`recon.calibration.band_mean_positions`."""
    from recon.calibration.dispersion import band_wavelengths
    from sim.bands import band_intervals

    lam = band_wavelengths(band_intervals(design, np.asarray(wavelengths, dtype=np.float64)),
                           SMEAR_SAMPLES)
    return design.dispersion_px_at(lam.ravel()).reshape(lam.shape).mean(axis=1)


def _design_of(metadata, design=None):
    if design is not None:
        return design
    from sim.design import Design

    d = (metadata or {}).get("design")
    if not isinstance(d, dict):
        raise InputError("the frame's sidecar has no design: cannot place the ground truth")
    return Design.from_dict(d)


def truth_on_grid(truth, design, cal, model: str | None = None) -> np.ndarray:
    """The ground truth (v, v, L) resampled onto the grid of the calibrated ``model``
    (:func:`cube_grid`).

    A bilinear sub-pixel translation by :func:`grid_offset`; pixels beyond the truth's edge take
    the edge value.
    """
    t = np.asarray(truth, dtype=np.float32)
    (h, w), n = cube_grid(cal, model), cal.n_bands
    if t.ndim != 3 or t.shape[2] != n:
        raise InputError(f"truth shape {t.shape} does not have the calibration's {n} bands")
    oy, ox = grid_offset(design, cal, model)
    iy, ix = math.floor(oy), math.floor(ox)
    fy, fx = np.float32(oy - iy), np.float32(ox - ix)
    # Edge-padded so that the (h+1, w+1) window at (iy, ix) always exists.
    pad_lo_y, pad_lo_x = max(0, -iy), max(0, -ix)
    pad_hi_y = max(0, iy + h + 1 - t.shape[0])
    pad_hi_x = max(0, ix + w + 1 - t.shape[1])
    tp = np.pad(t, ((pad_lo_y, pad_hi_y), (pad_lo_x, pad_hi_x), (0, 0)), mode="edge")
    y0, x0 = iy + pad_lo_y, ix + pad_lo_x
    a = tp[y0:y0 + h + 1, x0:x0 + w + 1]
    out = ((1 - fy) * ((1 - fx) * a[:h, :w] + fx * a[:h, 1:w + 1])
           + fy * ((1 - fx) * a[1:h + 1, :w] + fx * a[1:h + 1, 1:w + 1]))
    return np.ascontiguousarray(out, dtype=np.float32)


# ------------------------------------------------------------------------------- reconstruction
def _check_views(n_views) -> tuple[int, ...]:
    try:
        n = int(n_views)
    except (TypeError, ValueError):
        raise InputError(f"the number of views must be an integer 1..9, got {n_views!r}") from None
    if n != n_views or not 1 <= n <= 9:
        raise InputError(f"the number of views must be an integer 1..9, got {n_views!r}")
    return VIEW_ORDER[:n]


def unit_row_scale(op) -> float:
    r"""The :math:`s` that makes the mean squared norm of the measured rows of :math:`sH` one.

    The data term :math:`\tfrac12\|s g - s H f\|^2` then weighs a measurement pixel alike
    whatever the exposure units of :math:`H`, so one TV weight :math:`\tau` serves the
    calibrated and the exact operator, the ``small`` and the ``paper`` design.
    """
    mean = getattr(op, "mean_row_norm_sq", None)
    if mean is not None:        # the exact operator estimates it (its row norms are costly)
        m = float(mean())
        return 1.0 if m <= 0 else 1.0 / math.sqrt(m)
    rn = np.asarray(op.row_norms_sq(), dtype=np.float64)
    pos = rn[rn > 0]
    return 1.0 if pos.size == 0 else 1.0 / math.sqrt(float(pos.mean()))


def normalised(op, g):
    """``(s·H, s·g)`` with :math:`s` from :func:`unit_row_scale`."""
    from recon.operators import ScaledOperator

    s = unit_row_scale(op)
    return ScaledOperator(op, s), (g * np.float32(s)).astype(g.dtype, copy=False)


def solve_views(op, g, n_views: int, *, solver: str = DEFAULTS["solver"],
                iters: int = DEFAULTS["iters"], tau=None, x0=None, truth=None, wavelengths=None,
                progress: bool = False):
    """Reconstruct measurements ``g`` of ``n_views`` views through ``op`` the way every path of
    the pipeline does: operator and data brought to unit mean row norm (:func:`normalised`),
    the TV weight from :func:`tv_weight`, then :func:`recon.app.reconstruct`.  Adds ``seconds``."""
    from recon.app import reconstruct

    op, g = normalised(op, g)
    t0 = time.perf_counter()
    tau = tv_weight(solver, tau, n_views)
    cube, info = reconstruct(g, op, solver=solver, iters=iters, tau=tau, x0=x0, truth=truth,
                             wavelengths=wavelengths, progress=progress)
    info["seconds"] = time.perf_counter() - t0
    return cube, info


def calibrated_operator(cal, view_ids, model: str | None = None):
    """:func:`recon.calibration.operator_from_calibration` with the gains folded in: the
    operator maps a cube in radiance (cube) units to exposure-normalised DN.

    ``model`` is one of :data:`recon.calibration.operator.MODELS` or ``None``
    (:func:`model_of`).
    """
    from recon.calibration.operator import operator_from_calibration

    kind = model_of(cal, model)
    gains = model_gains(cal, kind)
    if not np.all(gains > 0):
        raise InputError("the calibration's radiometric gains must be positive")
    return operator_from_calibration(cal, view_ids, model=kind, band_scale=1.0 / gains)


def reconstruct_views(frame, metadata, cal, n_views, *, solver: str = DEFAULTS["solver"], iters: int = DEFAULTS["iters"],
                      tau=None, x0=None, truth=None, progress: bool = False, design=None,
                      model: str | None = None):
    """Reconstruct from the first ``n_views`` views of a raw frame with a calibration.

    Parameters
    ----------
    frame : (Hs, Ws) array
        Raw frame (DN).
    metadata : dict
        Its sidecar: ``design_hash`` must match the calibration's; ``radiance_scale`` (the
        exposure factor) is divided out.
    cal : recon.calibration.Calibration
    n_views : int
        1..9, views taken in the order centre, left, right, top, bottom, corners; all must be
        in the calibration.
    solver, iters, tau, x0, progress
        As for :func:`recon.app.reconstruct`.
    truth : (v, v, L) or (H, W, L) array, optional
        Ground truth on the design's grid (moved onto the model's grid :func:`cube_grid` with
        :func:`truth_on_grid`, using the design in the sidecar) or already on it.
    model : str, optional
        The calibrated forward model (:func:`calibrated_operator`).

    Returns
    -------
    cube : (H, W, L) float32, on :func:`cube_grid`, cube units
    info : dict
        :func:`recon.app.reconstruct`'s, plus ``view_ids``, ``seconds`` and, with a truth,
        ``metrics`` and ``truth_grid`` (the truth on the reconstruction grid).
    """
    from recon.calibration import check_design, measurements

    ids = _check_views(n_views)
    check_design(cal, metadata)
    missing = [v for v in ids if v not in cal.view_ids]
    if missing:
        raise InputError(f"view(s) {missing} missing: the calibration has views "
                         f"{list(cal.view_ids)} (recalibrate with the views the run needs)")
    s = float((metadata or {}).get("radiance_scale") or 1.0)
    if not (math.isfinite(s) and s > 0):
        raise InputError(f"the frame's radiance_scale must be positive, got {s}")
    g = measurements(frame, cal, ids, metadata=metadata) / np.float32(s)
    tg = None
    if truth is not None:
        t = np.asarray(truth, dtype=np.float32)
        tg = t if t.shape == cube_grid(cal, model) + (cal.n_bands,) else \
            truth_on_grid(t, _design_of(metadata, design), cal, model)
    cube, info = solve_views(calibrated_operator(cal, ids, model), g, len(ids), solver=solver,
                             iters=iters, tau=tau, x0=x0, truth=tg, wavelengths=cal.wavelengths,
                             progress=progress)
    info["view_ids"] = list(ids)
    if tg is not None:
        info["truth_grid"] = tg
    return cube, info


def oracle_operator(design, n_views: int, *, inversion: bool = True, seed: int | None = None):
    """The converged exact operator of ``design`` on the ground-truth grid (:mod:`sim.oracle`),
    traced with its own seed (another ``seed`` traces another realisation of the optics)."""
    from sim.oracle import oracle_operator as _op

    return _op(design, n_views, inversion=inversion, seed=seed)


def reconstruct_oracle(frame, metadata, design, n_views, *, solver: str = DEFAULTS["solver"],
                       iters: int = DEFAULTS["iters"], tau=None, truth=None, progress: bool = False,
                       inversion: bool = True, op=None):
    """Reconstruct a frame with the exact operator (:func:`oracle_operator`), on the
    ground-truth grid.  Returns ``(cube (v, v, L), info)``."""
    from sim.oracle import oracle_measurements

    _check_views(n_views)
    g = oracle_measurements(frame, metadata, design, n_views)
    if op is None:
        op = oracle_operator(design, n_views, inversion=inversion)
    return solve_views(op, g, n_views, solver=solver, iters=iters, tau=tau, truth=truth,
                       wavelengths=design.wavelengths, progress=progress)


# ------------------------------------------------------------------------------- run
def parse_views(spec) -> tuple[int, ...]:
    """``"1,2,3,5,9"`` or a sequence → sorted distinct view counts in 1..9."""
    if isinstance(spec, str):
        parts = [p for p in spec.replace(" ", "").split(",") if p]
        try:
            counts = [int(p) for p in parts]
        except ValueError:
            raise InputError(f"--views must be a comma-separated list of counts 1..9, got "
                             f"{spec!r}") from None
    else:
        counts = [int(c) for c in spec]
    if not counts or any(not 1 <= c <= 9 for c in counts):
        raise InputError(f"view counts must be in 1..9, got {spec!r}")
    return tuple(sorted(set(counts)))


def _finite(obj):
    if isinstance(obj, dict):
        return {str(k): _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def run(scene, design, out_dir, *, views=(1, 2, 3, 5, 9), solver: str = DEFAULTS["solver"],
        iters: int = DEFAULTS["iters"], tau=None, seed: int = 0, progress: bool = True, cache_dir=None,
        oracle: bool = True, figures: bool = True, raw=None, widen: bool = True,
        log=None, model: str | None = None) -> dict:
    """Render ``scene``, calibrate (cached), reconstruct for every view count, write a report.

    Everything is written into a fresh temporary folder beside ``out_dir`` that replaces
    ``out_dir`` only at the end, so a failure leaves ``out_dir`` as it was; missing folders
    above it are created (:func:`recon.io.atomic.output_parents`).

    Parameters
    ----------
    scene : str or path
        Built-in scene name or cube file.
    design : sim.design.Design
        Widened to the views the largest count needs (:func:`design_for_views`).
    out_dir : path
    views : sequence of int
        View counts (1..9).
    solver, iters, tau, seed
        Reconstruction settings and the sensor-noise seed.
    oracle : bool
        Also reconstruct with the exact operator (for the "within 1 dB" comparison).
    figures : bool
        Band montage and spectral plots (matplotlib).
    raw : (frame, metadata), optional
        Reconstruct this raw frame instead of rendering (the scene then only gives the truth);
        its ``design_hash`` must match ``design``'s calibration.
    widen : bool
        Widen the design to the views the largest count needs (:func:`design_for_views`);
        ``False`` keeps it, and a count needing views it lacks is an error.
    log : callable, optional
        Called with each summary line (default: nothing).
    model : {"shifted", "footprint"}, optional
        The calibrated forward model (default :data:`CALIBRATED_MODEL`); ``"footprint"``
        calibrates with the comb captures too.

    Returns
    -------
    dict
        The content of ``metrics.json``.
    """
    from recon.io.atomic import atomic_dir, check_output, output_parents, write_text
    from recon.io.cubes import write_cube
    from recon.io.raw import write_raw

    counts = parse_views(views)
    if widen:
        design = design_for_views(design, max(counts))
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"{out_dir}: exists and is not a folder")
    scene_path = Path(str(scene))
    if scene_path.exists() and out_dir.resolve() in (scene_path.resolve(),
                                                     *scene_path.resolve().parents):
        raise InputError(f"{out_dir}: would overwrite the input {scene}")
    check_output(out_dir, folder=True, parents=True)
    say = log or (lambda line: None)

    # --- inputs first: the scene (a bad cube fails before any long step) ----------------------
    t_start = time.perf_counter()
    frame, meta, truth, wl = render_scene(scene, design, seed=seed)
    if raw is not None:
        frame, meta = raw
        if meta.get("design_hash") not in (None, design.hash):
            raise InputError(f"raw frame was taken with design {meta.get('design_hash')}, but "
                             f"the calibration is for design {design.hash}")
        if np.shape(frame) != (design.sensor_height_px, design.sensor_width_px):
            raise InputError(f"raw frame shape {np.shape(frame)} is not the design's sensor")
    missing = [v for v in VIEW_ORDER[:max(counts)] if v not in design.views]
    if missing:
        raise InputError(f"view(s) {missing} missing: the design traces views "
                         f"{list(design.views)}, {max(counts)} views need {list(VIEW_ORDER[:max(counts)])}")
    cal_t0 = time.perf_counter()
    cached = _is_cached(design, cache_dir)
    cal = calibrate(design, cache_dir=cache_dir, progress=progress,
                    footprint=model == "footprint")
    cal_seconds = time.perf_counter() - cal_t0
    from recon.calibration import check_design

    check_design(cal, meta)
    model = model_of(cal, model)
    missing = [v for v in VIEW_ORDER[:max(counts)] if v not in cal.view_ids]
    if missing:
        raise InputError(f"view(s) {missing} missing from the calibration {list(cal.view_ids)}")

    with output_parents(out_dir), atomic_dir(out_dir) as tmp:
        write_raw(tmp / "raw.exr", frame, meta)
        tg = truth_on_grid(truth, design, cal, model)
        write_cube(tmp / "truth.exr", tg, wl)
        rgb_truth, peak = _srgb(tg, wl)
        _write_png(tmp / "srgb_truth.png", rgb_truth)
        result = {
            "scene": str(scene), "design": design.to_dict(), "design_hash": design.hash,
            "wavelengths_nm": [float(x) for x in wl], "solver": solver, "iters": int(iters),
            "tau": tau, "seed": int(seed), "model": model,
            "cube_shape": list(cube_grid(cal, model)) + [cal.n_bands],
            "calibration": {"cached": cached, "seconds": cal_seconds,
                            "view_ids": list(cal.view_ids),
                            "gains": model_gains(cal, model).tolist()},
            "views": {}, "oracle": {},
        }
        cubes = {}
        patches = colorchecker_patches(design, cal, model) if str(scene) == "colorchecker" \
            else {}
        bar = _bar(len(counts) * (2 if oracle else 1), "reconstruct", progress)
        try:
            for n in counts:
                cube, info = reconstruct_views(frame, meta, cal, n, solver=solver, iters=iters,
                                               tau=tau, truth=tg, design=design, model=model)
                _tick(bar)
                cubes[n] = cube
                write_cube(tmp / f"cube_{n}views.exr", cube, wl)
                _write_png(tmp / f"srgb_{n}views.png", _srgb(cube, wl, peak)[0])
                result["views"][str(n)] = _entry(info, n)
                if patches:
                    result["views"][str(n)]["delta_e2000_patches"] = patch_delta_e2000(
                        cube, info["truth_grid"], list(patches.values()), wl)
                if oracle:
                    ocube, oinfo = reconstruct_oracle(frame, meta, design, n, solver=solver,
                                                      iters=iters, tau=tau, truth=truth)
                    _tick(bar)
                    result["oracle"][str(n)] = _entry(oinfo, n)
        finally:
            if bar is not None:
                bar.close()
        if figures:
            from recon.report import band_montage, spectra_plot

            band_montage(tmp / "bands.png", tg, cubes, wl)
            spectra_plot(tmp / "spectra.png", tg, cubes, wl,
                         _probe_boxes(scene, design, cal, model))
        result["targets"] = targets(result)
        result["total_seconds"] = time.perf_counter() - t_start
        write_text(tmp / "metrics.json",
                   json.dumps(_finite(result), indent=2, allow_nan=False) + "\n")
    for line in summary_lines(result):
        say(line)
    return result


def _is_cached(design, cache_dir) -> bool:
    from recon.calibration import calibration_path

    return calibration_path(_cache_dir(cache_dir), design.hash).is_file()


def _entry(info, n) -> dict:
    m = dict(info.get("metrics", {}))
    return {"n_views": n, "view_ids": info.get("view_ids", list(VIEW_ORDER[:n])),
            "psnr": m.get("psnr"), "psnr_bandwise": m.get("psnr_bandwise"),
            "ssim": m.get("ssim"), "sam_deg": m.get("sam_deg"),
            "delta_e2000": m.get("delta_e2000"), "seconds": info.get("seconds"),
            "iters": info.get("iters"), "tau": info.get("tau")}


def targets(result) -> dict:
    """The issue's targets checked on a result (``None`` where the run lacks the data)."""
    v = result["views"]
    ps = [(int(n), e["psnr"]) for n, e in v.items() if e["psnr"] is not None]
    ps.sort()
    out = {"psnr_rises_with_views": (all(b[1] > a[1] for a, b in zip(ps, ps[1:]))
                                     if len(ps) > 1 else None)}
    if "1" in v and "5" in v:
        out["gain_5_vs_1_db"] = v["5"]["psnr"] - v["1"]["psnr"]
        out["gain_5_vs_1_ge_3db"] = out["gain_5_vs_1_db"] >= 3.0
    gaps = {n: result["oracle"][n]["psnr"] - v[n]["psnr"] for n in v
            if n in result.get("oracle", {})}
    if gaps:
        out["oracle_minus_calibrated_db"] = gaps
        out["within_1db_of_oracle"] = all(g <= 1.0 for g in gaps.values())
    if "5" in v and v["5"].get("delta_e2000") is not None:
        out["delta_e2000_5views"] = v["5"]["delta_e2000"]
        if str(result["scene"]) == "colorchecker":
            out["delta_e2000_5views_le_3"] = v["5"]["delta_e2000"] <= 3.0
    if "5" in v and v["5"].get("delta_e2000_patches") is not None:
        out["delta_e2000_patches_5views"] = v["5"]["delta_e2000_patches"]
        out["delta_e2000_patches_5views_le_3"] = v["5"]["delta_e2000_patches"] <= 3.0
    return out


def summary_lines(result) -> list[str]:
    """The human summary ``kaleidospec run`` prints."""
    lines = [f"scene {result['scene']}, design {result['design_hash']}, cube "
             f"{'x'.join(str(x) for x in result['cube_shape'])}, {result.get('model', 'shifted')}"
             f" model, {result['solver']} x"
             f"{result['iters']}, tau " + " / ".join(
                 f"{e['tau']:g}" for e in result["views"].values() if e.get("tau") is not None),
             f"calibration: {'cached' if result['calibration']['cached'] else 'rendered'} "
             f"({result['calibration']['seconds']:.1f} s)"]
    # dE00: per pixel of the sRGB rendering; dE00p: per ColorChecker patch (mean spectra).
    head = (f"{'views':>5} {'PSNR':>7} {'PSNRb':>7} {'SSIM':>6} {'SAM':>6} {'dE00':>6} "
            f"{'dE00p':>6} {'s':>6} {'oracle':>7}")
    lines += [head, "-" * len(head)]
    for n, e in result["views"].items():
        o = result["oracle"].get(n, {}).get("psnr")

        def f(x, fmt):
            return format(x, fmt) if x is not None else "n/a".rjust(len(format(0.0, fmt)))
        lines.append(f"{n:>5} {f(e['psnr'], '7.2f')} {f(e['psnr_bandwise'], '7.2f')} "
                     f"{f(e['ssim'], '6.3f')} {f(e['sam_deg'], '6.2f')} "
                     f"{f(e['delta_e2000'], '6.2f')} {f(e.get('delta_e2000_patches'), '6.2f')} "
                     f"{f(e['seconds'], '6.1f')} {f(o, '7.2f')}")
    t = result.get("targets", {})
    bits = []
    if t.get("psnr_rises_with_views") is not None:
        bits.append(f"PSNR rises with views: {'yes' if t['psnr_rises_with_views'] else 'NO'}")
    if "gain_5_vs_1_db" in t:
        bits.append(f"5 vs 1 view: {t['gain_5_vs_1_db']:+.2f} dB "
                    f"({'>=' if t['gain_5_vs_1_ge_3db'] else 'NOT >='} 3)")
    if "oracle_minus_calibrated_db" in t:
        worst = max(t["oracle_minus_calibrated_db"].values())
        bits.append(f"oracle - calibrated: at most {worst:+.2f} dB "
                    f"({'within' if t['within_1db_of_oracle'] else 'NOT within'} 1 dB)")
    if "delta_e2000_5views" in t:
        bits.append(f"CIEDE2000 (5 views): {t['delta_e2000_5views']:.2f} per pixel")
    if "delta_e2000_patches_5views" in t:
        bits.append(f"{t['delta_e2000_patches_5views']:.2f} per patch")
    if bits:
        lines.append("targets: " + "; ".join(bits))
    return lines


def colorchecker_patches(design, cal, model: str | None = None) -> dict:
    """The ColorChecker patches that lie wholly on the ``model``'s reconstruction grid, their
    middle half (edges mix neighbouring patches): ``{patch index: (y0, x0, h, w)}``."""
    from scenes.colorchecker import patch_boxes

    h, w = cube_grid(cal, model)
    oy, ox = grid_offset(design, cal, model)
    out = {}
    for k, (r0, c0, r1, c1) in enumerate(patch_boxes((design.view_size_px,) * 2)):
        y0, x0 = int(round(r0 - oy)), int(round(c0 - ox))
        hh, ww = r1 - r0, c1 - c0
        dy, dx = hh // 4, ww // 4
        if y0 + dy >= 0 and x0 + dx >= 0 and y0 + hh - dy <= h and x0 + ww - dx <= w:
            out[k] = (y0 + dy, x0 + dx, hh - 2 * dy, ww - 2 * dx)
    return out


def patch_delta_e2000(cube, truth, boxes, wavelengths) -> float:
    """Mean CIEDE2000 between the mean spectra of patches ``boxes`` (y0, x0, h, w) in ``cube``
    and in ``truth``: spectral accuracy as a spectroradiometer would judge it (paper Fig. 9),
    free of the edge errors that dominate the per-pixel figure."""
    from recon.metrics import delta_e2000

    def spectra(c):
        return np.stack([c[y:y + h, x:x + w].reshape(-1, c.shape[2]).mean(axis=0)
                         for y, x, h, w in boxes])[:, None, :]

    return delta_e2000(spectra(cube), spectra(truth), wavelengths)[0]


def _probe_boxes(scene, design, cal, model=None):
    """A few regions (y0, x0, h, w) on the reconstruction grid for the spectral plots: six
    ColorChecker patches, or four small squares elsewhere."""
    h, w = cube_grid(cal, model)
    if str(scene) == "colorchecker":
        patches = colorchecker_patches(design, cal, model)
        # light skin, blue sky, bluish green, red, green, blue
        out = [(f"patch {k + 1}", patches[k]) for k in (1, 2, 5, 13, 14, 15) if k in patches]
        if out:
            return out
    return grid_regions((h, w))
