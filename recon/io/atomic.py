"""Atomic output: a file appears complete under its final name, or not at all.

Writers produce a temporary file in the destination folder (same file system, so the final
:func:`os.replace` is an atomic rename) and rename it only once it is fully written; on any
error the temporary file is removed and an existing destination is left untouched.  Outputs may
never overwrite one of the inputs they were computed from.  Files and folders get the ordinary
permissions of the user's umask, not the private ones of :mod:`tempfile`.

The writers themselves refuse a destination whose folder does not exist (a library call should
not invent folders); the command line creates missing output folders, and every command does it
the same way: :func:`check_output` with ``parents=True`` before the work starts (nothing is
created yet), then :func:`output_parents` around the writes (the missing folders are created,
and removed again if the writes fail).
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
           "output_parents", "same_path"]

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


def _folder_of(path: Path) -> Path:
    return path.parent if str(path.parent) else Path(".")


def _check_parent(path: Path) -> None:
    parent = _folder_of(path)
    if not parent.is_dir():
        if parent.exists() or any(p.exists() and not p.is_dir() for p in parent.parents):
            raise InputError(f"{path}: the output folder {parent} is not a folder")
        raise InputError(f"{path}: the output folder {parent} does not exist")


def _missing_folders(path: Path) -> tuple[Path, list[Path]]:
    """The nearest existing ancestor of ``path``'s folder, and the folders missing below it
    (outermost first).

    Raises
    ------
    InputError
        When that ancestor is not a folder (a file, or a link to one).
    """
    folder = _folder_of(path)
    missing = []
    # ``exists()`` is False below a regular file (ENOTDIR), so the walk stops at the file.
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    if not folder.is_dir():
        raise InputError(f"{path}: the output folder {folder} is not a folder")
    return folder, missing[::-1]


def _cannot_write(path: Path, err: OSError) -> InputError:
    return InputError(f"{path}: cannot write here ({err.strerror or err})")


def _probe(path: Path, folder: Path) -> None:
    """Create and delete an anonymous file in ``folder``: permission bits do not tell whether
    it accepts new entries (root, read-only mounts, /proc)."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        raise _cannot_write(path, err) from None


def check_output(path: PathLike, inputs: Iterable[PathLike | None] = (), *,
                 folder: bool = False, parents: bool = False) -> Path:
    """Check, before any long computation, that ``path`` can be written as an output.

    ``path`` must not be one of ``inputs``, its folder must exist (or, with ``parents``, be
    creatable) and accept new files, and it must not be a folder (a file for ``folder=True``).
    Writability is probed by creating and deleting an anonymous temporary file in the folder
    (or in its nearest existing ancestor).  Nothing is left behind and nothing is created.

    Parameters
    ----------
    path : path-like
        The output file (or folder, with ``folder=True``).
    inputs : iterable of path-like or None
        Files the output must not overwrite (``None`` entries are skipped).
    folder : bool
        The output is a folder.
    parents : bool
        Missing folders above ``path`` are allowed (they are created by
        :func:`output_parents` when the output is written); only an ancestor that is a file or
        refuses new entries is an error.

    Raises
    ------
    InputError
        With a one-line reason naming ``path``.
    """
    path = Path(path)
    check_not_input(path, inputs)
    if parents:
        existing, _ = _missing_folders(path)
    else:
        _check_parent(path)
        existing = _folder_of(path)
    if folder:
        if path.exists() and not path.is_dir():
            raise InputError(f"{path}: exists and is not a folder")
    elif path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file name")
    _probe(path, existing)
    return path


@contextlib.contextmanager
def output_parents(path: PathLike) -> Iterator[Path]:
    """Context manager: the missing folders above ``path`` exist inside the body.

    They are created with the ordinary permissions (``0o777`` less the umask), like
    ``mkdir -p``.  If the body raises, the folders created here are removed again (those still
    empty), so a failed command leaves no trace; folders that existed before are never touched.

    Parameters
    ----------
    path : path-like
        The output file or folder about to be written.

    Yields
    ------
    pathlib.Path
        ``path``.

    Raises
    ------
    InputError
        An ancestor is a file, or a folder cannot be created (one line naming ``path``).
    """
    path = Path(path)
    _, missing = _missing_folders(path)
    made: list[Path] = []
    try:
        for d in missing:
            try:
                d.mkdir()
            except FileExistsError:
                if not d.is_dir():
                    raise InputError(f"{path}: the output folder {d} is not a folder") from None
                continue  # made meanwhile by someone else: theirs, not ours to remove
            except OSError as err:
                raise _cannot_write(path, err) from None
            made.append(d)
        yield path
    except BaseException:
        for d in reversed(made):
            with contextlib.suppress(OSError):
                d.rmdir()
        raise


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
        try:
            os.replace(tmp, path)
        except OSError:
            if old is not None:  # put the previous folder back rather than lose it
                os.replace(old / "d", path)
                old.rmdir()
            raise
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
