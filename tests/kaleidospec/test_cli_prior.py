"""``--prior`` on ``run``, ``demo``, ``reconstruct`` and ``video``: the names ``--help`` lists
are the registry's, an unknown name is a one-line error (exit 2) before any work, ``tv`` is
today's reconstruction, and the prior is recorded."""

import numpy as np
import pytest

from kaleidospec.cli import main
from kaleidospec.commands.prior_option import DEFAULT, PRIOR_CHOICES, RUN_DEFAULT
from recon.io.arrays import write_array2d
from recon.io.cubes import read_cube

COMMANDS = ["run", "demo", "reconstruct", "video"]


def _call(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    out, err = capsys.readouterr()
    return exc.value.code, out, err


def test_help_names_are_the_registry():
    from recon.priors import DEFAULT_PRIOR, PRIORS

    assert set(PRIOR_CHOICES) == set(PRIORS)
    assert DEFAULT == DEFAULT_PRIOR


def test_run_and_demo_default_to_the_subspace_prior(capsys):
    """``run`` and ``demo`` (and :func:`kaleidospec.run.run`) default to ``subspace-tv``, the
    prior that beats TV on the CAVE development scenes; ``reconstruct`` and ``video`` keep TV."""
    import inspect

    from kaleidospec.run import run

    assert RUN_DEFAULT == "subspace-tv" and RUN_DEFAULT in PRIOR_CHOICES
    assert inspect.signature(run).parameters["prior"].default == RUN_DEFAULT
    for command, default in (("run", RUN_DEFAULT), ("demo", RUN_DEFAULT),
                             ("reconstruct", DEFAULT), ("video", DEFAULT)):
        code, out, _ = _call([command, "--help"], capsys)
        assert code in (0, None)
        assert f"[default: {default}]" in " ".join(out.replace("│", " ").split()), command


@pytest.mark.parametrize("command", COMMANDS)
def test_help_lists_the_priors(command, capsys):
    code, out, _ = _call([command, "--help"], capsys)
    assert code in (0, None)
    flat = " ".join(out.replace("│", " ").split())   # a name and its "=" may wrap apart
    assert "--prior" in flat
    for name in PRIOR_CHOICES:
        assert f"{name} =" in flat


ARGS = {"run": ["run", "--scene", "natural", "--out", "{tmp}/o"],
        "demo": ["demo", "--out", "{tmp}/o"],
        "reconstruct": ["reconstruct", "--measurement", "{tmp}/m.npy", "--mask", "{tmp}/k.npy",
                        "--step", "1", "--out", "{tmp}/o.npz"],
        "video": ["video", "--scene", "colorwheel", "--out", "{tmp}/o"]}


@pytest.mark.parametrize("command", COMMANDS)
def test_unknown_prior_is_a_clear_error(command, tmp_path, capsys):
    write_array2d(tmp_path / "m.npy", np.ones((8, 10), np.float32))
    write_array2d(tmp_path / "k.npy", np.ones((8, 8), np.float32))
    argv = [a.format(tmp=tmp_path) for a in ARGS[command]] + ["--prior", "nope"]
    code, _, err = _call(argv, capsys)
    assert code == 2
    assert err.strip().count("\n") == 0
    assert "unknown prior 'nope'" in err and "tv" in err
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.npz").exists()


@pytest.mark.parametrize("command", ["run", "reconstruct", "video"])
def test_negative_tau_is_refused_alike(command, tmp_path, capsys):
    write_array2d(tmp_path / "m.npy", np.ones((8, 10), np.float32))
    write_array2d(tmp_path / "k.npy", np.ones((8, 8), np.float32))
    argv = [a.format(tmp=tmp_path) for a in ARGS[command]] + ["--tau", "-0.1"]
    code, _, err = _call(argv, capsys)
    assert code == 2 and "--tau must be finite and >= 0" in err


def test_reconstruct_with_prior_tv_is_the_default(tmp_path, capsys):
    from recon.operators import standard_cassi

    rng = np.random.default_rng(0)
    mask = (rng.random((16, 16)) < 0.5).astype(np.float32)
    cube = rng.random((4, 16, 16)).astype(np.float32)
    g = standard_cassi(mask, 1, 4).forward(cube)[0]
    write_array2d(tmp_path / "m.npy", g)
    write_array2d(tmp_path / "k.npy", mask)
    base = ["reconstruct", "--measurement", str(tmp_path / "m.npy"), "--mask",
            str(tmp_path / "k.npy"), "--step", "1", "--iters", "5", "--no-pictures"]
    code, out, _ = _call(base + ["--out", str(tmp_path / "a.npz"), "--prior", "tv"], capsys)
    assert code in (0, None) and "prior tv" in out
    code, _, _ = _call(base + ["--out", str(tmp_path / "b.npz")], capsys)
    assert code in (0, None)
    np.testing.assert_array_equal(read_cube(tmp_path / "a.npz")[0],
                                  read_cube(tmp_path / "b.npz")[0])
