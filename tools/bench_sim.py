#!/usr/bin/env python3
"""Benchmark the simulator: transport-cache build, cache size, per-frame time, fast-path error.

For each preset: traces the transport cache (into a temporary cache folder unless
``--cache-dir``), reports its build time and size on disk, times a frame from the cache (the
per-band gather, with and without the sensor model), and compares the cached per-band
irradiance with a higher-sample direct render (relative RMS error over lit pixels and the
relative error of the total). ``--bands N`` keeps N evenly spaced bands and ``--crop`` limits
tracing/rendering to a centred window of the sensor so the ``paper`` preset runs in minutes;
the full-frame figures are then extrapolated linearly (and said so).

Targets on a 2-core machine: ``paper`` frame from the cache ≤ 2 s; cache build ≤ 15 min and
≤ 1 GB; ``small`` end to end (build + one frame) ≤ 30 s.

Usage::

    python tools/bench_sim.py --preset small
    python tools/bench_sim.py --preset paper --bands 3 --crop 400
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


def bench(preset: str, bands: int | None, crop: int | None, spp: int, direct_spp: int,
          cache_dir: str | None) -> None:
    from scenes.registry import get_scene
    from sim import transport
    from sim.design import get_design
    from sim.frame import simulate_frame
    from sim.render import render_direct

    d = get_design(preset)
    v = d.view_size_px
    wl_all = d.wavelengths
    idx = np.arange(wl_all.size)
    if bands is not None and bands < wl_all.size:
        idx = np.unique(np.round(np.linspace(0, wl_all.size - 1, bands)).astype(int))
    wl = wl_all[idx]
    Hs, Ws = d.sensor_height_px, d.sensor_width_px
    win = None
    if crop is not None:
        win = (Hs // 2 - crop // 2, Ws // 2 - crop // 2, crop, crop)
    print(f"== {preset}: sensor {Ws}×{Hs}, view {v} px, views {d.views}, "
          f"{wl.size}/{wl_all.size} bands, spp {spp}, crop {win}")
    t0 = time.perf_counter()
    cube_all, _ = get_scene("colorchecker", shape=(v, v), wavelengths=wl_all)
    cube = np.ascontiguousarray(cube_all[:, :, idx])
    print(f"scene: {time.perf_counter() - t0:.2f} s")
    tmp = None
    if cache_dir is None:
        tmp = tempfile.TemporaryDirectory()
        cache_dir = tmp.name
    os.environ["KALEIDOSPEC_CACHE"] = cache_dir
    transport._MEMO.clear()
    t0 = time.perf_counter()
    tr = transport.load_or_build(d, (v, v), wl, spp=spp, crop=win, progress=False)
    t_build = time.perf_counter() - t0
    size = tr.path.stat().st_size if tr.path is not None else 0
    npix = transport.sensor_pixels(d).size
    npix_c = transport.sensor_pixels(d, crop=win).size
    frac = npix / max(npix_c, 1) * wl_all.size / wl.size
    print(f"cache build: {t_build:.1f} s ({npix_c * wl.size * spp / t_build / 1e6:.2f} M samples/s)"
          f", {size / 2**20:.1f} MiB on disk, {tr.nbytes() / 2**20:.1f} MiB in memory")
    if frac > 1.001:
        print(f"  extrapolated to all bands and the used views: build ≈ {t_build * frac / 60:.1f} "
              f"min, ≈ {size * frac / 2**30:.2f} GiB on disk")
    # Per-frame time from the cache (gather only, then with the sensor model).
    tr.apply(cube)
    reps = 3
    t0 = time.perf_counter()
    for _ in range(reps):
        irr = tr.apply(cube)
    t_gather = (time.perf_counter() - t0) / reps
    print(f"frame from cache (gather, {wl.size} bands): {t_gather * 1e3:.0f} ms"
          + (f"; extrapolated to the full frame ≈ {t_gather * frac:.2f} s" if frac > 1.001 else ""))
    if win is None:
        t0 = time.perf_counter()
        simulate_frame(d, cube, wl, spp=spp, seed=1)
        t_frame = time.perf_counter() - t0
        print(f"frame incl. sensor (Airy blur per band, noise, ADC): {t_frame:.2f} s")
        print(f"end to end (build + one frame): {t_build + t_frame:.1f} s")
    # Error against a higher-sample direct render of the same bands and window.
    t0 = time.perf_counter()
    ref = render_direct(d, cube, wl, spp=direct_spp, seed=11, crop=win, progress=False)
    t_direct = time.perf_counter() - t0
    lit = ref > 0
    err = irr[lit] - ref[lit]
    rel_rms = float(np.sqrt(np.mean(err ** 2)) / np.sqrt(np.mean(ref[lit] ** 2)))
    rel_tot = float(irr.sum() / ref.sum() - 1)
    # 8×8 block sums average the per-pixel Monte Carlo noise away and expose any bias.
    L, H, W = ref.shape
    hb, wb = H // 8 * 8, W // 8 * 8
    bi = irr[:, :hb, :wb].reshape(L, hb // 8, 8, wb // 8, 8).sum(axis=(2, 4))
    br = ref[:, :hb, :wb].reshape(L, hb // 8, 8, wb // 8, 8).sum(axis=(2, 4))
    m = br > 0.5 * br.max()
    rel_blk = float(np.sqrt(np.mean((bi[m] - br[m]) ** 2)) / np.sqrt(np.mean(br[m] ** 2)))
    print(f"direct render ({direct_spp} spp): {t_direct:.1f} s; cache vs direct: relative RMS "
          f"{rel_rms:.3f} per pixel (Monte Carlo noise of {spp} vs {direct_spp} spp at mask-cell "
          f"edges), {rel_blk:.4f} over 8×8 blocks, total {rel_tot:+.4f}")
    if tmp is not None:
        tmp.cleanup()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", choices=["small", "paper", "both"], default="both")
    ap.add_argument("--bands", type=int, default=None, help="use N evenly spaced bands")
    ap.add_argument("--crop", type=int, default=None, help="centred square window (px)")
    ap.add_argument("--spp", type=int, default=4, help="transport samples per pixel")
    ap.add_argument("--direct-spp", type=int, default=32, help="reference samples per pixel")
    ap.add_argument("--cache-dir", default=None, help="keep the cache here (default: temp)")
    a = ap.parse_args()
    presets = ["small", "paper"] if a.preset == "both" else [a.preset]
    for p in presets:
        bands, crop = a.bands, a.crop
        if p == "paper" and a.preset == "both" and bands is None and crop is None:
            bands, crop = 3, 400  # keep the default run to minutes
        bench(p, bands, crop, a.spp, a.direct_spp, a.cache_dir)


if __name__ == "__main__":
    main()
