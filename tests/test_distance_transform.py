"""The exact distance transform gives the same bits wherever its buffers sit (issue 18's nondeterminism)."""

import numpy as np
from scipy import ndimage

from mocap.distance_transform import exact_distance_transform


def _mask_at_offset(mask: np.ndarray, offset: int) -> np.ndarray:
    """The same mask, copied into a buffer that starts ``offset`` bytes further on."""
    buf = np.zeros(mask.size + offset, np.uint8)
    out = buf[offset:].reshape(mask.shape)
    out[:] = mask
    return out


def test_the_same_mask_at_any_memory_alignment_gives_the_same_bits_and_the_exact_distances():
    rng = np.random.default_rng(0)
    mask = (rng.random((72, 72)) > 0.02).astype(np.uint8)  # a few target pixels, long distances
    reference = exact_distance_transform(mask)
    for offset in range(64):
        np.testing.assert_array_equal(exact_distance_transform(_mask_at_offset(mask, offset)), reference)
    # the exact Euclidean distance between pixel centres (scipy's transform, float64)
    np.testing.assert_allclose(reference, ndimage.distance_transform_edt(mask), rtol=0, atol=1e-5)


def test_an_image_without_a_target_pixel_is_far_everywhere():
    far = exact_distance_transform(np.ones((5, 7), np.uint8))
    assert far.shape == (5, 7) and far.dtype == np.float32
    assert np.all(far > 1e18)
