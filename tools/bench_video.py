#!/usr/bin/env python3
"""Benchmark of the video engine (issue 5) on the ``small`` design, 5 views.

Prints
1. rendering speed from the transport cache (frames/s: scene + gather + sensor, and with the
   EXR writes), the one-time transport load excluded (reported apart);
2. reconstruction speed and quality: every frame cold-started with 50 iterations (the
   reference) against the warm-started chain (``--iters`` per frame); per-frame PSNR gap and
   frames/s, serial and with the segment engine on all cores;
3. the colour wheel's sector CIEDE2000 for 1, 2, 3 and 5 views, next to the paper's
   21 / 19 / 18 / 10 (red sector against a spectroradiometer, paper Sec. 5).

With ``--priors`` it prints only the comparison of priors across frames instead: for each scene
and prior, ``kaleidospec video`` (:func:`kaleidospec.video.run_video`, one worker) frame by frame
(``--segment 1``, cold, and cold with as many iterations as the chain accumulates), as the
warm-started chain, and as the chain plus each temporal weight; mean PSNR / SSIM / SAM over the
frames and the mean solve time of frames 1..N-1 (docs/priors.md, "Video").

Targets: render ≥ 5 frames/s; reconstruct ≥ 1 frame/s warm, within 0.5 dB of cold × 50.

    python3 tools/bench_video.py [--frames 12] [--iters 15] [--design small]
    python3 tools/bench_video.py --priors tv,subspace-tv --frames 6 [--temporal 0.01,0.05]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

PAPER_DE = {1: 21, 2: 19, 3: 18, 5: 10}


def prior_modes(frames: int, iters: int, cold_iters: int, temporal) -> list[tuple[str, dict]]:
    """The ways of solving a sequence that ``--priors`` compares: ``(label, run_video keywords)``.

    Frame by frame (one-frame segments: every frame cold, no temporal term), frame by frame with
    the iterations the chain has run by its last frame (``cold_iters + (frames - 1) * iters``:
    a chain's gain is then not only more iterations), the warm-started chain (one segment) and
    the chain with each temporal weight.
    """
    long_iters = cold_iters + (frames - 1) * iters
    modes = [("frame by frame", {"segment_frames": 1}),
             (f"frame by frame x{long_iters}", {"segment_frames": 1, "cold_iters": long_iters}),
             ("chain", {})]
    modes += [(f"chain + temporal {mu:g}", {"temporal": float(mu)}) for mu in temporal]
    return modes


def frame_summary(frames: list[dict]) -> tuple[float, float, float, float]:
    """(mean PSNR, mean SSIM, mean SAM over all frames, mean solve seconds of frames 1..N-1)
    from ``metrics.json``'s per-frame records (frame 0 is a cold solve in every mode)."""
    frames = sorted(frames, key=lambda m: m["frame"])
    if len(frames) < 2:
        raise ValueError("the comparison needs at least two frames")
    mean = lambda key, rows: float(np.mean([m[key] for m in rows]))  # noqa: E731
    return (mean("psnr", frames), mean("ssim", frames), mean("sam_deg", frames),
            mean("solve_seconds", frames[1:]))


def compare_priors(args, priors: list[str], temporal: list[float]) -> None:
    """Print, per scene, one row per mode and one column per prior (see the module notes)."""
    import json
    import shutil

    from kaleidospec.video import run_video

    tmp = Path(tempfile.mkdtemp(prefix="bench_video_priors_"))
    modes = prior_modes(args.frames, args.iters, args.cold_iters, temporal)
    try:
        for scene in args.scenes.split(","):
            print(f"\n[priors] {scene}: {args.frames} frames, design {args.design}, 5 views, "
                  f"{args.operator} operator; "
                  "PSNR dB / SSIM / SAM deg / solve s per frame (frames 1..N-1)")
            print(f"{'':<28}" + "".join(f"{p:>34}" for p in priors))
            for label, kw in modes:
                cells = []
                for p in priors:
                    out = tmp / f"{scene}_{p}_{len(cells)}_{label.replace(' ', '_')}"
                    opts = {"iters": args.iters, "cold_iters": args.cold_iters, **kw}
                    run_video(scene, out, design=args.design, frames=args.frames, views=5,
                              prior=p, workers=1, operator=args.operator, progress=False,
                              **opts)
                    rec = json.loads((out / "metrics.json").read_text())["frames"]
                    ps, ss, sam, sec = frame_summary(rec)
                    cells.append(f"{ps:.2f} / {ss:.3f} / {sam:.1f} / {sec:.2f} s")
                    shutil.rmtree(out, ignore_errors=True)
                print(f"{label:<28}" + "".join(f"{c:>34}" for c in cells), flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", default="small")
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--iters", type=int, default=15, help="iterations of a warm-started frame")
    ap.add_argument("--cold-iters", type=int, default=50)
    ap.add_argument("--speed", type=float, default=36.0, help="wheel speed, deg/s")
    ap.add_argument("--views", default="1,2,3,5", help="view counts of the CIEDE2000 sweep")
    ap.add_argument("--sweep-frames", type=int, default=4)
    ap.add_argument("--skip-parallel", action="store_true")
    ap.add_argument("--operator", choices=("calibrated", "oracle"), default="calibrated",
                    help="reconstruct with the calibration or the design's exact operator")
    ap.add_argument("--priors", default=None,
                    help="comma-separated prior names: print only the comparison of priors "
                         "across frames (frame by frame, chain, chain + temporal term)")
    ap.add_argument("--scenes", default="colorwheel,moving_object",
                    help="scenes of the --priors comparison")
    ap.add_argument("--temporal", default="0.01,0.05",
                    help="temporal weights of the --priors comparison")
    args = ap.parse_args(argv)
    if args.priors is not None:
        from recon.errors import InputError
        from recon.priors import check_prior_name

        try:
            priors = [check_prior_name(p.strip()) for p in args.priors.split(",")]
        except InputError as e:
            ap.error(str(e))
        try:
            temporal = [float(mu) for mu in args.temporal.split(",") if mu.strip()]
        except ValueError:
            ap.error(f"--temporal must be comma-separated numbers, got {args.temporal!r}")
        if args.frames < 2 or any(not mu > 0 for mu in temporal):
            ap.error("--priors needs --frames >= 2 and temporal weights > 0")
        compare_priors(args, priors, temporal)
        return 0

    from kaleidospec.calibrate import calibrate, calibration_file
    from kaleidospec.evaluate import frame_metrics
    from kaleidospec.instrument import FrameRenderer
    from kaleidospec.reconstruct import Reconstructor
    from kaleidospec.video import VideoLayout, reconstruct_sequence, render_sequence
    from recon.kernels import cores
    from recon.metrics import psnr
    from scenes.animated import RotatingColorwheel
    from sim.optics.design import get_design
    from sim.frame import ground_truth, simulate_frame  # noqa: F401  (imports counted once)

    d = get_design(args.design)
    v = d.view_size_px
    n = args.frames
    anim = RotatingColorwheel((v, v), d.wavelengths, n_frames=n, fps=10.0,
                              exposure_ms=d.exposure_ms, speed_deg_s=args.speed)
    print(f"design {args.design} ({d.hash}): sensor {d.sensor_width_px}x{d.sensor_height_px}, "
          f"views {v} px, {d.n_bands} bands; colour wheel at {args.speed:g} deg/s, 10 fps, "
          f"{n} frames; {cores()} cores")

    # ---- 1. rendering ------------------------------------------------------------------------
    t = time.perf_counter()
    r = FrameRenderer(d, (v, v), d.wavelengths, progress=True)
    t_load = time.perf_counter() - t
    s = r.exposure_for(anim.frame(0))
    t = time.perf_counter()
    for i in range(n):
        r.render(anim.frame(i), radiance_scale=s, seed=[0, i])
    t_mem = time.perf_counter() - t
    cubes = [anim.frame(i) for i in range(n)]
    t = time.perf_counter()
    for i in range(n):
        r.render(cubes[i], radiance_scale=s, seed=[0, i])
    t_gather = time.perf_counter() - t
    tmp = Path(tempfile.mkdtemp(prefix="bench_video_"))
    st = render_sequence(anim, d, tmp, radiance_scale=s, renderer=r, progress=False)
    t_files = st["seconds"] + st["write_seconds"]
    print("\n[render] transport load (once per design): "
          f"{t_load:.2f} s")
    print(f"[render] gather + sensor only:          {n / t_gather:6.1f} frames/s")
    print(f"[render] + building the scene frame:    {n / t_mem:6.1f} frames/s   (target >= 5)")
    print(f"[render] + writing raw EXR/sidecar/truth: {n / t_files:6.1f} frames/s")

    # ---- 2. reconstruction -------------------------------------------------------------------
    t = time.perf_counter()
    cal = calibrate(d, progress=True)
    print(f"\n[reconstruct] operator: {args.operator}")
    print(f"[reconstruct] calibration (cached after the first run): {time.perf_counter() - t:.1f} s")
    from recon.io.cubes import read_cube
    from recon.io.raw import read_raw

    lay = VideoLayout(tmp)

    def make(nv):
        if args.operator == "oracle":
            return Reconstructor.oracle(d, nv)
        return Reconstructor.calibrated(cal, nv)
    rec = make(5)
    rec.solver_options()  # the step, computed once per segment
    frames = [read_raw(lay.raw(i)) for i in range(n)]
    truths = [rec.truth_on_grid(read_cube(lay.truth(i))[0], frames[i][1]) for i in range(n)]
    gs = [rec.measurement(f, m) for f, m in frames]
    cold = []
    t = time.perf_counter()
    for i in range(n):
        c, _ = rec.solve(gs[i], iters=args.cold_iters)
        cold.append(psnr(c, truths[i]))
    t_cold = time.perf_counter() - t
    warm = []
    prev = None
    t = time.perf_counter()
    for i in range(n):
        c, _ = rec.solve(gs[i], iters=args.cold_iters if prev is None else args.iters, x0=prev)
        warm.append(psnr(c, truths[i]))
        prev = c
    t_warm = time.perf_counter() - t
    gap = np.array(warm) - np.array(cold)
    print(f"[reconstruct] cold x{args.cold_iters}: {n / t_cold:5.2f} frames/s, mean PSNR "
          f"{np.mean(cold):.2f} dB")
    print(f"[reconstruct] warm x{args.iters} (frame 0 cold): {n / t_warm:5.2f} frames/s "
          f"(target >= 1), mean PSNR {np.mean(warm):.2f} dB")
    print("[reconstruct] warm - cold PSNR per frame (dB): "
          + " ".join(f"{x:+.2f}" for x in gap))
    print(f"[reconstruct] warm frames 1..{n - 1}: worst {gap[1:].min():+.2f} dB, mean "
          f"{gap[1:].mean():+.2f} dB (target: within 0.5 dB)")
    if not args.skip_parallel:
        settings = {"operator": args.operator, "design": d.to_dict(),
                    "calibration": str(calibration_file(d)), "views": 5,
                    "solver": "gap-tv", "iters": args.iters, "cold_iters": args.cold_iters,
                    "tau": None, "mu": 0.0, "animation": anim.describe(),
                    "wavelengths": [float(x) for x in d.wavelengths]}
        workers = cores()
        seg = max(1, -(-n // workers))
        segs = [[a, min(a + seg, n)] for a in range(0, n, seg)]
        res = reconstruct_sequence(tmp, n, segs, settings, workers=workers, progress=False)
        print(f"[reconstruct] segment engine, {res['workers']} process(es), {len(segs)} "
              f"segment(s), files + metrics included: {res['done'] / res['seconds']:.2f} "
              f"frames/s ({res['seconds']:.1f} s wall incl. process start-up)")

    # ---- 3. CIEDE2000 against views ----------------------------------------------------------
    counts = [int(c) for c in args.views.split(",")]
    offset = rec.grid_offset(frames[0][1])
    k = min(args.sweep_frames, n)
    print(f"\n[colour] sector CIEDE2000 (sector mean spectrum vs truth), frames 0..{k - 1}, "
          f"frame 0 cold x{args.cold_iters}, then warm x{args.iters}")
    print(f"{'views':>5} {'PSNR':>7} {'SAM':>6} {'dE00 img':>8} {'dE00 sectors':>12} "
          f"{'dE00 red':>8} {'paper (red)':>11}")
    for nv in counts:
        rv = make(nv)
        prev = None
        rows = []
        for i in range(k):
            g = rv.measurement(*frames[i])
            c, _ = rv.solve(g, iters=args.cold_iters if prev is None else args.iters, x0=prev)
            prev = c
            masks = anim.sector_masks(i, grid_shape=c.shape[:2], offset=offset)
            rows.append(frame_metrics(c, truths[i], d.wavelengths, masks))
        ps = np.mean([m["psnr"] for m in rows])
        sam = np.mean([m["sam_deg"] for m in rows])
        de = np.mean([m["delta_e2000"] for m in rows])
        sec = np.mean([m["sector_delta_e2000_mean"] for m in rows])
        red = np.mean([m["sector_delta_e2000"][0] for m in rows])
        print(f"{nv:>5} {ps:7.2f} {sam:6.2f} {de:8.2f} {sec:12.2f} {red:8.2f} "
              f"{PAPER_DE.get(nv, float('nan')):>11}")
    import shutil

    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
