"""Where the product's solve stops, against the minimum of the objective it minimises.

``run`` reconstructs a frame with FISTA-TV in the band metric and stops it once the relative
change of the cube falls below 10⁻³ (:data:`kaleidospec.reconstruct.DEFAULTS`).  Its
objective is

.. math::

    F(x) = \\tfrac12\\|g - Hx\\|^2 + \\tau\\,\\mathrm{TV}(x)

(the operator and data at unit mean row norm, :math:`\\tau` the product's weight).  This
script runs that solve on a CAVE scene rendered through a real (cached) calibration, records
:math:`F` and the PSNR where the rule stops it, then runs a primal-dual solver on the same
:math:`F` far past that point and reports both again: how far the product's stopping point is
from the minimum, and what the minimum's PSNR is.  The PSNR that ``run`` reports is the one at
its stopping point, so the difference is part of what the reported accuracy depends on.

The primal-dual solver is Chambolle & Pock's, with Pock & Chambolle's diagonal
preconditioning (2011), on :math:`K = [H; \\nabla]`: the data term and TV are both taken on
the dual, so no inner prox is inexact (FISTA's TV prox is two warm-started dual iterations an
iteration).  The steps are

.. math::

    y_H &\\leftarrow \\frac{y_H + \\Sigma_H (H\\bar x - g)}{1 + \\Sigma_H}, \\qquad
    y_\\nabla \\leftarrow \\Pi_{\\|\\cdot\\|_2 \\le \\tau}\\bigl(y_\\nabla + \\sigma_\\nabla
    \\nabla\\bar x\\bigr), \\\\
    x^+ &= x - T\\,(H^\\top y_H + \\nabla^\\top y_\\nabla), \\qquad \\bar x = 2x^+ - x,

with :math:`T = \\theta / (|H|^\\top\\mathbf 1 + 4)`, :math:`\\Sigma_H = 1/(\\theta\\,|H|
\\mathbf 1)` and :math:`\\sigma_\\nabla = 1/(2\\theta)` (the absolute row and column sums of
:math:`K`; :math:`\\theta` balances the primal and dual steps).  The calibrated operators have
no negative entry (masks in [0, 1], a positive PSF, bilinear warps), so :math:`|H|\\mathbf 1 =
H\\mathbf 1`; an operator for which :math:`H\\mathbf 1` or :math:`H^\\top\\mathbf 1` has a
negative entry is refused.  The solver lives here, not in :mod:`recon.solvers`: it is the
reference this experiment measures against (docs/speed_product.md, "Tried, not kept").

``--tau-scales`` solves the same problem with other TV weights as well (the product's times
each scale), as far: whether some weight's minimum reads the PSNR of the product's stop.

Usage::

    python3 tools/exp_minimum.py --configs small --scenes egyptian_statue --views 1,5
    python3 tools/exp_minimum.py --configs paper --views 1 --iters 2000 --json out/min.json
    python3 tools/exp_minimum.py --configs small --tau-scales 0.5,0.7,1.4,2

T. Pock, A. Chambolle, "Diagonal preconditioning for first order primal-dual algorithms in
convex optimization", ICCV 2011.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

#: Iterations after which the primal-dual solve's objective and PSNR are printed.
CHECKPOINTS = (100, 200, 400, 800, 1600, 3200, 6400)


def pdhg_tv(op, g: np.ndarray, tau: float, iters: int, theta: float = 30.0,
            callback=None) -> np.ndarray:
    r"""Minimise :math:`\tfrac12\|g-Hx\|^2 + \tau\,\mathrm{TV}(x)` (isotropic, per band) by
    preconditioned primal-dual iterations (see the module notes); returns the last ``x``
    (float32, ``op.ishape``).  ``callback(k, x)`` after every iteration ``k``.

    Raises
    ------
    ValueError
        :math:`H\mathbf 1` or :math:`H^\top\mathbf 1` has a negative entry (the
        preconditioner needs :math:`|H|`).
    """
    from recon.prox.tv import divergence, gradient

    g = np.asarray(g, np.float32)
    rows = op.forward(np.ones(op.ishape, np.float32))
    cols = op.adjoint(np.ones(op.oshape, np.float32))
    if rows.min() < 0 or cols.min() < 0:
        raise ValueError("the operator has negative entries: |H| is not H")
    t = (theta / (cols + 4.0)).astype(np.float32)
    s_h = (1.0 / (theta * np.maximum(rows, 1e-12))).astype(np.float32)
    s_g = np.float32(1.0 / (2.0 * theta))
    x = np.zeros(op.ishape, np.float32)
    x_bar = x.copy()
    y_h = np.zeros(op.oshape, np.float32)
    y_g = np.zeros((2,) + tuple(op.ishape), np.float32)
    grad = np.empty_like(y_g)
    div = np.empty_like(x)
    for k in range(1, int(iters) + 1):
        y_h += s_h * (op.forward(x_bar) - g)
        y_h /= 1.0 + s_h
        y_g += s_g * gradient(x_bar, out=grad)
        norm = np.sqrt(y_g[0] ** 2 + y_g[1] ** 2)
        y_g /= np.maximum(1.0, norm / np.float32(tau))
        # grad^T = -div: x+ = x - T (H^T y_H - div y_G).
        step = op.adjoint(y_h) - divergence(y_g, out=div)
        x_bar = x - t * step
        x, x_bar = x_bar, x
        # x_bar = 2 x+ - x, in the array that held the previous x.
        np.subtract(2.0 * x, x_bar, out=x_bar)
        if callback is not None:
            callback(k, x)
    return x


def _psnr(x: np.ndarray, truth: np.ndarray) -> float:
    return float(10.0 * np.log10(float(truth.max()) ** 2 / np.mean((x - truth) ** 2)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configs", default="small", help="calibrated designs, comma-separated")
    ap.add_argument("--scenes", default="egyptian_statue",
                    help="CAVE scenes under KALEIDOSPEC_DATA/cave, comma-separated")
    ap.add_argument("--views", default="1,5")
    ap.add_argument("--iters", type=int, default=3200, help="primal-dual iterations")
    ap.add_argument("--theta", type=float, default=30.0,
                    help="the primal-dual balance (larger: longer primal steps)")
    ap.add_argument("--tau-scales", default="",
                    help="also solve with the TV weight times each of these (comma-separated, "
                         "e.g. 0.5,0.7,1.4,2), --iters primal-dual iterations each: the PSNR "
                         "of the minimum for other weights")
    ap.add_argument("--json", default=None, help="write every number here")
    args = ap.parse_args(argv)
    try:
        scales = [float(v) for v in args.tau_scales.split(",") if v.strip()]
    except ValueError:
        ap.error(f"--tau-scales must be numbers, got {args.tau_scales!r}")
    if any(not v > 0 for v in scales):
        ap.error("--tau-scales must be positive")

    from kaleidospec.calibrate import calibrate
    from kaleidospec.instrument import release_transports, render_scene
    from kaleidospec.models import model_of, truth_on_grid
    from kaleidospec.reconstruct import (DEFAULTS, calibrated_operator, first_views,
                                         frame_measurements, measurement_noise, normalised,
                                         tv_weight)
    from recon.solvers import fista_tv, objective
    from sim.optics.design import get_design

    data = Path(os.environ.get("KALEIDOSPEC_DATA", "data")) / "cave"
    views = [int(v) for v in args.views.split(",")]
    print(f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}", flush=True)
    report = []
    for name in args.configs.split(","):
        design = get_design(name)
        cal = calibrate(design, progress=False)
        model = model_of(cal, None)
        for scene in args.scenes.split(","):
            if not (data / scene).is_dir():
                print(f"[{name}] {scene}: not found under {data}; skipped", flush=True)
                continue
            frame, meta, native, _ = render_scene(str(data / scene), design, seed=0,
                                                 native=True)
            release_transports("scene")
            for n in views:
                ids = first_views(n)
                truth = np.moveaxis(truth_on_grid(native, design, cal, model, ids), 2, 0)
                truth = np.ascontiguousarray(truth, np.float32)
                raw = frame_measurements(frame, meta, cal, ids)
                op, g = normalised(calibrated_operator(cal, ids, model), raw)
                noise = measurement_noise(raw, meta, cal.noise)
                tau = tv_weight("fista-tv", None, n, None if noise is None else
                                noise * op.scale)
                t0 = time.perf_counter()
                res = fista_tv(op, g, tau=tau, iters=DEFAULTS["iters"], tol=DEFAULTS["tol"],
                               metric=DEFAULTS["metric"])
                product = {"iterations": res.iterations,
                           "objective": objective(op, g, res.x, tau),
                           "psnr": _psnr(res.x, truth),
                           "seconds": time.perf_counter() - t0}
                print(f"[{name}] {scene} {n} view(s): the product's solve stops after "
                      f"{product['iterations']} iterations, F = {product['objective']:.6g}, "
                      f"{product['psnr']:.2f} dB ({product['seconds']:.1f} s)", flush=True)
                trace = []

                def record(k, x, op=op, g=g, tau=tau, truth=truth, trace=trace):
                    if k in CHECKPOINTS or k == args.iters:
                        trace.append({"iteration": k, "objective": objective(op, g, x, tau),
                                      "psnr": _psnr(x, truth)})
                        print(f"    primal-dual, {k:5d} iterations: F = "
                              f"{trace[-1]['objective']:.6g}, {trace[-1]['psnr']:.2f} dB",
                              flush=True)

                t0 = time.perf_counter()
                pdhg_tv(op, g, tau, args.iters, args.theta, callback=record)
                last = trace[-1]
                if product["objective"] <= last["objective"]:
                    print(f"    the product's F is below the primal-dual solve's after "
                          f"{args.iters} iterations: no lower F found (more --iters, or "
                          f"another --theta) ({time.perf_counter() - t0:.0f} s)", flush=True)
                else:
                    print(f"    the product stops {product['objective'] - last['objective']:.4g} "
                          f"({(product['objective'] / last['objective'] - 1) * 100:.2f} %) "
                          f"above the lowest F found, at {product['psnr'] - last['psnr']:+.2f} "
                          f"dB from its PSNR ({time.perf_counter() - t0:.0f} s)", flush=True)
                others = []
                for m in scales:
                    x = pdhg_tv(op, g, tau * m, args.iters, args.theta)
                    others.append({"scale": m, "objective": objective(op, g, x, tau * m),
                                   "psnr": _psnr(x, truth)})
                    print(f"    primal-dual with the TV weight x {m:g}, {args.iters} "
                          f"iterations: {others[-1]['psnr']:.2f} dB "
                          f"({others[-1]['psnr'] - product['psnr']:+.2f} dB from the "
                          f"product's)", flush=True)
                report.append({"design": name, "scene": scene, "views": n, "tau": tau,
                               "theta": args.theta, "product": product, "primal_dual": trace,
                               "tau_scales": others})
                del op, g, truth, res
            del frame, native
    if args.json:
        from kaleidospec.experiments import write_json

        write_json(Path(args.json), report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
