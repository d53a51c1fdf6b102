"""Time and memory of every step of ``kaleidospec run --design paper --views 1,5 --no-oracle``
(without writing the report): the captures, each calibration step, the scene frame and one
reconstruction per view count.

After each step it prints the step's seconds, the process's resident memory then (RSS) and its
peak so far (``ru_maxrss``), so that the step that raises the peak is the first whose peak
exceeds the previous line's.  Run it from an empty cache (the default: a fresh temporary
folder as ``KALEIDOSPEC_CACHE``) to include the transports' build.

Usage: python3 tools/bench_pipeline_memory.py [--design paper] [--views 1,5] [--iters 100]
                                               [--cache DIR]
"""

from __future__ import annotations

import argparse
import functools
import os
import resource
import tempfile
import time


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


T0 = time.perf_counter()


def report(step: str, seconds: float) -> None:
    print(f"{step:<34s} {seconds:7.1f} s   RSS {_rss_mb():7.0f} MB   peak {_peak_mb():7.0f} MB"
          f"   (at {time.perf_counter() - T0:6.1f} s)", flush=True)


def timed(module, name: str, label: str | None = None) -> None:
    """Replace ``module.name`` by a wrapper that reports each call."""
    fn = getattr(module, name)

    @functools.wraps(fn)
    def wrapper(*args, **kw):
        t0 = time.perf_counter()
        out = fn(*args, **kw)
        report(label or name, time.perf_counter() - t0)
        return out

    setattr(module, name, wrapper)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--design", default="paper")
    p.add_argument("--views", default="1,5")
    p.add_argument("--iters", type=int, default=100)
    p.add_argument("--cache", default=None, help="cache folder (default: a fresh one)")
    args = p.parse_args()
    cache = args.cache or tempfile.mkdtemp(prefix="kaleidospec-mem-")
    os.environ["KALEIDOSPEC_CACHE"] = cache

    import kaleidospec.instrument as inst
    import recon.calibration as rc
    import recon.calibration.dispersion as rcd
    import recon.calibration.mask as rcm
    from kaleidospec.calibrate import calibrate
    from kaleidospec.reconstruct import reconstruct_views
    from kaleidospec.run import parse_views

    for mod, name in [(inst, "render_captures"), (rc, "find_view_boxes"),
                      (rcd, "profile_centroids"), (rcm, "deconvolve_views"),
                      (rc, "view_homographies"),
                      (rc, "build_calibration")]:
        timed(mod, name)
    report("start", 0.0)
    counts = parse_views(args.views)
    design = inst.design_for_views(inst.get_design(args.design), max(counts))
    t0 = time.perf_counter()
    cal = calibrate(design, cache_dir=cache, progress=True)
    report("calibration (all)", time.perf_counter() - t0)
    t0 = time.perf_counter()
    frame, meta, truth, wl = inst.render_scene("colorchecker", design, seed=0)
    report("scene frame", time.perf_counter() - t0)
    for n in counts:
        t0 = time.perf_counter()
        reconstruct_views(frame, meta, cal, n, iters=args.iters, progress=True)
        report(f"reconstruct {n} view(s), {args.iters} it", time.perf_counter() - t0)
    print(f"cache: {cache}")


if __name__ == "__main__":
    main()
