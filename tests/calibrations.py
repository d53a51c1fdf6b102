"""A tiny three-view calibration assembled directly from arrays (no captures): the centre view and
two views mirrored along x, four bands, for the tests of what a calibration's fields do to the
calibrated operator."""

import numpy as np

from recon.calibration import build_calibration

K, L, HV, WM = 3, 4, 12, 40
#: Where view column 0 lands in each band (box columns), the same in every view.
PHI = np.array([0.0, 2.0, 3.5, 5.0])
#: Centre box → view box: the identity, then two views mirrored along x.
BOX_HOMOGRAPHIES = np.stack([np.eye(3)]
                            + [np.array([[-1, 0, WM - 1.0], [0, 1, 0.5], [0, 0, 1]])] * 2)


def three_view_calibration(masks, box_fields=None):
    """:func:`recon.calibration.build_calibration` of (K, L, HV, WM) mask images, the board at
    the third band's wavelength; ``box_fields`` as for it."""
    phi = np.stack([PHI] * K)
    return build_calibration(
        view_ids=(0, 1, 2), view_boxes=[(0, 40, HV, WM), (0, 0, HV, WM), (0, 80, HV, WM)],
        box_homographies=BOX_HOMOGRAPHIES, mask_images=masks, wavelengths=[450.0, 500.0, 550.0, 600.0],
        dispersion=phi, checker_dispersion=phi[:, 2], box_fields=box_fields)
