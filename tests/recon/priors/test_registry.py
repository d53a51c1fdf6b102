"""Priors by name (recon.priors): the registry, its errors, and extending it."""

import numpy as np
import pytest

from recon.errors import InputError
from recon.priors import (DEFAULT_PRIOR, PRIORS, PriorBase, TVPrior, check_prior_name,
                          make_prior, prior_help, prior_names, register_prior)
from recon.priors.tv import DEFAULT_WEIGHT


def test_tv_is_the_default_and_listed():
    assert DEFAULT_PRIOR == "tv" and "tv" in prior_names()
    assert "tv:" in prior_help()


def test_make_tv():
    p = make_prior("tv", shape=(2, 5, 6), weight=0.3, tv_iters=4, isotropic=False)
    assert isinstance(p, TVPrior)
    assert (p.weight, p.iters, p.isotropic) == (0.3, 4, False)
    # Without a weight: the solver's default, or FISTA's without a solver.
    assert make_prior("tv", solver="gap-tv").weight == DEFAULT_WEIGHT["gap"]
    assert make_prior("tv", solver="twist").weight == DEFAULT_WEIGHT["twist"]
    assert make_prior().weight == DEFAULT_WEIGHT["fista"]


def test_unknown_name_lists_the_known_ones():
    with pytest.raises(InputError, match=r"unknown prior 'nope'; choose one of .*tv"):
        make_prior("nope")
    with pytest.raises(InputError, match="unknown prior"):
        check_prior_name("TV")


def test_bad_weight_and_options():
    with pytest.raises(InputError, match="weight"):
        make_prior("tv", weight=-1)
    with pytest.raises(InputError, match="no option.*colour"):
        make_prior("tv", colour=3)


class _Scale(PriorBase):
    name = "scale"

    def __init__(self, ctx, k):
        self.ctx, self.k = ctx, k

    def prox(self, v, step, out=None):
        return np.multiply(v, self.k, out=out)


def test_register_and_make(monkeypatch):
    monkeypatch.setitem(PRIORS, "tv", PRIORS["tv"])  # restored after the test
    monkeypatch.delitem(PRIORS, "scale", raising=False)
    register_prior("scale", lambda ctx, k=0.5: _Scale(ctx, k), "multiplies by k")
    try:
        assert "scale" in prior_names() and "scale: multiplies by k" in prior_help()
        p = make_prior("scale", shape=(1, 2, 3), weight=0.2, noise=0.01, n_views=5, k=2.0)
        assert p.k == 2.0
        assert (p.ctx.shape, p.ctx.weight, p.ctx.noise, p.ctx.n_views) == \
            ((1, 2, 3), 0.2, 0.01, 5)
    finally:
        PRIORS.pop("scale", None)
    with pytest.raises(InputError, match="name"):
        register_prior("a,b", lambda ctx: None, "")


def test_factory_must_return_a_prior(monkeypatch):
    register_prior("broken", lambda ctx: object(), "returns no prior")
    try:
        with pytest.raises(InputError, match="must be a recon prior"):
            make_prior("broken")
    finally:
        PRIORS.pop("broken", None)
