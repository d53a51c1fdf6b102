"""Priors (regularisers and plug-and-play denoisers) that any solver takes."""

from recon.priors.base import Prior

__all__ = ["Prior"]
