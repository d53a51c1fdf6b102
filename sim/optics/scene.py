"""Assemble the Mitsuba scene of the instrument from a :class:`sim.optics.design.Design`.

Light travels along +z and meets, in order (paper Fig. 2):

=====================  =========================================================================
z (mm)                 element
=====================  =========================================================================
0                      diffuser (:mod:`sim.optics.diffuser`), the scene cube as an area emitter
0 … L                  kaleidoscope, four Al mirrors (:mod:`sim.optics.kaleidoscope`), if enabled
a                      relay lens, f_r (:mod:`sim.optics.lens`); a = L + gap (1/a + 1/b = 1/f_r)
a + b                  chrome-on-quartz mask (:mod:`sim.optics.mask`) in the relay's image plane
a + b + f_c            collimating lens, f_c
a + b + f_c + p f_c/2  BK-7 prism at minimum deviation (:mod:`sim.optics.prism`), folds the axis by δ
… along δ              imaging lens + sensor (:mod:`sim.optics.camera`): its aperture (the stop) lies
                       p·f_c (air-equivalent) behind the collimator, p = ``imaging_stop_fraction``
=====================  =========================================================================

Where the stop goes matters for the kaleidoscope. Imaged back through the collimator and the
relay, the stop becomes the entrance pupil seen from the diffuser; a ray bound for an outer
virtual copy must still pass the tube's 24 mm exit, so the closer the entrance pupil is to the
tube's exit, the less the outer views are vignetted. With the stop at the collimator's back
focal plane (p = 1, telecentric on the mask) the entrance pupil sits at the relay's front focal
point, 136 mm beyond the tube's exit in the ``small`` design, and the outer 20–30 px of the
left/right views lose up to 80 % of their light; p = 0.5 (the default; the prism sits between
collimator and stop) keeps every view's light within a few percent except at the very outer
edges (≈ 20 % at the outermost 10 px). The paper gives no stop position; a field lens at the
mask would remove the remaining vignetting.

The plain single-view CASSI (``design.kaleidoscope = False``) is the same scene without the
mirrors and with the relay moved so the one view fills the 3×3 grid's area
(:attr:`Design.object_distance_mm`). Mitsuba's dict keys may not contain dots; ours do not.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sim.optics.variant import ensure_variant

__all__ = ["SceneSpec", "build_scene", "TraceSetup", "trace_setup"]


@dataclass
class SceneSpec:
    """A scene dict plus what the renderers need to know about it."""

    scene: dict
    camera_position: np.ndarray
    camera_direction: np.ndarray
    texture: object
    z: dict = field(default_factory=dict)

    def camera(self, design, film=None, crop=None, seed=0, spp=1,
               sampler: str = "independent") -> dict:
        """The sensor dict (:func:`sim.optics.camera.camera_dict`) for this scene."""
        from sim.optics.camera import camera_dict

        return camera_dict(design, self.camera_position, self.camera_direction, film=film,
                           crop=crop, sampler_seed=seed, spp=spp, sampler=sampler)


def build_scene(design, cube_lhw: np.ndarray | None = None, wavelengths=None, *,
                lenses: str = "thin", mask_pattern: np.ndarray | None = None,
                max_depth: int = 64, pupil_fraction: float | None = None) -> SceneSpec:
    """The instrument as a Mitsuba scene dict (no sensor: renderers add one per band/view).

    Parameters
    ----------
    design : sim.optics.design.Design
    cube_lhw : ndarray (L, H, W), optional
        Band-major radiance cube on the diffuser; None for a dark diffuser (transport tracing).
    wavelengths : array_like (L,), optional
        The cube's band centres (nm).
    lenses : {"thin", "real"}
        Ideal thin-lens BSDFs (default, exact imaging) or real BK-7 singlet meshes for the relay
        and collimator (chromatic and spherical aberration; the imaging lens stays ideal).
    mask_pattern : ndarray of bool, optional
        Override ``design.mask_pattern()`` (e.g. all open).
    max_depth : int
        Path tracer depth; every mirror bounce and lens/mask/prism crossing is one vertex.
    pupil_fraction : float, optional
        Air-equivalent distance from the collimator to the imaging lens's aperture (the stop),
        in units of f_c. 1 puts the stop at the collimator's back focal plane (telecentric on
        the mask); smaller values move the entrance pupil toward the tube's exit and reduce
        the vignetting of the outer views by the tube (see the module notes). Default:
        ``design.imaging_stop_fraction`` (so the stop position is part of the design hash).
    """
    if pupil_fraction is None:
        pupil_fraction = design.imaging_stop_fraction
    ensure_variant()
    from sim.optics import diffuser, kaleidoscope, lens, mask, prism

    if lenses not in ("thin", "real"):
        from recon.errors import InputError

        raise InputError(f"lenses must be 'thin' or 'real', got {lenses!r}")
    a, b = design.object_distance_mm, design.image_distance_mm
    fr, fc = design.relay_focal_mm, design.collimator_focal_mm
    z_relay, z_mask = a, a + b
    z_col = z_mask + fc
    z_prism = z_col + 0.5 * pupil_fraction * fc
    N = design.imaging_f_number
    pupil = design.imaging_focal_mm / N
    half_sensor = 0.5 * np.hypot(design.sensor_width_px, design.sensor_height_px) \
        * design.sensor_pixel_um * 1e-3
    field_tan = half_sensor / design.imaging_focal_mm
    # Beam footprint at the prism (pupil plus the field's spread over f_c/2), with margin.
    footprint = pupil + 2.0 * 0.5 * pupil_fraction * fc * field_tan
    grid_mask = design.grid_size * design.view_size_mask_mm

    scene: dict = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(max_depth), "rr_depth": int(max_depth),
                       "hide_emitters": False},
    }
    dshape, tex = diffuser.diffuser_shape(design, cube_lhw, wavelengths, z=0.0)
    scene["diffuser"] = dshape
    if design.kaleidoscope:
        scene.update(kaleidoscope.mirror_shapes(design, z0=0.0))
    # Relay: large enough not to vignette the 3×3 grid's cones (the tube exit is the stop).
    d_relay = 2.0 * (0.5 * grid_mask + b / (2.0 * N)) + 0.5 * design.tube_width_mm + 10.0
    d_col = grid_mask + fc / N + 2.0 * fc * field_tan + 10.0
    if lenses == "thin":
        scene["relay_lens"] = lens.lens_shape(fr, [0, 0, z_relay], d_relay)
        scene["collimator_lens"] = lens.lens_shape(fc, [0, 0, z_col], d_col)
    else:
        scene["relay_lens"] = lens.real_lens_shape(fr, [0, 0, z_relay], d_relay)
        scene["collimator_lens"] = lens.real_lens_shape(fc, [0, 0, z_col], d_col)
    scene["mask"] = mask.mask_shape(design, z_mask, mask_pattern)
    pmesh, exit_dir, exit_pt, entry_pt, glass_path = prism.prism_shape(
        design.prism_glass, design.prism_apex_deg, design.prism_center_nm,
        [0.0, 0.0, z_prism], height_mm=1.6 * footprint + 6.0, depth_mm=2.0 * footprint + 10.0,
        base_side=1.0,
    )
    scene["prism"] = pmesh
    # The pupil sits on the axis ray at the collimator's back focal plane, the distance measured
    # along the folded axis with the glass path reduced by n (so the mask side is telecentric
    # and the pupil is centred on every beam: a decentred pupil vignettes one side).
    from sim.optics.glass import refractive_index

    n_c = float(refractive_index(design.prism_glass, design.prism_center_nm))
    left = pupil_fraction * fc - (entry_pt[2] - z_col) - glass_path / n_c
    cam_pos = exit_pt + exit_dir * left
    return SceneSpec(scene=scene, camera_position=cam_pos, camera_direction=exit_dir,
                     texture=tex,
                     z={"relay": z_relay, "mask": z_mask, "collimator": z_col, "prism": z_prism})


@dataclass
class TraceSetup:
    """A loaded instrument for the tracers (:func:`sim.optics.rays.walk`): the Mitsuba scene, its
    camera and the places the tracers record."""

    mi: object
    scene: object
    camera: object
    z: dict
    #: z of the tube's exit (its only stop), None without the kaleidoscope.
    tube_length: float | None
    tube_width: float
    sensor_shape: tuple[int, int]


def trace_setup(design, *, open_mask: bool = False) -> TraceSetup:
    """Load the instrument with a dark diffuser for tracing (not for rendering a scene).

    ``open_mask`` replaces the code by an all-open plate (the optical maps need where a ray
    crosses the mask, whatever the cell there; the pattern is applied afterwards).
    """
    mi = ensure_variant()
    pattern = np.ones((design.mask_cells, design.mask_cells), bool) if open_mask else None
    spec = build_scene(design, None, None, mask_pattern=pattern)
    return TraceSetup(mi=mi, scene=mi.load_dict(spec.scene), camera=mi.load_dict(spec.camera(design)),
                      z=dict(spec.z), tube_length=(float(design.mirror_length_mm)
                                                   if design.kaleidoscope else None),
                      tube_width=float(design.tube_width_mm),
                      sensor_shape=(design.sensor_height_px, design.sensor_width_px))
