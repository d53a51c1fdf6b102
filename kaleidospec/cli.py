"""The ``kaleidospec`` command line.

Commands are defined in :mod:`kaleidospec.commands`; this module only assembles them and turns
user errors (:class:`recon.errors.InputError`), and writes that fail for want of space or
permission, into one line on stderr and exit status 2.
"""

from __future__ import annotations

import errno
import sys

import typer

from kaleidospec.commands import demo, design, reconstruct, render, run, sweep, video

app = typer.Typer(
    name="kaleidospec",
    help="Simulate and reconstruct a kaleidoscopic multisampling CASSI (compressive video spectroscopy).",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)


@app.callback()
def _root() -> None:
    """Simulate and reconstruct a kaleidoscopic multisampling CASSI."""


app.command("reconstruct")(reconstruct.reconstruct)
app.add_typer(design.app, name="design")
app.command("demo")(demo.demo)
app.command("render")(render.render)
app.command("run")(run.run)
app.command("video")(video.video)
app.add_typer(sweep.app, name="sweep")


#: Errors of a write that the user can fix: no space or quota left, a read-only place.
_WRITE_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM}


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script."""
    from recon.errors import InputError

    try:
        app(args=argv, prog_name="kaleidospec")
    except InputError as err:
        print(f"kaleidospec: error: {err}", file=sys.stderr)
        sys.exit(2)
    except OSError as err:
        # A full disk or a folder that refuses writes mid-run: the writers have removed their
        # temporaries (recon.io.atomic), so one line says what to free or fix.
        if err.errno not in _WRITE_ERRORS:
            raise
        where = f"{err.filename}: " if err.filename else ""
        print(f"kaleidospec: error: {where}cannot write ({err.strerror or err}); nothing "
              "partial was left", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":  # pragma: no cover
    main()
