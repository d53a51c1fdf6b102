"""Calibration of the kaleidoscopic CASSI from captures (paper Sec. 4.1–4.2).

Works on raw frames only (NumPy, OpenCV, scikit-image), as with real hardware:

- :mod:`~recon.calibration.views`: the views' rectangles on the sensor (uniform white),
- :mod:`~recon.calibration.dispersion`: :math:`\\varphi_k(\\lambda)` from line captures,
- :mod:`~recon.calibration.mask`: per-band mask images from monochromatic white captures, and
  every view's mask in view coordinates from all of them jointly (the smeared model),
- :mod:`~recon.calibration.geometry`: homographies to the centre view (checkerboard),
- :mod:`~recon.calibration.extent`: view images that start where each view's light does,
- :mod:`~recon.calibration.radiometry`: per-band gains (the flat field through a model;
  the ColorChecker),
- :mod:`~recon.calibration.noise`: the sensor's photon-transfer curve (a pair of frames),
- :mod:`~recon.calibration.store`: one ``.npz`` + JSON file, cached by design hash,
- :mod:`~recon.calibration.operator`: the calibrated operator and the per-view measurements.

Typical order: views → dispersion → masks → geometry → :func:`build_calibration` →
:func:`with_leads` → reconstruct the ColorChecker → radiometry.
"""

from recon.calibration.dispersion import (DispersionFit, band_mean_positions, band_positions,
                                          fit_dispersion, line_centroids, normalise_offsets,
                                          normalise_offsets_phase)
from recon.calibration.extent import lead_columns, measure_leads, with_leads
from recon.calibration.geometry import (apply_homography, board_field, find_corners,
                                        refine_homography, to_view_coordinates, unmask,
                                        view_homographies)
from recon.calibration.mask import airy_kernel, airy_radius_px, mask_images, view_masks
from recon.calibration.noise import noise_rms, photon_transfer
from recon.calibration.operator import (check_design, measurements, operator_from_calibration,
                                        read_measurements)
from recon.calibration.radiometry import apply_gains, fit_gains, flat_field_gains, patch_spectra
from recon.calibration.store import (Calibration, build_calibration, calibration_path,
                                     load_cached, load_calibration, save_cached,
                                     save_calibration)
from recon.calibration.views import VIEW_FLIPS, VIEW_GRID, find_view_boxes

__all__ = [
    "Calibration", "DispersionFit", "VIEW_FLIPS", "VIEW_GRID", "airy_kernel", "airy_radius_px",
    "apply_gains", "apply_homography", "band_mean_positions", "band_positions", "board_field",
    "build_calibration", "calibration_path", "check_design", "find_corners", "find_view_boxes",
    "fit_dispersion", "fit_gains", "flat_field_gains", "lead_columns", "line_centroids",
    "load_cached", "load_calibration", "mask_images", "measure_leads", "measurements", "noise_rms",
    "normalise_offsets", "normalise_offsets_phase", "operator_from_calibration",
    "patch_spectra", "photon_transfer", "read_measurements", "refine_homography",
    "save_cached", "save_calibration", "to_view_coordinates", "unmask", "view_homographies",
    "view_masks", "with_leads",
]
