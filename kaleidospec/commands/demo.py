"""``kaleidospec demo``: the main job on the built-in default scene.

``kaleidospec run`` on the ColorChecker (24 known spectra: the colour error is meaningful) with
the ``small`` design and 1, 2, 3, 5 views, including the first calibration (about a minute on
two cores; later runs reuse the cached transport and calibration).
"""

from __future__ import annotations

from pathlib import Path

import typer

DEFAULT_SCENE = "colorchecker"
DEFAULT_VIEWS = "1,2,3,5"


def demo(
    out: Path = typer.Option(Path("kaleidospec-demo"), "--out", "-o", help="Output folder."),
    progress: bool = typer.Option(True, "--progress/--no-progress", help="Progress bars."),
) -> None:
    """Render the ColorChecker with the small design, calibrate, reconstruct, report."""
    from kaleidospec import pipeline
    from sim.design import get_design

    d = pipeline.design_for_views(get_design("small"), 5)
    pipeline.run(DEFAULT_SCENE, d, out, views=pipeline.parse_views(DEFAULT_VIEWS),
                 progress=progress, oracle=False, log=typer.echo)
    typer.echo(f"wrote {out}/")
