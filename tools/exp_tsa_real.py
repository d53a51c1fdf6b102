"""TSA-Net's real CASSI captures reconstructed with each prior, pictures side by side.

The five real captures published with TSA-Net (Meng, Ma, Yuan, ECCV 2020; the public
repository ``mengziyi64/TSA-Net``, folder ``TSA_Net_realdata/Data``: ``scene1.mat`` …
``scene5.mat`` with ``meas_real`` 660×714, and ``mask.mat`` with the 660×660 mask) are read
from ``$KALEIDOSPEC_DATA/tsa/`` (never part of the repository).  Each capture is reconstructed
with each prior by the command a user runs::

    kaleidospec reconstruct --measurement scene1.mat --mask mask.mat --step 2 --prior P --out …

(its defaults: GAP, 50 iterations, the solver's TV weight; 28 bands), so the figures are those
of the product.  There is no ground truth for real captures: the output is a figure of sRGB
previews (one row per capture, one column per prior, every panel of a row at the exposure of
its TV panel, so brightness compares) and one band (``--band``, by default the 14th) per prior,
with each run's solve time and wall time (the process, Python's start included).

Usage::

    python3 tools/exp_tsa_real.py --priors tv,subspace-tv,subspace-nlr --solver-args "--iters 100" \
        --figure docs/tsa_real_priors.jpg

Writes the cubes and ``exp_tsa_real.json`` in ``--out``, the figure atomically.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from kaleidospec.experiments import (matplotlib_agg, parse_list, save_figure, srgb, write_json)

SOLVE_LINE = re.compile(r"(\d+) iterations on \S+ in ([0-9.]+) s")


def tsa_folder() -> Path | None:
    """``$KALEIDOSPEC_DATA/tsa`` if it holds ``mask.mat``, else None."""
    root = os.environ.get("KALEIDOSPEC_DATA")
    if not root:
        return None
    folder = Path(root) / "tsa"
    return folder if (folder / "mask.mat").is_file() else None


def run_one(folder: Path, scene: str, prior: str, out: Path, extra: list[str]) -> dict:
    """One ``kaleidospec reconstruct`` run: its solve seconds, iterations and wall seconds."""
    target = out / f"{scene}_{prior}.npz"
    cmd = ["kaleidospec", "reconstruct", "--measurement", str(folder / f"{scene}.mat"),
           "--mask", str(folder / "mask.mat"), "--step", "2", "--prior", prior,
           "--no-pictures", "--no-progress", "--out", str(target), *extra]
    if target.exists():
        target.unlink()  # the command never overwrites: this tool owns its output folder
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr}")
    m = SOLVE_LINE.search(proc.stdout + proc.stderr)
    return {"scene": scene, "prior": prior, "cube": str(target), "wall_s": wall,
            "iterations": int(m.group(1)) if m else None,
            "solve_s": float(m.group(2)) if m else None}


def figure(rows: list[dict], scenes, priors, band: int, path: Path) -> None:
    """sRGB previews and one band: rows = captures, columns = priors (sRGB) then priors (band)."""
    from recon.io.cubes import standard_wavelengths
    from recon.metrics import cube_to_xyz

    plt = matplotlib_agg()
    by = {(r["scene"], r["prior"]): r for r in rows}
    n = len(priors)
    fig, axes = plt.subplots(len(scenes), 2 * n, figsize=(2.3 * 2 * n, 2.4 * len(scenes)),
                             squeeze=False)
    for i, scene in enumerate(scenes):
        cubes = [np.load(by[scene, p]["cube"])["cube"] for p in priors]
        wl = standard_wavelengths(cubes[0].shape[2])
        ref = np.clip(cubes[0], 0, None)
        peak = float(np.percentile(cube_to_xyz(ref, wl)[..., 1], 99.0))
        top = float(np.percentile(ref[..., band], 99.5))
        for j, (p, c) in enumerate(zip(priors, cubes)):
            r = by[scene, p]
            a = axes[i, j]
            a.imshow(srgb(c, wl, peak))
            a.set_title(f"{scene} · {p}\nsolve {r['solve_s']:.1f} s", fontsize=8)
            b = axes[i, n + j]
            b.imshow(np.clip(c[..., band], 0, None), cmap="gray", vmin=0, vmax=top)
            b.set_title(f"{p}: {wl[band]:.0f} nm", fontsize=8)
        for a in axes[i]:
            a.set_xticks([])
            a.set_yticks([])
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--priors", default="tv,subspace-tv")
    ap.add_argument("--scenes", default="scene1,scene2,scene3,scene4,scene5")
    ap.add_argument("--band", type=int, default=13, help="band index shown in grey (0-based)")
    ap.add_argument("--out", default="out/tsa_real", help="cubes and JSON")
    ap.add_argument("--figure", default=None, help="the side-by-side figure (PNG or JPEG, by its suffix)")
    ap.add_argument("--solver-args", default="", help="extra arguments for every run, quoted")
    args = ap.parse_args(argv)

    folder = tsa_folder()
    if folder is None:
        sys.exit("set KALEIDOSPEC_DATA to a folder whose tsa/ holds TSA-Net's real captures "
                 "(scene1.mat … scene5.mat and mask.mat, from TSA_Net_realdata/Data)")
    priors, scenes = parse_list(args.priors), parse_list(args.scenes)
    missing = [s for s in scenes if not (folder / f"{s}.mat").is_file()]
    if missing:
        sys.exit(f"missing captures in {folder}: {', '.join(missing)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for scene in scenes:
        for prior in priors:
            r = run_one(folder, scene, prior, out, args.solver_args.split())
            rows.append(r)
            print(f"{scene:8s} {prior:14s} {r['iterations']} it  solve {r['solve_s']:6.2f} s  "
                  f"wall {r['wall_s']:6.2f} s", flush=True)
    for prior in priors:
        mine = [r for r in rows if r["prior"] == prior]
        print(f"mean {prior:14s} solve {np.mean([r['solve_s'] for r in mine]):6.2f} s  "
              f"wall {np.mean([r['wall_s'] for r in mine]):6.2f} s")
    load = os.getloadavg()[0]
    write_json(out / "exp_tsa_real.json", {"rows": rows, "load_average": load,
                                           "cpus": os.cpu_count()})
    print(f"load average {load:.2f} ({os.cpu_count()} CPUs)")
    if args.figure:
        figure(rows, scenes, priors, args.band, Path(args.figure))
        print(f"wrote {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
