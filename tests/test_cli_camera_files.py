"""``mocap.cli.common``: per-camera files matched to the calibration's cameras by name."""

from __future__ import annotations

from pathlib import Path

import pytest

from mocap.cli.common import order_by_camera_name, order_videos_by_camera
from mocap.errors import InputFileError


def test_files_are_matched_to_cameras_by_a_word_of_their_name() -> None:
    files = [Path("s/scribbles_right.png"), Path("s/scribbles_left.png")]
    assert order_by_camera_name(files, ["left", "right"]) == files[::-1]
    # cam1 is not a word of cam10's name
    cams = [Path("e/empty-cam10.mp4"), Path("e/empty-cam1.mp4")]
    assert order_by_camera_name(cams, ["cam1", "cam10"]) == cams[::-1]


@pytest.mark.parametrize("names", [
    ["a.png", "b.png"],                    # no camera named: as given
    ["left_right.png", "other.png"],       # both names in one file
    ["left.png", "left_2.png"],            # one camera in two files, the other in none
])
def test_files_not_matched_one_to_one_stay_in_the_given_order(names) -> None:
    files = [Path(n) for n in names]
    assert order_by_camera_name(files, ["left", "right"]) == files


def test_a_second_file_after_a_per_camera_option_gets_the_fix_in_the_error() -> None:
    with pytest.raises(InputFileError, match=r"scribbles_right.png is none of them.*once per file"):
        order_videos_by_camera([Path("left.mp4"), Path("right.mp4"), Path("scribbles_right.png")], ["left", "right"],
                               ("--scribbles", "--empty"))
    with pytest.raises(InputFileError, match=r"3 videos for 2 calibrated cameras") as err:
        order_videos_by_camera([Path("a.mp4"), Path("b.mp4"), Path("c.mp4")], ["left", "right"])
    assert "once per file" not in str(err.value)  # a command without such options says nothing of them
