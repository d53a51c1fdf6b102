"""``kaleidospec sweep mirror-length|prism-apex``: design sweeps with the physical simulator."""

from __future__ import annotations

from typing import List, Optional

import typer

app = typer.Typer(help="Design sweeps: mirror length and prism apex angle.", no_args_is_help=True)

#: Default ranges (start, stop, step): ten points each on the ``small`` design.
DEFAULT_RANGES = {"mirror-length": (150.0, 420.0, 30.0), "prism-apex": (25.0, 70.0, 5.0)}


def _run(kind: str, start, stop, step, design, set_, scene, views, solver, iters, tau, seed,
         spp, recon, out, workers, scheduler) -> None:
    """Shared body of both commands (heavy imports here, not at module level)."""
    import os

    from kaleidospec.instrument import parse_overrides
    from kaleidospec.sweep import SweepSettings, run_sweep, sweep_values
    from recon.errors import InputError
    from recon.io.atomic import check_output, output_parents
    from recon.priors.tv import check_weight

    d0, d1, ds = DEFAULT_RANGES[kind]
    values = sweep_values(d0 if start is None else start, d1 if stop is None else stop,
                          ds if step is None else step)
    if workers is not None and workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    if tau is not None:
        check_weight(tau, "--tau")
    given = {k: v for k, v in (("solver", solver), ("iters", iters)) if v is not None}
    settings = SweepSettings(kind=kind, design=design, overrides=parse_overrides(set_),
                             scene=scene, n_views=views, tau=tau, seed=seed, spp=spp,
                             reconstruct=recon, **given)
    # Validate the base design (unknown fields, bad values) before any work starts.
    settings.base_design()
    out = out or f"sweeps/{kind}-{design}"
    # A built-in scene's name is no file to protect (an --out of that name is fine).
    check_output(out, [scene if os.path.exists(scene) else None], folder=True, parents=True)
    with output_parents(out):
        run_sweep(settings, values, out, workers=workers, scheduler=scheduler, log=typer.echo)


def _options(kind: str):
    d0, d1, ds = DEFAULT_RANGES[kind]
    unit = "mm" if kind == "mirror-length" else "degrees"

    def command(
        start: Optional[float] = typer.Option(None, "--start", help=f"First value ({unit}; default {d0:g})."),
        stop: Optional[float] = typer.Option(None, "--stop", help=f"Last value, inclusive ({unit}; default {d1:g})."),
        step: Optional[float] = typer.Option(None, "--step", help=f"Step ({unit}; default {ds:g})."),
        design: str = typer.Option("small", "--design", help="Design preset: small or paper."),
        set_: Optional[List[str]] = typer.Option(None, "--set", help="Override a design field, "
                                                 "name=value (repeatable)."),
        scene: str = typer.Option("colorchecker", "--scene", help="Scene reconstructed at "
                                  "each point (built-in name or cube file)."),
        views: int = typer.Option(5, "--views", help="Views used for the reconstruction (1..9)."),
        solver: Optional[str] = typer.Option(None, "--solver", help="twist, gap-tv or fista-tv "
                                             "(default: kaleidospec run's, fista-tv)."),
        iters: Optional[int] = typer.Option(None, "--iters", help="Most solver iterations "
                                            "(default: kaleidospec run's, 1000, stopping at "
                                            "a relative change below 1e-3)."),
        tau: Optional[float] = typer.Option(None, "--tau", help="TV weight (default: "
                                            "follows the measured noise; gap-tv its own)."),
        seed: int = typer.Option(0, "--seed", help="Render/noise seed."),
        spp: int = typer.Option(8, "--spp", help="Samples per pixel of the measurement renders."),
        recon: bool = typer.Option(True, "--recon/--no-recon", help="Reconstruct at each point "
                                   "(PSNR/SAM) or only measure."),
        out: Optional[str] = typer.Option(None, "--out", help=f"Result folder (default "
                                          f"sweeps/{kind}-<design>); finished points in it are "
                                          "reused."),
        workers: Optional[int] = typer.Option(None, "--workers", help="Local worker processes "
                                              "(default: one per core)."),
        scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Dask scheduler "
                                                "address (tcp://host:port); needs "
                                                "dask.distributed."),
    ) -> None:
        _run(kind, start, stop, step, design, set_, scene, views, solver, iters, tau, seed, spp,
             recon, out, workers, scheduler)

    return command


mirror_length = _options("mirror-length")
mirror_length.__doc__ = ("Sweep the kaleidoscope's mirror length: view size and minification, "
                         "gaps, vignetting, dispersion and reconstruction quality per point.")
prism_apex = _options("prism-apex")
prism_apex.__doc__ = ("Sweep the prism's apex angle: dispersion span (predicted and measured), "
                      "view geometry and reconstruction quality; prints the smallest apex "
                      "reaching 60 px.")
app.command("mirror-length")(mirror_length)
app.command("prism-apex")(prism_apex)
