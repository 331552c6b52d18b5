"""Video files read with PyAV: frame times, names, random and sequential access; bad videos refused in one line."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import drive, mutated, read_mutated, write_video
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seqnet.core.errors import ConfigError, DatasetError, ImageError
from seqnet.describe.images import list_images, load_images
from seqnet.security.videos import check_streams, container_of, open_video_file
from seqnet.sources.video import VideoFile, choose_stream, video_images

TIMES = [0.0, 0.1, 0.25, 0.3, 0.7, 0.75, 1.2, 1.3, 1.35, 2.0]  # a variable frame rate


@pytest.fixture
def video(tmp_path):
    return write_video(tmp_path / "drive.mp4", drive(10, 1), times=TIMES, creation_time="2024-05-01T10:00:00Z")


def test_frames_times_and_names(video):
    v = VideoFile(video)
    np.testing.assert_allclose(v.times, TIMES, atol=1e-9)
    assert v.start.isoformat() == "2024-05-01T10:00:00+00:00" and len(v) == 10
    frames, names = video_images(video)
    assert names[:3] == ["0.000000", "0.100000", "0.250000"] and str(frames[2]).endswith("drive.mp4@0.250000")
    images = list_images(video, fps=2.0)  # the first frame of each half second
    assert images.names == ["0.000000", "0.700000", "1.200000", "2.000000"]


def test_decoded_frames_are_the_frames_written_in_any_order(video):
    frames, _ = video_images(video)
    written = np.stack(drive(10, 1)).astype(int)
    in_order = load_images(frames)[0].astype(int)
    assert np.abs(in_order - written).max() <= 3  # x264 lossless; RGB <-> YUV rounding only
    shuffled = [9, 2, 5, 0, 0, 7]
    np.testing.assert_array_equal(load_images([frames[i] for i in shuffled])[0], in_order[shuffled])


def test_no_creation_time(tmp_path):
    assert VideoFile(write_video(tmp_path / "a.mkv", drive(3, 1))).start is None


def _bad_videos(tmp_path, video):
    data = video.read_bytes()
    yield tmp_path / "empty.mp4", b"", "has 0 bytes"
    yield tmp_path / "text.mp4", b"hello, not a video\n" * 40, "not a video of a container seqnet reads"
    yield tmp_path / "cut.mp4", data[: len(data) // 3], "cannot read the video"
    yield tmp_path / "header.mp4", data[:40], "cannot read the video"


def test_bad_videos_are_one_error(tmp_path, video):
    for path, data, match in _bad_videos(tmp_path, video):
        path.write_bytes(data)
        with pytest.raises(DatasetError, match=match):
            VideoFile(path)
    fifo = tmp_path / "pipe.mp4"
    os.mkfifo(fifo)
    with pytest.raises(DatasetError, match="FIFO"):
        VideoFile(fifo)
    with pytest.raises(DatasetError, match="not found"):
        VideoFile(tmp_path / "missing.mp4")


def test_frame_size_is_bounded_before_decoding(video):
    container, f = open_video_file(video)
    with pytest.raises(DatasetError, match="more than the limit of 100"):
        check_streams(container, video, max_pixels=100)
    f.close()


def test_containers_are_recognised_by_their_bytes():
    assert container_of(b"\x00\x00\x00\x20ftypisom") == "mov"
    assert container_of(b"\x1a\x45\xdf\xa3....") == "matroska"
    assert container_of(b"#EXTM3U\nhttp://example.com/a.ts") is None  # a playlist: FFmpeg would fetch it
    assert container_of(b"ffconcat version 1.0\nfile /etc/passwd") is None


def _good() -> bytes:
    with tempfile.TemporaryDirectory() as d:
        return write_video(Path(d) / "v.mp4", drive(4, 1), codec="mpeg4").read_bytes()


GOOD = _good()


def _read_all(path: Path) -> np.ndarray:
    frames, _ = video_images(path)
    return load_images(frames)[0]


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_fuzzed_videos_read_or_refuse(tmp_path, data):
    bad = data.draw(mutated(GOOD))
    try:
        images = read_mutated(_read_all, tmp_path / "bad.mp4", bad)
    except ImageError:  # a frame listed but damaged: refused by name
        return
    if images is not None:
        assert images.dtype == np.uint8 and images.ndim == 4


@pytest.mark.parametrize("rotation", [-90, 90, 180])
def test_frames_come_upright_by_the_display_rotation(tmp_path, rotation):
    from seqnet.sources.stream import FrameStream

    upright = [np.asarray(f) for f in drive(3, 1)]  # what a player shows
    stored = [np.rot90(f, k=-rotation // 90) for f in upright]  # a phone's pixels: turned back by the rotation
    path = write_video(tmp_path / f"r{rotation}.mp4", stored, rotation=rotation)
    frames, _ = video_images(path)
    for got in (load_images(frames)[0], load_images(list(FrameStream(str(path))))[0]):
        assert got.shape[1:3] == upright[0].shape[:2]
        assert np.abs(got.astype(int) - np.stack(upright).astype(int)).max() <= 3


def _dual(path, front, rear):
    """A file of two video streams (a dual dashcam): ``rear`` stored first, ``front`` second (10 fps, lossless)."""
    import av

    with av.open(str(path), "w") as c:
        streams = []
        for frames in (rear, front):
            s = c.add_stream("libx264", rate=10, options={"crf": "0"})
            s.width, s.height, s.pix_fmt = frames[0].shape[1], frames[0].shape[0], "yuv444p"
            streams.append(s)
        for i in range(len(front)):
            for s, frames in zip(streams, (rear, front), strict=True):
                for p in s.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frames[i]), format="rgb24")):
                    c.mux(p)
        for s in streams:
            for p in s.encode():
                c.mux(p)
    return path


def test_a_file_of_two_video_streams_is_said_and_either_can_be_read(tmp_path, caplog):
    front = drive(4, 1)
    rear = [f[:, ::-1] for f in front]
    path = _dual(tmp_path / "dual.mp4", front, rear)
    first = load_images(video_images(path)[0])[0].astype(int)
    assert "dual.mp4 has 2 video streams (0: 32x16, 1: 32x16); using 0 (hint: --stream N" in caplog.text
    assert np.abs(first - np.stack(rear)).max() <= 3
    caplog.clear()
    v = VideoFile(path, stream=1, flag="--query-stream")
    assert v.stream_number == 1 and not caplog.text  # chosen: nothing to say
    second = load_images(video_images(path, stream=1)[0])[0].astype(int)
    assert np.abs(second - np.stack(front)).max() <= 3
    with pytest.raises(ConfigError, match=r"--query-stream 2: video stream 2 of .*dual.mp4 does not exist; it holds "
                                          r"2 video streams \(0: 32x16, 1: 32x16\)"):
        VideoFile(path, stream=2, flag="--query-stream")


def test_every_stream_that_may_be_read_is_bounded_before_decoding(tmp_path):
    """Each video stream but a cover picture has its frame size checked on opening (only the first was: a larger
    second stream, readable with --stream 1, passed to the per-frame check); a large cover picture is no video."""
    from types import SimpleNamespace

    front = drive(4, 1)
    big = [np.repeat(np.repeat(f, 2, axis=0), 2, axis=1) for f in front]  # 64x32 beside 32x16
    container, f = open_video_file(_dual(tmp_path / "dual.mp4", big, front))
    with pytest.raises(DatasetError, match="declares frames of 64x32 pixels, more than the limit of 600"):
        check_streams(container, "dual.mp4", max_pixels=600)
    f.close()

    def stream(w, h, disposition):
        return SimpleNamespace(codec_context=SimpleNamespace(width=w, height=h, name="h264"), disposition=disposition)

    cover, video = stream(600, 600, 0x400), stream(64, 32, 0)
    container = SimpleNamespace(streams=SimpleNamespace(video=[cover, video]), close=lambda: None)
    assert check_streams(container, "song.mp4", max_pixels=5000) is video  # the cover is never decoded
    container = SimpleNamespace(streams=SimpleNamespace(video=[cover]), close=lambda: None)
    with pytest.raises(DatasetError, match="600x600"):  # a cover alone is what would be read
        check_streams(container, "song.mp4", max_pixels=5000)


def test_one_video_stream_is_silent(video, caplog):
    assert VideoFile(video).stream_number == 0 and not caplog.text


def test_a_cover_picture_is_not_taken_for_the_video(caplog):
    from types import SimpleNamespace

    def stream(w, h, disposition):
        return SimpleNamespace(codec_context=SimpleNamespace(width=w, height=h), disposition=disposition)

    cover, video = stream(600, 600, 0x400 | 1), stream(64, 32, 0)
    container = SimpleNamespace(streams=SimpleNamespace(video=[cover, video]))
    assert choose_stream(container, "song.mp4") == (video, 1) and not caplog.text  # one video: nothing to say
    with pytest.raises(ConfigError, match="stream 0 of song.mp4 is a cover picture"):
        choose_stream(container, "song.mp4", 0)


def test_a_pyav_without_frame_rotation_is_said_not_silent(caplog):
    """An older PyAV without VideoFrame.rotation reads phone videos sideways: said once, not silently."""
    import logging

    import numpy as np
    from PIL import Image

    from seqnet.sources.video import frame_image

    class OldFrame:
        def to_image(self):
            return Image.fromarray(np.zeros((4, 8, 3), np.uint8))

    with caplog.at_level(logging.WARNING, logger="seqnet"):
        assert frame_image(OldFrame()).size == (8, 4)
    assert "does not give a frame's display rotation" in caplog.text
