r"""Cubes and their truth → scores, and the project's targets checked on them.

The metrics themselves are :mod:`recon.metrics`' (PSNR with peak 1 on the cube scaled to
[0, 1] and per band min–max normalised, SSIM, the spectral angle SAM, CIEDE2000 of the sRGB
rendering).  This stage adds what needs the scene: where a target's parts lie on a model's
reconstruction grid, and the colour error a spectroradiometer aimed at one would measure.

- Stills: :func:`scores` (one view count's entry of ``metrics.json``),
  :func:`colorchecker_patches` and :func:`patch_delta_e2000` (CIEDE2000 of the patches' mean
  spectra, paper Fig. 9), :func:`targets` (PSNR rises with views, five views beat one by
  ≥ 3 dB, within 1 dB of the exact operator, CIEDE2000 ≤ 3 on the chart).
- Videos: :func:`frame_metrics` with the colour wheel's :func:`sector_colour_errors`
  (:func:`sector_masker`), and :func:`frame_means` over a sequence.
- Design sweeps: :func:`smallest_reaching` and :func:`apex_reaching` — at which prism apex the
  dispersion span over the pass band reaches :data:`TARGET_SPAN_PX`, as predicted and as
  measured.
"""

from __future__ import annotations

import math

import numpy as np

from recon.errors import InputError

__all__ = ["scores", "targets", "colorchecker_patches", "patches_on_grid", "patch_delta_e2000",
           "sector_colour_errors", "sector_masker", "frame_metrics", "frame_means",
           "TARGET_SPAN_PX", "smallest_reaching", "apex_reaching"]

#: The dispersion span the paper asks for over the pass band (px).
TARGET_SPAN_PX = 60.0


# ------------------------------------------------------------------------------- stills
def scores(info, n_views: int) -> dict:
    """The entry of one view count in ``metrics.json`` from a reconstruction's ``info``
    (:func:`kaleidospec.reconstruct.reconstruct_views`): the metrics, the views, the time."""
    from recon.view_ids import VIEW_ORDER

    m = dict(info.get("metrics", {}))
    return {"n_views": n_views, "view_ids": info.get("view_ids", list(VIEW_ORDER[:n_views])),
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


def colorchecker_patches(design, cal, model: str | None = None) -> dict:
    """The ColorChecker patches that lie wholly on the ``model``'s reconstruction grid, their
    middle half (edges mix neighbouring patches): ``{patch index: (y0, x0, h, w)}``."""
    from kaleidospec.models import cube_grid, grid_offset

    return patches_on_grid(design, cube_grid(cal, model), grid_offset(design, cal, model))


def patches_on_grid(design, shape, offset=(0.0, 0.0)) -> dict:
    """The ColorChecker patches' middle halves on a grid of ``shape`` (H, W) whose pixel
    :math:`(y, x)` is ground-truth pixel :math:`(y + o_y, x + o_x)`: those that lie wholly on
    it, ``{patch index: (y0, x0, h, w)}`` (the exact operator's grid is the truth's: offset 0)."""
    from scenes.colorchecker import patch_boxes

    h, w = (int(v) for v in shape)
    oy, ox = offset
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


# ------------------------------------------------------------------------------- videos
def sector_colour_errors(est, truth, wavelengths, masks) -> list:
    r"""CIEDE2000 of each colour-wheel sector: the sector's mean spectrum against the truth's.

    As a spectroradiometer aimed at a sector would (the paper's check), the spectra are
    averaged over the sector's interior pixels (``masks`` (N, H, W), bool) first; both means
    are rendered with the exposure of the whole true frame (the 99th percentile of its
    luminance) and compared with :func:`recon.metrics.delta_e2000`.  Empty sectors give None.
    """
    from recon.metrics import cube_to_xyz, delta_e2000

    est = np.asarray(est, np.float64)
    truth = np.asarray(truth, np.float64)
    peak = float(np.percentile(cube_to_xyz(truth, wavelengths)[..., 1], 99.0))
    out = []
    for m in np.asarray(masks, bool):
        if not m.any():
            out.append(None)
            continue
        a = est[m].mean(axis=0)[None, None, :]
        b = truth[m].mean(axis=0)[None, None, :]
        out.append(float(delta_e2000(a, b, wavelengths, peak=peak)[0]))
    return out


def sector_masker(desc: dict | None):
    """The colour wheel that ``desc`` (an animation's ``describe()``) describes, whose
    ``sector_masks`` give each frame's sectors; None for any other scene."""
    if not desc or desc.get("kind") != "colorwheel":
        return None
    from scenes.animated import RotatingColorwheel

    return RotatingColorwheel(tuple(desc["shape"]), None, n_frames=desc["frames"],
                              fps=desc["fps"], exposure_ms=desc["exposure_ms"],
                              subframes=desc["subframes"], speed_deg_s=desc["speed_deg_s"],
                              angle0_deg=desc["angle0_deg"], **desc["wheel"])


def frame_metrics(cube, truth, wavelengths, sector_masks=None) -> dict:
    """:func:`recon.metrics.all_metrics` plus the per-sector CIEDE2000 when masks are given."""
    from recon.metrics import all_metrics

    m = all_metrics(cube, truth, wavelengths)
    if sector_masks is not None:
        de = sector_colour_errors(cube, truth, wavelengths, sector_masks)
        m["sector_delta_e2000"] = de
        vals = [v for v in de if v is not None]
        m["sector_delta_e2000_mean"] = float(np.mean(vals)) if vals else None
    return m


def frame_means(frames: list[dict]) -> dict:
    """The means of the frames' metrics (each frame's :func:`frame_metrics` and solve
    figures): ``frames`` and ``mean_<metric>``, and the mean CIEDE2000 of every sector."""
    summary: dict = {"frames": len(frames)}
    for k in ("psnr", "psnr_bandwise", "ssim", "sam_deg", "delta_e2000",
              "sector_delta_e2000_mean", "solve_seconds", "iters"):
        vals = [f[k] for f in frames if f.get(k) is not None]
        if vals:
            summary[f"mean_{k}"] = float(np.mean(vals))
    sectors = [f["sector_delta_e2000"] for f in frames if f.get("sector_delta_e2000")]
    if sectors:
        arr = np.array([[np.nan if v is None else v for v in s] for s in sectors], np.float64)
        summary["mean_sector_delta_e2000"] = [None if np.all(np.isnan(c)) else float(np.nanmean(c))
                                              for c in arr.T]
    return summary


# ------------------------------------------------------------------------------- design sweeps
def smallest_reaching(values, spans, target: float = TARGET_SPAN_PX) -> float | None:
    """The smallest swept value at which ``spans`` reaches ``target``, interpolated linearly
    between the last point below and the first at or above; None if never reached (NaN spans
    are skipped). The first point already reaching it gives its own value."""
    pts = [(float(v), float(s)) for v, s in zip(values, spans) if s is not None and math.isfinite(s)]
    pts.sort()
    for i, (v, s) in enumerate(pts):
        if s >= target:
            if i == 0:
                return v
            v0, s0 = pts[i - 1]
            return v0 + (target - s0) * (v - v0) / (s - s0)
    return None


def apex_reaching(design, apexes, spans, target: float = TARGET_SPAN_PX
                  ) -> tuple[float | None, float | None]:
    """The smallest prism apex (degrees) whose dispersion span over the design's pass band
    reaches ``target`` px: predicted (Sellmeier, bisection; None when total internal reflection
    comes first) and measured (:func:`smallest_reaching` over the sweep's ``apexes`` and
    measured ``spans``)."""
    from kaleidospec.instrument import apex_for_span

    try:
        pred = apex_for_span(design.prism_glass, target, design.filter_min_nm,
                             design.filter_max_nm, design.prism_center_nm,
                             design.imaging_focal_mm, design.sensor_pixel_um)
    except InputError:
        pred = None
    return pred, smallest_reaching(apexes, spans, target)
