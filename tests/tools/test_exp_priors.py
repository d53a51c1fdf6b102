"""tools/exp_priors.py: a prior given with options (``name:key=value``) is built with them and
the caller's weight; a bare name goes to the solvers as before."""

from __future__ import annotations

import numpy as np
import pytest

from tool_scripts import load_tool


def _tool():
    return load_tool("exp_priors")


def test_parse_prior_reads_typed_options():
    tool = _tool()
    assert tool.parse_prior("tv") == ("tv", {})
    assert tool.parse_prior("subspace-nlr:warmup=80:strength=0.5") == \
        ("subspace-nlr", {"warmup": 80, "strength": 0.5})
    with pytest.raises(SystemExit, match="key=value"):
        tool.parse_prior("subspace-tv:rank")
    from recon.errors import InputError

    with pytest.raises(InputError, match="unknown prior"):
        tool.parse_prior("nope:rank=3")


def test_build_keeps_bare_names_and_builds_options_with_the_weight():
    tool = _tool()
    assert tool.build("subspace-tv", (11, 8, 9), "fista", 0.02) == ("subspace-tv", {"tau": 0.02})
    prior, kw = tool.build("subspace-tv:rank=4", (11, 8, 9), "fista", 0.02)
    assert kw == {} and prior.rank == 4 and prior.weight == pytest.approx(0.02)
    assert prior.prox(np.ones((11, 8, 9), np.float32), 1.0).shape == (11, 8, 9)


def test_build_gives_each_prior_the_weight_run_gives_it():
    """With no weight (what ``kaleidospec.reconstruct.prior_weight`` returns for a prior other
    than TV) the prior sets its strength from the noise and the view count, as in ``run``."""
    from kaleidospec.reconstruct import prior_weight, tv_weight
    from recon.priors import PriorContext
    from recon.priors.subspace import subspace_weight

    tool = _tool()
    assert prior_weight("subspace-tv", "fista-tv", None, 5, 0.01) is None
    assert tool.build("subspace-tv", (11, 8, 9), "fista-tv", None, 0.01, 5) == \
        ("subspace-tv", {"tau": None, "noise": 0.01})
    prior, kw = tool.build("subspace-tv:rank=4", (11, 8, 9), "fista-tv", None, 0.01, 5)
    expected = subspace_weight(PriorContext(shape=(11, 8, 9), dtype=np.float32, weight=None,
                                            solver="fista-tv", noise=0.01, n_views=5))
    assert kw == {} and prior.weight == pytest.approx(expected)
    # Today the subspace prior's noise rule is TV's.
    assert expected == pytest.approx(tv_weight("fista-tv", None, 5, 0.01))


@pytest.mark.parametrize("argv", [["--iters", "0"], ["--tol", "-1"], ["--tol", "nan"]])
def test_bad_iteration_settings_are_refused(argv, capsys):
    assert _tool().main(["--designs", "small"] + argv) == 2
    assert "--iters must be >= 1 and --tol >= 0" in capsys.readouterr().err
