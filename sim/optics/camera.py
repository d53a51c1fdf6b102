"""The imaging lens and the sensor as Mitsuba's sensor: a ``thinlens`` camera focused at infinity.

After the prism, every mask point's light is a collimated beam; the imaging lens (focal length
:math:`f`, f-number N, aperture radius :math:`f/(2N)`) focuses each beam on the sensor at
:math:`f \\tan\\theta` from the centre. A ``thinlens`` camera focused at infinity does exactly that
in reverse: each pixel emits parallel rays from every point of the aperture, in the pixel's
direction. Its field of view follows from the sensor width, :math:`\\tan(\\mathrm{fov}_x/2) =
W \\Delta / (2 f)`. The camera looks back along the centre wavelength's exit ray of the prism, so
the optical axis meets the sensor centre for ``prism_center_nm``; up is world +y (the prism
disperses in the x–z plane).

Film values: the camera's importance is normalised so that a pixel records the mean radiance
over its aperture rays; the sensor's irradiance is then :math:`E = \\pi \\bar L / (1 + 4N^2)`
(the solid angle of the aperture cone seen from the sensor, :math:`\\pi\\sin^2\\theta_{\\max}` with
:math:`\\sin^2\\theta_{\\max} = 1/(1 + 4N^2)`). :func:`irradiance_factor` is that factor.
"""

from __future__ import annotations

import math

import numpy as np

from sim.optics.variant import ensure_variant

__all__ = ["camera_dict", "irradiance_factor", "band_response", "FOCUS_DISTANCE_MM"]

#: "Infinity" for the thin-lens camera (mm); the defocus it leaves is < 1e-6 px.
FOCUS_DISTANCE_MM = 1.0e8


def irradiance_factor(design) -> float:
    """π / (1 + 4N²): sensor irradiance per unit mean radiance through the aperture."""
    N = float(design.imaging_f_number)
    return math.pi / (1.0 + 4.0 * N * N)


def band_response(lo_nm: float, hi_nm: float) -> dict:
    """A box spectral response on [lo, hi] (nm) for ``specfilm`` (a 0.02 nm box if lo == hi)."""
    if hi_nm - lo_nm < 0.02:
        c = 0.5 * (lo_nm + hi_nm)
        lo_nm, hi_nm = c - 0.01, c + 0.01
    return {"type": "regular", "wavelength_min": float(lo_nm), "wavelength_max": float(hi_nm),
            "values": "1, 1"}


def camera_dict(design, position, direction, film: dict | None = None,
                crop: tuple[int, int, int, int] | None = None, sampler_seed: int = 0,
                spp: int = 1, sampler: str = "independent") -> dict:
    """Mitsuba dict of the imaging lens + sensor.

    Parameters
    ----------
    design : sim.optics.design.Design
        Sensor size and pixel, imaging focal length and f-number.
    position : sequence of 3 floats
        Centre of the imaging lens (world mm).
    direction : sequence of 3 floats
        Direction of the light arriving at the lens (the camera looks the opposite way).
    film : dict, optional
        Film dict without its size (``specfilm`` with a band, typically); ``hdrfilm`` if None.
    crop : (row0, col0, height, width), optional
        Render only this window of the sensor.
    sampler : str
        Mitsuba sampler plugin (``independent``, ``multijitter``, ...).
    """
    mi = ensure_variant()
    W, H = int(design.sensor_width_px), int(design.sensor_height_px)
    f = float(design.imaging_focal_mm)
    pix = design.sensor_pixel_um * 1e-3
    fov = 2.0 * math.degrees(math.atan(0.5 * W * pix / f))
    fd = dict(film) if film is not None else {"type": "hdrfilm"}
    fd.update({"width": W, "height": H, "rfilter": {"type": "box"}})
    if crop is not None:
        r0, c0, h, w = (int(v) for v in crop)
        fd.update({"crop_offset_x": c0, "crop_offset_y": r0, "crop_width": w, "crop_height": h})
    o = mi.ScalarPoint3f(*[float(v) for v in position])
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    target = o - mi.ScalarVector3f(*[float(v) for v in d])
    return {
        "type": "thinlens",
        "fov": fov,
        "fov_axis": "x",
        "aperture_radius": f / (2.0 * float(design.imaging_f_number)),
        "focus_distance": FOCUS_DISTANCE_MM,
        "near_clip": 1e-3,
        "far_clip": 1e9,
        "to_world": mi.ScalarTransform4f().look_at(origin=o, target=target,
                                                   up=mi.ScalarVector3f(0, 1, 0)),
        "sampler": {"type": sampler, "sample_count": int(spp), "seed": int(sampler_seed)},
        "film": fd,
    }
