#!/usr/bin/env python3
"""What limits reconstruction from calibration? Calibrated vs exact operator under what-if
instruments.

The default calibrated model (per-band mask images and one shift per band) trails the
simulator's exact operator; the footprint model (every pixel's weights measured with comb
targets) does not.  This experiment re-renders the `small` design, its calibration captures
and its exact operator with the transport sampled differently, and prints, for the natural
scene and the ColorChecker, the PSNR reached with

- ``calibrated``: the product's default (shifted) operator, from the calibration captures only;
- ``footprint``: the footprint model (``kaleidospec run --model footprint``), from the same
  captures plus the comb captures, on the scenes' own grid;
- ``exact``: the transport the frame was rendered with (:mod:`sim.oracle`).  With ``spp`` rays
  per pixel and band it holds *which* texel and wavelength each of those rays met: the
  simulator's Monte Carlo draw, fixed per pixel.  Captures rendered through the same transport
  see that draw as part of the instrument, as a lab's captures see a real pixel's response:
  the comb captures measure it, the white captures only its sum over a footprint;
- ``exact*``: the same optics traced again with another random seed (same ``spp``, same
  sampling): the instrument's physics without this frame's draw.  How far ``exact`` is above
  ``exact*`` is what knowing the draw is worth;
- ``cal+geom``: the calibrated mask images with the *simulator's* geometry, a per-band affine
  map from the ground-truth grid into every view's box fitted to the transport
  (:class:`recon.operators.BandWarpCassi`): what perfect geometric calibration would reach
  with the shifted-mask model;
- ``model err``: how far the calibrated operator misses a noise-free frame of the truth,
  ``||g - H f|| / ||g||``.

Knobs, applied to every transport the run builds (the scene frame, the captures, the exact
operators) by wrapping :func:`sim.transport.load_or_build` and the band intervals a lab reads
from its filters' datasheet (:func:`sim.transport.band_intervals`): a what-if, not a setting
of the product.  A temporary cache folder keeps the product's caches clean.

- ``--sampling box`` (the instrument: wavelengths spread over each band's width) or ``centre``
  (a what-if instrument seeing each band at one wavelength: no smear within a band);
- ``--spp N``: rays per pixel and band (4 in the product);
- ``--sampler independent|sobol``: how a pixel's rays are drawn (i.i.d. in the product;
  ``sobol`` stratifies them, :func:`sim.transport.pixel_samples`);
- ``--repeats N``: noisy frames averaged per calibration capture (0: noise-free captures);
- ``--soften SIGMA``: also reconstruct both scenes blurred by a Gaussian of SIGMA texels
  (rows ``natural~``, ``colorchecker~``): the same content without the sharp edges;
- ``--period PY,PX`` and ``--floor F``: the footprint model's comb period (instead of
  :func:`recon.calibration.footprint.comb_period`'s) and weight floor (instead of
  :data:`~recon.calibration.footprint.FOOTPRINT_FLOOR`), with the number of weights kept;
- ``--set FIELD=VALUE``: another design than `small`'s defaults (e.g. ``band_step_nm=50``).

Usage: python3 tools/exp_calibration_gap.py [--sampling box|centre] [--spp 4]
       [--sampler independent|sobol] [--views 1,3,5] [--soften SIGMA] [--period PY,PX]
       [--floor F] [--set FIELD=VALUE ...]
"""

from __future__ import annotations

import argparse
import os
import tempfile


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sampling", choices=("box", "centre"), default="box")
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--sampler", choices=("independent", "sobol"), default="independent")
    ap.add_argument("--views", default="1,3,5")
    ap.add_argument("--repeats", type=int, default=4,
                    help="noisy frames averaged per calibration capture (0: noise-free)")
    ap.add_argument("--soften", type=float, default=0.0,
                    help="also reconstruct the scenes blurred by a Gaussian of this many texels")
    ap.add_argument("--trace-seed", type=int, default=1,
                    help="random seed of the second exact operator's trace (the frame's is 0)")
    ap.add_argument("--period", default=None, help="comb period PY,PX of the footprint model")
    ap.add_argument("--floor", type=float, default=None, help="footprint weight floor")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    metavar="FIELD=VALUE", help="design override (repeatable)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="kaleidospec-gap-") as cache:
        os.environ["KALEIDOSPEC_CACHE"] = cache
        run(a, cache)


def run(a, scratch) -> None:
    import sim.transport as transport

    build, intervals = transport.load_or_build, transport.band_intervals

    def what_if_intervals(design, wavelengths=None, sampling="box"):
        return intervals(design, wavelengths, a.sampling if sampling == "box" else sampling)

    def what_if(*args, **kw):
        # Band-wide transports take the what-if sampling; monochromatic ones (the line and
        # checkerboard captures, already at one wavelength) keep theirs.
        if kw.get("sampling", "box") == "box":
            kw["sampling"] = a.sampling
        kw["spp"] = a.spp
        kw["sampler"] = a.sampler
        return build(*args, **kw)

    transport.load_or_build = what_if
    transport.band_intervals = what_if_intervals
    what_if_footprints(a)

    from kaleidospec import pipeline
    from sim.design import get_design, parse_overrides

    d = pipeline.design_for_views(get_design("small", parse_overrides(a.overrides)), 5)
    cal = pipeline.calibrate(d, progress=False, repeats=a.repeats, footprint=True)
    counts = [int(v) for v in a.views.split(",")]
    exact = {n: pipeline.oracle_operator(d, n) for n in counts}
    retraced = {n: pipeline.oracle_operator(d, n, seed=a.trace_seed) for n in counts}
    geometry = transport_geometry(d, cal)
    print(f"sampling {a.sampling}, {a.spp} rays per pixel and band ({a.sampler}), {a.repeats} frames per "
          f"calibration capture; exact* traced with seed {a.trace_seed}; footprint model: "
          f"{cal.footprint_data.size / 1e6:.1f} M weights")
    print(f"{'scene':<13}{'views':>6}{'calibrated':>12}{'cal+geom':>10}{'footprint':>11}"
          f"{'exact':>8}{'exact*':>8}{'exact-cal':>11}{'exact*-cal':>12}{'exact-fp':>10}"
          f"{'model err':>11}{'fp err':>8}")
    scenes = [("natural", "natural"), ("colorchecker", "colorchecker")]
    if a.soften > 0:
        scenes += [(f"{name}~", softened(name, d, a.soften, scratch)) for name, _ in scenes[:2]]
    for scene, source in scenes:
        frame, meta, truth, _ = pipeline.render_scene(source, d, seed=0)
        clean = pipeline.render_scene(source, d, seed=0, noise=False)
        for n in counts:
            _, cal_info = pipeline.reconstruct_views(frame, meta, cal, n, truth=truth, design=d)
            _, fp_info = pipeline.reconstruct_views(frame, meta, cal, n, truth=truth, design=d,
                                                    model="footprint")
            _, geo = reconstruct_with_geometry(pipeline, frame, meta, cal, geometry, n, truth)
            _, ora = pipeline.reconstruct_oracle(frame, meta, d, n, truth=truth, op=exact[n])
            _, ret = pipeline.reconstruct_oracle(frame, meta, d, n, truth=truth, op=retraced[n])
            c, g = cal_info["metrics"]["psnr"], geo["metrics"]["psnr"]
            fp = fp_info["metrics"]["psnr"]
            o, r = ora["metrics"]["psnr"], ret["metrics"]["psnr"]
            err = model_error(pipeline, cal, d, clean, n)
            fp_err = model_error(pipeline, cal, d, clean, n, "footprint")
            print(f"{scene:<13}{n:>6}{c:>12.2f}{g:>10.2f}{fp:>11.2f}{o:>8.2f}{r:>8.2f}"
                  f"{o - c:>+11.2f}{r - c:>+12.2f}{o - fp:>+10.2f}{err:>10.1%}{fp_err:>8.1%}",
                  flush=True)


def what_if_footprints(a) -> None:
    """Apply ``--period`` and ``--floor`` to the footprint calibration the pipeline runs."""
    import recon.calibration.footprint as footprint

    if a.period is not None:
        period = tuple(int(v) for v in a.period.split(","))
        footprint.comb_period = lambda smear_px, airy_radius_px=0.0: period
    if a.floor is not None:
        decode = footprint.footprint_matrix
        footprint.footprint_matrix = lambda *args, **kw: decode(*args, **dict(kw, floor=a.floor))


def model_error(pipeline, cal, design, clean, n, model=None):
    """||g - H f|| / ||g||: how far the calibrated ``model``'s operator H of ``n`` views misses a
    noise-free frame g of the truth f (on that model's grid)."""
    import numpy as np
    from recon.calibration import measurements

    frame, meta, truth, _ = clean
    ids = pipeline.VIEW_ORDER[:n]
    g = measurements(frame, cal, ids, metadata=meta) / np.float32(meta["radiance_scale"])
    f = pipeline.truth_on_grid(truth, design, cal, model).transpose(2, 0, 1)
    m = pipeline.calibrated_operator(cal, ids, model).forward(np.ascontiguousarray(f))
    return float(np.linalg.norm(g - m) / np.linalg.norm(g))


def softened(name, design, sigma, folder):
    """A cube file of scene ``name`` blurred by a Gaussian of ``sigma`` texels, band by band."""
    import numpy as np
    from scipy.ndimage import gaussian_filter

    from scenes.registry import get_scene

    v = design.view_size_px
    cube, wl = get_scene(name, shape=(v, v), wavelengths=design.wavelengths)
    soft = gaussian_filter(cube, (sigma, sigma, 0), mode="nearest").astype(np.float32)
    path = os.path.join(folder, f"{name}-soft.npz")
    np.savez(path, cube=soft, wavelengths=wl)
    return path


def transport_geometry(design, cal):
    """(K, L, 3, 3): per view and band, the affine map from the ground-truth grid (x, y) to the
    view's box, least squares over every ray of the transport (texel -> sensor pixel, weighted
    by throughput; the mask's cut of a pixel averages out over the field)."""
    import numpy as np
    from sim.transport import load_or_build

    v = design.view_size_px
    tr = load_or_build(design, (v, v), design.wavelengths)
    ws = tr.sensor[1]
    out = np.empty((len(cal.view_ids), len(tr.pix), 3, 3))
    for l in range(len(tr.pix)):
        py, px = np.divmod(tr.pix[l].astype(np.int64), ws)
        ty, tx = np.divmod(tr.tex[l].astype(np.int64), v)
        for k, (y0, x0, h, w) in enumerate(cal.view_boxes):
            sel = (py >= y0) & (py < y0 + h) & (px >= x0) & (px < x0 + w) & (tr.w[l] > 0)
            a = np.stack([tx[sel], ty[sel], np.ones(int(sel.sum()))], axis=1).astype(np.float64)
            b = np.stack([px[sel] - x0, py[sel] - y0], axis=1).astype(np.float64)
            sw = np.sqrt(tr.w[l][sel].astype(np.float64))[:, None]
            sol = np.linalg.lstsq(a * sw, b * sw, rcond=None)[0]        # (3, 2)
            out[k, l] = np.vstack([sol.T, [0.0, 0.0, 1.0]])
    return out


def reconstruct_with_geometry(pipeline, frame, meta, cal, geometry, n, truth):
    """The calibrated mask images and gains with ``geometry`` (:func:`transport_geometry`), on
    the ground-truth grid."""
    import numpy as np
    from recon.calibration import measurements
    from recon.operators import BandWarpCassi, HomographyWarp

    ids = pipeline.VIEW_ORDER[:n]
    idx = [cal.view_ids.index(i) for i in ids]
    hv, wm = cal.mask_images.shape[2:]
    grid = truth.shape[:2]
    masks = cal.mask_images[idx] / cal.gains.astype(np.float32)[None, :, None, None]
    warps = [[HomographyWarp(m, grid, (hv, wm)) for m in geometry[i]] for i in idx]
    g = measurements(frame, cal, ids, metadata=meta) / np.float32(meta["radiance_scale"])
    return pipeline.solve_views(BandWarpCassi(masks, warps), g, n, truth=truth,
                                wavelengths=cal.wavelengths)


if __name__ == "__main__":
    main()
