"""``kaleidospec reconstruct``: a cube from a measurement file and a mask file."""

from __future__ import annotations


def reconstruct() -> None:
    """Reconstruct a hyperspectral cube from a CASSI measurement (not yet implemented)."""
    from recon.errors import InputError

    raise InputError("reconstruct is not implemented yet")
