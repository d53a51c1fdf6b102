"""Time the CASSI operators' forward and adjoint (milliseconds, median of repeats).

Configurations:
  (a) standard single-view CASSI, 256x256x28, step 2 (the KAIST benchmark);
  (b) the paper's kaleidoscope, 645x501x25, five views (centre, left, right, top, bottom),
      sub-pixel dispersion spanning about 50 px (BK-7 prism, 450-690 nm);
  (c) as (b) with a calibrated homography on every non-centre view (sparse bilinear warps);
  (d) the calibrated operator of ``kaleidospec run --design paper --views 5``
      (:class:`~recon.operators.CalibratedCassi`): cube 900x848x26 (the view less its
      52 px guard stripe), five views of per-band mask images 900x954 (the view, the ~50 px
      dispersion span and the box margins), four of them through homographies, with a band
      scale (the inverse radiometric gains).

Each is timed through the fused kernels (:mod:`recon.kernels`, where they apply: for (b)-(c)
the views whose map is a permutation, for (d) every view) and through the NumPy reference
path, in float32.

Usage: python3 tools/bench_operators.py [--repeat N] [--skip-homography] [--only-calibrated]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from recon import kernels
from recon.operators import (
    CalibratedCassi, HomographyWarp, kaleidoscope_cassi, standard_cassi,
)


def _time(fn, arg, repeat):
    fn(arg)  # warm-up: first-touch page faults and caches
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn(arg)
        ts.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(ts))


def bench(name, op, repeat, rng):
    x = rng.random(op.ishape, dtype=np.float32)
    y = rng.random(op.oshape, dtype=np.float32)
    f = _time(op.forward, x, repeat)
    a = _time(op.adjoint, y, repeat)
    with kernels.numpy_only():
        fn = _time(op.forward, x, repeat)
        an = _time(op.adjoint, y, repeat)
    print(f"{name:<52s} forward {f:7.2f} ms   adjoint {a:7.2f} ms   (NumPy path {fn:7.2f} / "
          f"{an:7.2f} ms)   {op.ishape} -> {op.oshape}")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--skip-homography", action="store_true")
    p.add_argument("--only-calibrated", action="store_true", help="only configuration (d)")
    args = p.parse_args()
    rng = np.random.default_rng(0)
    if args.only_calibrated:
        bench_calibrated(args.repeat, rng)
        return

    mask = (rng.random((256, 256)) > 0.5).astype(np.float32)
    bench("(a) standard 256x256x28 step 2", standard_cassi(mask, 2, 28), args.repeat, rng)

    h, w, nl, k = 501, 645, 25, 5
    masks = (rng.random((k, h, w)) > 0.5).astype(np.float32)
    # A smooth, non-uniform, sub-pixel dispersion curve over ~50 px (prism-like).
    lam = np.linspace(450.0, 690.0, nl)
    phi = 50.0 * (1.0 / lam**2 - 1.0 / 450.0**2) / (1.0 / 690.0**2 - 1.0 / 450.0**2)
    bench("(b) kaleidoscope 645x501x25, 5 views, sub-pixel",
          kaleidoscope_cassi(masks, phi, k), args.repeat, rng)
    bench("(b') same, integer offsets", kaleidoscope_cassi(masks, np.round(phi), k),
          args.repeat, rng)
    if not args.skip_homography:
        warps = [None]
        flips = [(-1, 1), (-1, 1), (1, -1), (1, -1)]
        for sx, sy in flips:
            hm = np.array([[sx * 1.0, 0.004, (w - 1) if sx < 0 else 0.0],
                           [-0.003, sy * 1.0, (h - 1) if sy < 0 else 0.0],
                           [1e-6, 0.0, 1.0]])
            hm[:2, 2] += (0.37, -0.61)
            warps.append(HomographyWarp(hm, (h, w), (h, w)))
        bench("(c) as (b) with 4 homography warps", kaleidoscope_cassi(masks, phi, k, warps=warps),
              max(1, args.repeat // 2), rng)
    bench_calibrated(args.repeat, rng)


def bench_calibrated(repeat, rng):
    """(d): the paper design's calibrated operator, five views (module docstring)."""
    h, w, nl, k, wm = 900, 848, 26, 5, 954
    lam = np.linspace(450.0, 700.0, nl)
    phi = 50.0 * (1.0 / lam**2 - 1.0 / 450.0**2) / (1.0 / 700.0**2 - 1.0 / 450.0**2)
    # Absolute box columns: the bands land 2..52 px in (the box margin), per view a little
    # apart (each view's own calibrated offsets).
    offsets = 2.0 + (phi - phi.min())[None, :] + rng.uniform(0.0, 2.0, (k, 1))
    cm = (rng.random((k, nl, h, wm)) > 0.5).astype(np.float32)
    warps = [None]
    for sx, sy in [(-1, 1), (-1, 1), (1, -1), (1, -1)]:
        hm = np.array([[sx * 1.0, 0.004, (w - 1) if sx < 0 else 0.0],
                       [-0.003, sy * 1.0, (h - 1) if sy < 0 else 0.0],
                       [1e-6, 0.0, 1.0]])
        hm[:2, 2] += (0.37, -0.61)
        warps.append(HomographyWarp(hm, (h, w), (h, w)))
    op = CalibratedCassi(cm, offsets, warps, (nl, h, w), band_scale=rng.uniform(0.5, 2.0, nl))
    bench("(d) calibrated 848x900x26, 5 views (4 homographies)", op, max(1, repeat // 2), rng)


if __name__ == "__main__":
    main()
