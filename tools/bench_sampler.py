#!/usr/bin/env python3
"""How close is a frame from the transport cache to the converged one, per sampler?

Traces a window of the `small` design's centre view (64 x 64 px, all 11 bands) with ``spp``
samples per pixel and band, i.i.d. (``independent``, the default) or randomised quasi-Monte
Carlo (``sobol``, :func:`sim.transport.pixel_samples`), and prints for the natural scene and the
ColorChecker the relative L2 error of the frame against a reference traced with 512 Sobol
samples and another seed:

- per band and pixel (what a band's mask image or a monochromatic capture sees);
- per pixel of the sum over bands (what a raw frame sees);

and the trace time. Lower is better; the two samplers cost the same per sample.

Usage: python3 tools/bench_sampler.py [--spp 4,16,64] [--reference 512] [--plot PNG]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", default="4,16,64", help="sample counts, comma-separated")
    ap.add_argument("--reference", type=int, default=512, help="samples of the reference")
    ap.add_argument("--plot", default=None, help="save error against samples as this PNG")
    a = ap.parse_args()
    counts = [int(s) for s in a.spp.split(",")]
    with tempfile.TemporaryDirectory(prefix="kaleidospec-sampler-") as cache:
        os.environ["KALEIDOSPEC_CACHE"] = cache
        rows = run(counts, a.reference)
    if a.plot:
        plot(rows, a.plot)


def run(counts, reference):
    from scenes.registry import get_scene
    from sim.design import get_design
    from sim.transport import SAMPLERS, load_or_build

    d = get_design("small")
    v = d.view_size_px
    r0, c0 = d.view_rect(0)[:2]
    crop = (r0 + 20, c0 + 30, 64, 64)
    win = np.s_[:, crop[0]:crop[0] + crop[2], crop[1]:crop[1] + crop[3]]
    print(f"`small`, centre-view window {crop[2]}x{crop[3]} px, {d.wavelengths.size} bands; "
          f"reference: {reference} Sobol samples, another seed")
    print(f"{'scene':<14}{'spp':>5}{'sampler':>13}{'per band':>10}{'raw frame':>11}"
          f"{'trace s':>9}")
    # The transport does not depend on the scene: trace each configuration once.
    traced = {}
    for spp, sampler, seed in [(reference, "sobol", 99)] + [(s, m, 0) for s in counts
                                                            for m in SAMPLERS]:
        t0 = time.perf_counter()
        tr = load_or_build(d, (v, v), d.wavelengths, spp=spp, sampler=sampler, seed=seed,
                           crop=crop, use_disk=False)
        traced[spp, sampler, seed] = (tr, time.perf_counter() - t0)
    rows = []
    for name in ("natural", "colorchecker"):
        cube, _ = get_scene(name, shape=(v, v), wavelengths=d.wavelengths)
        ref = traced[reference, "sobol", 99][0].apply(cube)[win].astype(np.float64)
        for spp in counts:
            for sampler in SAMPLERS:
                tr, secs = traced[spp, sampler, 0]
                e = tr.apply(cube)[win].astype(np.float64)
                band = np.linalg.norm(e - ref) / np.linalg.norm(ref)
                raw = np.linalg.norm(e.sum(0) - ref.sum(0)) / np.linalg.norm(ref.sum(0))
                rows.append((name, spp, sampler, band, raw))
                print(f"{name:<14}{spp:>5}{sampler:>13}{band:>10.4f}{raw:>11.4f}{secs:>9.2f}",
                      flush=True)
    return rows


def plot(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from recon.io.atomic import atomic_path

    fig, ax = plt.subplots(figsize=(6, 4))
    for name, style in (("natural", "-"), ("colorchecker", "--")):
        for sampler, colour in (("independent", "C0"), ("sobol", "C1")):
            pts = [(s, b) for n, s, smp, b, _ in rows if n == name and smp == sampler]
            if pts:
                s, b = zip(*pts)
                ax.loglog(s, b, style, color=colour, marker="o", label=f"{name}, {sampler}")
    ax.set_xlabel("samples per pixel and band")
    ax.set_ylabel("relative L2 error per band and pixel")
    ax.set_title("transport cache against its converged frame")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110)
    plt.close(fig)
    print(f"saved {path}")


if __name__ == "__main__":
    main()
