"""``kaleidospec run``: render, calibrate (cached), reconstruct per view count, report."""

from __future__ import annotations


def run() -> None:
    """Render a scene and reconstruct it for several view counts (being written)."""
    from recon.errors import InputError

    raise InputError("run is not implemented yet")
