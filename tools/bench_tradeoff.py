"""Run time against error: solver × iterations × views × noise on the simulator's ``small`` design.

The problem (numbers from :func:`sim.optics.design.get_design`):

- default: the ``small`` design: views of ``view_size_px`` (158 px) square, its 11 bands
  (450-700 nm) and its prism dispersion ``dispersion_px`` (~17 px, sub-pixel, not linear);
- ``--full``: 256×256×28 (28 bands over 450-700 nm) with the ``paper`` design's dispersion at
  those wavelengths (~50 px).

Operator: :func:`recon.operators.kaleidoscope_cassi` with 1, 2, 3, 5 views (centre, left,
right, top, bottom; dispersion inversion on), each view with its own seeded random mask of
2×2-pixel cells (the design's cell size and fill factor; the view's code region of
``Design.mask_pattern()`` would be the same kind of pattern).  Ground truth: the built-in
``colorchecker`` (and with ``--full`` also ``natural``) scene of :mod:`scenes`, maximum 1.
Noise: Poisson shot noise plus Gaussian read noise (a quarter of the shot-noise variance) at
a given SNR, or none.

``--priors tv,subspace-tv`` runs every solver with each prior (:mod:`recon.priors`, the solver's
TV weight for all of them), one Pareto front per solver and prior; ``--scene`` replaces the
ColorChecker by another scene or cube file (e.g. a CAVE folder, resampled to the design's size and
bands).

Each (solver, prior, views, noise) is one run of the largest iteration count; a callback records
PSNR/SAM at every iteration count of the sweep (a solver's first k iterations do not depend on
the total, and the seconds reported by the solvers exclude the callback's time).  Writes
``tradeoff.json`` (the table), ``tradeoff_psnr.png`` and ``tradeoff_sam.png`` (metric
against seconds, Pareto front per solver) into ``--out`` (atomically), and prints the table
and, per view count and noise level, the recommended default: the fastest setting within
0.5 dB of the best PSNR.

Usage: python3 tools/bench_tradeoff.py [--out out/tradeoff] [--quick] [--full]
       [--priors tv,subspace-tv] [--scene $KALEIDOSPEC_DATA/cave/egyptian_statue]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from recon.io.atomic import atomic_path
from recon.metrics import psnr, sam
from recon.operators import kaleidoscope_cassi
from recon.solvers import solve

# TV weights for data in [0, 1]: the paper's 0.15 for TwIST (and FISTA, same objective),
# GAP-TV's per-step denoising weight 0.1 (tools/bench_recon.py).
TAU = {"gap-tv": 0.1, "twist": 0.15, "fista-tv": 0.15}
SOLVERS = ("gap-tv", "twist", "fista-tv")
WITHIN_DB = 0.5


def add_noise(g: np.ndarray, snr_db: float, seed: int, read_share: float = 0.25) -> np.ndarray:
    r"""Poisson + read noise at ``snr_db``: :math:`k = \mathrm{SNR}(1+c)\bar g/\overline{g^2}`
    electrons per unit, read variance :math:`c\,k\bar g` (as ``tests/recon/stress``)."""
    g = np.asarray(g, dtype=np.float64)
    if not np.isfinite(snr_db):
        return g.astype(np.float32)
    rng = np.random.default_rng(seed)
    k = 10 ** (snr_db / 10) * (1 + read_share) * g.mean() / np.mean(g * g)
    e = rng.poisson(np.clip(k * g, 0, None)).astype(np.float64)
    e += rng.normal(0.0, np.sqrt(read_share * k * g.mean()), g.shape)
    return (e / k).astype(np.float32)


def problem(full: bool, scene: str, seed: int = 0):
    """(truth (L, H, W) band-major, masks (5, H, W), offsets (L,), description dict)."""
    from scenes.registry import get_scene
    from sim.optics.design import get_design

    small = get_design("small")
    if full:
        size, wl = 256, np.linspace(450.0, 700.0, 28)
        offsets = get_design("paper").dispersion_px_at(wl)
    else:
        size, wl = small.view_size_px, small.wavelengths
        offsets = small.dispersion_px
    cell = max(1, int(round(small.mask_cell_px)))
    rng = np.random.default_rng(seed)
    nc = -(-size // cell)
    cells = rng.random((5, nc, nc)) < small.mask_fill
    masks = np.repeat(np.repeat(cells, cell, 1), cell, 2)[:, :size, :size].astype(np.float32)
    cube, _ = get_scene(scene, (size, size), wl)
    cube = np.asarray(cube, np.float32)
    cube /= cube.max()
    truth = np.ascontiguousarray(np.moveaxis(cube, 2, 0))
    desc = {"size": size, "bands": int(wl.size), "wavelengths_nm": [float(w) for w in wl],
            "offsets_px": [float(o) for o in offsets], "mask_cell_px": cell, "scene": scene,
            "design": "paper dispersion, 256x256x28" if full else "small"}
    return truth, masks, np.asarray(offsets, np.float64), desc


def run_one(solver, op, g, truth_hwl, checkpoints, prior="tv"):
    """One run; returns [{iters, seconds, psnr, sam}] at the checkpoints."""
    rows, want = [], set(checkpoints)

    def cb(it, x, info):
        if it in want:
            est = np.moveaxis(x, 0, 2)
            rows.append({"iters": it, "seconds": float(info["seconds"]),
                         "psnr": float(psnr(est, truth_hwl)), "sam": float(sam(est, truth_hwl))})

    res = solve(solver, op, g, iters=max(checkpoints), tau=TAU[solver], callback=cb, prior=prior)
    return rows, res


def pareto(points):
    """Indices of the points not dominated in (fewer seconds, higher value)."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], -points[i][1]))
    front, best = [], -np.inf
    for i in order:
        if points[i][1] > best:
            front.append(i)
            best = points[i][1]
    return front


def recommend(rows):
    """The fastest row within WITHIN_DB of the best PSNR."""
    best = max(r["psnr"] for r in rows)
    ok = [r for r in rows if r["psnr"] >= best - WITHIN_DB]
    return min(ok, key=lambda r: r["seconds"]), best


def plot(table, views, noises, key, path, priors=("tv",)):
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(noises), len(views), figsize=(3.6 * len(views), 2.9 * len(noises)),
                             squeeze=False, sharex=False)
    colours = {"gap-tv": "tab:blue", "twist": "tab:red", "fista-tv": "tab:green"}
    styles = ["-", "--", ":", "-."]
    for i, nz in enumerate(noises):
        for j, k in enumerate(views):
            ax = axes[i][j]
            for s, (pi, prior) in ((s, p) for s in SOLVERS for p in enumerate(priors)):
                rows = [r for r in table if r["solver"] == s and r["views"] == k
                        and r["snr_db"] == nz and r.get("prior", "tv") == prior]
                if not rows:
                    continue
                label = s if len(priors) == 1 else f"{s} / {prior}"
                pts = [(r["seconds"], r[key] if key == "psnr" else -r[key]) for r in rows]
                xs = [r["seconds"] for r in rows]
                ys = [r[key] for r in rows]
                ax.plot(xs, ys, "o", ms=3, color=colours[s], alpha=0.5)
                fr = pareto(pts)
                ax.plot([xs[f] for f in fr], [ys[f] for f in fr], styles[pi % len(styles)],
                        color=colours[s], label=label)
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
            ax.set_title(f"{k} view(s), {'no noise' if nz is None else f'{nz:g} dB'}",
                         fontsize=9)
            ax.set_xlabel("seconds")
            ax.set_ylabel("PSNR (dB)" if key == "psnr" else "SAM (deg)")
            ax.grid(True, alpha=0.3)
            if i == 0 and j == 0:
                ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/tradeoff", help="output folder (default out/tradeoff)")
    ap.add_argument("--quick", action="store_true", help="fewer iterations, views and noise levels")
    ap.add_argument("--full", action="store_true", help="256x256x28 instead of the small design")
    ap.add_argument("--priors", default="tv", help="comma-separated recon.priors names")
    ap.add_argument("--scene", default=None,
                    help="a scene name or cube file instead of the ColorChecker")
    args = ap.parse_args(argv)
    from recon.priors import check_prior_name

    priors = [check_prior_name(p.strip()) for p in args.priors.split(",") if p.strip()]

    if args.quick:
        views, noises, checkpoints = (1, 3), (None, 30.0), (5, 10, 20, 50)
    else:
        views, noises, checkpoints = (1, 2, 3, 5), (None, 30.0, 20.0), (5, 10, 20, 30, 50, 100, 200)
    scenes = ("colorchecker", "natural") if args.full else ("colorchecker",)
    if args.scene:
        scenes = (args.scene,)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    table, problems = [], []
    t_start = time.perf_counter()
    for scene in scenes:
        truth, masks, offsets, desc = problem(args.full, scene)
        problems.append(desc)
        truth_hwl = np.moveaxis(truth, 0, 2)
        for k in views:
            op = kaleidoscope_cassi(masks, offsets, k)
            clean = op.forward(truth)
            for nz in noises:
                g = add_noise(clean, np.inf if nz is None else nz, seed=1)
                for s, prior in ((s, p) for s in SOLVERS for p in priors):
                    rows, res = run_one(s, op, g, truth_hwl, checkpoints, prior)
                    extra = {}
                    if s == "twist":
                        extra = {"svd_doublings": res.info.get("svd_doublings"),
                                 "rejected": res.info.get("rejected")}
                    for r in rows:
                        table.append({"scene": scene, "solver": s, "prior": prior, "views": k,
                                      "snr_db": nz, "tau": TAU[s], **r, **extra})
                    last = rows[-1]
                    print(f"{Path(scene).name:12s} {k} view(s) "
                          f"{'clean' if nz is None else f'{nz:g} dB':>6s} {s:8s} {prior:12s} " + "  ".join(f"{r['iters']}:{r['psnr']:.2f}dB/{r['seconds']:.2f}s"
                                                  for r in rows), flush=True)
                    del last

    # Recommendations: per scene, view count and noise level.
    recs = []
    print("\nrecommended default (fastest within %.1f dB of the best PSNR):" % WITHIN_DB)
    for scene in scenes:
        for nz in noises:
            for k in views:
                rows = [r for r in table if r["scene"] == scene and r["views"] == k
                        and r["snr_db"] == nz]
                r, best = recommend(rows)
                recs.append({"scene": scene, "views": k, "snr_db": nz, "solver": r["solver"],
                             "prior": r["prior"],
                             "iters": r["iters"], "seconds": r["seconds"], "psnr": r["psnr"],
                             "sam": r["sam"], "best_psnr": best})
                print(f"  {Path(scene).name:12s} {'clean' if nz is None else f'{nz:g} dB':>6s} "
                      f"{k} view(s): {r['solver']} / {r['prior']} {r['iters']} it, {r['seconds']:.2f} s, {r['psnr']:.2f} dB "
                      f"(best {best:.2f} dB), SAM {r['sam']:.2f} deg")

    doc = {"problems": problems, "tau": TAU, "priors": priors, "views": list(views),
           "snr_db": [n for n in noises], "checkpoints": list(checkpoints),
           "within_db": WITHIN_DB, "table": table, "recommended": recs,
           "wall_seconds": time.perf_counter() - t_start}
    with atomic_path(out / "tradeoff.json") as tmp:
        tmp.write_text(json.dumps(doc, indent=1, allow_nan=False))
    for scene in scenes:
        sub = [r for r in table if r["scene"] == scene]
        suffix = "" if len(scenes) == 1 else f"_{scene}"
        plot(sub, views, noises, "psnr", out / f"tradeoff_psnr{suffix}.png", priors)
        plot(sub, views, noises, "sam", out / f"tradeoff_sam{suffix}.png", priors)
    print(f"wrote {out / 'tradeoff.json'} and plots in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
