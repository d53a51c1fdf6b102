"""Raw frames: single-channel EXR + JSON sidecar."""

import json

import numpy as np
import pytest

from recon.errors import InputError
from recon.io.arrays import write_exr
from recon.io.raw import read_raw, sidecar_path, write_raw


@pytest.fixture
def frame():
    return np.random.default_rng(0).random((12, 20)).astype(np.float32)


def test_round_trip_with_metadata(tmp_path, frame):
    meta = {
        "design": {"apex_deg": 17.0, "views": 5, "prism": "BK7"},
        "design_hash": "3f2a9c",
        "exposure_s": np.float32(0.1),
        "wavelengths_nm": np.linspace(450, 700, 26),
        "seed": np.int64(7),
    }
    exr, side = write_raw(tmp_path / "frame_0001.exr", frame, meta)
    assert side == tmp_path / "frame_0001.json" == sidecar_path(exr)
    back, m = read_raw(exr)
    np.testing.assert_array_equal(back, frame)
    assert m["design"] == meta["design"] and m["seed"] == 7 and m["design_hash"] == "3f2a9c"
    assert m["exposure_s"] == pytest.approx(0.1)
    np.testing.assert_allclose(m["wavelengths_nm"], meta["wavelengths_nm"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame_0001.exr", "frame_0001.json"]


def test_missing_sidecar(tmp_path, frame):
    write_exr(tmp_path / "f.exr", {"Y": frame})
    with pytest.raises(InputError, match="f.json: the metadata sidecar"):
        read_raw(tmp_path / "f.exr")
    back, m = read_raw(tmp_path / "f.exr", require_metadata=False)
    assert m == {} and np.array_equal(back, frame)


def test_bad_sidecar(tmp_path, frame):
    write_raw(tmp_path / "f.exr", frame, {})
    (tmp_path / "f.json").write_text("{not json")
    with pytest.raises(InputError, match="f.json: not valid JSON"):
        read_raw(tmp_path / "f.exr")
    (tmp_path / "f.json").write_text("[1, 2]")
    with pytest.raises(InputError, match="JSON object"):
        read_raw(tmp_path / "f.exr")
    (tmp_path / "f.json").write_text("")
    with pytest.raises(InputError, match="empty"):
        read_raw(tmp_path / "f.exr")


def test_bad_frames(tmp_path, frame):
    with pytest.raises(InputError, match="no such file"):
        read_raw(tmp_path / "none.exr")
    write_exr(tmp_path / "two.exr", {"Y": frame, "Z": frame})
    (tmp_path / "two.json").write_text("{}")
    with pytest.raises(InputError, match="one channel"):
        read_raw(tmp_path / "two.exr")
    bad = frame.copy()
    bad[0, 0] = np.nan
    write_exr(tmp_path / "nan.exr", {"Y": bad})
    (tmp_path / "nan.json").write_text("{}")
    with pytest.raises(InputError, match="NaN"):
        read_raw(tmp_path / "nan.exr")
    write_raw(tmp_path / "t.exr", frame, {})
    data = (tmp_path / "t.exr").read_bytes()
    (tmp_path / "t.exr").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="t.exr"):
        read_raw(tmp_path / "t.exr")


def test_failed_writes_leave_nothing(tmp_path, frame):
    with pytest.raises(InputError, match="JSON"):
        write_raw(tmp_path / "a.exr", frame, {"f": object()})
    with pytest.raises(InputError, match="JSON"):
        write_raw(tmp_path / "a.exr", frame, {"x": float("nan")})  # not valid JSON
    with pytest.raises(InputError, match="2-D"):
        write_raw(tmp_path / "a.exr", frame[None], {})
    with pytest.raises(InputError, match=".exr"):
        write_raw(tmp_path / "a.npy", frame, {})
    with pytest.raises(InputError, match="NaN"):
        write_raw(tmp_path / "a.exr", np.full_like(frame, np.inf), {})
    assert list(tmp_path.iterdir()) == []


def test_refuses_to_overwrite_input(tmp_path, frame):
    exr, side = write_raw(tmp_path / "a.exr", frame, {"seed": 1})
    with pytest.raises(InputError, match="input"):
        write_raw(exr, frame * 0, {"seed": 2}, protect=[exr])
    back, m = read_raw(exr)
    assert np.array_equal(back, frame) and m == {"seed": 1}
    assert json.loads(side.read_text()) == {"seed": 1}
