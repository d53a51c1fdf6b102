"""Where one iteration of the product's solve spends its time, part by part.

Runs the product's own solve (``kaleidospec.reconstruct.reconstruct_views``: the calibrated
model of a real, cached calibration, brought to unit mean row norm, FISTA with the prior and
the noise-following weight, the truth's metrics at the end and no PSNR history, as ``run``
solves) for a
few iterations, with timers wrapped around the parts it calls: the operators' forward and
gradient step (``adjoint_add``) per layer (row scaling, PSF blur, calibrated kernels), the
prior's prox and value (and, for ``subspace-tv``, its basis, projection, TV prox and
expansion), FISTA's restart test (its data misfit) and its momentum pass (the restart
test's inner product, the extrapolation and the relative change in one pass), and the loop's
step.  Each part's
*own* time (its callees' time taken out) is averaged over iterations 2..N (the first
iteration and the set-up are left out: the set-up is reported on its own line, as
``normalised`` + the power iteration).  What no timer covers is the "rest" (FISTA's own
residual arithmetic).

The frame is rendered with its own Monte Carlo draw (``kaleidospec.instrument.render_scene``)
as in ``tools/bench_recon.py``.  The calibration comes from the cache (made when missing).

``--compare N`` also runs the reference paths (:func:`reference_paths`: the calibrated
model's view-by-view gradient step) and the current ones, alternated N times in the process,
and prints the medians and the largest relative difference of the cubes.

Usage: python3 tools/profile_iteration.py [--configs small,paper] [--scenes egyptian_statue]
                                          [--views 1,5] [--priors tv,subspace-tv]
                                          [--iters 6] [--compare N] [--json FILE]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time
from collections import defaultdict
from pathlib import Path

import numpy as np


class Timers:
    """Nested wall-clock timers: each wrapped call's inclusive time, and its own time (the
    time of wrapped calls inside it taken out)."""

    def __init__(self):
        self.own = defaultdict(float)
        self.calls = defaultdict(int)
        self._stack: list[list] = []

    def wrap(self, label, fn):
        timers = self

        def wrapped(*a, **k):
            frame = [0.0]
            timers._stack.append(frame)
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                dt = time.perf_counter() - t0
                timers._stack.pop()
                timers.own[label] += dt - frame[0]
                timers.calls[label] += 1
                if timers._stack:
                    timers._stack[-1][0] += dt

        wrapped.__wrapped__ = fn
        return wrapped

    def snapshot(self):
        return dict(self.own), dict(self.calls)


@contextlib.contextmanager
def instrumented(timers: Timers):
    """Wrap the parts of the product's iteration (module attributes and methods), restored
    on exit."""
    import importlib

    from recon.app import reconstruct  # noqa: F401  (imports the modules patched below)

    (kvec, obase, oblur, ocal, psub, ptv, xtv, sbase, sfista) = (
        importlib.import_module(m) for m in (
            "recon.kernels.vector", "recon.operators.base", "recon.operators.blur",
            "recon.operators.calibrated", "recon.priors.subspace", "recon.priors.tv",
            "recon.prox.tv", "recon.solvers.base", "recon.solvers.fista_tv"))

    patches = [
        (obase.ScaledOperator, "_forward", "forward: row scaling"),
        (obase.ScaledOperator, "adjoint_add", "gradient step: row scaling"),
        (oblur.BlurredOperator, "_forward", "forward: PSF blur (wrapper)"),
        (oblur.BlurredOperator, "adjoint_add", "gradient step: PSF blur (wrapper)"),
        (oblur, "convolve_views", "PSF blur (correlation)"),
        (ocal.CalibratedCassi, "_forward", "forward: calibrated kernels"),
        (ocal.CalibratedCassi, "adjoint_add", "gradient step: calibrated kernels"),
        (sfista, "data_misfit", "restart test: data misfit (subtract, norm)"),
        (sfista, "prior_value", "restart test: prior value"),
        (sfista, "_restart_dot", "restart test: momentum inner product"),
        (sfista, "_extrapolate", "momentum extrapolation"),
        (sfista, "_momentum_pass", "momentum pass (restart test's inner product, "
                                   "extrapolation, relative change)"),
        (ptv.TVPrior, "prox", "prior prox: TV"),
        (psub.SubspaceTV, "prox", "prior prox: subspace-TV (rest)"),
        (psub, "leading_basis", "subspace: basis (Gram + eigh)"),
        (psub, "project", "subspace: projection"),
        (psub, "expand", "subspace: expansion"),
        (xtv.TVProx, "__call__", "TV prox (Chambolle)"),
        (ptv, "tv_norm", "TV norm"),
        (psub, "tv_norm", "TV norm"),
        (sbase.IterationLoop, "relative_change", "relative change"),
        (sbase.IterationLoop, "step", "loop step (callback rest)"),
        (kvec, "squared_distance", "PSNR history (squared distance)"),
    ]
    saved = []
    try:
        for owner, name, label in patches:
            # A part the code no longer has (renamed, inlined) is left untimed: its time
            # goes to its caller's line, or to the rest.
            fn = owner.__dict__.get(name) if isinstance(owner, type) else getattr(owner, name,
                                                                                  None)
            if fn is None:
                continue
            saved.append((owner, name, fn))
            if isinstance(fn, staticmethod):
                setattr(owner, name, staticmethod(timers.wrap(label, fn.__func__)))
            else:
                setattr(owner, name, timers.wrap(label, fn))
        yield
    finally:
        for owner, name, fn in reversed(saved):
            setattr(owner, name, fn)


def scene_source(name: str):
    """A built-in scene's name, or the CAVE folder ``$KALEIDOSPEC_DATA/cave/<name>`` (None
    when absent)."""
    from kaleidospec.experiments import cave_folder
    from scenes.registry import list_scenes

    if name in list_scenes():
        return name
    folder = cave_folder(name)
    return None if folder is None else str(folder)


@contextlib.contextmanager
def reference_paths():
    """Within this block the calibrated model's gradient step takes the view-by-view kernels
    (``shift_adjoint`` + ``warp_adjoint`` a view) instead of the one-pass ``adjoint_views``
    (for the A/B of ``--compare``)."""
    import importlib

    ocal = importlib.import_module("recon.operators.calibrated")
    plan = ocal.CalibratedCassi._fused_plan
    ocal.CalibratedCassi._fused_plan = lambda self: False
    try:
        yield
    finally:
        ocal.CalibratedCassi._fused_plan = plan


def profile_solve(frame, meta, cal, n, truth, design, model, prior, iters):
    """Run the product's solve for ``iters`` iterations under the timers; return the per-part
    own seconds per iteration (iterations 2..iters), the iteration's wall time and the
    set-up's."""
    import importlib

    from kaleidospec.reconstruct import reconstruct_views

    sbase = importlib.import_module("recon.solvers.base")

    timers = Timers()
    marks = []  # (perf_counter, timers snapshot) at the start of every loop step
    t0 = time.perf_counter()
    with instrumented(timers):
        wrapped_step = sbase.IterationLoop.step
        sbase.IterationLoop.step = lambda self, *a, **k: (
            marks.append((time.perf_counter(), timers.snapshot())) or wrapped_step(self, *a, **k))
        try:
            cube, info = reconstruct_views(frame, meta, cal, n, truth=truth, design=design,
                                           model=model, iters=iters, tol=1e-3, prior=prior)
        finally:
            sbase.IterationLoop.step = wrapped_step
    total = time.perf_counter() - t0
    (ta, (own_a, calls_a)), (tb, (own_b, calls_b)) = marks[0], marks[-1]
    k = len(marks) - 1
    parts = {lab: (own_b.get(lab, 0.0) - own_a.get(lab, 0.0)) / k for lab in own_b}
    counts = {lab: (calls_b.get(lab, 0) - calls_a.get(lab, 0)) / k for lab in calls_b}
    iteration = (tb - ta) / k
    parts = {lab: v for lab, v in parts.items() if counts.get(lab, 0) > 0}
    parts["rest (FISTA's residual arithmetic, untimed)"] = iteration - sum(parts.values())
    # Set-up: everything before the first iteration's step, less that iteration.
    first_iteration = (marks[1][0] - marks[0][0]) if len(marks) > 1 else 0.0
    setup = marks[0][0] - t0 - first_iteration
    return {"iteration_s": iteration, "parts_s": parts, "calls": counts,
            "setup_s": setup, "total_s": total, "iters": info["iters"],
            "psnr": info["metrics"]["psnr"], "cube": cube}


def compare(frame, meta, cal, n, truth, design, model, prior, iters, times, cube):
    """Reference paths against the current ones, alternated ``times`` times: the iteration's
    time and the parts that differ, medians, and the largest relative difference of the
    cubes after ``iters`` iterations."""
    runs = {"reference": [], "current": []}
    cubes = {"current": cube}
    for _ in range(times):
        for which in ("reference", "current"):
            ctx = reference_paths() if which == "reference" else contextlib.nullcontext()
            with ctx:
                r = profile_solve(frame, meta, cal, n, truth, design, model, prior, iters)
            cubes[which] = r.pop("cube")
            runs[which].append(r)
    med = {w: float(np.median([r["iteration_s"] for r in rs])) for w, rs in runs.items()}
    lab = "gradient step: calibrated kernels"
    step = {w: float(np.median([r["parts_s"].get(lab, 0.0) for r in rs]))
            for w, rs in runs.items()}
    a, b = (np.asarray(cubes[w], np.float64) for w in ("current", "reference"))
    diff = float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-30))
    print(f"  compare ({times} alternations, medians): iteration reference "
          f"{med['reference'] * 1e3:.1f} ms, current {med['current'] * 1e3:.1f} ms "
          f"({med['reference'] / med['current']:.2f}x); calibrated gradient step "
          f"{step['reference'] * 1e3:.1f} -> {step['current'] * 1e3:.1f} ms "
          f"({step['reference'] / max(step['current'], 1e-12):.2f}x); largest relative "
          f"difference of the cubes after {iters} iterations {diff:.1e}", flush=True)
    return {"iteration_s": med, "gradient_step_s": step, "max_rel_diff": diff,
            "alternations": times}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--configs", default="small,paper")
    p.add_argument("--scenes", default="egyptian_statue")
    p.add_argument("--views", default="1,5")
    p.add_argument("--priors", default="tv,subspace-tv")
    p.add_argument("--iters", type=int, default=6, help="iterations run (>= 3)")
    p.add_argument("--compare", type=int, default=0, metavar="N",
                   help="also run the reference paths (reference_paths) and the current ones "
                        "N times each, alternated, and print their iteration times")
    p.add_argument("--json", type=Path, help="write the figures there (atomically)")
    args = p.parse_args(argv)
    if args.iters < 3:
        p.error("--iters must be >= 3")

    from kaleidospec.calibrate import calibrate
    from kaleidospec.instrument import release_transports, render_scene
    from kaleidospec.models import model_of, truth_on_grid
    from kaleidospec.reconstruct import first_views
    from recon import kernels
    from sim.optics.design import get_design

    report = {"cpus": kernels.cores(), "loadavg_start": os.getloadavg(), "runs": [],
              "iters": args.iters}
    print(f"{kernels.cores()} CPUs, load {os.getloadavg()[0]:.2f}", flush=True)
    for name in args.configs.split(","):
        design = get_design(name)
        cal = calibrate(design, progress=False)
        model = model_of(cal, None)
        for scene in args.scenes.split(","):
            src = scene_source(scene)
            if src is None:
                print(f"[{name}] {scene}: not found; skipped", flush=True)
                continue
            frame, meta, native, _ = render_scene(src, design, seed=0, native=True)
            release_transports("scene")
            for n in (int(v) for v in args.views.split(",")):
                truth = truth_on_grid(native, design, cal, model, first_views(n))
                for prior in args.priors.split(","):
                    # One untimed solve first: Numba's kernels loaded, the threads started.
                    profile_solve(frame, meta, cal, n, truth, design, model, prior, 3)
                    r = profile_solve(frame, meta, cal, n, truth, design, model, prior,
                                      args.iters)
                    cube = r.pop("cube")
                    r.update(design=name, scene=scene, views=n, prior=prior,
                             cube=list(cal.cube_shape), load=os.getloadavg()[0])
                    report["runs"].append(r)
                    print(f"\n[{name}] {scene}, {n} view(s), prior {prior}: one iteration "
                          f"{r['iteration_s'] * 1e3:.1f} ms (mean of iterations 2..{args.iters}"
                          f"); set-up {r['setup_s']:.2f} s", flush=True)
                    for lab, v in sorted(r["parts_s"].items(), key=lambda kv: -kv[1]):
                        print(f"  {v * 1e3:9.2f} ms  {100 * v / r['iteration_s']:5.1f} %  "
                              f"{lab}  (x{r['calls'].get(lab, 0):.0f})", flush=True)
                    if args.compare:
                        r["compare"] = compare(frame, meta, cal, n, truth, design, model,
                                               prior, args.iters, args.compare, cube)
    report["loadavg_end"] = os.getloadavg()
    print(f"\nload {report['loadavg_start'][0]:.2f} -> {report['loadavg_end'][0]:.2f}")
    if args.json:
        from kaleidospec.experiments import write_json

        write_json(Path(args.json), report)


if __name__ == "__main__":
    main()
