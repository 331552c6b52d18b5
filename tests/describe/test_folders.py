"""A folder given as images that holds none of its own: the hint names where its images are."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from seqnet.core.errors import ImageError
from seqnet.describe.images import list_images


def _save(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.zeros((4, 6, 3), np.uint8)).save(path)


def test_images_only_in_sub_folders_get_a_command_that_lists_them_in_order(tmp_path):
    """A camera's split recording (seg1/ ... seg10/): the hint lists them in natural order and gives a command."""
    for k in range(1, 11):
        _save(tmp_path / "rec" / f"seg{k}" / f"f{k}.png")
    with pytest.raises(ImageError, match=r"its images are in 10 sub-folders \(seg1/, seg2/, seg3/, \.\.\.\); pass "
                                         r"one, or list them all in order in a text file: find .*/rec -name "
                                         r"'\*\.png' \| sort -V > images\.txt\)$"):
        list_images(tmp_path / "rec")


def test_kitti_image_folder_names_its_data_sub_folder(tmp_path):
    """KITTI's image_02 (timestamps.txt and data/) instead of image_02/data: the one sub-folder is named."""
    _save(tmp_path / "image_02" / "data" / "0000000000.png")
    (tmp_path / "image_02" / "timestamps.txt").write_text("2011-09-26 13:02:25.594360375\n")
    with pytest.raises(ImageError, match=r"hint: its images are in the sub-folder data/: pass .*image_02/data\)$"):
        list_images(tmp_path / "image_02")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ImageError, match=r"hint: pass a folder of images or a text file listing them\)$"):
        list_images(tmp_path / "empty")
