"""The order of a folder's images (seqnet.data.order): natural sort, decimal-number names by value."""

from __future__ import annotations

import random
import re

import pytest

from seqnet.data.order import decimal_values, name_order, natural_key


def old_natural_key(text: str) -> list:
    """The natural sort key before decimal names were ordered by value (the reference for ordinary names)."""
    return [int(t) if t.isdecimal() else t.lower() for t in re.split(r"(\d+)", text)]


ORDINARY = [
    [f"images-{i:05d}.png" for i in range(0, 200, 10)],
    [f"frame_{i}.png" for i in range(1, 12)],
    [f"img-{i}.jpg" for i in (2, 10, 1, 33)],
    ["2024-05-01_10.30.15.png", "2024-05-01_10.30.5.png", "2024-05-01_9.59.59.png", "2024-05-02_00.00.00.png"],
    ["2024.05.01.png", "2024.5.2.png", "2024.10.1.png"],
    ["v1.9.png", "v1.10.png", "v1.2.png", "v1.11.png", "v2.0.png"],  # versions: 1.10 after 1.9
    ["img_1.2.3.png", "img_1.10.3.png", "img_1.2.10.png"],
    ["1.05.png", "1.10.png", "0.95.png", "2.00.png"],  # one fraction length: value and natural order agree
    ["a.png", "B.png", "c10.png", "c9.png"],
    ["cam0_5.png", "cam1_5.png", "cam0_10.png"],
    ["only.png"],
]


@pytest.mark.parametrize("names", ORDINARY)
def test_ordinary_names_keep_the_natural_order(names):
    shuffled = random.Random(0).sample(names, len(names))
    assert [shuffled[i] for i in name_order(shuffled)] == sorted(shuffled, key=old_natural_key)
    assert natural_key("a10") == old_natural_key("a10")


@pytest.mark.parametrize("fmt", ["{:g}.png", "t{:g}s.jpg", "frame_{:g}.png", "{}.png"])
def test_names_that_are_decimal_numbers_sort_by_value(fmt):
    """Frames named by their time (0.25.png, 1.5.png, 2.png: '%g' or str(float)) keep time order; the natural
    sort read 1.25 and 1.5 as 1, 25 and 1, 5 and put 1.png after 1.75.png."""
    times = [k * 0.25 for k in range(40)]
    names = [fmt.format(t) for t in times]
    shuffled = random.Random(1).sample(names, len(names))
    assert [shuffled[i] for i in name_order(shuffled)] == names
    assert decimal_values(names) is not None
    assert sorted(names, key=old_natural_key) != names  # the old order was scrambled


def test_text_sorted_pair_finds_a_list_in_text_order_only():
    """An ``ls`` / ``sorted()`` of unpadded frame numbers is found with an example pair; a list in natural order,
    one whose numbers change nothing, one in any other order or differing only in case is not."""
    from seqnet.data.order import text_order_line, text_sorted_pair

    frames = [f"img_{i}.png" for i in range(200)]
    assert text_sorted_pair(sorted(frames)) == ("img_10.png", "img_2.png")
    assert text_sorted_pair(sorted(frames, key=str.lower)) == ("img_10.png", "img_2.png")
    assert text_sorted_pair(sorted(["0.25.png", "1.5.png", "1.png", "10.png"])) == ("1.5.png", "1.png")
    for silent in (frames, frames[::-1], sorted(f"f{i:05d}.png" for i in range(30)), ["b.png", "a.png"],
                   ["B.png", "a.png"], ["a.png", "b.png"], ["img_10.png"], [frames[k] for k in (3, 1, 2, 10)]):
        assert text_sorted_pair(silent) is None, silent
    line = text_order_line(sorted(frames), "image list ref.txt")
    assert line is not None and line.startswith("image list ref.txt is in text order, not by the numbers in its names: "
                                                "'img_10.png' comes before 'img_2.png' (a plain ls or sorted()?)")
    assert "hint: list the images by number: ls -v (or sort -V)" in line
