"""Priors against TV on measured hyperspectral scenes: PSNR, SSIM, SAM and seconds per prior.

Two kinds of problem (``--designs``):

``cassi``
    Single-view CASSI in the standard convention (KAIST benchmark): a 256×256 crop (the
    centre of a CAVE scene), 28 bands (CAVE's bands 2-29, 410-680 nm: the 31 bands less 400,
    690 and 700 nm), a random binary mask (seed 0), dispersion step 2, Gaussian noise of rms
    ``--noise`` times the measurement's peak (0.5 %, seed 0).  Every prior runs in GAP
    (:func:`recon.solvers.gap_tv.gap_tv`) with the same weight ``--gap-tau`` and ``--gap-iters``
    iterations.
``cassi-fista``
    The same problem solved as ``kaleidospec run`` solves a frame: operator and data at unit
    mean row norm, the default solver (FISTA), stopping rule and step metric, each prior's
    weight by ``run``'s rule from the noise's rms (known here, as ``run`` knows it from the
    sensor's model).
``small``, ``paper``
    The product's own work, as ``kaleidospec run`` does it: one raw frame of the scene rendered
    through the design (the sensor's noise, seed 0; the frame independent of the calibration
    captures), the cached calibration, the first n views, the default solver, stopping rule and
    weight rules (:func:`kaleidospec.reconstruct.prior_weight`: TV's weight follows the
    measurement's noise; another prior sets its strength from the same noise by its own rule,
    ``subspace-tv`` with TV's constant).  Scored on the reconstruction grid as ``run``
    scores it.

Scenes: CAVE folders ``$KALEIDOSPEC_DATA/cave/<name>``; by default the eight development
scenes (the rest of CAVE is held out for independent evaluation).  None of them is RGB-lifted.
Metrics: :mod:`recon.metrics` (PSNR with the truth's peak as 1, SSIM, SAM in degrees).

Usage::

    python3 tools/exp_priors.py --designs cassi --priors tv,subspace-tv
    python3 tools/exp_priors.py --designs cassi,cassi-fista --priors tv,subspace-tv,subspace-nlr
    python3 tools/exp_priors.py --designs small --views 1,5 --priors tv,subspace-tv
    python3 tools/exp_priors.py --designs paper --views 5 --scenes cloth,paints,superballs
    python3 tools/exp_priors.py --designs small --priors tv,subspace-tv,subspace-tv:rank=4
    python3 tools/exp_priors.py --designs paper --views 1 --scenes superballs --iters 800 --tol 0

A prior is a name of :data:`recon.priors.PRIORS`, optionally with options of its factory after
colons (``subspace-tv:rank=4``, ``subspace-nlr:strength=0.4:warmup=40``; integers and floats
as written); the row's label is the text as given.

Prints one row per problem and prior, then the mean per design, views and prior with its gain
over TV and its time relative to TV's; writes ``exp_priors.json`` in ``--out`` (atomically).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from kaleidospec.experiments import CAVE_DEV_SCENES, cave_folder

CASSI_SIZE, CASSI_BANDS, CASSI_STEP = 256, slice(1, 29), 2


def parse_prior(spec: str) -> tuple[str, dict]:
    """``name:key=value:...`` as (name, options); the values as int, else float, else text."""
    from recon.priors import check_prior_name

    name, *parts = spec.split(":")
    options = {}
    for part in parts:
        key, sep, text = part.partition("=")
        if not sep or not key:
            raise SystemExit(f"bad prior option {part!r} in {spec!r} (want key=value)")
        for kind in (int, float):
            try:
                options[key] = kind(text)
                break
            except ValueError:
                continue
        else:
            options[key] = text
    return check_prior_name(name), options


def build(spec: str, shape, solver: str, tau, noise=None, n_views=None):
    """The prior ``spec`` for a solve: its name where it has no options (the solvers build
    it, TV's arithmetic included), else the object from :func:`recon.priors.make_prior`.
    ``tau`` None lets the prior set its strength from ``noise`` (as ``run`` does)."""
    from recon.priors import make_prior

    name, options = parse_prior(spec)
    if not options:
        return name, {"tau": tau, **({} if noise is None else {"noise": noise})}
    return make_prior(name, shape=shape, dtype=np.float32, weight=tau, solver=solver,
                      noise=noise, n_views=n_views, **options), {}


def compile_denoiser(priors) -> None:
    """Compile the non-local denoiser's kernels where a prior uses them: two iterations of a
    two-stage prior run only its first stage (``recon.solvers.solve``)."""
    if any(parse_prior(p)[0] == "subspace-nlr" for p in priors):
        from recon.priors.nonlocal_lowrank import denoise_nonlocal

        z = np.random.default_rng(0).random((2, 16, 16)).astype(np.float32)
        denoise_nonlocal(z, np.ones(2))


def scores(est_bm: np.ndarray, truth_bm: np.ndarray) -> dict:
    """PSNR, SSIM, SAM of band-major cubes (truth's peak taken as 1 by recon.metrics)."""
    from recon.metrics import psnr, sam, ssim

    e, t = np.moveaxis(est_bm, 0, 2), np.moveaxis(truth_bm, 0, 2)
    return {"psnr": psnr(e, t), "ssim": ssim(e, t), "sam": sam(e, t)}


def cassi_problem(folder: Path, noise: float):
    """The single-view CASSI problem of one scene: truth (band-major, peak 1), operator, noisy
    measurement and the noise's rms."""
    from recon.io.cubes import read_cube
    from recon.operators import standard_cassi

    cube, _ = read_cube(folder)
    h0 = (cube.shape[0] - CASSI_SIZE) // 2
    w0 = (cube.shape[1] - CASSI_SIZE) // 2
    crop = cube[h0:h0 + CASSI_SIZE, w0:w0 + CASSI_SIZE, CASSI_BANDS]
    truth = np.ascontiguousarray(np.moveaxis(crop / crop.max(), 2, 0), dtype=np.float32)
    rng = np.random.default_rng(0)
    mask = (rng.random(truth.shape[1:]) > 0.5).astype(np.float32)
    op = standard_cassi(mask, CASSI_STEP, truth.shape[0])
    g = np.asarray(op.forward(truth), dtype=np.float32)
    sigma = noise * float(g.max())
    g = g + rng.normal(0.0, sigma, g.shape).astype(np.float32)
    return truth, op, g, sigma


def cassi_rows(name: str, folder: Path, priors, args) -> list[dict]:
    """GAP with each prior on the single-view CASSI crop of one scene."""
    from recon.solvers.gap_tv import gap_tv

    truth, op, g, _ = cassi_problem(folder, args.noise)
    rows = []
    for prior in priors:   # untimed: the first solve of a process compiles its kernels
        p, kw = build(prior, truth.shape, "gap", args.gap_tau)
        gap_tv(op, g, iters=2, prior=p, **kw)
    for prior in priors:
        p, kw = build(prior, truth.shape, "gap", args.gap_tau)
        t0 = time.perf_counter()
        res = gap_tv(op, g, iters=args.gap_iters, prior=p, **kw)
        seconds = time.perf_counter() - t0
        rows.append({"design": "cassi", "views": 1, "scene": name, "prior": prior,
                     "seconds": seconds, "iters": res.iterations, **scores(res.x, truth)})
        print(fmt_row(rows[-1]), flush=True)
    return rows


def run_rows(label: str, n: int, scene: str, op, g, noise, truth_bm, priors,
             args) -> list[dict]:
    """Each prior's solve of ``g`` (``n`` views through ``op``) as ``run`` solves a frame:
    operator and data at unit mean row norm, the default solver, stopping rule and step
    metric, each prior's weight by ``run``'s rule from the noise's rms ``noise`` (None:
    unknown); rows of design ``label`` scored against ``truth_bm``."""
    from kaleidospec.reconstruct import DEFAULTS, normalised, prior_weight, solver_metric
    from recon.app import reconstruct

    op, gn = normalised(op, g)
    nz = None if noise is None else noise * op.scale
    solver = DEFAULTS["solver"]
    metric = solver_metric(solver, DEFAULTS["metric"])    # FISTA's step metric, as run's
    # Each prior's weight as run gives it (TV's rule; the others' own, from the noise).
    taus = {prior: prior_weight(parse_prior(prior)[0], solver, None, n, nz) for prior in priors}
    for prior in priors:   # untimed: the first solve of a process compiles its kernels
        p, kw = build(prior, op.ishape, solver, taus[prior], nz, n)
        reconstruct(gn, op, solver=solver, iters=2, tol=None, prior=p, **kw, **metric)
    compile_denoiser(priors)
    rows = []
    for prior in priors:
        p, kw = build(prior, op.ishape, solver, taus[prior], nz, n)
        cube, info = reconstruct(gn, op, solver=solver, iters=args.iters,
                                 tol=args.tol if args.tol > 0 else None, prior=p, **kw,
                                 **metric)
        rows.append({"design": label, "views": n, "scene": scene, "prior": prior,
                     "seconds": info["seconds"], "iters": info["iters"],
                     **scores(np.moveaxis(cube, 2, 0), truth_bm)})
        print(fmt_row(rows[-1]), flush=True)
    return rows


def cassi_fista_rows(name: str, folder: Path, priors, args) -> list[dict]:
    """The same single-view CASSI problem solved as ``run`` solves a frame (:func:`run_rows`),
    the noise's rms known here, as ``run`` knows it from the sensor's model."""
    truth, op, g, sigma = cassi_problem(folder, args.noise)
    return run_rows("cassi-fista", 1, name, op, g, sigma, truth, priors, args)


def design_rows(design_name: str, name: str, folder: Path, priors, counts, args) -> list[dict]:
    """The product's reconstruction of one scene with each prior, per view count."""
    from kaleidospec import instrument
    from kaleidospec.calibrate import calibrate
    from kaleidospec.models import model_of, truth_on_grid
    from kaleidospec.reconstruct import (calibrated_operator, first_views, frame_measurements,
                                         measurement_noise)
    from sim.optics.design import get_design

    design = instrument.design_for_views(get_design(design_name), max(counts))
    frame, meta, _, wl = instrument.render_scene(str(folder), design, seed=0)
    instrument.release_transports("scene")
    cal = calibrate(design, progress=False)
    model = model_of(cal, None)
    native = instrument.scene_cube(str(folder), design)[0]
    rows = []
    for n in counts:
        ids = first_views(n)
        truth = truth_on_grid(native, design, cal, model, ids)
        truth_bm = np.ascontiguousarray(np.moveaxis(truth, 2, 0), dtype=np.float32)
        g = frame_measurements(frame, meta, cal, ids)
        noise = measurement_noise(g, meta, cal.noise)
        rows += run_rows(design_name, len(ids), name, calibrated_operator(cal, ids, model), g,
                         noise, truth_bm, priors, args)
    return rows


def fmt_row(r: dict) -> str:
    return (f"{r['design']:6s} {r['views']:>2d}v {r['scene']:22s} {r['prior']:22s} "
            f"PSNR {r['psnr']:6.2f}  SSIM {r['ssim']:.3f}  SAM {r['sam']:5.2f}  "
            f"{r['seconds']:6.1f} s  ({r['iters']} it)")


def summary(rows: list[dict], priors) -> list[str]:
    """Mean per (design, views, prior) over the scenes, gain over TV and time ratio."""
    lines = []
    keys = sorted({(r["design"], r["views"]) for r in rows})
    for design, views in keys:
        sub = [r for r in rows if r["design"] == design and r["views"] == views]
        means = {}
        for prior in priors:
            pr = [r for r in sub if r["prior"] == prior]
            if pr:
                means[prior] = {k: float(np.mean([r[k] for r in pr]))
                                for k in ("psnr", "ssim", "sam", "seconds")}
                means[prior]["n"] = len(pr)
        tv = means.get("tv")
        for prior, m in means.items():
            extra = ""
            if tv is not None and prior != "tv":
                extra = (f"  {m['psnr'] - tv['psnr']:+.2f} dB vs tv, "
                         f"{m['seconds'] / tv['seconds']:.2f}x tv's time")
            lines.append(f"mean {design:6s} {views:>2d}v {prior:22s} ({m['n']} scenes) "
                         f"PSNR {m['psnr']:6.2f}  SSIM {m['ssim']:.3f}  SAM {m['sam']:5.2f}  "
                         f"{m['seconds']:6.1f} s{extra}")
    return lines


def write_results(out: Path, args, rows: list[dict], lines: list[str]) -> None:
    """``exp_priors.json`` in ``out`` (atomically): the settings, every row, the summary."""
    from recon.io.atomic import write_text

    write_text(out / "exp_priors.json",
               json.dumps({"settings": vars(args), "rows": rows, "summary": lines}, indent=2)
               + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--designs", default="cassi",
                    help="comma list of cassi, cassi-fista, small, paper")
    ap.add_argument("--views", default="1,5", help="view counts for small/paper")
    ap.add_argument("--priors", default="tv,subspace-tv",
                    help="comma list of recon.priors names (tv first: the reference)")
    ap.add_argument("--scenes", default=",".join(CAVE_DEV_SCENES))
    ap.add_argument("--noise", type=float, default=0.005,
                    help="cassi: Gaussian noise rms over the measurement's peak")
    ap.add_argument("--gap-tau", type=float, default=0.05, help="cassi: every prior's weight")
    ap.add_argument("--gap-iters", type=int, default=100, help="cassi: GAP iterations")
    ap.add_argument("--iters", type=int, default=None,
                    help="small/paper/cassi-fista: most iterations (run's default if unset)")
    ap.add_argument("--tol", type=float, default=None,
                    help="small/paper/cassi-fista: the stopping rule's relative change (run's "
                         "default if unset; 0: none, every solve runs --iters)")
    ap.add_argument("--out", default="out/exp_priors")
    args = ap.parse_args(argv)
    from kaleidospec.reconstruct import DEFAULTS

    args.iters = DEFAULTS["iters"] if args.iters is None else args.iters
    args.tol = DEFAULTS["tol"] if args.tol is None else args.tol
    if args.iters < 1 or not args.tol >= 0:
        print("--iters must be >= 1 and --tol >= 0", file=sys.stderr)
        return 2

    priors = [p for p in args.priors.split(",") if p]
    for p in priors:
        parse_prior(p)
    scenes = [s for s in args.scenes.split(",") if s]
    held_out = [s for s in scenes if s not in CAVE_DEV_SCENES]
    if held_out:
        print(f"refusing scenes outside the development set: {', '.join(held_out)}",
              file=sys.stderr)
        return 2
    counts = [int(v) for v in args.views.split(",") if v]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    for name in scenes:
        folder = cave_folder(name)
        if folder is None:
            print(f"skipping {name}: no folder $KALEIDOSPEC_DATA/cave/{name} "
                  f"(KALEIDOSPEC_DATA={os.environ.get('KALEIDOSPEC_DATA')!r})", flush=True)
            continue
        for design in args.designs.split(","):
            if design == "cassi":
                rows += cassi_rows(name, folder, priors, args)
            elif design == "cassi-fista":
                rows += cassi_fista_rows(name, folder, priors, args)
            else:
                rows += design_rows(design, name, folder, priors, counts, args)
        # After every scene: a long run (paper: minutes a solve) keeps what it measured.
        write_results(out, args, rows, summary(rows, priors))
    if not rows:
        print("nothing measured: no scene found")
        return 1
    print("\n".join(summary(rows, priors)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
