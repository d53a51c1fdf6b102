"""``kaleidospec render``: a raw 3×3 frame of a scene through the simulated instrument.

The output is checked before the render (it must not be the scene file, and missing folders
above it must be creatable); the raw frame, its sidecar and the ground truth are each written
atomically, and folders created for them are removed again if a write fails.
"""

from __future__ import annotations

from typing import List, Optional

import typer


def render(
    scene: str = typer.Option(..., "--scene", help="Built-in scene name or a cube file."),
    out: str = typer.Option(..., "--out", help="Output raw frame (.exr); a .json sidecar and "
                            "<stem>_gt.npz (ground truth) are written next to it."),
    design: str = typer.Option("small", "--design", help="Design preset: paper or small."),
    set_: Optional[List[str]] = typer.Option(None, "--set", help="Override a design field, "
                                             "name=value (repeatable)."),
    wavelength: Optional[float] = typer.Option(None, "--wavelength", help="Monochromatic "
                                               "capture at this wavelength (nm)."),
    spp: Optional[int] = typer.Option(None, "--spp", help="Samples per pixel per band of a "
                                      "--direct render (default 64)."),
    direct: bool = typer.Option(False, "--direct", help="Mitsuba's path tracer (a Monte Carlo "
                                "reference) instead of the transport's exact pixel integrals."),
    seed: int = typer.Option(0, "--seed", help="Noise (and direct sampler) seed."),
    sampling: str = typer.Option("box", "--band-sampling", help="box: whole band; centre: "
                                 "band centre only."),
    noise: bool = typer.Option(True, "--noise/--no-noise", help="Shot and read noise."),
) -> None:
    """Render a raw frame of SCENE through the kaleidoscopic CASSI."""
    import math
    import time

    from kaleidospec.instrument import (get_design, parse_overrides, scene_cube,
                                        simulate_frame, write_frame)
    from recon.errors import InputError
    from recon.io.atomic import check_output, output_parents

    if spp is not None and spp < 1:
        raise InputError(f"--spp must be at least 1, got {spp}")
    if wavelength is not None and not math.isfinite(wavelength):
        raise InputError("--wavelength must be a finite number of nm")
    if sampling not in ("box", "centre"):
        raise InputError(f"--band-sampling must be box or centre, got {sampling!r}")
    check_output(out, [scene], parents=True)
    d = get_design(design, parse_overrides(set_))
    cube, wl = scene_cube(scene, d)
    t0 = time.perf_counter()
    frame, meta = simulate_frame(d, cube, wl, direct=direct, spp=spp, seed=seed,
                                 sampling=sampling, wavelength_nm=wavelength, noise=noise,
                                 progress=True)
    meta["scene"] = scene
    meta["render_seconds"] = time.perf_counter() - t0
    with output_parents(out):
        paths = write_frame(out, frame, meta, d, cube, wl, protect=[scene])
    typer.echo(f"wrote {paths['raw']} ({frame.shape[1]}×{frame.shape[0]}, design {d.hash}, "
               f"{meta['render_seconds']:.1f} s)")
