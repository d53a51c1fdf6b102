r"""Image regression: a fresh render and a fresh reconstruction against the stored goldens.

The goldens in ``tests/golden/`` are a noise-free raw frame of a reduced ``small`` design
(:data:`OVERRIDES`: a 300×240 sensor of 40 µm pixels, 80 µm mask cells, 6 bands; 78 px views)
showing the ``natural`` scene, and its reconstruction from five views (:data:`RECON_PATH`: the
design's exact operator for now, the calibrated product path once it matches it).
Regenerate them on purpose, after a change that is meant to alter the images, with::

    python3 tools/regen_golden.py

Tolerances (:func:`compare_frames`).  The render is deterministic: the transport integrates
every pixel exactly on optical maps traced with a fixed seed, so on one machine a fresh frame
equals the golden to the bit.  Elsewhere float rounding (another CPU's vector width, another
drjit/NumPy) moves the traced maps by their float32 round-off (measured between independent
traces, the far larger difference: 1·10⁻⁴ of a frame, 2.4·10⁻⁴ of its peak at most) and can
tip the ADC's rounding.  Hence, with 1 DN for the rounding and the peak value :math:`M`:

1. every pixel: :math:`|\Delta| \le 1 + 10^{-3} M`;
2. block means over 8×8 pixels: :math:`|\bar\Delta| \le 0.5 + 2 \cdot 10^{-4} M` (a smooth
   radiometric change cannot hide below check 1: a 1 % change of exposure moves them by
   :math:`10^{-2} M`).

:func:`test_comparison_catches_a_changed_design` shows in the test itself that the checks fail
on a real change (a 0.5° apex, another mask seed), and
:func:`test_comparison_tolerates_float_noise` that float-level noise passes.

Reconstruction (:func:`compare_reconstructions`): the fresh cube must agree with the golden
cube to ≥ 40 dB PSNR (peak = golden maximum), and its PSNR against the truth must be within
0.25 dB of the golden's.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

GOLDEN_DIR = Path(__file__).resolve().parent / "golden"
FRAME_FILE = "frame.npz"
RECON_FILE = "recon.npz"
META_FILE = "golden.json"

SCENE = "natural"
#: The ``small`` preset further reduced so that tracing, calibrating and solving take seconds.
OVERRIDES = {"sensor_width_px": 376, "sensor_height_px": 300, "sensor_pixel_um": 32.0,
             "mask_pitch_um": 64.0, "band_step_nm": 50.0}
SEED = 0
N_VIEWS = 5
SOLVER = "fista-tv"
ITERS = 50
#: Which reconstruction the golden holds: "oracle" (the exact operator of the design on the
#: rendered frame, :func:`kaleidospec.reconstruct.reconstruct_oracle`) or "calibrated" (the
#: product path: calibration from rendered captures, then
#: :func:`kaleidospec.reconstruct.reconstruct_views`), which the golden holds so that a change
#: in the calibration code is caught too.
RECON_PATH = "calibrated"

BLOCK = 8
#: :func:`compare_reconstructions`: agreement with the golden cube, and PSNR drift vs truth.
RECON_MIN_PSNR_DB = 40.0
RECON_MAX_DRIFT_DB = 0.25


# ------------------------------------------------------------------------- producing the images
def golden_design(**changes):
    """The golden design: ``small`` with :data:`OVERRIDES` (and ``changes``)."""
    from sim.optics.design import get_design

    return get_design("small", {**OVERRIDES, **changes})


def render(design):
    """Noise-free raw frame of :data:`SCENE` → ``(frame, metadata, truth, wavelengths)``."""
    from kaleidospec.instrument import render_scene

    return render_scene(SCENE, design, seed=SEED, noise=False)


def reconstruct(frame, meta, design, truth, *, iters: int = ITERS, tau=None):
    """Reconstruct ``N_VIEWS`` views of ``frame`` by :data:`RECON_PATH` (a calibration is
    cached in ``$KALEIDOSPEC_CACHE``). Returns ``(cube, truth on its grid, info)``."""
    from kaleidospec.calibrate import calibrate
    from kaleidospec.reconstruct import reconstruct_oracle, reconstruct_views

    if RECON_PATH == "oracle":
        cube, info = reconstruct_oracle(frame, meta, design, N_VIEWS, solver=SOLVER,
                                        iters=iters, tau=tau, truth=truth)
        return cube, np.asarray(truth, np.float32), info
    cal = calibrate(design, progress=False)
    cube, info = reconstruct_views(frame, meta, cal, N_VIEWS, solver=SOLVER, iters=iters,
                                   tau=tau, truth=truth, design=design)
    return cube, info["truth_grid"], info


def produce():
    """Everything the goldens hold, freshly computed: a dict of arrays and metadata."""
    d = golden_design()
    frame, meta, truth, wl = render(d)
    cube, grid, info = reconstruct(frame, meta, d, truth)
    from recon.metrics import psnr

    return {"design": d, "frame": frame, "meta": meta, "truth_grid": grid, "cube": cube,
            "wavelengths": np.asarray(wl, np.float64), "psnr_truth": psnr(cube, grid),
            "tau": info.get("tau")}


# ------------------------------------------------------------------------- the comparisons
def _blocks(x: np.ndarray, b: int) -> np.ndarray:
    h, w = (x.shape[0] // b) * b, (x.shape[1] // b) * b
    return x[:h, :w].reshape(h // b, b, w // b, b).mean(axis=(1, 3))


#: :func:`compare_frames`: per-pixel and 8×8-block tolerances, fractions of the peak.
PIXEL_LEVEL = 1e-3
BLOCK_LEVEL = 2e-4


def compare_frames(fresh, golden) -> list[str]:
    """The reasons ``fresh`` differs from ``golden`` beyond float differences (empty list: they
    agree).  See the module notes for the two checks."""
    a = np.asarray(fresh, np.float64)
    g = np.asarray(golden, np.float64)
    if a.shape != g.shape:
        return [f"frame shape {a.shape} != golden {g.shape}"]
    if not np.all(np.isfinite(a)):
        return ["the fresh frame has non-finite values"]
    d = a - g
    M = float(g.max())
    if M <= 0:
        return ["the golden frame is black"]
    out = []
    worst = float(np.abs(d).max())
    if worst > 1.0 + PIXEL_LEVEL * M:
        out.append(f"a pixel moved by {worst:.1f} DN > {1.0 + PIXEL_LEVEL * M:.1f} DN")
    bd = float(np.abs(_blocks(d, BLOCK)).max())
    lim = 0.5 + BLOCK_LEVEL * M
    if bd > lim:
        out.append(f"a {BLOCK}×{BLOCK} block mean moved by {bd:.2f} DN > {lim:.2f} DN")
    return out


def compare_reconstructions(fresh, golden, truth, golden_psnr: float) -> list[str]:
    """The reasons a fresh reconstruction differs from the golden one (empty: they agree)."""
    from recon.metrics import psnr

    a = np.asarray(fresh, np.float32)
    g = np.asarray(golden, np.float32)
    if a.shape != g.shape:
        return [f"cube shape {a.shape} != golden {g.shape}"]
    out = []
    agree = psnr(a, g)
    if not agree >= RECON_MIN_PSNR_DB:
        out.append(f"PSNR against the golden cube {agree:.2f} dB < {RECON_MIN_PSNR_DB:g} dB")
    p = psnr(a, truth)
    if not abs(p - golden_psnr) <= RECON_MAX_DRIFT_DB:
        out.append(f"PSNR against the truth {p:.3f} dB, golden {golden_psnr:.3f} dB "
                   f"(> {RECON_MAX_DRIFT_DB:g} dB apart)")
    return out


# ------------------------------------------------------------------------- golden files
def write_goldens(folder: Path = GOLDEN_DIR) -> list[Path]:
    """Compute and write the goldens into ``folder`` (atomically, file by file)."""
    import drjit
    import mitsuba

    from recon.io.atomic import atomic_path, write_text

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    p = produce()
    frame = p["frame"]
    # Noise-free frames are whole DN in [0, 4095]: uint16 stores them exactly and compresses.
    if not np.array_equal(frame, np.rint(frame)) or frame.min() < 0 or frame.max() > 65535:
        raise RuntimeError("the golden frame is not in whole DN")
    with atomic_path(folder / FRAME_FILE) as tmp:
        np.savez_compressed(tmp, frame=frame.astype(np.uint16))
    # float16 keeps ~3.3 significant digits (rounding alone: PSNR > 60 dB against the float32
    # cube, far above the 40 dB agreement asked for) and halves the file. The truth is not
    # stored: the scene generator is deterministic and a change of it shows in the frame.
    with atomic_path(folder / RECON_FILE) as tmp:
        np.savez_compressed(tmp, cube=p["cube"].astype(np.float16),
                            wavelengths=p["wavelengths"])
    d = p["design"]
    meta = {
        "what": "golden raw frame and reconstruction for tests/test_golden.py",
        "regenerate": "python3 tools/regen_golden.py",
        "scene": SCENE, "preset": "small", "recon_path": RECON_PATH, "overrides": OVERRIDES, "design": d.to_dict(),
        "design_hash": d.hash, "seed": SEED, "noise": False,
        "trace_seed": int(p["meta"]["trace_seed"]), "scene_shape": p["meta"]["scene_shape"],
        "radiance_scale": p["meta"]["radiance_scale"], "n_views": N_VIEWS, "solver": SOLVER,
        "iters": ITERS, "tau": p["tau"], "psnr_truth_db": p["psnr_truth"],
        "frame_max_dn": float(frame.max()),
        "versions": {"numpy": np.__version__, "mitsuba": mitsuba.__version__,
                     "drjit": drjit.__version__},
    }
    write_text(folder / META_FILE, json.dumps(meta, indent=2, sort_keys=True) + "\n")
    return [folder / FRAME_FILE, folder / RECON_FILE, folder / META_FILE]


def load_goldens(folder: Path = GOLDEN_DIR) -> dict:
    folder = Path(folder)
    meta = json.loads((folder / META_FILE).read_text(encoding="utf-8"))
    with np.load(folder / FRAME_FILE, allow_pickle=False) as z:
        frame = z["frame"].astype(np.float32)
    with np.load(folder / RECON_FILE, allow_pickle=False) as z:
        cube, wl = z["cube"].astype(np.float32), z["wavelengths"]
    return {"meta": meta, "frame": frame, "cube": cube, "wavelengths": wl}


# ------------------------------------------------------------------------- the tests
pytestmark = pytest.mark.mitsuba


@pytest.fixture(scope="module")
def cache(fresh_cache):
    """A fresh, empty cache folder for the whole module (nothing reused from earlier runs)."""
    return fresh_cache


@pytest.fixture(scope="module")
def golden():
    if not (GOLDEN_DIR / META_FILE).is_file():
        pytest.fail("no goldens in tests/golden/: run python3 tools/regen_golden.py")
    return load_goldens()


@pytest.fixture(scope="module")
def fresh(cache):
    d = golden_design()
    frame, meta, truth, wl = render(d)
    return {"design": d, "frame": frame, "meta": meta, "truth": truth, "wavelengths": wl}


@pytest.fixture(scope="module")
def fresh_recon(fresh):
    return reconstruct(fresh["frame"], fresh["meta"], fresh["design"], fresh["truth"])


def test_goldens_are_of_the_golden_design(golden):
    d = golden_design()
    assert golden["meta"]["design_hash"] == d.hash, (
        "the golden design changed (a design default or the overrides); if intended, "
        "regenerate with: python3 tools/regen_golden.py")
    assert golden["frame"].shape == (d.sensor_height_px, d.sensor_width_px)


def test_fresh_render_matches_the_golden_frame(golden, fresh):
    assert fresh["meta"]["noise"] is False
    problems = compare_frames(fresh["frame"], golden["frame"])
    assert not problems, "; ".join(problems) + " (regenerate on purpose: tools/regen_golden.py)"


def test_render_is_deterministic(fresh):
    """Rendering again (transport now in memory) gives the identical frame."""
    frame, _, _, _ = render(fresh["design"])
    assert np.array_equal(frame, fresh["frame"])


def test_fresh_reconstruction_matches_the_golden(golden, fresh_recon):
    cube, grid, _ = fresh_recon
    problems = compare_reconstructions(cube, golden["cube"], grid,
                                       golden["meta"]["psnr_truth_db"])
    assert not problems, "; ".join(problems) + " (regenerate on purpose: tools/regen_golden.py)"


@pytest.mark.parametrize("change", [{"prism_apex_deg": 30.5}, {"mask_seed": 1}],
                         ids=["apex+0.5deg", "mask-seed"])
def test_comparison_catches_a_changed_design(golden, fresh, change):
    """A real change of the instrument must fail :func:`compare_frames` (while the unchanged
    fresh render passes it, see above)."""
    frame, _, _, _ = render(golden_design(**change))
    assert compare_frames(frame, golden["frame"])


def test_comparison_catches_a_changed_reconstruction(golden, fresh, fresh_recon):
    """Stopping the solver early (a real change of the reconstruction) fails the comparison."""
    cube, grid, _ = reconstruct(fresh["frame"], fresh["meta"], fresh["design"], fresh["truth"],
                                iters=ITERS // 3)
    assert compare_reconstructions(cube, golden["cube"], grid, golden["meta"]["psnr_truth_db"])


def test_comparison_tolerates_float_noise_and_catches_an_exposure_change(golden):
    """Float-level noise within the tolerances passes: ±1 DN of rounding everywhere and the
    measured difference between two independent traces (2.4·10⁻⁴ of the peak, at random);
    a 1 % change of exposure does not."""
    g = golden["frame"]
    M = float(g.max())
    rng = np.random.default_rng(0)
    a = g + rng.integers(-1, 2, size=g.shape).astype(np.float32)
    a += rng.uniform(-2.4e-4, 2.4e-4, size=g.shape).astype(np.float32) * M
    assert compare_frames(np.clip(a, 0, None), g) == []
    assert compare_frames(np.rint(g * 1.01), g)
