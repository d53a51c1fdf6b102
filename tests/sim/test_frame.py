"""sim.frame: the expected frame, taken view by view, equals the whole-sensor sum; the blurred sum
over bands by FFT equals the direct blurs."""

from __future__ import annotations

import numpy as np
import pytest

from sim import sensor


def _direct(images, kernels, scales, R):
    """Each image blurred directly (OpenCV, zero padding ``R``), weighted and summed."""
    import cv2

    h, w = images.shape[1:]
    out = np.zeros((h + 2 * R, w + 2 * R), np.float32)
    for img, k, s in zip(images, kernels, scales):
        pad = cv2.copyMakeBorder(img, R, R, R, R, cv2.BORDER_CONSTANT, value=0.0)
        out += np.float32(s) * cv2.filter2D(pad, -1, k, borderType=cv2.BORDER_CONSTANT)
    return out


def test_blurred_sum_is_the_sum_of_direct_blurs():
    """The FFT's sum over bands against each band blurred directly and weighted: kernels of
    different reach, a border the widest one fills; some bands only, each with its weight."""
    rng = np.random.default_rng(5)
    kernels = [sensor.airy_kernel(r) for r in (0.8, 1.6, 2.4)]
    assert len({k.shape for k in kernels}) == 3
    scales = np.array([1.0, 0.5, 2.0])
    images = rng.random((3, 37, 52)).astype(np.float32)
    blur = sensor.BlurredSum(kernels, scales)
    for bands in ([0, 1, 2], [2, 0], [1]):
        R = blur.reach(bands)
        assert R == max(kernels[l].shape[0] // 2 for l in bands)
        got = blur(images[bands], bands)
        want = _direct(images[bands], [kernels[l] for l in bands], scales[bands], R)
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-6 * float(want.max()))
        # The images handed over already padded to the transforms' shape: the same bits.
        shape = blur.shape(37, 52, bands)
        assert shape[0] >= 37 + 2 * R and shape[1] >= 52 + 2 * R
        padded = np.zeros((len(bands),) + shape, np.float32)
        padded[:, :37, :52] = images[bands]
        np.testing.assert_array_equal(blur(padded, bands, size=(37, 52)), got)
        with pytest.raises(ValueError):
            blur(padded[:, :-1], bands, size=(37, 52))
    # No kernels: the weighted sum itself.
    plain = sensor.BlurredSum(None, scales)(images, [0, 1, 2])
    np.testing.assert_allclose(plain, np.tensordot(scales, images, 1), rtol=1e-6)


def test_blurred_sum_adjoint_is_its_adjoint():
    """``adjoint`` against the sum's own transpose: <S(E), Y> = Σ_l <E_l, S*(Y)_l>, for kernels
    of different reach and for none; its image must be the view widened by the reach."""
    rng = np.random.default_rng(7)
    kernels = [sensor.airy_kernel(r) for r in (0.8, 1.6, 2.4)]
    scales = np.array([1.0, 0.5, 2.0])
    images = rng.standard_normal((3, 21, 34)).astype(np.float32)
    for kern in (kernels, None):
        blur = sensor.BlurredSum(kern, scales)
        for bands in ([0, 1, 2], [2, 0], [1]):
            R = blur.reach(bands)
            Y = rng.standard_normal((21 + 2 * R, 34 + 2 * R)).astype(np.float32)
            fwd = blur(images[bands], bands).astype(np.float64)
            adj = blur.adjoint(Y, bands, (21, 34)).astype(np.float64)
            lhs = float(np.sum(fwd * Y))
            rhs = float(np.sum(images[bands] * adj))
            assert abs(lhs - rhs) <= 1e-5 * np.sqrt(np.sum(fwd ** 2) * np.sum(Y ** 2)), (lhs, rhs)
            with pytest.raises(ValueError, match="widened"):
                blur.adjoint(Y[:-1], bands, (21, 34))


def test_ccs_multiplier_is_opencvs_spectrum_product():
    """A real spectrum laid out as OpenCV's packed transform: the element-wise product equals
    OpenCV's own product of packed spectra (``mulSpectrums``), for an even kernel centred on
    the origin, and the blur it gives is the circular convolution."""
    import cv2

    rng = np.random.default_rng(4)
    shape = (24, 30)
    k = sensor.airy_kernel(1.3).astype(np.float64)
    r = k.shape[0] // 2
    pad = np.zeros(shape)
    pad[:k.shape[0], :k.shape[1]] = k
    pad = np.roll(pad, (-r, -r), axis=(0, 1))
    spec = np.fft.rfft2(pad)
    assert np.abs(spec.imag).max() < 1e-9        # an even kernel: a real spectrum
    mult = sensor.ccs_multiplier(spec.real)
    assert mult.shape == shape and mult.dtype == np.float32
    img = rng.random(shape).astype(np.float32)
    F = cv2.dft(img)
    want = cv2.mulSpectrums(F, cv2.dft(pad.astype(np.float32)), 0)
    np.testing.assert_allclose(F * mult, want, rtol=0, atol=1e-5 * np.abs(want).max())
    blurred = cv2.dft(F * mult, flags=cv2.DFT_INVERSE | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
    circ = np.fft.irfft2(np.fft.rfft2(img.astype(np.float64)) * spec, s=shape)
    np.testing.assert_allclose(blurred, circ, rtol=0, atol=1e-6 * circ.max())
    with pytest.raises(ValueError):
        sensor.ccs_multiplier(spec.real[:-1])     # an odd height


def test_blurred_sum_refuses_a_kernel_that_is_not_symmetric():
    """A kernel with an odd part has no real spectrum: refused, not blurred wrongly."""
    k = sensor.airy_kernel(1.2)
    k[0, 0] += 0.1
    with pytest.raises(ValueError, match="symmetric"):
        sensor.BlurredSum([k], [1.0])(np.ones((1, 8, 9), np.float32), [0])


def test_packed_products_are_numpys_with_the_laid_out_spectrum():
    """The blurs' products of packed transforms with a real spectrum kept at half the size
    (``ccs_multiply``; and ``ccs_multiply_add``, one band or two a pass) against NumPy's
    element-wise product with :func:`sim.sensor.ccs_multiplier` of it; two bands in one pass
    the same to the bit as one after the other."""
    rng = np.random.default_rng(2)
    H, W = 10, 14
    a, b, acc = (rng.standard_normal((H, W)).astype(np.float32) for _ in range(3))
    ka, kb = (rng.standard_normal((H, W // 2 + 1)).astype(np.float32) for _ in range(2))
    A, B = sensor.ccs_multiplier(ka), sensor.ccs_multiplier(kb)
    out = np.empty_like(a)
    sensor.ccs_multiply(out, a, ka)
    np.testing.assert_array_equal(out, a * A)
    in_place = a.copy()
    sensor.ccs_multiply(in_place, in_place, ka)
    np.testing.assert_array_equal(in_place, a * A)
    one = acc.copy()
    sensor.ccs_multiply_add(one, a, ka, a, ka, two=False)
    # Round-off of the terms (the kernel may fuse a product and a sum into one rounding).
    want = acc + a * A
    bound = 2 * np.finfo(np.float32).eps * (np.abs(acc) + np.abs(a * A))
    assert (np.abs(one - want) <= bound).all()
    sensor.ccs_multiply_add(one, b, kb, b, kb, two=False)
    two = acc.copy()
    sensor.ccs_multiply_add(two, a, ka, b, kb)
    np.testing.assert_array_equal(two, one)
    assert np.abs(acc + a * A + b * B - two).max() <= 4 * np.finfo(np.float32).eps * (
        np.abs(acc) + np.abs(a * A) + np.abs(b * B)).max()


@pytest.mark.mitsuba
@pytest.mark.parametrize("diffraction", [True, False])
def test_electrons_equal_the_whole_sensor_sum(shared_cache, diffraction):
    """Nine views of ``small`` lie 2 px apart, so the blur's margins overlap: the frame, taken
    view by view with every band at once and blurred by FFT, must be the whole-sensor sum of
    every band's image, blurred directly, to the per-band kernel's agreement
    (``tests/sim/transport/test_view_integral.py``), and the same bits every time.  Six bands, the blur
    reaching 1 px in some and 2 px in others, and one band dark."""
    pytest.importorskip("mitsuba")
    from sim.optics.design import get_design
    from sim.frame import FrameModel

    d = get_design("small").replace(views=tuple(range(9)))
    wl = d.wavelengths[[1, 3, 6, 8, 9, 10]]
    model = FrameModel(d, wl, trace_seed=1, diffraction=diffraction)
    rng = np.random.default_rng(3)
    v = 2 * d.view_size_px
    cube = rng.random((v, v, wl.size)).astype(np.float32)
    cube[:, :, 2] = 0.0
    got = model.electrons(cube)
    assert np.array_equal(model.electrons(cube), got)

    tr = model.transport
    rects = [tuple(int(x) for x in r) for r in tr.maps.rects]
    want = np.zeros(tr.sensor, np.float32)
    for l in range(wl.size):
        img = np.zeros(tr.sensor, np.float32)
        for k, (r0, c0, h, w) in enumerate(rects):
            img[r0:r0 + h, c0:c0 + w] = tr.view_band(np.ascontiguousarray(cube[:, :, l]), k, l)
        if diffraction:
            img = sensor.airy_blur(img, kernel=model.kernels[l])
        img *= model.scale[l]
        want += img
    np.maximum(want, 0.0, out=want)
    assert got.max() > 0
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4 * float(want.max()))
    # Dark where no view reaches, blur or not.
    reach = max(k.shape[0] // 2 for k in model.kernels) if diffraction else 0
    lit = np.zeros(tr.sensor, bool)
    for r0, c0, h, w in rects:
        lit[max(r0 - reach, 0):r0 + h + reach, max(c0 - reach, 0):c0 + w + reach] = True
    assert not got[~lit].any()


@pytest.mark.mitsuba
def test_views_overlapped_give_the_frame_of_one_view_after_another(shared_cache, monkeypatch):
    """``FrameModel.electrons`` blurs each view while the next is integrated, keeps its padded
    images for the next frame and lets a second thread's frame take fresh ones: none of it may
    change a bit of the frame against integrating, blurring and adding one view after another
    — on two cores or one, for a frame after a frame of other bands or another scene, and for
    two frames computed at once on one model."""
    pytest.importorskip("mitsuba")
    from concurrent.futures import ThreadPoolExecutor

    import recon.kernels
    import sim.transport.exact
    from sim.optics.design import get_design
    from sim.frame import FrameModel

    d = get_design("small").replace(views=tuple(range(9)))
    wl = d.wavelengths[[1, 3, 6, 8, 9, 10]]
    model = FrameModel(d, wl, trace_seed=1)
    rng = np.random.default_rng(4)
    v = 2 * d.view_size_px
    cube = rng.random((v, v, wl.size)).astype(np.float32)
    cube[:, :, 2] = 0.0
    other = rng.random((v, v, wl.size)).astype(np.float32)
    band = np.zeros_like(cube)
    band[:, :, 4] = cube[:, :, 4]

    def one_after_another(c):
        tr = model.transport
        lit = [l for l in range(wl.size) if c[:, :, l].max() > 0]
        f = np.ascontiguousarray(c[:, :, lit])
        R = model.blur.reach(lit)
        want = np.zeros(tr.sensor, np.float32)
        for k, rect in enumerate(tr.maps.rects):
            r0, c0, h, w = (int(x) for x in rect)
            part = model.blur(tr.view_bands(f, k, lit), lit)
            a0, b0 = max(r0 - R, 0), max(c0 - R, 0)
            a1, b1 = min(r0 + h + R, tr.sensor[0]), min(c0 + w + R, tr.sensor[1])
            want[a0:a1, b0:b1] += part[a0 - (r0 - R):a1 - (r0 - R), b0 - (c0 - R):b1 - (c0 - R)]
        return np.maximum(want, 0.0)

    want = {id(c): one_after_another(c) for c in (cube, other, band)}
    assert want[id(cube)].max() > 0
    for c in (cube, band, cube, other, cube):       # buffers kept, dropped, made anew
        np.testing.assert_array_equal(model.electrons(c), want[id(c)])
    with ThreadPoolExecutor(2) as pool:
        both = list(pool.map(model.electrons, (cube, other)))
    np.testing.assert_array_equal(both[0], want[id(cube)])
    np.testing.assert_array_equal(both[1], want[id(other)])
    for module in (recon.kernels, sim.transport.exact):
        monkeypatch.setattr(module, "cores", lambda: 1)
    np.testing.assert_array_equal(model.electrons(cube), want[id(cube)])


def test_an_error_in_a_block_of_rows_reaches_the_caller(shared_cache, monkeypatch):
    """The threads go on to the next view's rows without waiting for a view's last block, and
    the view's blur waits for it instead: an error in any view's block of rows (the first
    view, a middle one, the last) must still reach the caller of ``FrameModel.electrons``,
    on two cores and on one, not leave a frame without it or a thread waiting for ever."""
    pytest.importorskip("mitsuba")
    import recon.kernels
    import sim.transport.exact
    from sim.optics.design import get_design
    from sim.frame import FrameModel

    d = get_design("small")
    wl = d.wavelengths[[2, 5, 7]]
    model = FrameModel(d, wl, trace_seed=1)
    tr = model.transport
    v = 2 * d.view_size_px
    cube = np.random.default_rng(5).random((v, v, wl.size)).astype(np.float32)
    view_blocks = tr.view_blocks
    n = len(tr.maps.rects)
    for one_core in (False, True):
        if one_core:
            for module in (recon.kernels, sim.transport.exact):
                monkeypatch.setattr(module, "cores", lambda: 1)
        for bad in (0, n // 2, n - 1):
            def failing(f, k, bands=None, out=None, bad=bad):
                out, blocks = view_blocks(f, k, bands, out)
                if k != bad:
                    return out, blocks

                def fail():
                    raise RuntimeError(f"a block of view {k}")
                return out, blocks[:-1] + [fail] + blocks[-1:]

            monkeypatch.setattr(tr, "view_blocks", failing)
            with pytest.raises(RuntimeError, match=f"a block of view {bad}$"):
                model.electrons(cube)
        monkeypatch.setattr(tr, "view_blocks", view_blocks)
        assert model.electrons(cube).max() > 0        # the model still makes frames
