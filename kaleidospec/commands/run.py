"""``kaleidospec run``: render a scene, calibrate (cached), reconstruct per view count, report.

Writes into ``--out`` (built in a temporary folder beside it and renamed at the end, so a bad
input or a failure leaves an existing folder untouched): ``raw.exr`` + ``raw.json``,
``truth.exr`` and ``srgb_truth.png`` (the truth on the reconstruction grid),
``cube_<n>views.exr``, ``srgb_<n>views.png``, ``bands.png`` (band montage), ``spectra.png``
(spectra of a few patches or points against the truth) and ``metrics.json``.
"""

from __future__ import annotations

from pathlib import Path
from typing import List, Optional

import typer

from kaleidospec.commands.prior_option import RUN_DEFAULT, check_prior, prior_option


def run(
    scene: str = typer.Option(..., "--scene", help="Built-in scene name or a cube file."),
    out: Path = typer.Option(..., "--out", "-o", help="Output folder."),
    design: str = typer.Option("small", "--design", help="Design preset: small or paper."),
    set_: Optional[List[str]] = typer.Option(None, "--set", help="Override a design field, "
                                             "name=value (repeatable)."),
    views: str = typer.Option("1,2,3,5,9", "--views", help="View counts, comma-separated "
                              "(views added in the order centre, left, right, top, bottom, "
                              "corners)."),
    solver: str = typer.Option("fista-tv", "--solver", help="Solver (recon.solvers); default fista-tv."),
    # kaleidospec.reconstruct.DEFAULTS["iters"], written out so that --help imports nothing
    # heavy (tests/kaleidospec/test_cli_run.py checks that they agree).
    iters: int = typer.Option(1000, "--iters", help="Most iterations (the stopping rule ends "
                              "a solve before them)."),
    tol: float = typer.Option(1e-3, "--tol", help="Stop once the relative change "
                              "of the cube per iteration falls below this (0: run all "
                              "--iters)."),
    tau: Optional[float] = typer.Option(None, "--tau", help="TV weight, >= 0 (default: "
                                        "fista-tv, twist and admm follow the noise the "
                                        "calibration measured; gap-tv its own); another "
                                        "prior's strength (default: the prior's own)."),
    prior: str = prior_option(RUN_DEFAULT),
    seed: int = typer.Option(0, "--seed", help="Sensor-noise seed of the scene frame."),
    raw: Optional[Path] = typer.Option(None, "--raw", help="Reconstruct this raw frame (.exr "
                                       "+ sidecar) instead of rendering; the scene gives the "
                                       "truth.  Its design hash must match the design's."),
    oracle: bool = typer.Option(True, "--oracle/--no-oracle", help="Also reconstruct with the "
                                "exact operator (for the calibration-vs-oracle figure)."),
    model: str = typer.Option("shifted", "--model", help="Calibrated forward model: shifted "
                              "(per-band mask images, the default) or footprint (every pixel's "
                              "weights measured with comb targets: 15 more captures per band "
                              "for small, within 1 dB of the exact operator)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bars."),
) -> None:
    """Render SCENE, reconstruct it from 1..9 views with the calibrated operator, and report."""
    from kaleidospec.instrument import design_for_views, get_design, parse_overrides
    from kaleidospec.models import check_model
    from kaleidospec.run import parse_views, run as run_scene
    from recon.app import solver_names
    from recon.errors import InputError
    from recon.priors.tv import check_weight

    if solver not in solver_names():
        raise InputError(f"--solver must be one of {', '.join(solver_names())}, got {solver!r}")
    if iters < 1:
        raise InputError(f"--iters must be >= 1, got {iters}")
    if not tol >= 0:
        raise InputError(f"--tol must be >= 0, got {tol}")
    check_model(model)
    check_prior(prior)
    if tau is not None:
        check_weight(tau, "--tau")
    counts = parse_views(views)
    d = get_design(design, parse_overrides(set_))
    raw_frame = None
    if raw is not None:
        from recon.io.raw import read_raw

        if out.resolve() == raw.resolve().parent or out.resolve() in raw.resolve().parents:
            raise InputError(f"{out}: holds the input {raw}; choose another --out")
        frame, meta = read_raw(raw)
        raw_frame = (frame, meta)
    else:
        d = design_for_views(d, max(counts))
    run_scene(scene, d, out, views=counts, solver=solver, iters=iters, tol=tol or None,
              tau=tau, seed=seed, progress=progress, oracle=oracle and raw is None,
              raw=raw_frame, widen=raw is None, log=typer.echo, model=model, prior=prior)
    typer.echo(f"wrote {out}/")
