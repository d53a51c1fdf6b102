"""``kaleidospec reconstruct``: a cube from a measurement file and a mask file.

Standard single-view convention (MST / TSA-Net): mask H×W, band l shifted right by step·l,
measurement H×(W + step·(L−1)).  Every input is checked before any work starts (the output
location too: it must not be an input, and its folder must exist and accept files), and the
output is written atomically, so a bad input gives one line on stderr, exit status 2 and no
file; the inputs are only read.  A boolean mask file is read as 0/1.  Warnings (e.g. a
measurement negative beyond read noise, see :mod:`recon.app`) are one line each on stderr,
``kaleidospec: warning: ...``, and do not change the exit status.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

OUT_SUFFIXES = (".npz", ".npy", ".exr", ".mat")


def parse_wavelengths(spec: str, n_bands: int, truth_wl=None):
    """``START:STOP:COUNT`` (evenly spaced, inclusive) or ``infer`` (from the truth file if it
    has them, else unknown) → array (L,) or None."""
    import numpy as np

    from recon.errors import InputError

    if spec.strip().lower() == "infer":
        return truth_wl
    parts = spec.split(":")
    try:
        if len(parts) != 3:
            raise ValueError
        start, stop, count = float(parts[0]), float(parts[1]), int(parts[2])
    except ValueError:
        raise InputError(f"--wavelengths must be START:STOP:COUNT (e.g. 450:650:28) or 'infer', got {spec!r}") from None
    if count != n_bands:
        raise InputError(f"--wavelengths gives {count} bands but the reconstruction has {n_bands}")
    if not (np.isfinite(start) and np.isfinite(stop)) or start <= 0 or (count > 1 and stop <= start):
        raise InputError(f"--wavelengths: need 0 < START < STOP, got {spec!r}")
    return np.linspace(start, stop, count)


def reconstruct(
    measurement: Path = typer.Option(..., "--measurement", "-m", help="Measurement H×Wm (.npy, .mat or .exr)."),
    mask: Path = typer.Option(..., "--mask", help="Coded-aperture mask H×W (.npy, .mat or .exr)."),
    step: int = typer.Option(..., "--step", help="Dispersion step in pixels per band."),
    out: Path = typer.Option(..., "--out", "-o", help="Output cube (.npz, .npy, .exr or .mat)."),
    bands: Optional[int] = typer.Option(None, "--bands", help="Number of bands (default: what the widths imply, (Wm − W)/step + 1)."),
    solver: str = typer.Option("gap-tv", "--solver", help="Solver: gap-tv (fastest on clean data), fista-tv (robust to noise) or twist (the paper's)."),
    iters: int = typer.Option(50, "--iters", help="Iterations."),
    tau: Optional[float] = typer.Option(None, "--tau", help="TV weight (default: the solver's own)."),
    truth: Optional[Path] = typer.Option(None, "--truth", help="Reference cube (H, W, L) for PSNR/SSIM/SAM."),
    wavelengths: str = typer.Option("infer", "--wavelengths", help="START:STOP:COUNT in nm, or 'infer' (from --truth)."),
    measurement_key: Optional[str] = typer.Option(None, "--measurement-key", help="Variable/channel name in the measurement file."),
    mask_key: Optional[str] = typer.Option(None, "--mask-key", help="Variable/channel name in the mask file."),
    truth_key: Optional[str] = typer.Option(None, "--truth-key", help="Variable name in the truth file."),
    progress: bool = typer.Option(False, "--progress/--no-progress", help="Show a progress bar."),
) -> None:
    """Reconstruct a hyperspectral cube from a single-view CASSI measurement."""
    import sys
    import warnings

    from recon.app import (NegativeMeasurementWarning, reconstruct_standard, solver_names,
                           standard_n_bands)
    from recon.errors import InputError
    from recon.io.arrays import read_array2d
    from recon.io.atomic import check_output
    from recon.io.cubes import read_cube, write_cube

    def one_line_warning(message, category, filename, lineno, file=None, line=None):
        print(f"kaleidospec: warning: {message}", file=sys.stderr)

    # -- everything that can be checked before the (long) solve --------------------------------
    if solver not in solver_names():
        raise InputError(f"--solver must be one of {', '.join(solver_names())}, got {solver!r}")
    if iters < 1:
        raise InputError(f"--iters must be >= 1, got {iters}")
    if out.suffix.lower() not in OUT_SUFFIXES:
        raise InputError(f"{out}: output must end in {', '.join(OUT_SUFFIXES)}")
    check_output(out, (measurement, mask, truth))

    g = read_array2d(measurement, key=measurement_key, what="measurement")
    m = read_array2d(mask, key=mask_key, what="mask", allow_bool=True)
    if g.shape[0] != m.shape[0]:
        raise InputError(f"{measurement}: height {g.shape[0]} does not match the mask's {m.shape[0]} ({mask})")
    n_bands = standard_n_bands(m.shape[1], g.shape[1], step)
    if bands is not None and bands != n_bands:
        raise InputError(
            f"--bands {bands} does not fit: mask width {m.shape[1]}, measurement width {g.shape[1]} "
            f"and step {step} imply {n_bands}"
        )
    truth_cube = truth_wl = None
    if truth is not None:
        truth_cube, truth_wl = read_cube(truth, key=truth_key)
        want = (m.shape[0], m.shape[1], n_bands)
        if truth_cube.shape != want:
            raise InputError(f"{truth}: truth shape {truth_cube.shape} does not match the reconstruction {want}")
    wl = parse_wavelengths(wavelengths, n_bands, truth_wl)
    if out.suffix.lower() == ".exr" and wl is None:
        raise InputError(f"{out}: spectral OpenEXR needs wavelengths; pass --wavelengths START:STOP:COUNT")

    # -- solve -----------------------------------------------------------------------------------
    with warnings.catch_warnings():
        warnings.simplefilter("always", NegativeMeasurementWarning)
        warnings.showwarning = one_line_warning
        cube, info = reconstruct_standard(
            g, m, step, n_bands, solver=solver, iters=iters, tau=tau, truth=truth_cube,
            wavelengths=wl, progress=progress,
        )
    try:
        write_cube(out, cube, wl, protect=(measurement, mask, truth))
    except OSError as err:  # disk full, or the folder changed during the solve
        raise InputError(f"{out}: cannot write ({err.strerror or err})") from None

    print(f"{solver}: {info['iters']} iterations on {cube.shape[0]}x{cube.shape[1]}x{cube.shape[2]} "
          f"in {info['wall_seconds']:.2f} s (wall)")
    if "metrics" in info:
        mt = info["metrics"]
        ssim = "n/a" if mt["ssim"] is None else f"{mt['ssim']:.4f}"
        print(f"PSNR {mt['psnr']:.2f} dB (band-wise {mt['psnr_bandwise']:.2f} dB)  SSIM {ssim}  "
              f"SAM {mt['sam_deg']:.2f} deg")
        if "delta_e2000" in mt:
            print(f"CIEDE2000 {mt['delta_e2000']:.2f}")
    print(f"wrote {out}")
