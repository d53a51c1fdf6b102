#!/usr/bin/env python3
"""Which part of the shifted model misses the optics, and by how much: model errors, no solves.

For one design (``paper`` by default) and one scene, the noise-free frame of the scene at its
native resolution (:func:`kaleidospec.instrument.scene_cube`, finer than any reconstruction
grid) through the scene frames' own trace, with the lens's diffraction, is compared with what
each model predicts from the scene's exact area means on the model's grid:

.. math:: \\epsilon = \\min_{a} \\Big\\| g - \\sum_l a_l\\, P_l * H_l f_l \\Big\\| \\big/ \\|g\\|,

:math:`H_l` band :math:`l`'s part of the shifted model (its mask images, offsets and warps),
:math:`P_l` the point-spread function it is blurred with and :math:`a_l` per-band
least-squares gains, so that neither the radiometry nor the exposure counts.  Rows:

- the exact operator (the simulator's pixel integrals on the design's grid, the frame's own
  trace): what the scene's detail finer than the grid costs any grid model;
- the calibrated shifted model with one PSF at the bands' mean Airy radius (the calibration's),
  and with each band's own Airy PSF cut at three radii as the simulator's and the
  deconvolution's;
- the same two with the simulator's own mask images (noise-free and unblurred, the captures'
  trace: what a perfect mask calibration would give; ``tools/exp_views.py --exact-masks``).

The rows are where the model error lies, not what a reconstruction gains: on ``paper`` lower
model errors of the calibrated masks did not reconstruct better (``docs/calibration.md``,
"What is left of the paper gap").  The fitted gains also hide any error of the calibration's
own gains.  Uses the design's cached calibration (made if missing).

Usage::

    python3 tools/exp_model_error.py                       # paper, natural, 5 views
    python3 tools/exp_model_error.py --design small --views 1,5
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def band_columns(cal, ids, x, kernels):
    """Per PSF set, the (L, n) float32 blurred band images of the shifted model on the views'
    pixels that any mask image opens; ``kernels``: name -> a function of the band giving its
    PSF (None: no blur)."""
    from recon.calibration.operator import _unblurred
    from recon.operators.blur import convolve_views

    op = _unblurred(cal, ids, "shifted", None)
    idx = cal.view_indices(ids)
    open_ = cal.mask_images[idx].max(axis=1) > 0
    cols = {name: [] for name in kernels}
    xb = np.zeros_like(x)
    for l in range(x.shape[0]):
        xb[l] = x[l]
        y = op.forward(xb)
        xb[l] = 0.0
        for name, psf in kernels.items():
            k = psf(l)
            cols[name].append((y if k is None else convolve_views(y, k))[open_])
    return {name: np.stack(c) for name, c in cols.items()}, open_


def fitted_error(cols: np.ndarray, g: np.ndarray) -> float:
    """min_a ‖g − Σ a_l cols_l‖/‖g‖: per-band least-squares gains, float64 normal
    equations."""
    n = cols.shape[0]
    gram = np.empty((n, n))
    rhs = np.empty(n)
    for i in range(n):
        ci = cols[i].astype(np.float64)
        rhs[i] = ci @ g
        for j in range(i, n):
            gram[i, j] = gram[j, i] = ci @ cols[j]
    a = np.linalg.solve(gram, rhs)
    r = g.copy()
    for i in range(n):
        r -= a[i] * cols[i]
    return float(np.linalg.norm(r) / np.linalg.norm(g))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--design", default="paper")
    ap.add_argument("--scene", default="natural")
    ap.add_argument("--views", default="5", help="view counts, comma-separated")
    a = ap.parse_args(argv)

    from exp_views import exact_mask_images
    from kaleidospec.calibrate import calibrate, deconvolution_radii
    from kaleidospec.instrument import design_for_views, get_design, scene_cube
    from kaleidospec.models import truth_on_grid
    from kaleidospec.reconstruct import first_views
    from recon.calibration.mask import airy_kernel, view_stack
    from sim.frame import FrameModel, ground_truth
    from sim.transport import SEEDS

    counts = sorted({int(v) for v in a.views.split(",")})
    design = design_for_views(get_design(a.design), max(counts))
    t0 = time.perf_counter()
    cal = calibrate(design, progress=False)
    cube, wl = scene_cube(a.scene, design)
    frames = FrameModel(design, wl, trace_seed=SEEDS["scene"])
    g_all = view_stack(frames.electrons(cube)[None], cal.view_boxes)[:, 0]
    g_grid = view_stack(frames.electrons(ground_truth(design, cube))[None], cal.view_boxes)[:, 0]
    radii = deconvolution_radii(design, wl)
    if radii is None:
        kernels = {"no PSF": lambda l: None}
    else:
        # The calibration's one PSF (the bands' mean radius) and each band's own, cut at
        # three radii as the simulator's and the deconvolution's.
        per_band = [airy_kernel(float(r), support=3.0).astype(np.float32) for r in radii]
        kernels = {"one PSF": lambda l: cal.psf, "PSF per band": lambda l: per_band[l]}
    sim_masks = dataclasses.replace(cal, mask_images=exact_mask_images(design, cal))
    print(f"design {a.design} ({design.hash}), scene {a.scene} at {cube.shape[0]}x{cube.shape[1]}"
          f" texels; frames and simulator masks in {time.perf_counter() - t0:.0f} s", flush=True)
    names = list(kernels)
    head = f"{'views':>5}  {'exact operator':>15}" + "".join(
        f"{'calibrated, ' + n:>26}" for n in names) + "".join(
        f"{'simulator masks, ' + n:>30}" for n in names)
    print(head)
    print("-" * len(head))
    for n in counts:
        ids = first_views(n)
        idx = cal.view_indices(ids)
        x = np.ascontiguousarray(np.moveaxis(truth_on_grid(cube, design, cal, "shifted", ids),
                                             2, 0))
        row = f"{n:>5}"
        errs = {}
        for label, c in (("calibrated", cal), ("simulator", sim_masks)):
            cols, open_ = band_columns(c, ids, x, kernels)
            g = g_all[idx][open_].astype(np.float64)
            for name in names:
                errs[label, name] = fitted_error(cols[name], g)
            if label == "calibrated":
                exact = g_grid[idx][open_].astype(np.float64)
                row += f"{100 * np.linalg.norm(g - exact) / np.linalg.norm(g):>14.2f}%"
        row += "".join(f"{100 * errs['calibrated', nm]:>25.2f}%" for nm in names)
        row += "".join(f"{100 * errs['simulator', nm]:>29.2f}%" for nm in names)
        print(row, flush=True)
    print("model error ‖g − Σ a_l P_l H_l f_l‖/‖g‖ of one noise-free frame, per-band "
          "least-squares gains (module notes)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
