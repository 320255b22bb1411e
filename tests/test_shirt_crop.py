"""The shirt pipeline's crops (mocap.shirt.classify.crop_view / crop_image): geometry, values, the halved stand-in."""

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.shirt.background import BackgroundModel, BackgroundParams
from mocap.shirt.classify import crop_image, crop_view, halve_image


def _blob(h: int, w: int, x: float, y: float, sigma: float = 6.0) -> np.ndarray:
    """A (h, w, 3) uint8 frame: a grey ramp with a bright Gaussian spot centred at pixel (x, y)."""
    yy, xx = np.mgrid[0:h, 0:w].astype(float)
    spot = 200.0 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * sigma ** 2))
    base = 20.0 + 20.0 * xx / w
    return np.repeat(np.clip(base + spot, 0, 255).round().astype(np.uint8)[..., None], 3, axis=2)


@given(x=st.floats(120, 520), y=st.floats(100, 380), side=st.floats(150, 620))
@settings(max_examples=60, deadline=None, derandomize=True)
def test_a_crop_view_is_centred_and_sized_for_exact_halvings(x, y, side):
    view = crop_view(x, y, side, 144)
    full = view.scale * view.size
    k = 0
    while full >= (2 << k) * view.size:
        k += 1
    m = 2 ** k
    assert abs(full - round(full)) < 1e-9 and round(full) % m == 0  # each halving is an exact 2 x 2 average
    assert abs(full - side) <= m / 2 + 0.5 + 1e-9  # rounded to a pixel, then to a multiple of m
    # the crop's middle pixel centre: the origin's rounding (to an even pixel when halved) and
    # crop_view's convention (the side's middle at x, pixel centres at integers) give 1 or 1.5 px
    centre = view.to_image(np.array([(view.size - 1) / 2.0] * 2))
    assert np.all(np.abs(centre - [x, y]) <= (1.5 if m > 1 else 1.0) + 1e-9)
    if m > 1:  # an even origin, so a halved image can stand in
        origin = view.to_image(np.zeros(2)) - 0.5 * view.scale + 0.5
        assert np.allclose(origin, np.round(origin)) and np.all(np.round(origin) % 2 == 0)


@given(x=st.floats(200, 440), y=st.floats(160, 320), side=st.floats(150, 600))
@settings(max_examples=40, deadline=None, derandomize=True)
def test_the_crop_keeps_a_spot_where_the_view_says_it_is(x, y, side):
    """Geometry: the spot's centroid in working pixels maps back to its image position."""
    img = _blob(480, 640, x, y)
    view = crop_view(x + 7.0, y - 5.0, side, 144)
    crop = crop_image(img, view)[..., 0].astype(float)
    w = np.clip(crop - np.percentile(crop, 50) - 40.0, 0, None)  # the spot, not the ramp (20 levels)
    yy, xx = np.mgrid[0:view.size, 0:view.size]
    c = np.array([(w * xx).sum(), (w * yy).sum()]) / w.sum()
    assert np.all(np.abs(view.to_image(c) - [x, y]) < 0.35 * view.scale)


def test_the_crop_is_close_to_opencvs_direct_area_resampling():
    """Values: the halvings and the last bilinear step stay within a few levels of one area resampling."""
    rng = np.random.default_rng(3)
    img = cv2.GaussianBlur(rng.integers(0, 256, (480, 640, 3), np.uint8), (0, 0), 4.0)
    for side in (170.0, 300.0, 410.0, 599.0):
        view = crop_view(320.0, 240.0, side, 144)
        full = int(round(view.scale * view.size))
        x0 = int(round(view.x0 - 0.5 * view.scale + 0.5))
        y0 = int(round(view.y0 - 0.5 * view.scale + 0.5))
        padded = np.pad(img, ((400, 400), (400, 400), (0, 0)))  # zero outside the image, as crop_image
        direct = cv2.resize(padded[400 + y0:400 + y0 + full, 400 + x0:400 + x0 + full], (144, 144), interpolation=cv2.INTER_AREA)
        diff = np.abs(crop_image(img, view).astype(int) - direct)
        assert diff.max() <= 4 and diff.mean() < 0.5, (side, diff.max(), diff.mean())


@given(x=st.floats(-100, 740), y=st.floats(-100, 580), side=st.floats(100, 700), f32=st.booleans())
@settings(max_examples=80, deadline=None, derandomize=True)
def test_a_halved_image_stands_in_for_the_first_halving_bit_for_bit(x, y, side, f32):
    rng = np.random.default_rng(int(x * 7 + y * 13 + side) % 1000)
    img = rng.integers(0, 256, (480, 640, 3), np.uint8)
    if f32:
        img = img.astype(np.float32) * np.float32(0.9)
    view = crop_view(x, y, side, 144)
    assert np.array_equal(crop_image(img, view, half=halve_image(img)), crop_image(img, view))


def test_the_background_reduction_is_the_area_average_to_a_level():
    """BackgroundModel reduces by 4 in two exact halvings: within one 8-bit level of one 4 x 4 average."""
    rng = np.random.default_rng(5)
    bg = BackgroundModel(BackgroundParams(reduce=4))
    for shape in ((480, 640, 3), (482, 646, 3)):
        bg._size = None
        img = rng.integers(0, 256, shape, np.uint8)
        small = bg._small(img)
        direct = cv2.resize(img, (shape[1] // 4, shape[0] // 4), interpolation=cv2.INTER_AREA)
        assert small.shape == direct.shape
        if shape[1] % 4 == 0 and shape[0] % 4 == 0:
            assert np.abs(small.astype(int) - direct).max() <= 1
