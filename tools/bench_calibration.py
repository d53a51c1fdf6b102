"""The calibration's faster steps against the paths they replace, alternated in one process.

Two steps of ``kaleidospec.calibrate`` (design ``--design``, default ``paper``), each timed
as the reference path and the current one in turn, ``--repeat`` times (medians of the wall
time and of the process's CPU time, all threads), with a check that both give the same bits:

1. **readout** of one capture: the mean electrons of a frame the sensor's size (the views'
   windows lit at 0 to 1.3 full wells, the rest dark, as a white capture) read out
   ``--repeats`` times (``sim.captures.capture``'s noisy frames): the reference is
   ``sim.sensor.digitise_reference`` repeat after repeat, the current path
   ``sim.sensor.digitise`` on a thread per core, as ``capture`` now runs them;
2. **flat-field gains** (``kaleidospec.calibrate.model_flat_gains``): the model of each band's
   white, 26 full forwards of the blurred model (reference) against one band's forward
   (``band_forward``); it needs the design's calibration in the cache (``kaleidospec
   calibrate``) and a PSF (designs whose masks are deconvolved).

With ``--whole`` it also calibrates the design from an empty temporary cache in a fresh
process (what ``kaleidospec run`` does the first time) and prints its wall and CPU time, its
peak resident memory (``ru_maxrss``) and each step's seconds and the peak after it: the
captures (``render_captures``, the line captures reduced to their profiles as they come), the
mask images' deconvolution, the homographies, the sensor's noise, the flat-field gains.

Usage: python3 tools/bench_calibration.py [--design paper] [--repeat 3] [--repeats 4]
                                          [--whole] [--json FILE]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np


def _timed(fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def alternate(name, reference, current, repeat, same):
    """Run ``reference`` and ``current`` in turn ``repeat`` times; print and return the
    medians and whether ``same(ref_out, cur_out)``."""
    walls = {"reference": [], "current": []}
    cpus = {"reference": [], "current": []}
    outs = {}
    for _ in range(repeat):
        for which, fn in (("reference", reference), ("current", current)):
            outs[which], w, c = _timed(fn)
            walls[which].append(w)
            cpus[which].append(c)
    med = {k: float(np.median(v)) for k, v in walls.items()}
    cpu = {k: float(np.median(v)) for k, v in cpus.items()}
    ok = bool(same(outs["reference"], outs["current"]))
    print(f"{name:28s} wall {med['reference']:7.2f} -> {med['current']:7.2f} s "
          f"({med['reference'] / med['current']:4.2f}x)   CPU {cpu['reference']:7.2f} -> "
          f"{cpu['current']:7.2f} s ({cpu['reference'] / cpu['current']:4.2f}x)   "
          f"{'same bits' if ok else 'OUTPUTS DIFFER'}", flush=True)
    return {"wall_s": med, "cpu_s": cpu, "same_bits": ok, "repeat": repeat}


def bench_readout(design, repeat, repeats):
    from recon.kernels import each
    from sim.sensor import digitise, digitise_reference

    h, w = int(design.sensor_height_px), int(design.sensor_width_px)
    rng = np.random.default_rng(0)
    ne = np.zeros((h, w), np.float32)
    m = max(1, min(h, w) // 16)
    ne[m:h - m, m:w - m] = rng.random((h - 2 * m, w - 2 * m), dtype=np.float32) * np.float32(
        1.3 * design.full_well_e)

    def reference():
        return [digitise_reference(ne, design, seed=100 + r) for r in range(repeats)]

    def current():
        return each(lambda r: digitise(ne, design, seed=100 + r), range(repeats))

    return alternate(f"readout ({repeats} repeats)", reference, current, repeat,
                     lambda a, b: all(np.array_equal(x, y) for x, y in zip(a, b)))


def bench_flat_gains(cal, repeat):
    from recon.calibration import operator_from_calibration

    op = operator_from_calibration(cal, model="shifted")
    ones = np.ones(op.ishape[1:], np.float32)

    def reference():
        x = np.zeros(op.ishape, np.float32)
        out = []
        for l in range(op.ishape[0]):
            x[l] = 1.0
            out.append(op.forward(x))
            x[l] = 0.0
        return out

    def current():
        return [op.band_forward(l, ones) for l in range(op.ishape[0])]

    return alternate("flat-field gains' models", reference, current, repeat,
                     lambda a, b: all(np.array_equal(x, y) for x, y in zip(a, b)))


#: The calibration's steps timed by ``--whole``: (module, function, label).
STEPS = [("kaleidospec.instrument", "render_captures", "captures"),
         ("recon.calibration.mask", "deconvolve_views", "mask images (deconvolution)"),
         ("recon.calibration", "view_homographies", "homographies and fields"),
         ("kaleidospec.calibrate", "sensor_noise", "sensor noise"),
         ("kaleidospec.calibrate", "model_flat_gains", "flat-field gains")]


def _peak_kib() -> int:
    import resource

    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


def _child(design_name: str, repeats: int) -> None:
    """In a fresh process: calibrate ``design_name`` (an empty ``KALEIDOSPEC_CACHE``) with
    every step of :data:`STEPS` timed; one JSON line on stdout."""
    import functools
    import importlib
    import json
    import resource

    from kaleidospec.calibrate import calibrate
    from sim.optics.design import get_design

    steps = []
    for mod, name, label in STEPS:
        m = importlib.import_module(mod)
        fn = getattr(m, name)

        def wrapper(*a, _fn=fn, _label=label, **kw):
            t0 = time.perf_counter()
            out = _fn(*a, **kw)
            steps.append({"step": _label, "seconds": time.perf_counter() - t0,
                          "peak_kib_after": _peak_kib()})
            return out

        setattr(m, name, functools.wraps(fn)(wrapper))
    w = time.perf_counter()
    calibrate(get_design(design_name), progress=False, repeats=repeats)
    wall = time.perf_counter() - w
    ru = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"wall_s": wall, "user_s": ru.ru_utime, "system_s": ru.ru_stime,
                      "peak_kib": int(ru.ru_maxrss), "steps": steps}))


def bench_whole(design_name: str, repeats: int) -> dict:
    """The whole calibration from an empty temporary cache in a fresh process
    (:func:`_child`); prints and returns its figures."""
    import json
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory(prefix="kaleidospec-cal-") as cache:
        env = dict(os.environ, KALEIDOSPEC_CACHE=cache)
        load0 = os.getloadavg()[0]
        done = subprocess.run([sys.executable, __file__, "--child", design_name,
                               "--repeats", str(repeats)], env=env, check=True,
                              capture_output=True, text=True)
        load1 = os.getloadavg()[0]
    got = json.loads(done.stdout.strip().splitlines()[-1])
    got["load"] = [load0, load1]
    print(f"whole calibration, empty cache, fresh process: wall {got['wall_s']:.1f} s, CPU "
          f"{got['user_s'] + got['system_s']:.1f} s (user {got['user_s']:.1f} + system "
          f"{got['system_s']:.1f}), peak RSS {got['peak_kib'] / 1e6:.2f} GB "
          f"({got['peak_kib']} KiB), load {load0:.2f} -> {load1:.2f}")
    for st in got["steps"]:
        print(f"  {st['step']:30s} {st['seconds']:7.1f} s   peak after "
              f"{st['peak_kib_after'] / 1e6:5.2f} GB")
    return got


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--design", default="paper")
    p.add_argument("--repeat", type=int, default=3, help="alternations (medians kept)")
    p.add_argument("--repeats", type=int, default=4, help="noisy frames of a capture")
    p.add_argument("--whole", action="store_true",
                   help="also the whole calibration from an empty cache, in a fresh process")
    p.add_argument("--child", help=argparse.SUPPRESS)
    p.add_argument("--json", type=Path)
    args = p.parse_args(argv)
    if args.child:
        _child(args.child, args.repeats)
        return

    from kaleidospec.instrument import cache_dir
    from recon import kernels
    from recon.calibration import load_cached
    from sim.optics.design import get_design

    design = get_design(args.design)
    report = {"design": args.design, "cpus": kernels.cores(),
              "loadavg_start": os.getloadavg()}
    print(f"{args.design}: {kernels.cores()} CPUs, load {os.getloadavg()[0]:.2f}", flush=True)
    report["readout"] = bench_readout(design, args.repeat, args.repeats)
    cal = load_cached(cache_dir(None), design.hash)
    if cal is None:
        print("no cached calibration of this design (kaleidospec calibrate first): the "
              "flat-field step is skipped")
    elif cal.psf is not None:
        report["flat_gains"] = bench_flat_gains(cal, args.repeat)
    if args.whole:
        report["whole"] = bench_whole(args.design, args.repeats)
    report["loadavg_end"] = os.getloadavg()
    print(f"load {report['loadavg_start'][0]:.2f} -> {report['loadavg_end'][0]:.2f}")
    if args.json:
        from kaleidospec.experiments import write_json

        write_json(Path(args.json), report)


if __name__ == "__main__":
    main()
