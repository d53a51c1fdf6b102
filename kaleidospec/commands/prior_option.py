"""The ``--prior`` option that ``run``, ``demo``, ``reconstruct`` and ``video`` share.

The names ``--help`` lists are kept here, beside the option, so that ``kaleidospec --help``
imports neither NumPy nor :mod:`recon`; ``tests/kaleidospec/test_cli_prior.py`` checks that
they are the names :data:`recon.priors.PRIORS` registers.
"""

from __future__ import annotations

import typer

#: The priors of :data:`recon.priors.PRIORS`, with the line ``--help`` shows for each.
PRIOR_CHOICES = {"tv": "total variation, spatial, per band",
                 "subspace-tv": "k spectral basis vectors from the iterate, TV on their images"}

#: The default prior (:data:`recon.priors.DEFAULT_PRIOR`).
DEFAULT = "tv"

PRIOR_HELP = ("Prior of the reconstruction: "
              + "; ".join(f"{k} = {v}" for k, v in PRIOR_CHOICES.items())
              + f".  Default {DEFAULT}.")


def prior_option():
    """A fresh ``--prior`` option (typer needs one object per command)."""
    return typer.Option(DEFAULT, "--prior", help=PRIOR_HELP)


def check_prior(name: str) -> str:
    """``name`` if :mod:`recon.priors` knows it, else an :class:`~recon.errors.InputError`
    that lists the known names."""
    from recon.priors import check_prior_name

    return check_prior_name(name)
