"""Atomic output: a file appears complete under its final name, or not at all.

Writers produce a temporary file in the destination folder (same file system, so the final
:func:`os.replace` is an atomic rename) and rename it only once it is fully written; on any
error the temporary file is removed and an existing destination is left untouched.  Outputs may
never overwrite one of the inputs they were computed from.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterable, Iterator

from recon.errors import InputError

__all__ = ["atomic_path", "atomic_dir", "write_text", "check_not_input", "check_output",
           "same_path"]

PathLike = str | os.PathLike


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


# mkstemp/mkdtemp create private (0600/0700) entries; outputs get the usual permissions.
_UMASK = _umask()


def same_path(a: PathLike, b: PathLike) -> bool:
    """True when ``a`` and ``b`` name the same file (through links, ``..``, relative paths)."""
    pa, pb = Path(a), Path(b)
    try:
        if pa.exists() and pb.exists():
            return os.path.samefile(pa, pb)
    except OSError:
        pass
    return pa.resolve() == pb.resolve()


def check_not_input(out: PathLike, inputs: Iterable[PathLike | None] = ()) -> None:
    """Raise :class:`InputError` if ``out`` is one of ``inputs`` (``None`` entries are skipped)."""
    for inp in inputs:
        if inp is not None and same_path(out, inp):
            raise InputError(f"{out}: refusing to overwrite an input file")


def _check_parent(path: Path) -> None:
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        if parent.exists() or any(p.exists() and not p.is_dir() for p in parent.parents):
            raise InputError(f"{path}: the output folder {parent} is not a folder")
        raise InputError(f"{path}: the output folder {parent} does not exist")


def _cannot_write(path: Path, err: OSError) -> InputError:
    return InputError(f"{path}: cannot write here ({err.strerror or err})")


def check_output(path: PathLike, inputs: Iterable[PathLike | None] = (), *,
                 folder: bool = False) -> Path:
    """Check, before any long computation, that ``path`` can be written as an output.

    ``path`` must not be one of ``inputs``, its folder must exist and accept new files (probed
    by creating and deleting an anonymous temporary file there: permission bits do not tell,
    e.g. for root or on read-only mounts), and it must not be a folder (a file for
    ``folder=True``).  Nothing is left behind.

    Raises
    ------
    InputError
        With a one-line reason naming ``path``.
    """
    path = Path(path)
    check_not_input(path, inputs)
    _check_parent(path)
    if folder:
        if path.exists() and not path.is_dir():
            raise InputError(f"{path}: exists and is not a folder")
    elif path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file name")
    try:
        with tempfile.TemporaryFile(dir=path.parent if str(path.parent) else "."):
            pass
    except OSError as err:
        raise _cannot_write(path, err) from None
    return path


@contextlib.contextmanager
def atomic_path(path: PathLike, *, protect: Iterable[PathLike | None] = ()) -> Iterator[Path]:
    """Context manager yielding a temporary path to write; renamed to ``path`` on success.

    The temporary name keeps the destination's suffix (``np.save`` and OpenEXR look at it) and
    lives in the same folder.  If the body raises, the temporary file is deleted and the
    exception propagates; ``path`` is then unchanged.

    Parameters
    ----------
    path : path-like
        Final destination.
    protect : iterable of path-like
        Input paths that ``path`` must not be (checked before anything is written).
    """
    path = Path(path)
    check_not_input(path, protect)
    _check_parent(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file name")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{path.suffix}",
                                   dir=path.parent)
    except OSError as err:
        raise _cannot_write(path, err) from None
    os.close(fd)
    tmp = Path(tmp)
    os.chmod(tmp, 0o666 & ~_UMASK)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        # An OSError of the writer (disk full, ...) propagates as it is; callers that promise
        # one-line errors (the command line) turn it into an InputError.
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


@contextlib.contextmanager
def atomic_dir(path: PathLike, *, protect: Iterable[PathLike | None] = ()) -> Iterator[Path]:
    """Like :func:`atomic_path` for a folder of files (e.g. a CAVE PNG stack).

    The body fills a fresh temporary folder next to ``path``; on success an existing ``path`` is
    moved aside, the new folder renamed into place, and the old one deleted.
    """
    path = Path(path)
    check_not_input(path, protect)
    _check_parent(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: exists and is not a folder")
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    except OSError as err:
        raise _cannot_write(path, err) from None
    os.chmod(tmp, 0o777 & ~_UMASK)
    try:
        yield tmp
        old = None
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
            os.replace(path, old / "d")
        os.replace(tmp, path)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_text(path: PathLike, text: str, *, protect: Iterable[PathLike | None] = ()) -> Path:
    """Write a UTF-8 text file atomically (flushed and fsync'ed before the rename)."""
    with atomic_path(path, protect=protect) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
    return Path(path)
