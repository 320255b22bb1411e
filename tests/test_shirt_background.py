"""Step 0 of the shirt pipeline: the coarse MOG2 mask and the empty-scene match that trims its ring of the set."""

from __future__ import annotations

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.shirt.background import BackgroundModel, BackgroundParams
from mocap.shirt.classify import crop_image, crop_reduced_mask, crop_view


def _empty(rng: np.random.Generator) -> np.ndarray:
    img = np.clip(rng.normal(120, 2, (240, 320, 3)), 0, 255).astype(np.uint8)  # a grey wall with sensor noise
    img[100:180, 170:230] = [40, 140, 60]  # a green box
    img[100:180, 195:203] = [220, 200, 40]  # its yellow ribbon (the shirt's yellow)
    return img


def _with_subject(rng: np.random.Generator) -> np.ndarray:
    img = _empty(rng)
    img[60:200, 110:171] = [200, 40, 40]  # the subject, right next to the box
    return img


def test_empty_match_trims_the_set_from_the_coarse_mask_and_keeps_the_subject():
    rng = np.random.default_rng(3)
    bg = BackgroundModel(BackgroundParams())
    bg.learn_empty([_empty(rng) for _ in range(3)])
    frame = _with_subject(rng)
    mask = BackgroundModel.full_size(bg.apply(frame), frame.shape[1], frame.shape[0])
    subject = np.zeros(frame.shape[:2], bool)
    subject[60:200, 110:171] = True
    ring = mask & ~subject
    assert ring[100:180, 171:180].mean() > 0.5  # the coarse mask takes in the box next to the subject
    view = crop_view(150.0, 130.0, 160.0, 80)
    same = bg.empty_match(crop_image(frame, view), crop_image(bg.empty, view))
    crop_ring = crop_image(ring.astype(np.uint8), view) > 0
    crop_subject = crop_image(subject.astype(np.uint8), view) > 0
    inner = crop_subject & ~(crop_image((~subject).astype(np.uint8), view) > 0)  # working pixels wholly on the subject
    assert same[crop_ring & ~crop_subject].mean() > 0.9
    assert not same[inner].any()


def test_after_a_change_of_light_nothing_matches_the_empty_scene():
    rng = np.random.default_rng(4)
    bg = BackgroundModel(BackgroundParams())
    bg.learn_empty([_empty(rng) for _ in range(3)])
    dim = (_empty(rng).astype(np.float32) * 0.6).astype(np.uint8)
    view = crop_view(160.0, 120.0, 200.0, 100)
    assert not bg.empty_match(crop_image(dim, view), crop_image(bg.empty, view)).any()
    off = BackgroundModel(BackgroundParams(match_empty=0.0))
    off.learn_empty([_empty(rng)])
    assert not off.empty_match(crop_image(_empty(rng), view), crop_image(off.empty, view)).any()


def _lamp_off(img: np.ndarray) -> np.ndarray:
    """The same set under another light: dimmer to the right, bluer (a tungsten lamp on the left went off)."""
    h, w = img.shape[:2]
    ramp = np.linspace(0.75, 0.45, w, dtype=np.float32)[None, :, None]
    tint = np.array([0.8, 0.95, 1.1], np.float32)
    return np.clip(img.astype(np.float32) * ramp * tint, 0, 255).astype(np.uint8)


def test_after_the_lamp_goes_off_the_empty_scene_is_relit_and_the_set_is_background_again():
    rng = np.random.default_rng(5)
    subject = np.zeros((240, 320), bool)
    subject[60:200, 110:171] = True
    box = (np.array([110.0, 60.0]), np.array([170.0, 130.0]))  # where the previous pose's shirt was
    results = {}
    for relight in (0.3, 0.0):
        bg = BackgroundModel(BackgroundParams(relight_fraction=relight))
        bg.learn_empty([_empty(rng) for _ in range(3)])
        for _ in range(3):
            bg.apply(_with_subject(rng), box)  # lamp on, subject in
        frame = _lamp_off(_with_subject(rng))
        mask = BackgroundModel.full_size(bg.apply(frame, box), frame.shape[1], frame.shape[0])
        view = crop_view(150.0, 130.0, 160.0, 80)
        same = bg.empty_match(crop_image(frame, view), crop_image(bg.empty, view))
        results[relight] = (mask, same, bg.relit, view)
    mask, same, relit, view = results[0.3]
    assert relit
    assert mask[subject].mean() > 0.95  # the subject stays foreground
    set_far = ~subject
    set_far[40:220, 90:191] = False  # away from the dilated mask's ring
    assert mask[set_far].mean() < 0.02  # the wall and the box are background again
    ribbon = crop_image(np.pad(np.ones((80, 8), np.uint8), ((100, 60), (195, 117))), view) > 0
    assert same[ribbon].mean() > 0.9  # the box's yellow ribbon matches the re-lit empty scene
    crop_subject = crop_image(subject.astype(np.uint8), view) > 0
    inner = crop_subject & ~(crop_image((~subject).astype(np.uint8), view) > 0)
    assert not same[inner].any()
    # without re-lighting the whole set is foreground and nothing matches the empty scene
    mask0, same0, relit0, _ = results[0.0]
    assert not relit0
    assert mask0[set_far].mean() > 0.5
    assert not same0[ribbon].any()


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([(640, 480), (1280, 720), (320, 240), (1920, 1080), (643, 479)]),
       st.sampled_from([2, 3, 4, 5]), st.sampled_from([16, 64, 96, 144, 200]))
def test_the_reduced_mask_cropped_directly_equals_cropping_it_at_full_size(seed, size, reduce, work):
    """crop_reduced_mask: OpenCV's two nearest-neighbour resamplings (to full size, then the crop) composed, to the
    pixel, for crops inside, across and outside the image, larger and smaller than the working size."""
    rng = np.random.default_rng(seed)
    W, H = size
    small = rng.random((H // reduce, W // reduce)) < rng.uniform(0.05, 0.8)
    view = crop_view(rng.uniform(-100, W + 100), rng.uniform(-100, H + 100), rng.uniform(5, 2 * max(W, H)), work)
    want = crop_image(BackgroundModel.full_size(small, W, H).view(np.uint8), view, cv2.INTER_NEAREST) > 0
    assert np.array_equal(crop_reduced_mask(small, W, H, view), want)
