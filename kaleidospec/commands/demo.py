"""``kaleidospec demo``: the main job on the built-in default scene.

``kaleidospec run`` on the ColorChecker (24 known spectra: the colour error is meaningful) with
the ``small`` design and 1, 2, 3, 5 views, including the first calibration (43 s in all on two
cores; later runs reuse the cached transport and calibration).  It uses the footprint model
(:mod:`recon.calibration.footprint`), which on ``small`` costs 19 s of comb captures once and
reaches the exact operator; ``--model shifted`` gives ``kaleidospec run``'s lighter default.
"""

from __future__ import annotations

from pathlib import Path

import typer

DEFAULT_SCENE = "colorchecker"
DEFAULT_VIEWS = "1,2,3,5"
DEFAULT_MODEL = "footprint"


def demo(
    out: Path = typer.Option(Path("kaleidospec-demo"), "--out", "-o", help="Output folder."),
    model: str = typer.Option(DEFAULT_MODEL, "--model", help="Calibrated forward model: "
                              "footprint (the default here) or shifted (see kaleidospec run "
                              "--help)."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bars."),
) -> None:
    """Render the ColorChecker with the small design, calibrate, reconstruct, report."""
    from kaleidospec import pipeline
    from kaleidospec.commands.run import check_model
    from sim.design import get_design

    check_model(model)
    d = pipeline.design_for_views(get_design("small"), 5)
    pipeline.run(DEFAULT_SCENE, d, out, views=pipeline.parse_views(DEFAULT_VIEWS),
                 progress=progress, oracle=False, log=typer.echo, model=model)
    typer.echo(f"wrote {out}/")
