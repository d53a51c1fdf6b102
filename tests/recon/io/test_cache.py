"""recon.io.cache: entries written with a checksum and their header, and every fault of one
found on load (removed with one warning line naming it, ``None`` returned: the caller rebuilds).

The rows of docs/faults.md on the entries themselves."""

from __future__ import annotations

import errno
import json
import os

import numpy as np
import pytest

from recon.errors import InputError
from recon.io import cache

KW = dict(kind="maps", design_hash="abc123", version="7", key="k1")
EXPECT = {"a": (np.float32, 2), "b": (np.integer, 1)}


def _arrays():
    rng = np.random.default_rng(0)
    return {"a": rng.random((40, 50)).astype(np.float32), "b": np.arange(300, dtype=np.int64),
            "s": np.array("text")}


def _truncate(p):
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 3])


def _garble(p):
    b = bytearray(p.read_bytes())
    mid = len(b) // 2
    b[mid:mid + 16] = bytes(x ^ 0x5A for x in b[mid:mid + 16])
    p.write_bytes(bytes(b))


def _empty(p):
    p.write_bytes(b"")


FAULTS = {"truncated": _truncate, "garbled": _garble, "empty": _empty}


def _one_warning(capsys, path, why):
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1, err
    assert str(path) in err[0] and why in err[0]


def test_npz_entry_round_trip(tmp_path, capsys):
    p = tmp_path / "e.npz"
    a = _arrays()
    cache.write_npz(p, a, meta={"x": [1, 2]}, compress=True, **KW)
    got, meta = cache.read_npz(p, expect=EXPECT, meta=True, **KW)
    assert set(got) == set(a) and meta == {"x": [1, 2]}
    for n in a:
        np.testing.assert_array_equal(got[n], a[n])
        assert got[n].dtype == a[n].dtype
    assert sorted(os.listdir(tmp_path)) == ["e.npz"]     # no temporary left
    assert capsys.readouterr().err == ""
    assert cache.read_npz(tmp_path / "none.npz", **KW) is None    # no entry: silently None
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("compress", [False, True])
def test_damaged_npz_entry_is_removed_with_one_warning(tmp_path, capsys, fault, compress):
    p = tmp_path / "e.npz"
    cache.write_npz(p, _arrays(), compress=compress, **KW)
    FAULTS[fault](p)
    assert cache.read_npz(p, expect=EXPECT, **KW) is None
    _one_warning(capsys, p, "empty file" if fault == "empty" else "")
    assert not p.exists()


@pytest.mark.parametrize("field, value, why", [
    ("design_hash", "other9", "design hash 'other9'"),
    ("version", "6", "version '6'"),
    ("key", "k2", "key 'k2'"),
    ("kind", "sampled", "'sampled' entry"),
])
def test_foreign_npz_entry_is_removed(tmp_path, capsys, field, value, why):
    """An entry of another design, code version, key or cache under this name."""
    p = tmp_path / "e.npz"
    cache.write_npz(p, _arrays(), **{**KW, field: value})
    assert cache.read_npz(p, **KW) is None
    _one_warning(capsys, p, why)
    assert not p.exists()


def test_npz_without_header_or_with_other_contents_is_removed(tmp_path, capsys):
    p = tmp_path / "e.npz"
    np.savez(p, **_arrays())                              # written by other code: no header
    assert cache.read_npz(p, **KW) is None
    _one_warning(capsys, p, "no cache header")
    # Sound, but not what the caller expects: a key missing, a dtype or a dimension wrong.
    for expect, why in [({"c": None}, "no array 'c'"),
                        ({"a": np.integer}, "array 'a' is float32, expected integer"),
                        ({"b": (np.integer, 2)}, "array 'b' is 1-D, expected 2-D")]:
        cache.write_npz(p, _arrays(), **KW)
        assert cache.read_npz(p, expect=expect, **KW) is None
        _one_warning(capsys, p, why)
    # An optional name ("?") may be absent.
    cache.write_npz(p, _arrays(), **KW)
    assert cache.read_npz(p, expect={"c?": np.float64, "a?": np.float32}, **KW) is not None


def test_npz_with_an_array_replaced_fails_its_checksum(tmp_path, capsys):
    """A member rewritten with a valid array of the same dtype and shape: only the checksum
    can tell."""
    p = tmp_path / "e.npz"
    a = _arrays()
    cache.write_npz(p, a, **KW)
    with np.load(p, allow_pickle=False) as z:
        members = {n: z[n] for n in z.files}
    members["a"] = members["a"] + np.float32(1e-3)
    np.savez(p, **members)
    assert cache.read_npz(p, **KW) is None
    _one_warning(capsys, p, "checksum mismatch")
    # A member dropped: incomplete.
    cache.write_npz(p, a, **KW)
    with np.load(p, allow_pickle=False) as z:
        members = {n: z[n] for n in z.files if n != "b"}
    np.savez(p, **members)
    assert cache.read_npz(p, **KW) is None
    _one_warning(capsys, p, "incomplete: missing ['b']")


def test_companions_go_with_a_damaged_entry(tmp_path, capsys):
    p, side = tmp_path / "e.npz", tmp_path / "e.json"
    cache.write_npz(p, _arrays(), **KW)
    side.write_text("{}")
    _truncate(p)
    assert cache.read_npz(p, companions=[side], **KW) is None
    assert not p.exists() and not side.exists()
    capsys.readouterr()


def test_an_entry_replaced_meanwhile_is_not_removed(tmp_path, capsys):
    """Two processes: one finds the damaged entry while the other replaces it with a sound
    one; the discard spares the new file."""
    p = tmp_path / "e.npz"
    cache.write_npz(p, _arrays(), **KW)
    old = os.stat(p)
    cache.write_npz(p, _arrays(), **KW)            # replaced (a new inode, atomic rename)
    cache.discard(p, "checksum mismatch", stat=old)
    assert p.exists() and cache.read_npz(p, **KW) is not None
    assert "another process has replaced it" in capsys.readouterr().err


# ------------------------------------------------------------------------------ JSON
def test_json_entry_round_trip_and_faults(tmp_path, capsys):
    p = tmp_path / "pt.json"
    obj = {"status": "ok", "value": 1.5, "t": (1, 2), "by": {2: "x", 10: "y"}}
    cache.write_json(p, obj, **KW)
    back = cache.read_json(p, **KW)
    assert back == json.loads(json.dumps(obj)) and cache.ENTRY not in back
    assert capsys.readouterr().err == ""
    for name, fault in FAULTS.items():
        cache.write_json(p, obj, **KW)
        fault(p)
        assert cache.read_json(p, **KW) is None, name
        _one_warning(capsys, p, "")
        assert not p.exists()
    # Valid JSON whose content was changed, or without the header, or another version's.
    cache.write_json(p, obj, **KW)
    d = json.loads(p.read_text())
    d["value"] = 2.5
    p.write_text(json.dumps(d))
    assert cache.read_json(p, **KW) is None
    _one_warning(capsys, p, "checksum mismatch")
    p.write_text(json.dumps(obj))
    assert cache.read_json(p, **KW) is None
    _one_warning(capsys, p, "no cache header")
    cache.write_json(p, obj, **{**KW, "version": "6"})
    assert cache.read_json(p, **KW) is None
    _one_warning(capsys, p, "version '6'")


def test_seal_finds_a_changed_or_missing_file(tmp_path, capsys):
    a, b, s = tmp_path / "a.exr", tmp_path / "b.json", tmp_path / "seal.json"
    a.write_bytes(os.urandom(5000))
    b.write_text("{}")
    files = {"image": a, "meta": b}
    assert not cache.check_seal(s, files, kind="video-frame")      # none yet: silent
    assert capsys.readouterr().err == ""
    cache.seal(s, files, kind="video-frame", key="raw-0")
    assert cache.check_seal(s, files, kind="video-frame", key="raw-0")
    _truncate(a)
    assert not cache.check_seal(s, files, kind="video-frame", key="raw-0")
    _one_warning(capsys, s, "a.exr does not match its checksum")
    assert not s.exists()
    cache.seal(s, files, kind="video-frame", key="raw-0")
    b.unlink()
    assert not cache.check_seal(s, files, kind="video-frame", key="raw-0")
    _one_warning(capsys, s, "b.json is missing")


# ------------------------------------------------------------------------------ the folder
def test_unwritable_cache_folder_is_one_clear_line(tmp_path, monkeypatch):
    """As root, permission bits stop nothing: the write itself is made to fail (EACCES, EROFS)
    as a read-only folder or mount would."""
    for code in (errno.EACCES, errno.EROFS):
        def refuse(*a, code=code, **k):
            raise OSError(code, os.strerror(code))

        monkeypatch.setattr(cache.tempfile, "TemporaryFile", refuse)
        folder = tmp_path / f"c{code}"
        with pytest.raises(InputError) as exc:
            cache.check_folder(folder)
        msg = str(exc.value)
        assert "\n" not in msg and str(folder) in msg and os.strerror(code) in msg
        assert "KALEIDOSPEC_CACHE" in msg
    monkeypatch.undo()
    assert cache.check_folder(tmp_path / "ok") == tmp_path / "ok"


def test_a_full_disk_leaves_the_old_entry_and_no_temporary(tmp_path, monkeypatch):
    p = tmp_path / "e.npz"
    cache.write_npz(p, _arrays(), **KW)
    before = p.read_bytes()

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(cache.os, "fsync", full)
    with pytest.raises(OSError) as exc:
        cache.write_npz(p, {"a": np.zeros((3, 3), np.float32)}, **KW)
    assert exc.value.errno == errno.ENOSPC
    assert sorted(os.listdir(tmp_path)) == ["e.npz"] and p.read_bytes() == before


def test_bad_arguments():
    with pytest.raises(InputError):
        cache.write_npz("x.npz", {"_entry": np.zeros(1)}, **KW)
    with pytest.raises(InputError):
        cache.write_npz("x.npz", {"o": np.array([None, 1], dtype=object)}, **KW)
    with pytest.raises(InputError):
        cache.write_json("x.json", {"_entry": 1}, **KW)


def test_temporaries_of_killed_writers_are_swept(tmp_path):
    import time

    old, new = tmp_path / ".e.npz.ab12.tmp.npz", tmp_path / ".f.npz.cd34.tmp.npz"
    for t in (old, new):
        t.write_bytes(b"PK")
    past = time.time() - cache.STALE_S - 60
    os.utime(old, (past, past))
    keep = tmp_path / "e.npz"
    cache.write_npz(keep, _arrays(), **KW)
    os.utime(keep, (past, past))
    cache.check_folder(tmp_path)
    # A writer still at work (a recent temporary) and the entries themselves are left alone.
    assert sorted(p.name for p in tmp_path.iterdir()) == [new.name, "e.npz"]
