#!/usr/bin/env python3
"""What separates reconstruction from calibration and reconstruction with the exact operator?

For one design (``small`` by default, widened to the views asked) and each scene, one noisy
frame from the scene frames' own trace (the scene at ``--oversample`` × the reconstruction
grid) is reconstructed with every calibrated model the calibration holds and with the
converged exact operator (its own trace), for each view count; and one noise-free frame of the
same scene measures each model's *model error*, how far the model applied to the truth on its
own grid misses the frame:

.. math:: \\epsilon = \\|g - s H f\\| / \\|g\\|,

with :math:`s` the least-squares scale (so a gain error does not count).  The exact operator's
model error is what the scene's detail finer than the grid costs it (zero at ``--oversample
1``, up to the trace's 10⁻⁴); a calibrated model's is that plus what calibration misses.

Knobs: ``--models`` (``shifted``, ``footprint``), ``--views``, ``--oversample`` (1 or 2),
``--soften SIGMA`` (blur the scenes by a Gaussian of SIGMA texels of the scene grid: the same
content without sharp edges), ``--repeats`` (noisy frames averaged per calibration capture),
``--set FIELD=VALUE`` (another design: e.g. ``band_step_nm=50``).  A temporary cache folder
keeps the product's caches clean.

Usage::

    python3 tools/exp_calibration_gap.py                      # small, natural + ColorChecker
    python3 tools/exp_calibration_gap.py --views 5 --oversample 1
    python3 tools/exp_calibration_gap.py --set band_step_nm=50 --models shifted,footprint
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--design", default="small")
    ap.add_argument("--set", dest="overrides", action="append", default=[],
                    metavar="FIELD=VALUE", help="design override (repeatable)")
    ap.add_argument("--scenes", default="natural,colorchecker")
    ap.add_argument("--models", default="shifted,footprint")
    ap.add_argument("--views", default="1,3,5")
    ap.add_argument("--oversample", type=int, default=2, choices=(1, 2),
                    help="scene grid over the reconstruction grid (the product uses 2)")
    ap.add_argument("--soften", type=float, default=0.0,
                    help="also blur each scene by a Gaussian of this many scene texels")
    ap.add_argument("--repeats", type=int, default=4,
                    help="noisy frames averaged per calibration capture (0: noise-free)")
    ap.add_argument("--seed", type=int, default=3, help="sensor noise seed of the scene frame")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="kaleidospec-gap-") as cache:
        os.environ["KALEIDOSPEC_CACHE"] = cache
        return run(a)


def scene(name, design, oversample, soften):
    """The scene cube at ``oversample`` × the view grid (blurred if ``soften``)."""
    from scenes.registry import get_scene

    v = design.view_size_px * oversample
    cube, wl = get_scene(name, shape=(v, v), wavelengths=design.wavelengths)
    if soften > 0:
        from scipy.ndimage import gaussian_filter

        cube = gaussian_filter(cube, sigma=(soften, soften, 0)).astype(np.float32)
    return cube, wl


def model_error(g, op, f) -> float:
    """‖g − s H f‖/‖g‖ with the least-squares scale s."""
    hf = op.forward(np.ascontiguousarray(np.moveaxis(f, 2, 0))).astype(np.float64)
    g = np.asarray(g, np.float64)
    s = float(np.vdot(g, hf) / max(np.vdot(hf, hf), 1e-300))
    return float(np.linalg.norm(g - s * hf) / np.linalg.norm(g))


def run(a) -> int:
    from kaleidospec import instrument
    from kaleidospec.calibrate import calibrate_from_captures
    from kaleidospec.models import truth_on_grid
    from kaleidospec.reconstruct import (calibrated_operator, first_views,
                                         frame_measurements, reconstruct_oracle,
                                         reconstruct_views)
    from kaleidospec.instrument import ground_truth, simulate_frame

    counts = sorted({int(v) for v in a.views.split(",")})
    models = [m.strip() for m in a.models.split(",") if m.strip()]
    d = instrument.design_for_views(
        instrument.get_design(a.design, instrument.parse_overrides(a.overrides)), max(counts))
    t0 = time.perf_counter()
    cal = calibrate_from_captures(d, models=tuple(models), repeats=a.repeats)
    print(f"design {a.design} {' '.join(a.overrides)} ({d.hash}); calibration {models} in "
          f"{time.perf_counter() - t0:.1f} s; scenes at {a.oversample}x the grid"
          + (f", softened by {a.soften:g} texels" if a.soften else ""), flush=True)
    head = f"{'scene':<14}{'views':>6}" + "".join(f"{m:>11}" for m in models) + \
        f"{'oracle':>9}" + "".join(f"{'err ' + m[:5]:>11}" for m in models) + f"{'err oracle':>12}"
    print(head)
    print("-" * len(head))
    for name in [s.strip() for s in a.scenes.split(",") if s.strip()]:
        cube, wl = scene(name, d, a.oversample, a.soften)
        frame, meta = simulate_frame(d, cube, wl, seed=a.seed)
        clean, cmeta = simulate_frame(d, cube, wl, noise=False, radiance_scale=meta["radiance_scale"])
        truth = ground_truth(d, cube)
        for n in counts:
            ids = first_views(n)
            # The scene itself onto each model's grid as these views see it (its mean on the
            # design's grid has lost the detail within a pixel).
            on_grid = {m: truth_on_grid(cube, d, cal, m, ids) for m in models}
            row = f"{name:<14}{n:>6}"
            errs = []
            for m in models:
                _, info = reconstruct_views(frame, meta, cal, n, truth=on_grid[m], model=m,
                                            design=d)
                row += f"{info['metrics']['psnr']:>11.2f}"
                g = frame_measurements(clean, cmeta, cal, ids) / np.float32(cmeta["radiance_scale"])
                errs.append(model_error(g, calibrated_operator(cal, ids, m), on_grid[m]))
            _, oinfo = reconstruct_oracle(frame, meta, d, n, truth=truth)
            row += f"{oinfo['metrics']['psnr']:>9.2f}"
            op = instrument.oracle_operator(d, n)
            go = instrument.oracle_measurements(clean, cmeta, d, n)
            row += "".join(f"{100 * e:>10.2f}%" for e in errs) + \
                f"{100 * model_error(go, op, truth):>11.2f}%"
            print(row, flush=True)
    print("PSNR (dB) of each calibrated model and of the exact operator on the same noisy frame; "
          "err: the noise-free model error (see the module notes).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
