"""A resize that changes the images' aspect ratio is said, once, with the way to keep it."""

from __future__ import annotations

import logging

import numpy as np

from seqnet.describe.images import prepare_image, warn_stretch


def test_a_stretching_resize_is_said_once(caplog):
    caplog.set_level(logging.WARNING, logger="seqnet")
    warn_stretch.cache_clear()
    square = np.zeros((80, 80, 3), np.uint8)
    for _ in range(3):
        assert prepare_image(square, (640, 320)).shape == (320, 640, 3)
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and "80x80 images to 640x320" in said[0] and "--resize keep-aspect:640" in said[0]
    caplog.clear()
    prepare_image(np.zeros((32, 64, 3), np.uint8), (640, 320))  # the same ratio
    prepare_image(np.zeros((100, 100, 3), np.uint8), (105, 100))  # within 10 %
    prepare_image(np.zeros((100, 100, 3), np.uint8), 50)  # keep-aspect
    assert caplog.records == []
