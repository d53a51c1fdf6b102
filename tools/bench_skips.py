#!/usr/bin/env python3
"""What kaleidospec skips when a scene does not need it, and the time each skip saves.

The scene needs little: light in three of the design's bands, a square over a black background
(a third of the scene's side). Each skip is timed against the same work with the skip defeated
(the two alternately, the best of ``--repeat`` each), so the ratio is taken within one run:

1. *dark bands*: a frame (:meth:`sim.frame.FrameModel.electrons`) integrates and blurs only the
   bands with light; defeated by a radiance of 10⁻³⁰ in one texel of every other band (which
   lights them, and changes the frame by nothing a float32 holds);
2. *one band lit*: the same for a band-pass capture's scene (one band), the calibration's
   whites;
3. *views whose blur reaches no measured pixel*: the exact operator of the centre view alone
   (:class:`sim.oracle.ExactOperator`) integrates the views whose blurred light reaches it;
   defeated by integrating every traced view, forward and adjoint;
4. *converged solves*: FISTA-TV stops once the cube's relative change per iteration falls below
   10⁻³ (the default) instead of running its 400 iterations; the frame of the scene above,
   five views, the calibrated shifted model (calibrated once, cached);
5. *diffraction within a pixel*: where every band's Airy radius stays below
   :data:`kaleidospec.calibrate.DECONVOLVE_MIN_PX` (``small``), the calibration does not
   deconvolve its mask images and the calibrated model carries no PSF; defeated by a threshold
   of 0 (one set of captures, rendered once), and the model's forward and adjoint timed with
   and without the PSF it would then carry.

Prints one line per skip: the time with the skip, without it, and their ratio.

    python3 tools/bench_skips.py [--design small|paper] [--repeat 3] [--bands 2,5,8]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def scene(design, bands, shape):
    """(H, W, L) float32: a square of light in ``bands`` over black."""
    h, w = shape
    cube = np.zeros((h, w, design.wavelengths.size), np.float32)
    cube[h // 3:2 * h // 3, w // 3:2 * w // 3, list(bands)] = 1.0
    return cube


def defeated(cube):
    """``cube`` with every dark band lit by 10⁻³⁰ in one texel."""
    out = cube.copy()
    dark = np.flatnonzero(out.max(axis=(0, 1)) == 0)
    out[0, 0, dark] = 1e-30
    return out


def best_pair(a, b, repeat):
    """Best wall times of ``a()`` and ``b()``, run alternately ``repeat`` times each."""
    ta, tb = [], []
    for _ in range(repeat):
        for fn, acc in ((a, ta), (b, tb)):
            t0 = time.perf_counter()
            fn()
            acc.append(time.perf_counter() - t0)
    return min(ta), min(tb)


def line(name, with_skip, without, extra=""):
    print(f"{name:<46} {with_skip:8.3f} s  {without:8.3f} s  {without / with_skip:5.2f}x"
          + (f"  {extra}" if extra else ""), flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", default="small")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--bands", default="2,5,8", help="the lit bands")
    ap.add_argument("--skip-solve", action="store_true", help="leave out the converged solves")
    ap.add_argument("--skip-calibration", action="store_true",
                    help="leave out the calibration without deconvolution")
    args = ap.parse_args(argv)

    from kaleidospec.instrument import FrameRenderer
    from recon.kernels import cores
    from sim.design import get_design
    from sim.frame import scene_grid
    from sim.oracle import oracle_operator

    d = get_design(args.design)
    bands = [int(b) for b in args.bands.split(",")]
    shape = scene_grid(d, "natural")
    cube = scene(d, bands, shape)
    print(f"design {args.design} ({d.wavelengths.size} bands, views {list(d.views)}), scene "
          f"{shape[0]}x{shape[1]}, light in bands {bands}, {cores()} cores, best of "
          f"{args.repeat}")
    print(f"{'skip':<46} {'with':>10}  {'without':>10}  ratio")

    # 1-2. Dark bands in a frame.
    r = FrameRenderer(d, shape)
    r.electrons(cube)                                   # load the transport, compile
    full = defeated(cube)
    a, b = best_pair(lambda: r.electrons(cube), lambda: r.electrons(full), args.repeat)
    e0, e1 = r.electrons(cube), r.electrons(full)
    line(f"dark bands: a frame, {len(bands)} of {d.wavelengths.size} bands lit", a, b,
         f"frames differ by {np.abs(e0 - e1).max() / e1.max():.1e} of the peak")
    one = scene(d, bands[:1], shape)
    a, b = best_pair(lambda: r.electrons(one), lambda: r.electrons(defeated(one)), args.repeat)
    line("dark bands: a one-band scene (a band-pass capture)", a, b)

    # 3. Views whose blur reaches no measured pixel (the exact operator of the centre view).
    op = oracle_operator(d, 1)
    x = np.ascontiguousarray(np.moveaxis(scene(d, bands, op.ishape[1:]), 2, 0))
    lit = list(op.lit_views)
    every = list(range(len(op.all_rects)))

    def with_views(views, fn):
        def run():
            kept = op.lit_views
            op.lit_views = views
            try:
                fn()
            finally:
                op.lit_views = kept
        return run

    y = op.forward(x)
    if lit == every:
        print("views: every traced view's blur reaches the centre view: nothing to skip",
              flush=True)
    else:
        a, b = best_pair(with_views(lit, lambda: op.forward(x)),
                         with_views(every, lambda: op.forward(x)), args.repeat)
        line(f"views: exact forward, views {lit} of {len(every)}", a, b)
        a, b = best_pair(with_views(lit, lambda: op.adjoint(y)),
                         with_views(every, lambda: op.adjoint(y)), args.repeat)
        line(f"views: exact adjoint, views {lit} of {len(every)}", a, b)

    # 4. Converged solves.
    if not args.skip_solve:
        from kaleidospec.calibrate import calibrate
        from kaleidospec.reconstruct import reconstruct_views
        from sim.frame import exposure

        cal = calibrate(d, progress=False)
        scale = exposure(r.electrons(cube), d)
        frame = r.render(cube, radiance_scale=scale, seed=0)
        meta = r.metadata(radiance_scale=scale, seed=0, noise=True)
        n = min(5, len(cal.view_ids))
        c1, i1 = reconstruct_views(frame, meta, cal, n, tol=1e-3, iters=400)
        c0, i0 = reconstruct_views(frame, meta, cal, n, tol=None, iters=400)
        change = float(np.linalg.norm(c1 - c0) / np.linalg.norm(c0))
        line(f"converged solve: FISTA-TV, {n} views", i1["seconds"], i0["seconds"],
             f"{i1['iters']} against {i0['iters']} iterations; cubes {change:.1e} apart")

    # 5. Diffraction within a pixel: no deconvolution, no PSF in the model.
    if not args.skip_calibration:
        within_a_pixel(d, args.repeat)
    return 0


def within_a_pixel(d, repeat):
    """Item 5: the calibration and the calibrated model with the skip and without it."""
    import dataclasses

    import kaleidospec.calibrate as kc
    from kaleidospec.instrument import render_captures
    from kaleidospec.reconstruct import calibrated_operator, first_views

    if kc.deconvolution_radii(d) is not None:
        print("diffraction: the Airy radius reaches past a pixel: nothing to skip", flush=True)
        return
    caps = render_captures(d)
    threshold = kc.DECONVOLVE_MIN_PX

    def calibration(minimum):
        kc.DECONVOLVE_MIN_PX = minimum
        try:
            return kc.calibrate_from_captures(d, captures=caps)
        finally:
            kc.DECONVOLVE_MIN_PX = threshold

    kept = {}

    def run(minimum):
        def go():
            kept[minimum] = calibration(minimum)
        return go

    a, b = best_pair(run(threshold), run(0.0), max(1, repeat // 2))
    line("diffraction within a pixel: calibration", a, b, "captures rendered once, apart")
    plain, blurred = kept[threshold], kept[0.0]
    assert plain.psf is None and blurred.psf is not None
    ids = first_views(min(5, len(plain.view_ids)))
    op0 = calibrated_operator(plain, ids)
    op1 = calibrated_operator(dataclasses.replace(plain, psf=blurred.psf), ids)
    x = np.random.default_rng(0).random(op0.ishape).astype(np.float32)
    y = op0.forward(x)

    def pair(op):
        return lambda: op.adjoint(op.forward(x) - y)

    a, b = best_pair(pair(op0), pair(op1), repeat)
    line(f"diffraction within a pixel: model forward+adjoint, {len(ids)} views", a, b,
         f"PSF {blurred.psf.shape[0]}x{blurred.psf.shape[1]}")


if __name__ == "__main__":
    raise SystemExit(main())
