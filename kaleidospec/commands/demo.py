"""``kaleidospec demo``: the main job on the built-in default scene.

``kaleidospec run`` on the ``natural`` scene (a photograph lifted to spectra, at twice the
reconstruction grid) with the ``small`` design and 1, 2, 3, 5 views, including the first
calibration (later runs reuse the cached traces and calibration).  No calibration capture shows
this scene: the ColorChecker fits the radiometric gains, so scoring it would score the fit.  It
uses the footprint model (:mod:`recon.calibration.footprint`, comb captures once);
``--model shifted`` gives ``kaleidospec run``'s lighter default.
"""

from __future__ import annotations

from pathlib import Path

import typer

from kaleidospec.commands.prior_option import RUN_DEFAULT, check_prior, prior_option

DEFAULT_SCENE = "natural"
DEFAULT_VIEWS = "1,2,3,5"
DEFAULT_MODEL = "footprint"


def demo(
    out: Path = typer.Option(Path("kaleidospec-demo"), "--out", "-o", help="Output folder."),
    model: str = typer.Option(DEFAULT_MODEL, "--model", help="Calibrated forward model: "
                              "footprint (the default here) or shifted (see kaleidospec run "
                              "--help)."),
    prior: str = prior_option(RUN_DEFAULT),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bars."),
) -> None:
    """Render the natural scene with the small design, calibrate, reconstruct, report."""
    from kaleidospec.instrument import design_for_views, get_design
    from kaleidospec.models import check_model
    from kaleidospec.run import parse_views, run

    check_model(model)
    check_prior(prior)
    d = design_for_views(get_design("small"), 5)
    run(DEFAULT_SCENE, d, out, views=parse_views(DEFAULT_VIEWS), progress=progress,
        oracle=False, log=typer.echo, model=model, prior=prior)
    typer.echo(f"wrote {out}/")
