r"""Cache entries that check themselves: written atomically with a checksum, verified on load.

Every cache of the project (calibrations, traced maps and transports, sweep points, a video's
frames) keeps its entries through this module, so that one damaged entry costs a rebuild and a
warning, never a traceback.  An entry is one file:

- ``.npz`` (:func:`write_npz`, :func:`read_npz`): the arrays, plus an array ``_entry`` that holds
  the header below as UTF-8 JSON bytes (no pickle anywhere: loaded with ``allow_pickle=False``);
- ``.json`` (:func:`write_json`, :func:`read_json`): the object, plus a key ``_entry`` holding the
  header (stripped again on load).

The header holds ``format`` (:data:`FORMAT`), ``kind`` (what cache it belongs to), the
``design_hash``, the ``version`` of the code that made it, the cache ``key``, every array's dtype
and shape, optional ``meta`` (caller's metadata) and ``sha256``, a digest of the content: for
arrays of every (name, dtype, shape, bytes) in name order, for JSON of the object's canonical
serialisation (sorted keys, no whitespace).  A :func:`seal` is a JSON entry whose content is
the SHA-256 of other files (a video frame's images, which other writers produce).

Loading checks, in order: the file is readable and complete (a truncated zip or JSON fails to
parse), the header is there and is this format and kind, the design hash, version and key are
the expected ones (an entry of another design or code version copied or left under this name is
*foreign*), the arrays are exactly the header's with its dtypes and shapes, the caller's
expected names, dtypes and dimensions hold, and the digest matches.  An entry that fails any of
these is removed with one warning line on stderr that names it and says why (:func:`discard`),
and the reader returns ``None``: the caller rebuilds it.  Removal only unlinks the file that was
read: if another process has meanwhile replaced it (a different inode), the new one stays.

A cache folder that cannot be written stops the command before any long work: :func:`check_folder`
raises :class:`recon.errors.InputError` with one line (the command line's exit status 2).  It
also removes the temporaries of writers killed mid-write (older than :data:`STALE_S`).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from recon.errors import InputError

__all__ = ["FORMAT", "ENTRY", "STALE_S", "Damaged", "write_npz", "read_npz", "read_header",
           "write_json", "read_json", "seal", "check_seal", "file_digest", "array_digest",
           "discard", "check_folder", "warn"]

FORMAT = "kaleidospec-cache"
#: Name of the header inside an entry (array name in ``.npz``, key in ``.json``).
ENTRY = "_entry"
_CHUNK = 1 << 20
_CHECKED: set[str] = set()


class Damaged(Exception):
    """An entry that fails a check (the message says which)."""


def warn(message: str) -> None:
    """One warning line on stderr (the caches' only output)."""
    print(f"kaleidospec: warning: {message}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------------------- digests
def array_digest(arrays: Mapping[str, np.ndarray]) -> str:
    """SHA-256 (hex) of every array's name, dtype, shape and bytes (C order), in name order."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(json.dumps([name, a.dtype.str, list(a.shape)]).encode())
        h.update(memoryview(a.reshape(-1)).cast("B") if a.size else b"")
    return h.hexdigest()


def _json_digest(obj) -> str:
    blob = json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(blob.encode()).hexdigest()


def file_digest(path) -> str:
    """SHA-256 (hex) of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(_CHUNK), b""):
            h.update(chunk)
    return h.hexdigest()


def _header(kind, design_hash, version, key, meta) -> dict:
    return {"format": FORMAT, "kind": str(kind),
            "design_hash": None if design_hash is None else str(design_hash),
            "version": None if version is None else str(version),
            "key": None if key is None else str(key), "meta": meta}


def _check_header(head, *, kind, design_hash, version, key) -> None:
    if not isinstance(head, dict) or head.get("format") != FORMAT:
        raise Damaged("no cache header (written by other code)")
    if head.get("kind") != kind:
        raise Damaged(f"a {head.get('kind')!r} entry, not {kind!r}")
    for name, want in (("design_hash", design_hash), ("version", version), ("key", key)):
        if want is not None and head.get(name) != str(want):
            raise Damaged(f"made for {name.replace('_', ' ')} {head.get(name)!r}, not {want!r}")


# ------------------------------------------------------------------------------- writing
def _write(path: Path, write, protect=()) -> Path:
    """``write(fh)`` into a temporary file next to ``path``, flushed to disk, then renamed."""
    from recon.io.atomic import atomic_path

    with atomic_path(path, protect=protect) as tmp:
        with open(tmp, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
    return path


def write_npz(path, arrays: Mapping[str, np.ndarray], *, kind: str, design_hash=None,
              version=None, key=None, meta: dict | None = None, compress: bool = False,
              protect: Iterable = ()) -> Path:
    """Write ``arrays`` and their header as one ``.npz`` entry, atomically (temporary file in the
    same folder, fsync, rename).

    Parameters
    ----------
    path : path-like
    arrays : mapping of str to array_like
        Numeric (or fixed-width string) arrays; none may be named ``_entry``.
    kind, design_hash, version, key : str
        Recorded in the header and checked again by :func:`read_npz`.
    meta : dict, optional
        JSON-ready metadata kept in the header (returned by :func:`read_npz` with ``meta=True``).
    compress : bool
        ``np.savez_compressed`` instead of ``np.savez``.
    """
    arrs = {str(n): np.asarray(a) for n, a in arrays.items()}
    if ENTRY in arrs:
        raise InputError(f"an array may not be named {ENTRY!r}")
    for n, a in arrs.items():
        if a.dtype.hasobject:
            raise InputError(f"array {n!r} holds Python objects: not storable without pickle")
    head = _header(kind, design_hash, version, key, meta)
    head["arrays"] = {n: [a.dtype.str, list(a.shape)] for n, a in arrs.items()}
    head["sha256"] = array_digest(arrs)
    save = np.savez_compressed if compress else np.savez
    header = np.frombuffer(json.dumps(head).encode(), np.uint8)
    return _write(Path(path), lambda fh: save(fh, **arrs, **{ENTRY: header}), protect)


def write_json(path, obj: dict, *, kind: str, design_hash=None, version=None, key=None,
               meta: dict | None = None, indent: int | None = 1,
               protect: Iterable = ()) -> Path:
    """Write the JSON object ``obj`` with its header (key ``_entry``) atomically."""
    if not isinstance(obj, dict) or ENTRY in obj:
        raise InputError(f"a JSON cache entry is an object without a key {ENTRY!r}")
    # The digest of what a reader will see (JSON turns tuples into lists, int keys into
    # strings, which sort differently).
    obj = json.loads(json.dumps(obj, allow_nan=False))
    head = _header(kind, design_hash, version, key, meta)
    head["sha256"] = _json_digest(obj)
    text = json.dumps({**obj, ENTRY: head}, indent=indent, sort_keys=True, allow_nan=False)
    return _write(Path(path), lambda fh: fh.write((text + "\n").encode()), protect)


def seal(path, files: Mapping[str, os.PathLike | str], *, kind: str, design_hash=None,
         version=None, key=None, protect: Iterable = ()) -> Path:
    """A JSON entry holding the SHA-256 of each of ``files`` (name → path): written after them,
    it marks them complete, and :func:`check_seal` finds any of them changed or cut short."""
    digests = {str(n): file_digest(p) for n, p in files.items()}
    return write_json(path, {"sha256": digests}, kind=kind, design_hash=design_hash,
                      version=version, key=key, protect=protect)


# ------------------------------------------------------------------------------- reading
def _stat(path: Path):
    try:
        return os.stat(path)
    except OSError:
        return None


def discard(path, reason: str, *, companions: Iterable = (), stat=None) -> None:
    """Remove a damaged entry (and its ``companions``, e.g. a sidecar) with one warning line.

    ``stat`` is the entry's :func:`os.stat` when it was read: a file that another process has
    replaced since (another inode or modification time) is left alone.
    """
    p = Path(path)
    now = _stat(p)
    same = (now is not None and (stat is None or (now.st_ino, now.st_mtime_ns)
                                 == (stat.st_ino, stat.st_mtime_ns)))
    if same:
        with contextlib.suppress(OSError):
            p.unlink()
        for c in companions:
            with contextlib.suppress(OSError):
                Path(c).unlink()
    what = "removed, it is rebuilt" if same else "another process has replaced it since"
    warn(f"{p}: damaged cache entry ({reason}); {what}")


def _check_arrays(arrays: dict, head: dict, expect) -> None:
    listed = head.get("arrays")
    if not isinstance(listed, dict):
        raise Damaged("the header lists no arrays")
    if set(listed) != set(arrays):
        missing = sorted(set(listed) - set(arrays))
        raise Damaged(f"incomplete: missing {missing}" if missing
                      else f"unlisted arrays {sorted(set(arrays) - set(listed))}")
    for n, a in arrays.items():
        dt, shape = listed[n]
        if a.dtype.str != dt or list(a.shape) != list(shape):
            raise Damaged(f"array {n!r} is {a.dtype.str} {list(a.shape)}, the header says "
                          f"{dt} {shape}")
    for n, want in (expect or {}).items():
        optional = n.endswith("?")
        n = n.rstrip("?")
        if n not in arrays:
            if optional:
                continue
            raise Damaged(f"no array {n!r}")
        dtype, ndim = want if isinstance(want, tuple) else (want, None)
        a = arrays[n]
        if dtype is not None and not np.issubdtype(a.dtype, dtype):
            raise Damaged(f"array {n!r} is {a.dtype}, expected {getattr(dtype, '__name__', dtype)}")
        if ndim is not None and a.ndim != ndim:
            raise Damaged(f"array {n!r} is {a.ndim}-D, expected {ndim}-D")
    if array_digest(arrays) != head.get("sha256"):
        raise Damaged("checksum mismatch")


def _load_checked(path, companions: Iterable, load):
    """``load(p)`` of the entry at ``path`` when it exists and is not empty; ``None`` when there
    is no file, or when the file is empty or ``load`` raises :class:`Damaged`: the file (and
    ``companions``) is then removed with one warning line (:func:`discard`)."""
    p = Path(path)
    st = _stat(p)
    if st is None:
        return None
    try:
        if st.st_size == 0:
            raise Damaged("empty file")
        return load(p)
    except Damaged as exc:
        discard(p, str(exc), companions=companions, stat=st)
        return None


def read_npz(path, *, kind: str, design_hash=None, version=None, key=None,
             expect: Mapping | None = None, meta: bool = False, companions: Iterable = ()):
    """The arrays of an ``.npz`` entry written by :func:`write_npz`, or ``None``.

    ``None`` when there is no file, or when it fails a check (see the module notes): the file
    (and ``companions``) is then removed with one warning line.

    Parameters
    ----------
    expect : mapping, optional
        Arrays the entry must hold: name → dtype (a NumPy dtype or an abstract one such as
        ``np.floating``) or ``(dtype, ndim)``; ``None`` leaves either unchecked.  A name ending
        in ``?`` is optional (checked when present).
    meta : bool
        Return ``(arrays, header_meta)`` instead of the arrays.
    """
    def load(p: Path):
        try:
            with np.load(p, allow_pickle=False) as z:
                if ENTRY not in z.files:
                    raise Damaged("no cache header (written by other code)")
                head = json.loads(bytes(z[ENTRY]).decode())
                _check_header(head, kind=kind, design_hash=design_hash, version=version,
                              key=key)
                arrays = {n: z[n] for n in z.files if n != ENTRY}
        except Damaged:
            raise
        except Exception as exc:
            # A cut or garbled archive fails in many ways (zipfile.BadZipFile, zlib.error,
            # EOFError, ValueError from the .npy header, ...): all of them mean "rebuild".
            raise Damaged(f"unreadable: {type(exc).__name__}: {exc}") from None
        _check_arrays(arrays, head, expect)
        return (arrays, head.get("meta")) if meta else arrays

    return _load_checked(path, companions, load)


def read_header(path, *, kind: str, design_hash=None, version=None, key=None) -> dict | None:
    """The header of the ``.npz`` entry ``path`` when it is readable and is the expected one
    (cache, design, version, key), else None; nothing is removed and nothing said.  A quick
    look (the arrays and the checksum are not read): whether :func:`read_npz` will most likely
    load it."""
    try:
        with np.load(Path(path), allow_pickle=False) as z:
            head = json.loads(bytes(z[ENTRY]).decode())
        _check_header(head, kind=kind, design_hash=design_hash, version=version, key=key)
    except Exception:    # noqa: BLE001 - any failure means "not a usable entry"
        return None
    return head


def read_json(path, *, kind: str, design_hash=None, version=None, key=None,
              companions: Iterable = ()) -> dict | None:
    """The object of a ``.json`` entry written by :func:`write_json` (header removed), or
    ``None`` (no file, or a damaged one: removed with one warning line)."""
    def load(p: Path) -> dict:
        try:
            with open(p, "rb") as fh:
                obj = json.loads(fh.read().decode("utf-8"))
        except (OSError, ValueError, UnicodeDecodeError) as exc:
            raise Damaged(f"unreadable: {type(exc).__name__}: {exc}") from None
        if not isinstance(obj, dict):
            raise Damaged("not a JSON object")
        head = obj.pop(ENTRY, None)
        _check_header(head, kind=kind, design_hash=design_hash, version=version, key=key)
        if _json_digest(obj) != head.get("sha256"):
            raise Damaged("checksum mismatch")
        return obj

    return _load_checked(path, companions, load)


def check_seal(path, files: Mapping[str, os.PathLike | str], *, kind: str, design_hash=None,
               version=None, key=None) -> bool:
    """Whether the seal ``path`` (:func:`seal`) is sound and each of ``files`` has the digest it
    records; a seal that is not is removed with one warning line (its files are then redone).
    No seal: False, silently."""
    obj = read_json(path, kind=kind, design_hash=design_hash, version=version, key=key)
    if obj is None:
        return False
    digests = obj.get("sha256")
    try:
        if not isinstance(digests, dict) or set(digests) != {str(n) for n in files}:
            raise Damaged("it lists other files")
        for n, f in files.items():
            try:
                got = file_digest(f)
            except OSError:
                raise Damaged(f"{Path(f).name} is missing or unreadable") from None
            if got != digests[str(n)]:
                raise Damaged(f"{Path(f).name} does not match its checksum")
    except Damaged as exc:
        discard(path, str(exc))
        return False
    return True


# ------------------------------------------------------------------------------- the folder
def _probe(folder: Path) -> None:
    with tempfile.TemporaryFile(dir=folder):
        pass


def check_folder(folder) -> Path:
    """``folder``, created if missing, after checking once per process that new files can be
    written in it (permission bits do not tell: root, read-only mounts).

    Raises
    ------
    InputError
        One line naming the folder and the reason, and what to do.
    """
    p = Path(folder)
    k = str(p)
    if k in _CHECKED and p.is_dir():
        return p
    try:
        p.mkdir(parents=True, exist_ok=True)
        _probe(p)
    except OSError as err:
        why = err.strerror or errno.errorcode.get(err.errno or 0, str(err))
        raise InputError(f"the cache folder {p} cannot be written ({why}); set "
                         "KALEIDOSPEC_CACHE to a writable folder") from None
    _sweep_temporaries(p)
    _CHECKED.add(k)
    return p


#: Temporaries older than this (s) belong to a writer that was killed: no write takes so long.
STALE_S = 6 * 3600


def _sweep_temporaries(folder: Path) -> None:
    """Remove what killed writers left: ``.<name>.<random>.tmp<suffix>`` files
    (:func:`recon.io.atomic.atomic_path`) older than :data:`STALE_S`."""
    import time

    now = time.time()
    for t in folder.glob(".*.tmp*"):
        with contextlib.suppress(OSError):
            if t.is_file() and now - t.stat().st_mtime > STALE_S:
                t.unlink()
