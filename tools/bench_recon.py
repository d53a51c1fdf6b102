"""Benchmark the reconstruction solvers: PSNR against seconds, and peak memory.

Configurations (synthetic piecewise-smooth ground truth made here, no downloads):
  (a) standard single-view CASSI, 256x256x28, step 2, random binary mask;
      also the reference "plain GAP-TV" (5 cold Chambolle iterations per step, as the public
      NumPy GAP-TV);
  (b) the paper's kaleidoscope, 645x501x25 (W x H), five views (centre, left, right, top,
      bottom) with dispersion inversion, 2x2-pixel random binary masks, a prism-like sub-pixel
      dispersion over ~50 px.

For every solver: one run with a callback that records (seconds, PSNR) per iteration (the
callback's own time is excluded from the seconds) and the peak memory (tracemalloc: NumPy
allocations during the solve; plus the process's maxrss), and one plain run of the full
iteration count, without tracemalloc, for the headline wall and CPU times.  Writes
``bench_recon.json`` and ``bench_recon.png`` to ``--out`` (atomically).

Targets (2-core machine): (a) 50 GAP-TV iterations <= 1.5 s at a PSNR no worse than the plain
GAP-TV; (b) 50 TwIST iterations (tau = 0.15) <= 10 s with peak memory <= 1.5 GB.  On (b) TwIST
also runs with the authors' settings (lambda1 = 1e-4, 10 Chambolle iterations per prox) for
comparison (``--no-reference`` skips it).  Each run also records the process CPU time (all
threads): on a shared machine wall time depends on the load, CPU time much less.

Usage: python3 tools/bench_recon.py [--quick] [--out DIR] [--iters 50] [--solvers a,b]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

# This checkout's recon, not whichever an editable install points at.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from recon.io.atomic import atomic_path  # noqa: E402
from recon.metrics import psnr  # noqa: E402
from recon.operators import kaleidoscope_cassi, standard_cassi  # noqa: E402
from recon.solvers import solve  # noqa: E402

# Per-solver TV weights and options used by the benchmark (data in [0, 1]).  tau = 0.15 is the
# paper's TwIST setting; GAP-TV's tau is its per-step denoising weight.
SETTINGS = {
    "gap-tv": {"tau": 0.1},
    "twist": {"tau": 0.15},
    "fista-tv": {"tau": 0.15},
}
REFERENCE = ("gap-tv (plain, 5 cold Chambolle)", "gap-tv",
             {"tau": 0.1, "tv_iters": 5, "warm_dual": False})
# The authors' TwIST settings (TwIST.m's lambda1 = 1e-4, ~10 Chambolle iterations per prox)
# on (b), to compare with the defaults (lambda1 = 1e-2, 2 warm Chambolle iterations).
REFERENCE_B = ("twist (lam1 1e-4, 10 Chambolle)", "twist",
               {"tau": 0.15, "lam1": 1e-4, "tv_iters": 10})


def synthetic_cube(h: int, w: int, n_bands: int, seed: int = 0, n_shapes: int = 14) -> np.ndarray:
    """A piecewise-smooth band-major cube (L, H, W) in [0, 1], maximum 1.

    Rectangles and discs on a background, each with a smooth (Gaussian bump) spectrum and a
    gentle vertical intensity ramp, so that TV priors are appropriate but not exact.
    """
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    lam = np.linspace(0.0, 1.0, n_bands, dtype=np.float32)

    def spectrum():
        c, s, a = rng.uniform(0, 1), rng.uniform(0.15, 0.5), rng.uniform(0.3, 1.0)
        return (0.1 + a * np.exp(-0.5 * ((lam - c) / s) ** 2)).astype(np.float32)

    cube = np.empty((n_bands, h, w), np.float32)
    cube[:] = 0.5 * spectrum()[:, None, None]
    ramp = (1.0 + 0.3 * (yy / h - 0.5)).astype(np.float32)
    for _ in range(n_shapes):
        if rng.random() < 0.5:
            y0, x0 = rng.uniform(0, h), rng.uniform(0, w)
            hy, hx = rng.uniform(h / 16, h / 3), rng.uniform(w / 16, w / 3)
            m = (np.abs(yy - y0) < hy) & (np.abs(xx - x0) < hx)
        else:
            r = rng.uniform(min(h, w) / 12, min(h, w) / 4)
            m = (yy - rng.uniform(0, h)) ** 2 + (xx - rng.uniform(0, w)) ** 2 < r * r
        cube[:, m] = spectrum()[:, None] * ramp[m][None, :]
    cube /= cube.max()
    return cube


def block_mask(rng, shape, cell=2):
    """Random binary mask (about 50 % open) of cell x cell pixel blocks."""
    h, w = shape
    m = rng.random((-(-h // cell), -(-w // cell))) > 0.5
    return np.kron(m, np.ones((cell, cell), bool))[:h, :w].astype(np.float32)


def config_a(quick: bool):
    h, w, nl = (64, 64, 14) if quick else (256, 256, 28)
    rng = np.random.default_rng(1)
    mask = (rng.random((h, w)) > 0.5).astype(np.float32)
    return f"(a) standard CASSI {w}x{h}x{nl}, step 2", standard_cassi(mask, 2, nl), \
        synthetic_cube(h, w, nl, seed=0)


def config_b(quick: bool):
    h, w, nl, k = (96, 128, 12, 5) if quick else (501, 645, 25, 5)
    rng = np.random.default_rng(2)
    masks = np.stack([block_mask(rng, (h, w)) for _ in range(k)])
    lam = np.linspace(450.0, 690.0, nl)
    span = 12.0 if quick else 50.0
    phi = span * (1.0 / lam**2 - 1.0 / 450.0**2) / (1.0 / 690.0**2 - 1.0 / 450.0**2)
    return (f"(b) kaleidoscope {w}x{h}x{nl}, {k} views, inversion",
            kaleidoscope_cassi(masks, phi, k, inversion=True), synthetic_cube(h, w, nl, seed=3))


def _psnr(x, truth):
    return float(psnr(np.moveaxis(x, 0, -1), np.moveaxis(truth, 0, -1)))


def run_one(label, name, kw, op, g, truth, iters):
    curve = []

    def cb(it, x, info):
        curve.append({"iteration": it, "seconds": info["seconds"], "psnr": _psnr(x, truth)})

    # Peak memory from the callback run: tracemalloc hooks every allocation and slowed the
    # TwIST solve of (b) by a third (CPU 20.5 s against 15.0 s), so the headline run below is
    # timed without it.
    tracemalloc.start()
    solve(name, op, g, iters=iters, callback=cb, **kw)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    t0, c0 = time.perf_counter(), time.process_time()
    res = solve(name, op, g, iters=iters, **kw)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    out = {"label": label, "solver": name, "options": kw, "iterations": res.iterations,
           "seconds": wall, "cpu_seconds": cpu, "psnr": _psnr(res.x, truth), "peak_traced_mb": peak / 2**20,
           "curve": curve,
           "info": {k: v for k, v in res.info.items() if isinstance(v, (int, float, bool, str))}}
    print(f"  {label:<36s} {res.iterations:3d} it  {wall:7.2f} s (cpu {cpu:6.2f} s)"
          f"  PSNR {out['psnr']:6.2f} dB  peak {out['peak_traced_mb']:7.1f} MB", flush=True)
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    p.add_argument("--out", type=Path, default=Path("bench_out"), help="output folder")
    p.add_argument("--iters", type=int, default=50)
    p.add_argument("--solvers", default="gap-tv,twist,fista-tv")
    p.add_argument("--configs", default="a,b")
    p.add_argument("--no-reference", action="store_true",
                   help="skip the authors'-settings TwIST run on (b)")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    names = [s for s in args.solvers.split(",") if s]
    report = {"iters": args.iters, "quick": args.quick, "configs": [],
              "cpus": os.cpu_count(), "loadavg_start": os.getloadavg()}

    for key in args.configs.split(","):
        title, op, truth = (config_a if key == "a" else config_b)(args.quick)
        g = op.forward(truth)
        print(f"{title}: {op.ishape} -> {op.oshape}", flush=True)
        runs = []
        if key == "a":
            runs.append(run_one(REFERENCE[0], REFERENCE[1], REFERENCE[2], op, g, truth,
                                args.iters))
        if key == "b" and "twist" in names and not args.no_reference:
            runs.append(run_one(REFERENCE_B[0], REFERENCE_B[1], REFERENCE_B[2], op, g, truth,
                                args.iters))
        for name in names:
            runs.append(run_one(name, name, dict(SETTINGS[name]), op, g, truth, args.iters))
        report["configs"].append({"key": key, "title": title, "ishape": op.ishape,
                                  "oshape": op.oshape, "runs": runs})

    report["loadavg_end"] = os.getloadavg()
    report["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"process peak RSS: {report['maxrss_mb']:.0f} MB")
    with atomic_path(args.out / "bench_recon.json") as tmp:
        tmp.write_text(json.dumps(report, indent=1))
    _plot(report, args.out / "bench_recon.png")
    print(f"wrote {args.out / 'bench_recon.json'} and {args.out / 'bench_recon.png'}")


def _plot(report, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfgs = report["configs"]
    fig, axes = plt.subplots(1, len(cfgs), figsize=(6 * len(cfgs), 4.5), squeeze=False)
    for ax, cfg in zip(axes[0], cfgs):
        for run in cfg["runs"]:
            c = run["curve"]
            ax.plot([r["seconds"] for r in c], [r["psnr"] for r in c], marker=".", ms=3,
                    label=f"{run['label']} ({run['seconds']:.2f} s)")
        ax.set_title(cfg["title"], fontsize=9)
        ax.set_xlabel("seconds")
        ax.set_ylabel("PSNR (dB)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
