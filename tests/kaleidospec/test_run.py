"""The still run's own checks: view counts (the run end to end is tests/kaleidospec/test_cli_run.py)."""

import pytest

from recon.errors import InputError


def test_parse_views():
    from kaleidospec.run import parse_views

    with pytest.raises(InputError, match="views"):
        parse_views("1,x")
    assert parse_views("5,1,1") == (1, 5)
