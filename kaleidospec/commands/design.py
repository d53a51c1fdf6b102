"""``kaleidospec design``: inspect an instrument design (:class:`sim.optics.design.Design`)."""

from __future__ import annotations

from typing import List, Optional

import typer

app = typer.Typer(help="Inspect the instrument design.", no_args_is_help=True)


@app.command("show")
def show(
    design: str = typer.Option("paper", "--design", help="Preset: paper or small."),
    set_: Optional[List[str]] = typer.Option(
        None, "--set", help="Override a design field: name=value (repeatable)."
    ),
) -> None:
    """Print the design's fields and derived quantities as JSON."""
    import json

    from kaleidospec.instrument import get_design, parse_overrides

    d = get_design(design, parse_overrides(set_))
    # Fields at the top level (as in a raw frame's sidecar), derived quantities below them.
    out = {"preset": design, "hash": d.hash, **d.to_dict(), "derived": d.derived()}
    typer.echo(json.dumps(out, indent=2))
