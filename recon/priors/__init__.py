r"""Priors (regularisers and plug-and-play denoisers) that any solver takes.

The contract is :class:`~recon.priors.base.Prior` (``prox``, ``value``, ``reset``); the
priors are built by name from :data:`PRIORS` with :func:`make_prior`, so that the command
line's ``--prior NAME`` and every solver see the same list.

Registering a prior::

    from recon.priors import register_prior

    def make_mine(ctx, **options):     # ctx: a PriorContext
        return MyPrior(ctx.weight if ctx.weight is not None else rule(ctx.noise), ...)

    register_prior("mine", make_mine, "one line for --help")

A factory receives a :class:`PriorContext` (the cube's shape and dtype, the strength the caller
chose or None, the solver, the measurement's rms noise and the number of views where known,
threads) and the caller's extra options, and returns a :class:`Prior`.  A prior registered
here for the command line is also listed, with its ``--help`` line, in
``kaleidospec.commands.prior_option.PRIOR_CHOICES`` (``--help`` must not import NumPy; a test
keeps the two lists equal).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from recon.errors import InputError
from recon.priors.base import Prior, PriorBase, check_prior
from recon.priors.tv import TVPrior, check_weight, default_weight

__all__ = ["Prior", "PriorBase", "TVPrior", "PriorContext", "PRIORS", "DEFAULT_PRIOR",
           "register_prior", "make_prior", "prior_names", "prior_help", "check_prior_name",
           "check_prior", "default_weight", "check_weight"]

#: The prior the commands and :func:`make_prior` use when none is named.
DEFAULT_PRIOR = "tv"


@dataclass(frozen=True)
class PriorContext:
    """What a prior's factory may use to set itself up.

    Attributes
    ----------
    shape : tuple of int or None
        The cube ``(L, H, W)``.
    dtype : numpy dtype
        The solver's working precision.
    weight : float or None
        The strength the caller chose (TV: :math:`\\tau`); None lets the prior choose.
    solver : str or None
        The solver's name (a prior's default strength may depend on it).
    noise : float or None
        Root-mean-square noise of the (normalised) measurement, where known.
    n_views : int or None
        Views of the measurement, where known.
    threads : int or None
    """

    shape: tuple | None = None
    dtype: np.dtype = np.dtype(np.float32)
    weight: float | None = None
    solver: str | None = None
    noise: float | None = None
    n_views: int | None = None
    threads: int | None = None


@dataclass(frozen=True)
class PriorEntry:
    """A registered prior: its factory and the line ``--help`` shows."""

    factory: Callable[..., Prior]
    help: str


def _make_tv(ctx: PriorContext, *, tv_iters: int = 2, warm_dual: bool = True,
             isotropic: bool = True) -> TVPrior:
    weight = ctx.weight
    if weight is None:
        weight = default_weight(ctx.solver) if ctx.solver is not None else DEFAULT_TV_WEIGHT
    return TVPrior(weight, ctx.shape, ctx.dtype, iters=tv_iters, warm=warm_dual,
                   isotropic=isotropic, threads=ctx.threads)


#: The TV weight of :func:`make_prior` ``("tv")`` without a weight or a solver.
DEFAULT_TV_WEIGHT = default_weight("fista")

#: Priors by name.  Extend with :func:`register_prior`.
PRIORS: dict[str, PriorEntry] = {
    "tv": PriorEntry(_make_tv, "total variation, spatial, per band (the default)"),
}


def register_prior(name: str, factory: Callable[..., Prior], help: str) -> None:
    """Add (or replace) the prior ``name``: ``factory(ctx, **options) -> Prior``."""
    if not isinstance(name, str) or not name or name != name.strip() or "," in name:
        raise InputError(f"a prior's name must be a non-empty word, got {name!r}")
    PRIORS[name] = PriorEntry(factory, str(help))


def prior_names() -> tuple[str, ...]:
    """The names :func:`make_prior` knows."""
    return tuple(PRIORS)


def prior_help() -> str:
    """``name: description`` of every prior, one per line (for ``--help``)."""
    return "; ".join(f"{k}: {e.help}" for k, e in PRIORS.items())


def check_prior_name(name) -> str:
    """``name`` if it is a known prior, else an :class:`~recon.errors.InputError` that lists
    the known ones."""
    if name not in PRIORS:
        raise InputError(f"unknown prior {name!r}; choose one of {', '.join(PRIORS)}")
    return name


def make_prior(name: str = DEFAULT_PRIOR, *, shape=None, dtype=np.float32, weight=None,
               solver: str | None = None, noise: float | None = None,
               n_views: int | None = None, threads: int | None = None, **options) -> Prior:
    """Build the prior ``name`` (a key of :data:`PRIORS`) for cubes of ``shape``.

    Parameters
    ----------
    name : str
    shape, dtype, weight, solver, noise, n_views, threads
        The :class:`PriorContext`.  ``weight`` None lets the prior choose (TV: the solver's
        default, :data:`recon.priors.tv.DEFAULT_WEIGHT`).
    **options
        The prior's own options (TV: ``tv_iters``, ``warm_dual``, ``isotropic``).

    Raises
    ------
    InputError
        An unknown name (the message lists the known ones), a bad weight or option.
    """
    entry = PRIORS[check_prior_name(name)]
    if weight is not None:
        weight = check_weight(weight, f"the {name} prior's weight")
    ctx = PriorContext(shape=None if shape is None else tuple(int(s) for s in shape),
                       dtype=np.dtype(dtype), weight=weight, solver=solver, noise=noise,
                       n_views=n_views, threads=threads)
    _check_options(name, entry.factory, options)
    return check_prior(entry.factory(ctx, **options))


def _check_options(name: str, factory, options: dict) -> None:
    """An :class:`~recon.errors.InputError` for options ``factory`` does not take."""
    import inspect

    params = inspect.signature(factory).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    unknown = sorted(k for k in options if k not in params or k == "ctx")
    if unknown:
        raise InputError(f"prior {name!r} has no option(s) {', '.join(unknown)}")


# Priors of their own modules, registered here so that every name is known once recon.priors is.
from recon.priors.subspace import make_subspace_tv  # noqa: E402

register_prior("subspace-tv", make_subspace_tv,
               "k spectral basis vectors re-estimated from the iterate, TV on their images")

from recon.priors.nonlocal_lowrank import make_subspace_nlr  # noqa: E402

register_prior("subspace-nlr", make_subspace_nlr,
               "k spectral basis vectors from the iterate, subspace-TV for a warm-up (GAP: "
               "60 calls; FISTA: a whole solve), then a non-local low-rank denoiser (patch "
               "groups, optimal singular-value shrinkage) on their images")
