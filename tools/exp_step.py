"""How long FISTA's step really is: the band metric's norm estimate against a converged one.

The product's FISTA takes its step in the band metric :math:`D = \\alpha\\,\\mathrm{diag}(s)`
(:mod:`recon.solvers.band_metric`), with :math:`\\alpha` the top eigenvalue of
:math:`S^{-1/2}H^\\top H S^{-1/2}` estimated by 15 power iterations and multiplied by 1.02.  A
power iteration approaches that eigenvalue from below, and slowly where the top of the
spectrum is clustered.  This script measures, on the calibrated model of a real (cached)
calibration, exactly as ``run`` builds it (unit mean row norm), for every view count:

* the product's estimate (``band_metric``: the 15 power iterations and the factor 1.02);
* the eigenvalue converged by Lanczos iterations (SciPy's ``eigsh``, ``--tol``), with the
  number of operator pairs (forward and adjoint) it took;
* their ratio: above 1 the product's step is longer than :math:`D^{-1}` with :math:`D` a
  majoriser of :math:`H^\\top H`, by that factor.

Usage::

    python3 tools/exp_step.py --configs paper --views 1,5
    python3 tools/exp_step.py --configs small,paper --views 1,5 --json out/exp_step.json
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np


def converged_alpha(op, s: np.ndarray, tol: float) -> tuple[float, int]:
    r"""The top eigenvalue of :math:`S^{-1/2}H^\top H S^{-1/2}` by Lanczos (``eigsh``, float64
    vectors, the operator in float32), and the operator pairs it took."""
    from scipy.sparse.linalg import LinearOperator, eigsh

    w = (1.0 / np.sqrt(s)).astype(np.float32).reshape(-1, 1, 1)
    n = int(np.prod(op.ishape))
    pairs = [0]
    y = np.empty(op.ishape, np.float32)

    def matvec(v):
        pairs[0] += 1
        x = v.astype(np.float32).reshape(op.ishape) * w
        y.fill(0)
        op.adjoint_add(op.forward(x), y, 1.0, out=y)
        return (y * w).reshape(-1).astype(np.float64)

    a = LinearOperator((n, n), matvec=matvec, dtype=np.float64)
    v0 = np.random.default_rng(0).standard_normal(n)
    top = eigsh(a, k=1, which="LA", tol=tol, v0=v0, return_eigenvectors=False)
    return float(top[0]), pairs[0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configs", default="paper", help="calibrated designs, comma-separated")
    ap.add_argument("--views", default="1,5")
    ap.add_argument("--tol", type=float, default=1e-6, help="eigsh's relative tolerance")
    ap.add_argument("--json", default=None, help="write every number here")
    args = ap.parse_args(argv)

    from kaleidospec.calibrate import calibrate
    from kaleidospec.reconstruct import calibrated_operator, first_views, normalised
    from recon.solvers.band_metric import band_metric
    from sim.optics.design import get_design

    views = [int(v) for v in args.views.split(",")]
    print(f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}", flush=True)
    report = []
    for name in args.configs.split(","):
        cal = calibrate(get_design(name), progress=False)
        for n in views:
            model = calibrated_operator(cal, first_views(n))
            op, _ = normalised(model, np.zeros(model.oshape, np.float32))
            t0 = time.perf_counter()
            d = band_metric(op, np.float32)
            t_product = time.perf_counter() - t0
            # d = alpha s with the shape s largest, 1, at the strongest band: alpha is the
            # largest d_l (the product's estimate), and s = d / alpha.
            product = float(d.max())
            s = d / product
            t0 = time.perf_counter()
            exact, pairs = converged_alpha(op, s, args.tol)
            t_exact = time.perf_counter() - t0
            row = {"design": name, "views": n, "alpha_product": product,
                   "alpha_power_15": product / 1.02, "alpha_converged": exact,
                   "converged_pairs": pairs, "seconds_product": t_product,
                   "seconds_converged": t_exact, "step_over_majoriser": exact / product}
            print(f"[{name}] {n} view(s): alpha after 15 power iterations {product / 1.02:.4g} "
                  f"(x1.02 = {product:.4g}; band_metric {t_product:.1f} s); converged "
                  f"{exact:.4g} ({pairs} forward/adjoint pairs, {t_exact:.1f} s): the "
                  f"product's step is {exact / product:.3f} x 1/alpha", flush=True)
            report.append(row)
            del op, model
    if args.json:
        from kaleidospec.experiments import write_json

        write_json(Path(args.json), report)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
