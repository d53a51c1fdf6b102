#!/usr/bin/env python3
"""How good and how fast is the simulated instrument? The converged transport against a
converged reference, for `small` and `paper`.

For each preset, from an empty cache folder:

- **build**: the optical maps' trace (Mitsuba), its size on disk, and the time to load it
  (the throughput images are computed on load);
- **frame**: the expected frame of a scene at the view grid (1×) and at twice it (2×, the
  scenes' default), steady state (best of three, alternating), the pixel integrals alone
  (every band of a view in one pass, as frames take them, and band by band, as the exact
  operator does) and with the sensor model (Airy blur, photo-electrons), and the exact
  operator's forward and adjoint on the same maps (one solver iteration of an "oracle"
  reconstruction); the frame again on one core, split into its views' pixel integrals and
  blurs (:func:`frame_parts`), and how much vector arithmetic the machine's second core adds
  (:func:`core_scaling`: a 2-core target means little on two hyperthreads);
- **convergence**: in windows of the centre view and of the left view's vignetted outer
  columns, the frame's mean photo-electrons at the default exposure (brightest pixel at 80 %
  of the full well) against Mitsuba's path tracer (``kaleidospec_path``, stratified) at a
  series of sample counts, two independent seeds each.  The squared bias of the transport is
  estimated without the references' own noise as mean((c − a)(c − b)) over the window (a, b
  the two renders); a series shows it settle while the renders' noise falls as 1/√spp.  The
  target is a per-pixel error at most half the sensor's noise σ = √(N̄e + σ_read²).  The Monte
  Carlo transport with 4 i.i.d. rays per pixel and band (:mod:`sim.sampled`) is scored the
  same way, for scale.
- ``--spawn``: how far one sensor point's aperture rays spread on the mask and the diffuser
  when Mitsuba's ``spawn_ray`` continues them, against :func:`sim.rays.continue_ray`.

Targets (2 cores): error ≤ σ/2 for both presets; build ≤ 60 s (`small`) and ≤ 20 min
(`paper`); the `paper` cache ≤ 2 GB; a `paper` frame ≤ 1 s.

Usage::

    python3 tools/bench_transport.py                     # both presets (~10 min)
    python3 tools/bench_transport.py --preset small --spp 256,1024,4096
    python3 tools/bench_transport.py --preset paper --frames-only   # build, frames, operator
    python3 tools/bench_transport.py --spawn
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def best_of(fn, n=3):
    out, best = None, np.inf
    for _ in range(n):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def core_scaling(seconds: float = 0.5) -> float:
    """How much vector arithmetic two threads do together, as a multiple of one thread's.

    A fused multiply-add stream over an array that stays in L1 (no memory traffic): 2.0 on two
    physical cores, about 1 where the two "cores" are hyperthreads of one (they share its
    vector units).  Much of a frame is such arithmetic, so this says what a 2-core wall time
    means on the machine at hand."""
    from concurrent.futures import ThreadPoolExecutor

    from numba import njit

    @njit(nogil=True, fastmath=True)
    def fma_stream(a, reps):
        for _ in range(reps):
            for i in range(a.shape[0]):
                a[i] = a[i] * 0.999999 + 1e-7
        return a[0]

    arrays = [np.random.default_rng(i).random(2048) for i in range(2)]
    fma_stream(arrays[0], 1)
    t0 = time.perf_counter()
    fma_stream(arrays[0], 1000)
    reps = max(1000, int(1000 * seconds / max(time.perf_counter() - t0, 1e-6)))
    ratios = []
    with ThreadPoolExecutor(2) as pool:
        for _ in range(3):
            t0 = time.perf_counter()
            fma_stream(arrays[0], reps)
            one = time.perf_counter() - t0
            t0 = time.perf_counter()
            list(pool.map(lambda a: fma_stream(a, reps), arrays))
            ratios.append(2.0 * one / (time.perf_counter() - t0))
    return float(np.median(ratios))


def on_one_core(fn):
    """``fn()`` with this process (and the threads it starts) held to one CPU; ``None`` where
    the platform cannot pin.  The frame's thread pools size themselves by the CPUs the process
    may use (:func:`recon.kernels.cores`), so this times one thread doing all the work."""
    cpus = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else set()
    if len(cpus) < 2:
        return None
    os.sched_setaffinity(0, {min(cpus)})
    try:
        return fn()
    finally:
        os.sched_setaffinity(0, cpus)


def frame_parts(model, cube):
    """One core's time for a frame's parts: each view's pixel integrals (every band in one
    pass, into the zero-padded images the blurs transform) and each view's blur (its bands'
    transforms, products and one inverse), best of three, with the process held to one CPU
    (:func:`on_one_core`); ``None`` where the platform cannot pin.  What a frame takes
    beyond their sum: the scene's check, the views added to the sensor, the threads'
    hand-overs, and the caches a blur evicts between blocks of rows."""
    tr = model.transport
    # The bands a frame integrates: the lit ones (FrameModel.electrons).
    lit = [int(l) for l in np.flatnonzero(cube.max(axis=(0, 1)) > 0)]
    f = np.ascontiguousarray(cube[:, :, lit], np.float32)
    tr.prepare(lit, f.shape[1])

    def parts():
        integrals, blurs = [], []
        for k in range(len(tr.views)):
            h, w = int(tr.maps.rects[k][2]), int(tr.maps.rects[k][3])
            shape = model.blur.shape(h, w, lit)
            buf = np.zeros((len(lit),) + shape, np.float32)
            model.blur.prepare(lit, shape)
            integrals.append(best_of(lambda: tr.view_bands(f, k, lit, out=buf))[1])
            blurs.append(best_of(lambda: model.blur(buf, lit, size=(h, w)))[1])
        return integrals, blurs

    return on_one_core(parts)


def windows(d, size):
    """A window in the centre view and one on the left view's outer (vignetted) columns."""
    r0, c0, h, w = d.view_rect(0)
    centre = (r0 + h // 2 - size // 2, c0 + w // 2 - size // 2, size, size)
    r0, c0, h, w = d.view_rect(1)
    guard = d.view_rect(1)[3] - d.code_region_px(1)[3]
    left = (r0 + h // 2 - size // 2, c0 + guard // 2, size, size)
    return {"centre": centre, "left edge": left}


def electrons(design, irr, wl):
    """Mean photo-electrons (window) of per-band irradiance (L, h, w), Airy blur included
    (inside the window: the window is padded by the blur's reach before, cut after)."""
    from sim.sensor import mean_electrons

    # The running integrals leave round-off of ~1e-12 of the peak, either sign.
    irr = np.maximum(irr, 0.0)
    return mean_electrons(np.moveaxis(irr, 0, 2), design, wl, diffraction=True).astype(np.float64)


def convergence(d, tr, cube, wl, win, counts, pad):
    """The transport's bias per pixel (electrons at the default exposure) against direct
    renders of the padded window at each count, and the renders' own noise."""
    from sim import sampled
    from sim.render import render_direct

    r0, c0, h, w = win
    big = (r0 - pad, c0 - pad, h + 2 * pad, w + 2 * pad)
    s = np.s_[:, big[0]:big[0] + big[2], big[1]:big[1] + big[3]]
    inner = np.s_[pad:pad + h, pad:pad + w]
    c = electrons(d, tr.apply(cube)[s], wl)
    full = electrons(d, tr.apply(cube), wl)
    scale = 0.8 * d.full_well_e / float(full.max())          # the default exposure
    c = c[inner] * scale
    sigma = np.sqrt(np.mean(c + d.read_noise_e ** 2))
    rows = []
    for n in counts:
        t0 = time.perf_counter()
        a, b = (electrons(d, render_direct(d, cube, wl, spp=n, seed=seed, windows=[big],
                                           sampler="stratified", progress=False)[s], wl)[inner]
                * scale for seed in (101, 202))
        t = time.perf_counter() - t0
        bias2 = float(np.mean((c - a) * (c - b)))
        noise = float(np.sqrt(np.mean((a - b) ** 2) / 2))
        rows.append((n, bias2, noise, t))
    # The old product: 4 i.i.d. rays per pixel and band.
    mc = sampled.build_transport(d, cube.shape[:2], wl, spp=4, seed=7, crop=big)
    m = electrons(d, mc.apply(cube)[s], wl)[inner] * scale
    a_last, b_last = a, b
    mc_bias2 = float(np.mean((m - a_last) * (m - b_last)))
    return sigma, float(np.mean(c)), rows, mc_bias2


def bench(preset, counts, size, cache, frames_only=False):
    from scenes.registry import get_scene
    from sim import transport
    from sim.design import get_design
    from sim.frame import FrameModel

    d = get_design(preset)
    v = d.view_size_px
    wl = d.wavelengths
    print(f"== {preset}: sensor {d.sensor_width_px}x{d.sensor_height_px}, views "
          f"{list(d.views)} of {v} px, {wl.size} bands", flush=True)
    os.environ["KALEIDOSPEC_CACHE"] = cache
    transport._MEMO.clear()
    t0 = time.perf_counter()
    tr = transport.load_or_build(d, wl, seed=transport.SEEDS["scene"])
    t_build = time.perf_counter() - t0
    size_mb = tr.path.stat().st_size / 2**20
    print(f"build: {t_build:.1f} s ({tr.maps.nodes_nm.size} wavelength nodes, "
          f"{len(tr.views)} views); on disk {size_mb:.2f} MiB")
    transport._MEMO.clear()
    t0 = time.perf_counter()
    tr = transport.load_or_build(d, wl, seed=transport.SEEDS["scene"])
    tr.prepare(range(wl.size), v)
    print(f"load (incl. throughput images): {time.perf_counter() - t0:.1f} s; in memory "
          f"{tr.nbytes() / 2**20:.0f} MiB")
    model = FrameModel(d, wl, trace_seed=transport.SEEDS["scene"])
    print(f"this machine: two threads do {core_scaling():.2f}x the vector arithmetic of one "
          f"(2 on two physical cores, ~1 on two hyperthreads of one)")
    views = range(len(tr.views))
    for scale in (1, 2):
        cube, _ = get_scene("natural", (scale * v, scale * v), wl)
        f = np.ascontiguousarray(cube, np.float32)
        lhw = np.ascontiguousarray(np.moveaxis(f, 2, 0))

        def all_bands():
            out = None
            for k in views:
                out = tr.view_bands(f, k, out=out)

        def band_by_band():
            transport.each(lambda l: [tr.view_band(lhw[l], k, l) for k in views],
                           range(wl.size))

        # The three alternate, so a slower spell of the machine touches all of them.
        best = {}
        for fn in (all_bands, band_by_band, lambda: model.electrons(cube)):
            fn()
        for _ in range(3):
            for name, fn in (("all", all_bands), ("band", band_by_band),
                             ("frame", lambda: model.electrons(cube))):
                t0 = time.perf_counter()
                fn()
                best[name] = min(best.get(name, np.inf), time.perf_counter() - t0)
        print(f"frame {scale}x ({scale * v} px scene): pixel integrals {best['all']:.2f} s "
              f"(every band of a view at once; band by band {best['band']:.2f} s, "
              f"{best['band'] / best['all']:.2f}x), with the sensor model {best['frame']:.2f} s")
        one = on_one_core(lambda: best_of(lambda: model.electrons(cube))[1])
        if one is not None:
            print(f"  the same frame on one core: {one:.2f} s (the second core gives "
                  f"{one / best['frame']:.2f}x)")
            integrals, blurs = frame_parts(model, cube)
            print(f"  its parts on one core: pixel integrals {sum(integrals):.2f} s (views "
                  f"{' / '.join(f'{t:.3f}' for t in integrals)}), blurs {sum(blurs):.2f} s, "
                  f"the rest {one - sum(integrals) - sum(blurs):.2f} s")
    # The exact operator (the "oracle" reconstructions) on the same maps: one application each
    # way is one solver iteration's optics.
    from sim.oracle import ExactOperator

    op = ExactOperator(d, tr, list(d.views))
    x = get_scene("natural", (v, v), wl)[0].transpose(2, 0, 1).copy()
    y = op.forward(x)
    op.adjoint(y)
    _, t_fwd = best_of(lambda: op.forward(x))
    _, t_adj = best_of(lambda: op.adjoint(y))
    print(f"exact operator ({len(d.views)} views, cube on the view grid): forward {t_fwd:.2f} s, "
          f"adjoint {t_adj:.2f} s")
    if frames_only:
        return
    cube, _ = get_scene("natural", (2 * v, 2 * v), wl)
    pad = 8
    print(f"convergence against Mitsuba's path tracer (stratified; electrons at the default "
          f"exposure; {size}x{size} px windows, natural scene at 2x)")
    for name, win in windows(d, size).items():
        sigma, mean, rows, mc_bias2 = convergence(d, tr, cube, wl, win, counts, pad)
        print(f"  {name} window: mean {mean:.0f} e-, sensor noise sigma {sigma:.1f} e-")
        for n, bias2, noise, t in rows:
            bias = np.sign(bias2) * np.sqrt(abs(bias2))
            print(f"    direct {n:>5} spp: renders' noise {noise:7.1f} e-; transport bias "
                  f"{bias:+7.1f} e- = {bias / sigma:+.3f} sigma ({t:.0f} s)")
        print(f"    4-ray Monte Carlo transport: bias {np.sqrt(max(mc_bias2, 0)):.1f} e- = "
              f"{np.sqrt(max(mc_bias2, 0)) / sigma:.2f} sigma")


def spawn():
    """Aperture rays of one sensor point: their spread on the mask and the diffuser."""
    import drjit as dr

    from sim.design import get_design
    from sim.maps import diffuser_coordinates, mask_coordinates
    from sim.rays import sensor_rays, walk
    from sim.scene import trace_setup

    print("one sensor point (the left view's centre), 256 aperture rays at 575 nm: spread (px)")
    for preset in ("small", "paper"):
        d = get_design(preset)
        setup = trace_setup(d, open_mask=True)
        r0, c0, h, w = d.view_rect(1)
        n = 256
        ap = np.random.default_rng(1).random((2, n))
        rows = np.full(n, r0 + h / 2)
        cols = np.full(n, c0 + w / 2)
        ours = walk(setup, sensor_rays(setup, rows, cols, ap, 575.0))
        # Mitsuba's own continuation: the same walk with spawn_ray.
        mi = setup.mi
        ray = sensor_rays(setup, rows, cols, ap, 575.0)
        mx, dx = mi.Float(np.nan), mi.Float(np.nan)
        ctx, active = mi.BSDFContext(), mi.Bool(True)
        for _ in range(24):
            si = setup.scene.ray_intersect(ray, active)
            active &= si.is_valid()
            at_d = active & (dr.abs(si.p.z) < 1e-3) & (ray.d.z < 0)
            dx = dr.select(at_d, si.p.x, dx)
            active &= ~at_d
            mx = dr.select(active & (dr.abs(si.p.z - setup.z["mask"]) < 1e-3), si.p.x, mx)
            bs, wgt = si.bsdf(ray).sample(ctx, si, 0.5, mi.Point2f(0.5, 0.5), active)
            active &= dr.any(wgt > 0)
            ray = dr.select(active, si.spawn_ray(si.to_world(bs.wo)), ray)
        zeros = np.zeros(n)
        m_sp = mask_coordinates(d, np.stack([np.asarray(mx), zeros]))[0] * d.mask_cell_px
        u_sp = diffuser_coordinates(d, np.stack([np.asarray(dx), zeros]))[0] * d.view_size_px
        m_ok = mask_coordinates(d, ours.mask)[0] * d.mask_cell_px
        u_ok = diffuser_coordinates(d, ours.diffuser)[0] * d.view_size_px
        print(f"  {preset}: spawn_ray mask {np.nanmax(m_sp) - np.nanmin(m_sp):.3f}, diffuser "
              f"{np.nanmax(u_sp) - np.nanmin(u_sp):.3f}; continue_ray mask "
              f"{np.ptp(m_ok):.4f}, diffuser {np.ptp(u_ok):.4f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", choices=["small", "paper", "both"], default="both")
    ap.add_argument("--spp", default=None, help="direct-render sample counts, comma-separated "
                    "(default 256,1024,4096 for small, 256,1024 for paper)")
    ap.add_argument("--window", type=int, default=24, help="window side (px)")
    ap.add_argument("--cache-dir", default=None, help="keep the traces here (default: temp)")
    ap.add_argument("--spawn", action="store_true", help="only the spawn_ray measurement")
    ap.add_argument("--frames-only", action="store_true",
                    help="build, load and frame times only (no convergence series)")
    a = ap.parse_args()
    if a.spawn:
        spawn()
        return
    presets = ["small", "paper"] if a.preset == "both" else [a.preset]
    with tempfile.TemporaryDirectory(prefix="kaleidospec-bench-") as tmp:
        for p in presets:
            counts = ([int(x) for x in a.spp.split(",")] if a.spp else
                      [256, 1024, 4096] if p == "small" else [256, 1024])
            bench(p, counts, a.window, a.cache_dir or tmp, a.frames_only)


if __name__ == "__main__":
    main()
