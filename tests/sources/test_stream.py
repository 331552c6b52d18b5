"""Videos read as streams: frames in order, --fps, --realtime pacing and drops, a stalled stream's timeout."""

from __future__ import annotations

import socket
import threading
import time

import numpy as np
import pytest
from conftest import drive, write_video

from seqnet.core.errors import ConfigError, DatasetError
from seqnet.security.videos import is_stream_name
from seqnet.sources.stream import FrameStream


@pytest.fixture
def video(tmp_path):
    return write_video(tmp_path / "v.mp4", drive(20, 1), rate=10, creation_time="2024-05-01T10:00:00Z")


def test_a_file_streams_its_frames_in_order(video):
    s = FrameStream(str(video))
    frames = [(f.name, f.time, np.asarray(f.open())) for f in s]
    assert [n for n, _, _ in frames][:3] == ["0.000000", "0.100000", "0.200000"] and len(frames) == 20
    assert frames[4][2].shape == (16, 32, 3) and s.decoded == 20 and s.dropped == 0 and len(s.decode_ms) == 20
    assert s.start is not None and s.start.year == 2024
    assert [f.name for f in FrameStream(str(video), fps=2.5)] == ["0.000000", "0.400000", "0.800000", "1.200000",
                                                                  "1.600000"]


class FakeClock:
    """A clock that advances by what the consumer spends (``work``) and what the stream sleeps."""

    def __init__(self) -> None:
        self.now, self.slept = 0.0, 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds
        self.slept += seconds


@pytest.mark.parametrize("work, dropped", [(0.05, (0, 0)), (0.25, (10, 13))])
def test_realtime_paces_and_drops(video, work, dropped):
    clock = FakeClock()
    s = FrameStream(str(video), realtime=True, clock=clock, sleep=clock.sleep)
    kept = []
    for f in s:
        kept.append(f.time)
        clock.now += work  # the localiser's time on this frame
    # a frame each 0.1 s; one localised each `work` s: 2 s of video keep about 2 / work frames
    assert dropped[0] <= s.dropped <= dropped[1] and len(kept) + s.dropped == 20
    assert clock.now == pytest.approx(max(1.9 + work, len(kept) * work), abs=0.3)  # about the video's duration
    assert (clock.slept > 0) == (work < 0.1)  # a fast consumer waits for each frame's time


def test_stream_names():
    assert is_stream_name("rtsp://cam.local/stream") and is_stream_name("/dev/video0")
    assert not is_stream_name("drive.mp4") and not is_stream_name("/dev/sda")
    with pytest.raises(ConfigError, match="not a stream seqnet opens"):
        FrameStream("file:///etc/passwd")


def test_a_stalled_stream_times_out():
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    port = server.getsockname()[1]
    held = []
    threading.Thread(target=lambda: held.append(server.accept()), daemon=True).start()  # accepts, never sends
    t0 = time.monotonic()
    with pytest.raises(DatasetError, match="stream"):
        list(FrameStream(f"tcp://127.0.0.1:{port}", timeout=0.5))
    assert time.monotonic() - t0 < 5
    server.close()
