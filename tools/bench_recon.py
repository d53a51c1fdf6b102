"""Benchmark the reconstruction solvers: seconds, PSNR and peak memory, against a plain
NumPy GAP-TV timed in the same run.

Configurations (synthetic piecewise-smooth ground truth made here, no downloads):
  (a) standard single-view CASSI, 256x256x28, step 2, random binary mask; the in-run
      reference is ``tools/plain_gap_tv.py``, a GAP-TV written the way public codes are
      (PnP-CASSI's operators, per-band Chambolle TV with 5 cold iterations per step, float64,
      no fused kernels), at its best TV weight (``REFERENCE_WEIGHT``);
  (b) the paper's kaleidoscope, 645x501x25 (W x H), five views (centre, left, right, top,
      bottom) with dispersion inversion, 2x2-pixel random binary masks, a prism-like sub-pixel
      dispersion over ~50 px.

The first solve of the process (GAP-TV on (a), or the first solver asked for) is timed on its
own: it includes importing Numba, loading the compiled kernels from Numba's on-disk cache (or
compiling them when the cache is cold; the report says which) and starting its threads.  Then
for every solver: one run with a callback that records (seconds, PSNR) per iteration (the
callback's own time is excluded) and the peak memory (tracemalloc: NumPy allocations during
the solve; plus the process's maxrss), and ``--repeat`` plain runs whose best wall time is the
headline (the machine is shared: the best of several is the least disturbed).  Each run also
records the process CPU time (all threads).  Writes ``bench_recon.json`` and
``bench_recon.png`` to ``--out`` (atomically).

Targets (2-core machine): (a) 50 GAP-TV iterations <= 0.25 s at a PSNR no lower than the
NumPy paths give (28.25 dB), and >= 40x faster than the plain NumPy GAP-TV; (b) 50 TwIST
iterations (tau = 0.15) <= 2 s at >= 35.5 dB with peak memory <= 1 GB.  On (b) TwIST also runs
with the authors' settings (lambda1 = 1e-4, 10 Chambolle iterations per prox) for comparison
(``--no-reference`` skips it, and the plain GAP-TV on (a)).  ``KALEIDOSPEC_KERNELS=numpy``
runs the NumPy paths of recon instead of the kernels.

The product's own work (``--configs small,paper``): the calibrated model of the ``small`` or
``paper`` design built from its real calibration (cached by design hash; calibrated here, and
timed, when the cache lacks it), a raw frame of each scene rendered with its own Monte Carlo
draw (``kaleidospec.instrument.render_scene``, as ``kaleidospec run`` renders it; the
captures never see it) and, per view count (``--views``, default 1,5), the operator
``kaleidospec.reconstruct`` solves through (unit row norm, the PSF blur, leads, displacement
fields, deconvolved masks): forward, adjoint and one FISTA-TV iteration (best of ``--repeat``;
an iteration of the product's solve (no PSNR history, as ``run``) is (t(1 + N) - t(1)) / N,
without the setup), then the converged solve of
``kaleidospec.reconstruct.reconstruct_views`` with the defaults (FISTA-TV, relative change
< 1e-3, at most 1 000 iterations), the truth on the model's grid as ``run`` scores it: time,
iterations, PSNR and the process's peak resident memory during the solve (sampled every
20 ms).  With ``--warm`` every view count above one also runs from the one-view cube (a warm
start: the same objective, another start).  ``--metrics scalar,auto`` solves each frame with
FISTA's scalar step and then with the default step metric (``auto``: a step per band where
the prior allows it, ``recon.solvers.band_metric``), one after the other in the process: the
before/after of the band metric.  ``--priors tv,subspace-tv`` solves each frame with every
prior listed (default ``tv``, the prior of the speed targets; ``subspace-tv`` is what ``run``
and ``demo`` solve by default).  ``--constants`` says where a converged solve takes the
operator's constants (its row scale and FISTA's step, ``kaleidospec.solve_constants``):
``cache`` (the default, as ``run``: read where a solve with this calibration and views kept
them, else estimated and kept), ``estimate`` (estimated, nothing kept), or both one after the
other; each row says which it was.  ``--compare`` times the reference paths (the
FFT blur, the unfused gradient step of the row scaling, the float64 PSNR history) against the
current ones, alternated in the process, with the largest relative difference of their
outputs.  Scenes (``--scenes``): ``natural`` and the CAVE development scene
``egyptian_statue`` (``$KALEIDOSPEC_DATA/cave/egyptian_statue``, skipped when absent).

Usage: python3 tools/bench_recon.py [--quick] [--out DIR] [--iters 50] [--solvers a,b]
                                    [--configs a,b] [--repeat 3] [--no-reference]
       python3 tools/bench_recon.py --configs small,paper [--scenes natural,egyptian_statue]
                                    [--views 1,5] [--warm] [--compare] [--no-solve]
                                    [--metrics scalar,auto] [--priors tv,subspace-tv]
                                    [--constants estimate,cache] [--repeat 3]
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import os
import resource
import sys
import threading
import time
import tracemalloc
from pathlib import Path

import numpy as np

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
#: TV weight of the plain GAP-TV on (a): the best of nine at 50 iterations (docs/speed.md), so
#: that the reference is not handicapped by its weight.
REFERENCE_WEIGHT = 0.12
# The authors' TwIST settings (TwIST.m's lambda1 = 1e-4, ~10 Chambolle iterations per prox)
# on (b), to compare with the defaults (lambda1 = 1e-2, 2 warm Chambolle iterations).
REFERENCE_B = ("twist (lam1 1e-4, 10 Chambolle)", "twist",
               {"tau": 0.15, "lam1": 1e-4, "tv_iters": 10})
TARGETS = {"a": {"solver": "gap-tv", "seconds": 0.25, "psnr": 28.25, "ratio": 40.0},
           "b": {"solver": "twist", "seconds": 2.0, "psnr": 35.5, "peak_mb": 1024.0}}


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


def run_one(label, name, kw, op, g, truth, iters, repeat):
    curve = []

    def cb(it, x, info):
        curve.append({"iteration": it, "seconds": info["seconds"], "psnr": _psnr(x, truth)})

    # Peak memory from the callback run: tracemalloc hooks every allocation and slows a solve
    # down, so the headline runs below are timed without it.
    tracemalloc.start()
    solve(name, op, g, iters=iters, callback=cb, **kw)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    walls, cpus = [], []
    for _ in range(max(1, repeat)):
        t0, c0 = time.perf_counter(), time.process_time()
        res = solve(name, op, g, iters=iters, **kw)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    best = int(np.argmin(walls))
    out = {"label": label, "solver": name, "options": kw, "iterations": res.iterations,
           "seconds": walls[best], "cpu_seconds": cpus[best], "all_seconds": walls,
           "psnr": _psnr(res.x, truth), "peak_traced_mb": peak / 2**20, "curve": curve,
           "info": {k: v for k, v in res.info.items() if isinstance(v, (int, float, bool, str))}}
    print(f"  {label:<36s} {res.iterations:3d} it  {walls[best]:7.3f} s (cpu {cpus[best]:6.2f} s,"
          f" best of {len(walls)})  PSNR {out['psnr']:6.2f} dB  peak "
          f"{out['peak_traced_mb']:7.1f} MB", flush=True)
    return out


def _kernels():
    """:mod:`recon.kernels`, or None in a checkout without it (this script copied into such a
    checkout's tools/ runs against its NumPy-only solvers)."""
    try:
        from recon import kernels
    except ImportError:
        return None
    return kernels


def first_call(name, op, g, truth, iters):
    """Time the process's first solve (Numba import, kernel loading or compiling, threads)."""
    kernels = _kernels()
    on = kernels is not None and kernels.enabled()
    t0 = time.perf_counter()
    res = solve(name, op, g, iters=iters, **SETTINGS[name])
    wall = time.perf_counter() - t0
    compiled = loaded = 0
    if on:
        import recon.kernels.cassi as kc
        import recon.kernels.tv as kt
        import recon.kernels.vector as kv

        for mod in (kc, kt, kv):
            for obj in vars(mod).values():
                stats = getattr(obj, "stats", None)
                if stats is not None and hasattr(stats, "cache_misses"):
                    compiled += sum(stats.cache_misses.values())
                    loaded += sum(stats.cache_hits.values())
    how = ("NumPy paths (kernels off or absent)" if not on else
           f"{compiled} kernel signature(s) compiled, {loaded} loaded from Numba's cache")
    print(f"  first call: {name} {wall:.3f} s ({how}; the solve itself {res.seconds:.3f} s)",
          flush=True)
    return {"solver": name, "seconds": wall, "kernels": on,
            "compiled": compiled, "loaded": loaded, "psnr": _psnr(res.x, truth)}


def run_reference(op, g, truth, iters, repeat):
    """The plain NumPy GAP-TV (tools/plain_gap_tv.py) on (a), timed like the solvers."""
    import plain_gap_tv

    view = op.views[0]
    steps = np.diff(view.offsets)
    step = int(round(steps[0])) if steps.size else 0
    phi = plain_gap_tv.shifted_masks(view.mask, step, op.n_bands)
    walls, cpus = [], []
    for _ in range(max(1, repeat)):
        t0, c0 = time.perf_counter(), time.process_time()
        x = plain_gap_tv.gap_tv(g[0].astype(np.float64), phi, step, REFERENCE_WEIGHT, iters)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    best = int(np.argmin(walls))
    ps = float(psnr(x, np.moveaxis(truth, 0, -1)))
    label = "plain NumPy GAP-TV (reference)"
    print(f"  {label:<36s} {iters:3d} it  {walls[best]:7.3f} s (cpu {cpus[best]:6.2f} s,"
          f" best of {len(walls)})  PSNR {ps:6.2f} dB  (float64, 5 cold Chambolle per band,"
          f" weight {REFERENCE_WEIGHT})", flush=True)
    return {"label": label, "solver": "plain-gap-tv", "options": {"weight": REFERENCE_WEIGHT,
            "tv_iters": 5}, "iterations": iters, "seconds": walls[best],
            "cpu_seconds": cpus[best], "all_seconds": walls, "psnr": ps, "curve": []}


# ------------------------------------------------------------------ the product's own work
#: The calibrated configurations: design presets of ``sim.design``.
CALIBRATED = ("small", "paper")
#: Scenes of the calibrated rows: a measured hyperspectral scene and the built-in one.
CALIBRATED_SCENES = ("egyptian_statue", "natural")
#: The issue's targets for the calibrated rows: (design, views) -> seconds of the converged
#: solve (TV prior, the default rule).
CALIBRATED_TARGETS = {("paper", 5): 12.0, ("paper", 1): 20.0, ("small", 5): 0.5}


class PeakRSS:
    """The process's peak resident memory while the ``with`` block runs, sampled from
    ``/proc/self/statm`` every ``period`` seconds (MB; None where there is no ``/proc``)."""

    def __init__(self, period: float = 0.02):
        self.period = period
        self.peak_mb = self.start_mb = None

    @staticmethod
    def _rss_mb():
        try:
            with open("/proc/self/statm") as f:
                return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
        except (OSError, ValueError, IndexError):
            return None

    def _sample(self):
        while not self._stop.wait(self.period):
            r = self._rss_mb()
            if r is not None:
                self.peak_mb = max(self.peak_mb or 0.0, r)

    def __enter__(self):
        self.start_mb = self.peak_mb = self._rss_mb()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        r = self._rss_mb()
        if r is not None:
            self.peak_mb = max(self.peak_mb or 0.0, r)
        return False


def scene_source(name: str):
    """A built-in scene's name, or the CAVE folder ``$KALEIDOSPEC_DATA/cave/<name>``; None when
    a CAVE scene is asked for and absent."""
    from scenes.registry import list_scenes

    from kaleidospec.experiments import cave_folder

    if name in list_scenes():
        return name
    folder = cave_folder(name)
    return None if folder is None else str(folder)


def _best(fn, repeat):
    walls = []
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        fn()
        walls.append(time.perf_counter() - t0)
    return min(walls)


def _iteration_seconds(op, g, tau, lip, truth, repeat, n=5):
    """Seconds of one iteration of the product's solve (``recon.app.reconstruct``: FISTA-TV,
    the truth's metrics at the end and no PSNR history, as ``run`` does), without its setup:
    (t(1 + n) - t(1)) / n, each the best of ``repeat`` runs."""
    from recon.app import reconstruct

    kw = dict(solver="fista-tv", tau=tau, tol=None, truth=truth, lipschitz=lip, history=False)
    t1 = _best(lambda: reconstruct(g, op, iters=1, **kw), repeat)
    tn = _best(lambda: reconstruct(g, op, iters=1 + n, **kw), repeat)
    return max(tn - t1, 0.0) / n


@contextlib.contextmanager
def reference_paths():
    """Within this block the product's iteration takes the paths it took before the fast
    ones it now has (for the A/B of ``--compare``): the PSF blur by FFT
    (``recon.operators.blur.convolve_views`` on its NumPy path), the row scaling's gradient step
    as the plain adjoint, a scaled copy and a sum (``LinearOperator.adjoint_add``), and the PSNR
    history in float64 band by band.  Everything else (the calibrated kernels, the prox) is the
    same in both."""
    from recon import kernels
    from recon.kernels import vector as kvec
    from recon.operators import base as obase
    from recon.operators import blur as oblur

    conv, sq, add = oblur.convolve_views, kvec.squared_distance, obase.ScaledOperator.adjoint_add

    def fft_blur(y, k):
        with kernels.numpy_only():
            return conv(y, k)

    def per_band(a, b, threads=None):
        return sum(float(np.sum((np.asarray(al, dtype=np.float64) - bl) ** 2))
                   for al, bl in zip(a, b))

    oblur.convolve_views = fft_blur
    kvec.squared_distance = per_band
    obase.ScaledOperator.adjoint_add = obase.LinearOperator.adjoint_add
    try:
        yield
    finally:
        oblur.convolve_views, kvec.squared_distance = conv, sq
        obase.ScaledOperator.adjoint_add = add


def compare_paths(op, g, truth, tau, lip, repeat, iters=5):
    """Reference paths (:func:`reference_paths`) against the current ones, alternated in this
    process: forward, gradient step, and ``iters`` iterations of the product's solve (FISTA-TV
    with the PSNR history, ``recon.app.reconstruct``; its start, one adjoint, included); best
    of ``repeat`` each.  Returns {"reference": {...}, "current": {...}, "max_rel_diff": {...}}."""
    from recon.app import reconstruct

    x = np.ascontiguousarray(np.moveaxis(truth, 2, 0), dtype=np.float32)
    times = {"reference": {}, "current": {}}
    outs = {}
    for _ in range(max(1, repeat)):
        for which in ("reference", "current"):
            ctx = reference_paths() if which == "reference" else contextlib.nullcontext()
            with ctx:
                res = {}
                t0 = time.perf_counter()
                res["forward"] = op.forward(x)
                t1 = time.perf_counter()
                res["gradient step"] = op.adjoint_add(g, x, -0.5)
                t2 = time.perf_counter()
                cube, info = reconstruct(g, op, solver="fista-tv", iters=iters, tol=None,
                                         tau=tau, truth=truth, lipschitz=lip)
                res["solve"] = cube
            for k, t in (("forward_s", t1 - t0), ("gradient_step_s", t2 - t1),
                         (f"solve_{iters}_it_s", info["wall_seconds"])):
                times[which][k] = min(times[which].get(k, np.inf), t)
            times[which]["psnr_history"] = info["psnr_history"]
            outs[which] = res
    diff = {k: rel_diff(outs["current"][k], outs["reference"][k]) for k in outs["current"]}
    return {**times, "max_rel_diff": diff}


def compare_blur(cal, views, alternations=10):
    """The PSF blur alone on the calibration's kernel and each view count's measurement shape:
    the FFT (the reference path) against the direct correlation, alternated; medians and
    bests in seconds, and the largest relative difference."""
    from recon import kernels
    from recon.operators.blur import convolve_views

    if cal.psf is None:
        return {}
    k = np.asarray(cal.psf, np.float32)
    h, w = (int(v) for v in cal.view_boxes[0, 2:])
    out = {}
    for n in views:
        y = np.random.default_rng(0).random((n, h, w), dtype=np.float32)
        tf, td = [], []
        for _ in range(alternations):
            t0 = time.perf_counter()
            with kernels.numpy_only():
                a = convolve_views(y, k)
            tf.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            b = convolve_views(y, k)
            td.append(time.perf_counter() - t0)
        out[n] = {"fft_median_s": float(np.median(tf)), "fft_best_s": min(tf),
                  "direct_median_s": float(np.median(td)), "direct_best_s": min(td),
                  "max_rel_diff": rel_diff(b, a)}
        r = out[n]
        print(f"  PSF blur {k.shape[0]}x{k.shape[1]}, {n} view(s) {y.shape}: FFT median "
              f"{r['fft_median_s'] * 1e3:6.1f} ms (best {r['fft_best_s'] * 1e3:6.1f}), direct "
              f"{r['direct_median_s'] * 1e3:6.1f} ms (best {r['direct_best_s'] * 1e3:6.1f}), "
              f"{r['fft_median_s'] / r['direct_median_s']:4.2f}x; largest relative difference "
              f"{r['max_rel_diff']:.1e}", flush=True)
    return out


def rel_diff(a, b) -> float:
    """Largest absolute difference over the largest absolute value of ``b``."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-30))


def bench_calibrated(design_name, scenes, views, repeat, warm, quick, converge=True,
                     compare=False, metrics=None, priors=("tv",), constants=("cache",)):
    """The rows of one calibrated design (see the module docstring); returns the report."""
    from kaleidospec.calibrate import calibrate, is_cached
    from kaleidospec.instrument import release_transports, render_scene
    from kaleidospec.models import model_of, truth_on_grid
    from kaleidospec.reconstruct import (DEFAULTS, calibrated_operator, first_views,
                                         frame_measurements, measurement_noise, normalised,
                                         reconstruct_views, tv_weight)
    from recon.solvers import operator_norm_sq
    from sim.optics.design import get_design

    metrics = [DEFAULTS["metric"]] if not metrics else list(metrics)
    design = get_design(design_name)
    cached = is_cached(design)
    t0 = time.perf_counter()
    with PeakRSS() as mem:
        cal = calibrate(design, progress=False)
    cal_s = time.perf_counter() - t0
    model = model_of(cal, None)
    print(f"[{design_name}] calibration {'loaded from the cache' if cached else 'made'} in "
          f"{cal_s:.1f} s (peak RSS {mem.peak_mb:.0f} MB); model {model}, cube "
          f"{cal.cube_shape}", flush=True)
    out = {"design": design_name, "design_hash": design.hash, "model": model,
           "calibration": {"cached": cached, "seconds": cal_s, "peak_rss_mb": mem.peak_mb},
           "scenes": []}
    if compare:
        out["blur"] = compare_blur(cal, views)
    for scene in scenes:
        src = scene_source(scene)
        if src is None:
            print(f"[{design_name}] scene {scene}: not found (KALEIDOSPEC_DATA/cave/{scene}); "
                  f"skipped", flush=True)
            continue
        t0 = time.perf_counter()
        frame, meta, native, _ = render_scene(src, design, seed=0, native=True)
        release_transports("scene")
        truths = {n: truth_on_grid(native, design, cal, model, first_views(n)) for n in views}
        del native
        print(f"[{design_name}] {scene}: frame rendered in {time.perf_counter() - t0:.1f} s",
              flush=True)
        rows, cubes = [], {}
        for n in views:
            ids = first_views(n)
            op = calibrated_operator(cal, ids, model)
            t0 = time.perf_counter()
            sop, g = normalised(op, frame_measurements(frame, meta, cal, ids))
            lip = operator_norm_sq(sop)
            setup = time.perf_counter() - t0
            x = np.ascontiguousarray(np.moveaxis(truths[n], 2, 0), dtype=np.float32)
            fwd = _best(lambda: sop.forward(x), repeat)
            adj = _best(lambda: sop.adjoint(g), repeat)
            noise = measurement_noise(frame_measurements(frame, meta, cal, ids), meta, cal.noise)
            tau = tv_weight("fista-tv", None, n, None if noise is None else noise * sop.scale)
            it_s = _iteration_seconds(sop, g, tau, lip, truths[n], repeat,
                                      n=2 if quick else 5)
            row = {"scene": scene, "views": n, "cube_shape": list(x.shape),
                   "forward_s": fwd, "adjoint_s": adj, "iteration_s": it_s,
                   "setup_s": setup}
            if compare:
                row["compare"] = c = compare_paths(sop, g, truths[n], tau, lip, repeat)
                ref, cur = c["reference"], c["current"]
                for k in ("forward_s", "gradient_step_s", "solve_5_it_s"):
                    print(f"  {design_name:5s} {scene:16s} {n} view(s) {k:16s} reference "
                          f"{ref[k]:7.3f} s  current {cur[k]:7.3f} s  ({ref[k] / cur[k]:4.2f}x)",
                          flush=True)
                print(f"  {design_name:5s} {scene:16s} {n} view(s) largest relative "
                      f"difference current/reference: " + ", ".join(
                          f"{k} {v:.1e}" for k, v in c["max_rel_diff"].items()), flush=True)
            del sop, g, op
            if not converge:
                print(f"  {design_name:5s} {scene:16s} {n} view(s): forward {fwd * 1e3:7.1f} ms"
                      f"  adjoint {adj * 1e3:7.1f} ms  iteration {it_s:6.3f} s  setup "
                      f"{setup:5.2f} s", flush=True)
                rows.append(row)
                continue
            # The converged solve with every prior (--priors) and step metric (--metrics)
            # asked for, one after the other on the same frame; the first prior's last cube
            # is kept (for --warm).
            for prior, metric, how in itertools.product(priors, metrics, constants):
                with PeakRSS() as mem:
                    c, info = reconstruct_views(frame, meta, cal, n, truth=truths[n],
                                                design=design, model=model, metric=metric,
                                                prior=prior, cached_constants=how == "cache")
                made = info.get("constants_estimated")
                state = ("estimated" if how == "estimate" else
                         "from the cache" if not made else "estimated, now cached")
                mrow = dict(row, prior=prior, metric=metric,
                            metric_used=info["solver_info"].get("metric"),
                            solve_s=info["seconds"], iters=info["iters"],
                            psnr=info["metrics"]["psnr"], peak_rss_mb=mem.peak_mb,
                            rss_start_mb=mem.start_mb, constants=state,
                            objective=(info["objective"] or [None])[-1])
                print(f"  {design_name:5s} {scene:16s} {n} view(s): forward "
                      f"{fwd * 1e3:7.1f} ms  adjoint {adj * 1e3:7.1f} ms  iteration "
                      f"{it_s:6.3f} s  | {prior:11s} metric {metric:6s} converged "
                      f"{info['iters']:3d} it {info['seconds']:7.2f} s  PSNR "
                      f"{mrow['psnr']:6.2f} dB  peak RSS {mem.peak_mb:6.0f} MB  "
                      f"constants {state}", flush=True)
                rows.append(mrow)
                if prior == priors[0]:
                    cube = c
                del c
            cubes[n] = cube
            if warm and n > 1 and 1 in cubes:
                with PeakRSS() as mem:
                    cube, info = reconstruct_views(frame, meta, cal, n, truth=truths[n],
                                                   design=design, model=model, x0=cubes[1],
                                                   prior=priors[0])
                wrow = dict(row, warm_from=1, prior=priors[0], metric=DEFAULTS["metric"],
                            solve_s=info["seconds"], iters=info["iters"],
                            psnr=info["metrics"]["psnr"], peak_rss_mb=mem.peak_mb)
                print(f"  {design_name:5s} {scene:16s} {n} view(s) from the 1-view cube: "
                      f"{info['iters']:3d} it {info['seconds']:7.2f} s  PSNR "
                      f"{wrow['psnr']:6.2f} dB", flush=True)
                rows.append(wrow)
        for r in rows:
            target = CALIBRATED_TARGETS.get((design_name, r["views"]))
            if target is not None and "warm_from" not in r and "solve_s" in r and \
                    r.get("metric") == DEFAULTS["metric"] and r.get("prior") == "tv":
                r["target_s"] = target
        out["scenes"].append({"scene": scene, "rows": rows})
        del frame, truths, cubes
    out["defaults"] = dict(DEFAULTS)
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    p.add_argument("--out", type=Path, default=Path("out/bench_recon"),
                   help="output folder (default out/bench_recon)")
    p.add_argument("--iters", type=int, default=50)
    p.add_argument("--solvers", default="gap-tv,twist,fista-tv")
    p.add_argument("--configs", default="a,b")
    p.add_argument("--repeat", type=int, default=3, help="timed runs per solver (best kept)")
    p.add_argument("--ref-repeat", type=int, default=2,
                   help="timed runs of the plain NumPy GAP-TV (best kept)")
    p.add_argument("--scenes", default=",".join(CALIBRATED_SCENES),
                   help="scenes of the calibrated configurations (built-in or CAVE names)")
    p.add_argument("--views", default="1,5", help="view counts of the calibrated configurations")
    p.add_argument("--compare", action="store_true",
                   help="calibrated configurations: also time the reference paths against the "
                        "current ones, alternated in this process")
    p.add_argument("--no-solve", action="store_true",
                   help="calibrated configurations: operator and iteration times only")
    p.add_argument("--warm", action="store_true",
                   help="also solve every view count above one from the one-view cube")
    p.add_argument("--metrics", default="auto",
                   help="FISTA step metrics of the calibrated converged solves, run one after "
                        "the other on each frame (e.g. scalar,auto: before / after the band "
                        "metric); --warm starts from the last one's 1-view cube")
    p.add_argument("--priors", default="tv",
                   help="priors of the calibrated converged solves, each with every metric "
                        "(e.g. tv,subspace-tv: the prior of the speed targets and what run and "
                        "demo solve by default); --warm takes the first")
    p.add_argument("--constants", default="cache",
                   help="where the calibrated converged solves take their operator constants "
                        "(row scale, band metric): cache (as run does: read where kept, else "
                        "estimated and kept), estimate (estimated, nothing kept), or both, "
                        "e.g. estimate,cache, one after the other on each frame")
    p.add_argument("--no-reference", action="store_true",
                   help="skip the plain NumPy GAP-TV on (a) and the authors'-settings TwIST "
                        "on (b)")
    args = p.parse_args(argv)
    from recon.priors import PRIORS

    priors = tuple(v for v in args.priors.split(",") if v)
    unknown = [v for v in priors if v not in PRIORS]
    if not priors or unknown:
        p.error(f"--priors: choose from {', '.join(PRIORS)} (got {args.priors!r})")
    constants = tuple(v for v in args.constants.split(",") if v)
    if not constants or any(v not in ("cache", "estimate") for v in constants):
        p.error(f"--constants: cache, estimate or both (got {args.constants!r})")
    args.out.mkdir(parents=True, exist_ok=True)
    names = [s for s in args.solvers.split(",") if s]
    kernels = _kernels()
    on = kernels is not None and kernels.enabled()
    # The CPUs the solves may use (a taskset or cpuset holds fewer than the machine has);
    # a checkout from before recon.kernels.cores reports the machine's.
    cpus = kernels.cores() if hasattr(kernels, "cores") else os.cpu_count()
    report = {"iters": args.iters, "quick": args.quick, "configs": [], "kernels": on,
              "cpus": cpus, "loadavg_start": os.getloadavg()}
    print(f"recon from {Path(sys.modules['recon'].__file__).parent}; fused kernels "
          f"{'on' if on else 'off'}", flush=True)
    first = None
    summary = []
    for key in args.configs.split(","):
        if key in CALIBRATED:
            views = [int(v) for v in args.views.split(",") if v]
            scenes = [v for v in args.scenes.split(",") if v]
            report.setdefault("calibrated", []).append(
                bench_calibrated(key, scenes, views, args.repeat, args.warm, args.quick,
                                 converge=not args.no_solve, compare=args.compare,
                                 metrics=[m for m in args.metrics.split(",") if m],
                                 priors=priors, constants=constants))
            summary += _check_calibrated(report["calibrated"][-1])
            continue
        if key not in ("a", "b"):
            p.error(f"unknown configuration {key!r}: a, b, {', '.join(CALIBRATED)}")
        title, op, truth = (config_a if key == "a" else config_b)(args.quick)
        # The measurement through the NumPy path, so that the first solve below is the first
        # use of the kernels in this process.
        with kernels.numpy_only() if kernels is not None else contextlib.nullcontext():
            g = op.forward(truth)
        print(f"{title}: {op.ishape} -> {op.oshape}", flush=True)
        if first is None and names:
            first = first_call("gap-tv" if "gap-tv" in names else names[0], op, g, truth,
                               args.iters)
            report["first_call"] = dict(first, config=key)
        runs = []
        if key == "a" and not args.no_reference:
            runs.append(run_reference(op, g, truth, args.iters, args.ref_repeat))
        if key == "b" and "twist" in names and not args.no_reference:
            runs.append(run_one(REFERENCE_B[0], REFERENCE_B[1], REFERENCE_B[2], op, g, truth,
                                args.iters, 1))
        for name in names:
            runs.append(run_one(name, name, dict(SETTINGS[name]), op, g, truth, args.iters,
                                args.repeat))
        ref = next((r for r in runs if r["solver"] == "plain-gap-tv"), None)
        if ref is not None:
            for r in runs:
                if r is not ref:
                    r["speedup_vs_plain"] = ref["seconds"] / r["seconds"]
                    print(f"  {r['label']:<36s} {r['speedup_vs_plain']:6.1f}x the plain NumPy "
                          f"GAP-TV", flush=True)
        report["configs"].append({"key": key, "title": title, "ishape": op.ishape,
                                  "oshape": op.oshape, "runs": runs})
        summary += _check_targets(key, runs, args)

    report["loadavg_end"] = os.getloadavg()
    report["maxrss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    report["targets"] = summary
    print(f"process peak RSS: {report['maxrss_mb']:.0f} MB; load average "
          f"{report['loadavg_start'][0]:.2f} -> {report['loadavg_end'][0]:.2f} "
          f"({report['cpus']} CPUs)")
    for line in summary:
        print(line)
    with atomic_path(args.out / "bench_recon.json") as tmp:
        tmp.write_text(json.dumps(report, indent=1))
    _plot(report, args.out / "bench_recon.png")
    print(f"wrote {args.out / 'bench_recon.json'} and {args.out / 'bench_recon.png'}")


def _check_targets(key, runs, args):
    """One line per target of the configuration (full size, 50 iterations only)."""
    t = TARGETS.get(key)
    run = next((r for r in runs if r["label"] == (t or {}).get("solver")), None)
    if t is None or run is None or args.quick or args.iters != 50:
        return []
    ok = lambda c: "met" if c else "MISSED"  # noqa: E731
    lines = [f"target ({key}) {t['solver']} <= {t['seconds']} s: {run['seconds']:.3f} s "
             f"{ok(run['seconds'] <= t['seconds'])}",
             f"target ({key}) {t['solver']} PSNR >= {t['psnr']} dB: {run['psnr']:.2f} dB "
             f"{ok(run['psnr'] >= t['psnr'])}"]
    if "ratio" in t and "speedup_vs_plain" in run:
        lines.append(f"target ({key}) {t['solver']} >= {t['ratio']:.0f}x the plain NumPy "
                     f"GAP-TV: {run['speedup_vs_plain']:.1f}x "
                     f"{ok(run['speedup_vs_plain'] >= t['ratio'])}")
    if "peak_mb" in t:
        lines.append(f"target ({key}) {t['solver']} peak memory <= {t['peak_mb']:.0f} MB: "
                     f"{run['peak_traced_mb']:.0f} MB traced "
                     f"{ok(run['peak_traced_mb'] <= t['peak_mb'])} (process RSS below)")
    return lines


def _check_calibrated(res):
    """One line per calibrated row that has a target (a cold, converged solve)."""
    lines = []
    for sc in res["scenes"]:
        for r in sc["rows"]:
            if "target_s" in r:
                ok = "met" if r["solve_s"] <= r["target_s"] else "MISSED"
                lines.append(f"target {res['design']} {sc['scene']} {r['views']} view(s) <= "
                             f"{r['target_s']:g} s: {r['solve_s']:.2f} s, {r['iters']} it, "
                             f"{r['psnr']:.2f} dB, constants {r['constants']} {ok}")
    return lines


def _plot(report, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cfgs = report["configs"]
    if not cfgs:
        return
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
