"""The ``--prior`` option that ``run``, ``demo``, ``reconstruct`` and ``video`` share.

The names ``--help`` lists are kept here, beside the option, so that ``kaleidospec --help``
imports neither NumPy nor :mod:`recon`; ``tests/kaleidospec/test_cli_prior.py`` checks that
they are the names :data:`recon.priors.PRIORS` registers.
"""

from __future__ import annotations

import typer

#: The priors of :data:`recon.priors.PRIORS`, with the line ``--help`` shows for each.
PRIOR_CHOICES = {"tv": "total variation, spatial, per band",
                 "subspace-tv": "k spectral basis vectors from the iterate, TV on their images",
                 "subspace-nlr": "as subspace-tv, then a non-local low-rank denoiser (patch "
                                 "groups, singular-value shrinkage) on their images: in run "
                                 "and demo 80 denoiser iterations (40 with several views) "
                                 "after the subspace-tv solve, 5-11x its time; in "
                                 "reconstruct after 60 of GAP's (give --iters 100)"}

#: The library's default prior (:data:`recon.priors.DEFAULT_PRIOR`): ``reconstruct`` (single-view
#: CASSI files) and ``video`` keep it.
DEFAULT = "tv"
#: The default of ``run`` and ``demo`` (kaleidoscope frames through the calibrated model):
#: the prior that beats TV by at least 1 dB at no more than 5 times its time on the eight CAVE
#: development scenes there (docs/priors.md); :func:`kaleidospec.run.run` has the same default.
RUN_DEFAULT = "subspace-tv"


def prior_help(default: str) -> str:
    """The ``--help`` text of ``--prior`` with ``default`` named."""
    return ("Prior of the reconstruction: "
            + "; ".join(f"{k} = {v}" for k, v in PRIOR_CHOICES.items())
            + f".  Default {default}.")


def prior_option(default: str = DEFAULT):
    """A fresh ``--prior`` option (typer needs one object per command) defaulting to
    ``default``."""
    return typer.Option(default, "--prior", help=prior_help(default))


def check_prior(name: str) -> str:
    """``name`` if :mod:`recon.priors` knows it, else an :class:`~recon.errors.InputError`
    that lists the known names."""
    from recon.priors import check_prior_name

    return check_prior_name(name)
