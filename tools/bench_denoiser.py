#!/usr/bin/env python3
"""The non-local low-rank denoiser's passes, and its eigensolver against the Jacobi one.

Times the three passes of :func:`recon.priors.nonlocal_lowrank.denoise_nonlocal`
(:mod:`recon.kernels.nonlocal_lowrank`: block matching, group filters, aggregation) on random
coefficient images of the sizes the product denoises (``small``'s 157×163 with k = 4, the
single-view CASSI crop's 256×256 with k = 7), and the group filters' eigensolver, Numba's
``np.linalg.eigh`` (LAPACK), against the cyclic Jacobi rotations of
:func:`recon.kernels.subspace.jacobi_eigh` on the same 24 × 24 Gram matrices, both parallel
over the groups as in the kernel.  Best of ``--repeat`` runs each, after one untimed run that
compiles; the eigensolvers alternate, so their ratio is measured under the same load.

Usage::

    python3 tools/bench_denoiser.py
    python3 tools/bench_denoiser.py --repeat 5
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from numba import njit, prange

from recon.kernels.subspace import jacobi_eigh

#: (k, H, W) of the coefficient images: small's cube with k = 4, the CASSI crop with k = 7.
SIZES = ((4, 157, 163), (7, 256, 256))
PATCH, RADIUS, GROUP, STRIDE = 4, 10, 24, 4


@njit(parallel=True)
def _jacobi_all(grams, out):
    for g in prange(grams.shape[0]):
        w, v = jacobi_eigh(grams[g].copy(), 1e-10, 30)
        i = np.argmax(w)
        out[g] = w[i] + abs(v[0, i])


@njit(parallel=True)
def _lapack_all(grams, out):
    for g in prange(grams.shape[0]):
        w, v = np.linalg.eigh(grams[g])
        i = np.argmax(w)
        out[g] = w[i] + abs(v[0, i])


def best(fn, repeat: int) -> float:
    """The shortest of ``repeat`` timed calls, in milliseconds."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1000.0 * min(times)


def passes(shape, repeat: int) -> dict:
    """Milliseconds of each pass of the denoiser on random images of ``shape``."""
    from recon.kernels import nonlocal_lowrank as kn
    from recon.priors.nonlocal_lowrank import denoise_nonlocal, reference_grid

    k, h, w = shape
    z = np.random.default_rng(0).random(shape).astype(np.float32)
    denoise_nonlocal(z, np.full(k, 0.1))                     # compiles
    gy, gx = np.meshgrid(reference_grid(h, PATCH, STRIDE), reference_grid(w, PATCH, STRIDE),
                         indexing="ij")
    ry, rx = np.ascontiguousarray(gy.ravel()), np.ascontiguousarray(gx.ravel())
    scale = np.full(k, 10.0)
    guide = np.ascontiguousarray(z[:1] * np.float32(scale[0]))
    iy, ix = np.empty((ry.size, GROUP), np.int64), np.empty((ry.size, GROUP), np.int64)
    filt, ranks = np.empty((ry.size, GROUP, GROUP)), np.empty(ry.size, np.int64)
    means = np.empty((ry.size, k * PATCH * PATCH))
    acc, count, out = np.zeros((k, h, w)), np.zeros((h, w)), np.empty_like(z)

    def aggregate():
        acc[:] = 0.0
        count[:] = 0.0
        kn.aggregate(z, scale, iy, ix, PATCH, filt, ranks, means, acc, count)
        kn.normalise(acc, count, out)

    return {"groups": ry.size,
            "match": best(lambda: kn.match(guide, ry, rx, PATCH, RADIUS, iy, ix), repeat),
            "filters": best(lambda: kn.group_filters(z, scale, iy, ix, PATCH, 1.0, filt, ranks,
                                                     means), repeat),
            "aggregate": best(aggregate, repeat),
            "call": best(lambda: denoise_nonlocal(z, np.full(k, 0.1)), repeat)}


def eigensolvers(n_groups: int, d: int, repeat: int) -> tuple[float, float]:
    """Milliseconds of Jacobi and of LAPACK for ``n_groups`` Gram matrices of 24 patches of
    ``d`` values, a few strong directions over noise (as a group's)."""
    rng = np.random.default_rng(1)
    y = rng.standard_normal((n_groups, d, GROUP))
    y[:, :, :3] *= 10.0
    grams = np.einsum("gdm,gdn->gmn", y, y)
    out = np.empty(n_groups)
    _jacobi_all(grams, out)
    _lapack_all(grams, out)
    jac, lap = [], []
    for _ in range(repeat):
        jac.append(best(lambda: _jacobi_all(grams, out), 1))
        lap.append(best(lambda: _lapack_all(grams, out), 1))
    return min(jac), min(lap)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each (best kept)")
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error("--repeat must be >= 1")
    for shape in SIZES:
        t = passes(shape, args.repeat)
        jac, lap = eigensolvers(t["groups"], shape[0] * PATCH * PATCH, args.repeat)
        print(f"{shape[0]}x{shape[1]}x{shape[2]}: {t['groups']} groups; match "
              f"{t['match']:.1f} ms, filters {t['filters']:.1f} ms, aggregate "
              f"{t['aggregate']:.1f} ms; a call {t['call']:.1f} ms.  Eigenvectors of the "
              f"groups: Jacobi {jac:.1f} ms, LAPACK {lap:.1f} ms ({jac / lap:.2f}x)",
              flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
