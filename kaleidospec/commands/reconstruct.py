"""``kaleidospec reconstruct``: a cube, and the pictures to look at, from a measurement file and
a mask file.

Standard single-view convention (MST / TSA-Net): mask H×W, band l shifted right by step·l,
measurement H×(W + step·(L−1)).  The mask may also be the 3-D shifted mask cube published with
real captures (TSA-Net's ``mask_3d_shift``, H×(W + step·(L−1))×L: band l's mask where band l
lands on the sensor), or an unshifted H×W×L cube of per-band masks.  Without ``--key`` the
measurement is the first of :data:`recon.io.arrays.MEASUREMENT_KEYS` in the file (``meas_real``,
``meas``, …) or its only 2-D array, the mask likewise (:data:`recon.io.arrays.MASK_KEYS`); the
first line printed says what was read.

Beside the cube (``rec.npz``) go ``rec_srgb.png`` (sRGB preview), ``rec_bands.png`` (band
montage) and, with ``--truth``, ``rec_spectra.png`` (spectra of four points against the truth);
``--no-pictures`` leaves them out.  Pictures need wavelengths: the cube's (``--wavelengths`` or
the truth's), else :func:`recon.io.cubes.standard_wavelengths` (TSA-Net's 28 bands), which is
then said, and not written into the cube.

Every input is checked before any work starts (the outputs too: none may be an input, and
missing folders above them must be creatable); the outputs are written atomically, together:
a bad input or a failed write gives one line on stderr, exit status 2, and no file (folders
made for the outputs are removed again); the inputs are only read.  A boolean mask file is read
as 0/1.  Warnings (e.g. a measurement negative beyond read noise, see :mod:`recon.app`) are one
line each on stderr, ``kaleidospec: warning: ...``, and do not change the exit status.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from kaleidospec.commands.prior_option import check_prior, prior_option

OUT_SUFFIXES = (".npz", ".npy", ".exr", ".mat")
#: Picture files written beside the cube ``<stem><suffix>``: name suffix per picture.
PICTURES = {"srgb": "_srgb.png", "bands": "_bands.png", "spectra": "_spectra.png"}


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


def picture_paths(out: Path, truth: bool) -> dict:
    """The pictures written beside the cube ``out``: ``{"srgb": …, "bands": …[, "spectra": …]}``
    (the spectra need a truth to compare with)."""
    names = [k for k in PICTURES if truth or k != "spectra"]
    return {k: out.with_name(out.stem + PICTURES[k]) for k in names}


def shifted_mask_operator(mask3d, step: int, measurement_shape):
    """The forward operator of a 3-D mask cube in the standard convention.

    Parameters
    ----------
    mask3d : (H, X, L) array
        Per-band masks, either shifted (``X`` = the measurement width: band ``l``'s mask where
        band ``l`` lands, TSA-Net's ``mask_3d_shift``) or not (``X`` = the scene width
        ``Wm − step·(L−1)``: each band's mask on the scene grid).
    step : int
        Dispersion step (px per band).
    measurement_shape : (H, Wm)

    Returns
    -------
    recon.operators.CalibratedCassi
        ``(L, H, W) -> (1, H, Wm)``: the measured per-band masks times the band shifted by
        ``step·l``; for a mask cube built from a 2-D mask it is :func:`standard_cassi`'s
        operator.

    Raises
    ------
    InputError
        When the cube fits neither layout.
    """
    import numpy as np

    from recon.errors import InputError
    from recon.operators import CalibratedCassi

    m = np.asarray(mask3d, dtype=np.float32)
    hg, wm = measurement_shape
    n_bands = m.shape[2]
    w = wm - step * (n_bands - 1)
    if m.shape[0] != hg or w < 1 or m.shape[1] not in (wm, w):
        raise InputError(
            f"a 3-D mask must be H×(W+step·(L−1))×L (shifted, like mask_3d_shift) or H×W×L for the "
            f"measurement's {hg}×{wm} and step {step}: with L = {n_bands}, {hg}×{wm}×{n_bands} or "
            f"{hg}×{w}×{n_bands}, got {'×'.join(map(str, m.shape))}")
    bands = np.zeros((n_bands, hg, wm), np.float32)
    for l in range(n_bands):
        a = step * l
        # A shifted cube already holds band l's mask at columns a … a+W; an unshifted one is
        # put there.  Columns outside that window are never lit by band l and are ignored.
        bands[l, :, a:a + w] = m[:, a:a + w, l] if m.shape[1] == wm else m[:, :, l]
    return CalibratedCassi(bands, step * np.arange(n_bands, dtype=np.float64),
                           cube_shape=(n_bands, hg, w))


def reconstruct(
    measurement: Path = typer.Option(..., "--measurement", "-m", help="Measurement H×Wm (.npy, .npz, .mat or .exr)."),
    mask: Path = typer.Option(..., "--mask", help="Coded-aperture mask: H×W, or a 3-D mask cube H×Wm×L (shifted, like TSA-Net's mask_3d_shift) or H×W×L (.npy, .npz, .mat or .exr)."),
    step: int = typer.Option(..., "--step", help="Dispersion step in pixels per band."),
    out: Path = typer.Option(..., "--out", "-o", help="Output cube (.npz, .npy, .exr or .mat); missing folders are created."),
    bands: Optional[int] = typer.Option(None, "--bands", help="Number of bands (default: what the widths imply, (Wm − W)/step + 1, or a 3-D mask's)."),
    solver: str = typer.Option("gap-tv", "--solver", help="Solver: gap-tv (fastest on clean data), fista-tv (robust to noise), twist (the paper's) or admm (for plug-and-play priors)."),
    iters: int = typer.Option(50, "--iters", help="Iterations (at most, with --tol)."),
    tol: Optional[float] = typer.Option(None, "--tol", help="Stop once the relative change falls below it, as run does with 0.001 (default: run all --iters)."),
    noise: Optional[float] = typer.Option(None, "--noise", help="The measurement's rms noise, in its units: solve as run solves a frame (operator and data at unit mean row norm; the weights of fista-tv, twist, admm and of the subspace priors follow this noise)."),
    tau: Optional[float] = typer.Option(None, "--tau", help="TV weight, >= 0 (default: the solver's own); another prior's strength (default: the prior's own)."),
    prior: str = prior_option(),
    truth: Optional[Path] = typer.Option(None, "--truth", help="Reference cube (H, W, L) for PSNR/SSIM/SAM and the spectra picture."),
    wavelengths: str = typer.Option("infer", "--wavelengths", help="START:STOP:COUNT in nm, or 'infer' (from --truth)."),
    measurement_key: Optional[str] = typer.Option(None, "--key", "--measurement-key", help="Variable/channel name of the measurement (default: meas_real, meas, measurement, … or the file's only 2-D array)."),
    mask_key: Optional[str] = typer.Option(None, "--mask-key", help="Variable/channel name of the mask (default: mask_3d_shift, mask, … or the file's only mask-shaped array)."),
    truth_key: Optional[str] = typer.Option(None, "--truth-key", help="Variable name in the truth file."),
    pictures: bool = typer.Option(True, "--pictures/--no-pictures", help="Write the sRGB preview, the band montage and (with --truth) the spectra beside the cube."),
    progress: bool = typer.Option(False, "--progress/--no-progress", help="Show a progress bar."),
) -> None:
    """Reconstruct a hyperspectral cube from a single-view CASSI measurement, with pictures."""
    import contextlib
    import math
    import sys
    import warnings

    from recon.app import (NegativeMeasurementWarning, reconstruct as solve, reconstruct_standard,
                           solver_names, standard_n_bands)
    from recon.errors import InputError
    from recon.io.arrays import MASK_KEYS, MEASUREMENT_KEYS, read_named_array
    from recon.io.atomic import atomic_path, check_output, output_parents
    from recon.io.cubes import read_cube, standard_wavelengths, write_cube
    from recon.priors.tv import check_weight

    def one_line_warning(message, category, filename, lineno, file=None, line=None):
        print(f"kaleidospec: warning: {message}", file=sys.stderr)

    # -- everything that can be checked before the (long) solve --------------------------------
    if solver not in solver_names():
        raise InputError(f"--solver must be one of {', '.join(solver_names())}, got {solver!r}")
    check_prior(prior)
    if tau is not None:
        check_weight(tau, "--tau")
    if iters < 1:
        raise InputError(f"--iters must be >= 1, got {iters}")
    if tol is not None and not (math.isfinite(tol) and tol > 0):
        raise InputError(f"--tol must be a positive number, got {tol}")
    if noise is not None and not (math.isfinite(noise) and noise > 0):
        raise InputError(f"--noise must be a positive rms in the measurement's units, got {noise}")
    if step < 1:
        raise InputError(f"--step must be a positive number of pixels per band, got {step}")
    if out.suffix.lower() not in OUT_SUFFIXES:
        raise InputError(f"{out}: output must end in {', '.join(OUT_SUFFIXES)}")
    inputs = (measurement, mask, truth)
    outputs = {"cube": out, **(picture_paths(out, truth is not None) if pictures else {})}
    for path in outputs.values():
        check_output(path, inputs, parents=True)

    g, g_name = read_named_array(measurement, key=measurement_key, ndim=2, what="measurement",
                                 preferred=MEASUREMENT_KEYS)
    m, m_name = read_named_array(mask, key=mask_key, ndim=(2, 3), what="mask", allow_bool=True,
                                 preferred=MASK_KEYS)
    if m.shape[0] != g.shape[0]:
        raise InputError(f"{measurement}: height {g.shape[0]} does not match the mask's {m.shape[0]} ({mask})")
    if m.ndim == 2:
        n_bands = standard_n_bands(m.shape[1], g.shape[1], step)
        cube_hw = m.shape
    else:
        op = shifted_mask_operator(m, step, g.shape)
        n_bands, cube_hw = op.ishape[0], op.ishape[1:]
    if bands is not None and bands != n_bands:
        raise InputError(
            f"--bands {bands} does not fit: the mask {'×'.join(map(str, m.shape))}, measurement "
            f"width {g.shape[1]} and step {step} imply {n_bands}")

    def named(path, name):
        return f"{path.name}[{name!r}]" if name is not None else path.name
    layout = ("2-D" if m.ndim == 2 else
              "3-D, shifted" if m.shape[1] == g.shape[1] else "3-D, per band")
    print(f"measurement {named(measurement, g_name)} {g.shape[0]}×{g.shape[1]}, mask "
          f"{named(mask, m_name)} {'×'.join(map(str, m.shape))} ({layout}), step {step}: "
          f"{n_bands} bands")
    truth_cube = truth_wl = None
    if truth is not None:
        truth_cube, truth_wl = read_cube(truth, key=truth_key)
        want = (*cube_hw, n_bands)
        if truth_cube.shape != want:
            raise InputError(f"{truth}: truth shape {truth_cube.shape} does not match the reconstruction {want}")
    wl = parse_wavelengths(wavelengths, n_bands, truth_wl)
    if out.suffix.lower() == ".exr" and wl is None:
        raise InputError(f"{out}: spectral OpenEXR needs wavelengths; pass --wavelengths START:STOP:COUNT")

    # -- solve -----------------------------------------------------------------------------------
    with warnings.catch_warnings():
        warnings.simplefilter("always", NegativeMeasurementWarning)
        warnings.showwarning = one_line_warning
        settings = dict(solver=solver, iters=iters, tau=tau, prior=prior, truth=truth_cube,
                        wavelengths=wl, progress=progress)
        if noise is not None:
            import numpy as np

            from kaleidospec.reconstruct import solve_views
            from recon.operators import standard_cassi

            if m.ndim == 2:
                op = standard_cassi(np.asarray(m, np.float32), step, n_bands)
            cube, info = solve_views(op, np.asarray(g, np.float32), 1, tol=tol, noise=noise,
                                     **settings)
        elif m.ndim == 2:
            cube, info = reconstruct_standard(g, m, step, n_bands, tol=tol, **settings)
        else:
            cube, info = solve(g, op, tol=tol, **settings)

    # -- write the cube and its pictures, all or none --------------------------------------------
    pic_wl = wl if wl is not None else standard_wavelengths(n_bands)
    try:
        with output_parents(out), contextlib.ExitStack() as stack:
            # Each output goes to a temporary file first; they are renamed together at the end
            # (ExitStack), so a failed picture leaves no cube and an older cube untouched.
            tmp = {k: stack.enter_context(atomic_path(path, protect=inputs))
                   for k, path in outputs.items()}
            write_cube(tmp["cube"], cube, wl)
            if pictures:
                _write_pictures(tmp, cube, truth_cube, pic_wl)
    except OSError as err:  # disk full, or the folder changed during the solve
        raise InputError(f"{out}: cannot write ({err.strerror or err})") from None

    print(f"{solver}, prior {info['prior']}: {info['iters']} iterations on {cube.shape[0]}x{cube.shape[1]}x{cube.shape[2]} "
          f"in {info['wall_seconds']:.2f} s (wall)")
    if "metrics" in info:
        mt = info["metrics"]
        ssim = "n/a" if mt["ssim"] is None else f"{mt['ssim']:.4f}"
        print(f"PSNR {mt['psnr']:.2f} dB (band-wise {mt['psnr_bandwise']:.2f} dB)  SSIM {ssim}  "
              f"SAM {mt['sam_deg']:.2f} deg")
        if "delta_e2000" in mt:
            print(f"CIEDE2000 {mt['delta_e2000']:.2f}")
    if pictures and wl is None:
        print(f"pictures: the inputs carry no wavelengths; assumed {pic_wl[0]:.1f}–{pic_wl[-1]:.1f} nm"
              + (" (the standard 28 CASSI bands)" if n_bands == 28 else " (evenly spaced)")
              + "; --wavelengths START:STOP:COUNT sets them")
    print("wrote " + ", ".join(str(p) for p in outputs.values()))


def _write_pictures(paths: dict, cube, truth, wavelengths) -> None:
    """The sRGB preview, the band montage and, with a truth, the spectra of four points
    (:mod:`recon.report`, the pictures ``kaleidospec run`` writes too)."""
    from recon.report import band_montage, grid_regions, spectra_plot, srgb_image, write_png

    rows = {"reconstruction": cube}
    write_png(paths["srgb"], srgb_image(cube, wavelengths)[0])
    band_montage(paths["bands"], truth, rows, wavelengths)
    if "spectra" in paths:
        spectra_plot(paths["spectra"], truth, rows, wavelengths, grid_regions(cube.shape))
