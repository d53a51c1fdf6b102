"""Atomic outputs, the output-folder helpers the commands share, and output permissions."""

import os
from pathlib import Path

import pytest

from recon.errors import InputError
from recon.io.atomic import atomic_dir, atomic_path, check_output, output_parents, write_text


def _umask():
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _mode(p):
    return p.stat().st_mode & 0o777


_WRITE_ALL = """
import sys
from pathlib import Path
from recon.io.atomic import atomic_dir, output_parents, write_text
root = Path(sys.argv[1])
write_text(root / "a.txt", "x")
with atomic_dir(root / "d") as tmp:
    (tmp / "f").write_text("y")
with output_parents(root / "p" / "q" / "r.txt"):
    write_text(root / "p" / "q" / "r.txt", "z")
"""


@pytest.mark.parametrize("umask", [None, 0o027])
def test_files_and_folders_get_the_umask_permissions(tmp_path, umask):
    # tempfile makes private entries (0600 / 0700); outputs must not stay private.  The umask
    # is read once, at import, so another one is tried in a fresh interpreter.
    import subprocess
    import sys

    umask = _umask() if umask is None else umask
    code = f"import os; os.umask({umask}); exec({_WRITE_ALL!r})"
    subprocess.run([sys.executable, "-c", code, str(tmp_path)], check=True, timeout=60,
                   cwd=Path(__file__).resolve().parents[3])
    assert _mode(tmp_path / "a.txt") == _mode(tmp_path / "p" / "q" / "r.txt") == 0o666 & ~umask
    for d in ("d", "p", "p/q"):
        assert _mode(tmp_path / d) == 0o777 & ~umask, d


def test_check_output_with_parents_creates_nothing(tmp_path):
    out = tmp_path / "a" / "b" / "c.npz"
    with pytest.raises(InputError, match="does not exist"):
        check_output(out)
    assert check_output(out, parents=True) == out
    assert check_output(tmp_path / "a" / "dir", folder=True, parents=True)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("below", [("f",), ("f", "x"), ("f", "x", "y")])
def test_a_file_on_the_way_is_refused(tmp_path, below):
    (tmp_path / "f").write_text("x")
    out = tmp_path.joinpath(*below, "c.npz")
    with pytest.raises(InputError, match="not a folder"):
        check_output(out, parents=True)
    with pytest.raises(InputError, match="not a folder"):
        with output_parents(out):
            pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f"]


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")
def test_a_folder_that_refuses_new_entries():
    # /proc refuses new entries even to root, so permission bits cannot stand in for it.
    out = Path("/proc/kaleidospec-no/x.npz")
    with pytest.raises(InputError, match="cannot write"):
        check_output(out, parents=True)
    with pytest.raises(InputError, match="cannot write"):
        with output_parents(out):
            pass


def test_output_parents_removes_what_it_made_when_the_body_fails(tmp_path):
    (tmp_path / "kept").mkdir()
    out = tmp_path / "kept" / "new" / "newer" / "c.txt"
    with pytest.raises(RuntimeError):
        with output_parents(out):
            assert out.parent.is_dir()
            raise RuntimeError("boom")
    assert [p.name for p in tmp_path.iterdir()] == ["kept"]
    assert list((tmp_path / "kept").iterdir()) == []


def test_output_parents_keeps_folders_that_hold_something(tmp_path):
    # A resumable output (video, sweep) interrupted half-way keeps what it finished.
    out = tmp_path / "runs" / "v1"
    with pytest.raises(KeyboardInterrupt):
        with output_parents(out):
            write_text(tmp_path / "runs" / "partial.json", "{}")
            raise KeyboardInterrupt
    assert (tmp_path / "runs" / "partial.json").is_file()


def test_output_parents_relative_paths(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with output_parents(Path("out/demo")) as p:
        assert p == Path("out/demo") and Path("out").is_dir() and not Path("out/demo").exists()
    with output_parents(Path("here.txt")):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_atomic_path_leaves_the_old_file_when_the_writer_fails(tmp_path):
    write_text(tmp_path / "a.txt", "old")
    with pytest.raises(OSError):
        with atomic_path(tmp_path / "a.txt") as tmp:
            tmp.write_text("half")
            raise OSError(28, "No space left on device")
    assert (tmp_path / "a.txt").read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_atomic_dir_replaces_a_folder_and_restores_it_if_the_rename_fails(tmp_path, monkeypatch):
    with atomic_dir(tmp_path / "d") as tmp:
        (tmp / "v").write_text("1")
    with atomic_dir(tmp_path / "d") as tmp:
        (tmp / "v").write_text("2")
    assert (tmp_path / "d" / "v").read_text() == "2"

    real = os.replace

    def failing(src, dst):
        if Path(src).name.endswith(".tmp") and Path(dst) == tmp_path / "d":
            raise OSError(5, "I/O error")
        return real(src, dst)
    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError):
        with atomic_dir(tmp_path / "d") as tmp:
            (tmp / "v").write_text("3")
    monkeypatch.undo()
    assert (tmp_path / "d" / "v").read_text() == "2"
    assert [p.name for p in tmp_path.iterdir()] == ["d"]
