"""Shared test fixtures: tiny synthetic data and the location of ../shared/data."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import shutil
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import torch

from seqnet.core.errors import DatasetError

torch.set_num_threads(2)

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("SEQNET_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_data(sub: str) -> Path:
    """Path of ``../shared/data/<sub>``; skips the test with a message when it is absent."""
    path = SHARED_DATA / sub
    if not path.exists():
        pytest.skip(f"shared data not found: {path} (set SEQNET_SHARED_DATA or place ../shared/data beside the repo)")
    return path


def nordland_lists(root: Path, first: int = 10000, n: int = 60) -> tuple[Path, list[str]]:
    """List files ``root/ref.txt`` (summer) and ``root/query.txt`` (winter) of ``n`` Nordland64 frames from ``first``
    (every 10th): the shared data folder and the frames' names (skips when the shared data is absent)."""
    data = shared_data("nordland64")
    names = [f"images-{i:05d}.png" for i in range(first, first + 10 * n, 10)]
    for side, season in (("ref", "summer"), ("query", "winter")):
        (root / f"{side}.txt").write_text("".join(f"{data / season / name}\n" for name in names))
    return data, names


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)


@pytest.fixture(scope="session")
def synth_dataset():
    """A small synthetic dataset (UTM positions, splits, sequence bounds)."""
    from seqnet.data.synth import make_synthetic

    return make_synthetic(places=200, dim=16, seed=1)


@pytest.fixture
def synth_dir(tmp_path, synth_dataset):
    """The small synthetic dataset saved in the directory format."""
    from seqnet.data.io import save_dataset

    return save_dataset(synth_dataset, tmp_path / "ds")


@pytest.fixture
def map_models(synth_dataset, tmp_path):
    """Checkpoint paths of a random S_L (L=4, w=2) and S_1 made for ``synth_dataset``'s descriptors."""
    from seqnet.sequence.checkpoints import save_checkpoint
    from seqnet.sequence.model import SeqNet

    torch.manual_seed(0)
    paths = []
    for name, (seq_len, w) in {"sl": (4, 2), "s1": (1, 1)}.items():
        model = SeqNet(16, 12, seq_len, w)
        model.provenance = synth_dataset.reference.provenance
        paths.append(save_checkpoint(tmp_path / f"{name}.pt", model))
    return paths


def image_folder(d, n: int = 10, seed: int = 0, stem: str = "f"):
    """A folder ``d`` of ``n`` random 32×16 RGB PNG images ``<stem>0.png`` … (made here)."""
    from PIL import Image

    rng = np.random.default_rng(seed)
    d.mkdir()
    for i in range(n):
        Image.fromarray(rng.integers(0, 256, size=(16, 32, 3), dtype=np.uint8)).save(d / f"{stem}{i}.png")
    return d


@pytest.fixture
def folder(tmp_path):
    """A folder of ten random 32×16 RGB PNG images ``f0.png`` … ``f9.png``."""
    return image_folder(tmp_path / "imgs")


def pytest_collection_modifyitems(config, items):
    """Tests marked ``cuda`` are skipped, with the reason, where torch sees no CUDA device."""
    if torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs a CUDA device (none here); benchmarks/gpu_check.sh runs these on a GPU")
    for item in items:
        if "cuda" in item.keywords:
            item.add_marker(skip)


def drive(n: int, seed: int, noise: int = 0) -> list[np.ndarray]:
    """``n`` places, each a random 32x16 image; ``noise`` perturbs them (another traverse of the same places)."""
    rng = np.random.default_rng(0)
    places = [rng.integers(0, 256, size=(16, 32, 3)) for _ in range(n)]
    other = np.random.default_rng(seed)
    return [np.clip(p + other.integers(-noise, noise + 1, size=p.shape), 0, 255).astype(np.uint8) for p in places]


BAG_KINDS = ("ros1", "ros2", "mcap")  # a ROS 1 .bag, a ROS 2 sqlite3 bag directory, a ROS 2 MCAP bag directory


def write_bag(path, images, kind: str = "ros1", topic: str = "/camera/image_raw", encoding: str = "rgb8",
              fixes=None, fix_topic: str = "/gps/fix", odometry=None, start: int = 10**18, period: int = 10**8,
              position_offset: int = 0, poses=None, pose_frame: str = "odom"):
    """A tiny bag written with rosbags' own writers (serialised with its ROS1_NOETIC / ROS2_HUMBLE typestores).

    ``images``: uint8 ``[H, W, 3]`` arrays (``[H, W]`` for mono8), one message each at ``start + i * period`` ns on
    ``topic`` as sensor_msgs/Image in ``encoding`` (bgr8: channels reversed), or as CompressedImage when
    ``encoding`` is ``"png"`` / ``"jpeg"``. ``fixes``: ``(lat, lon, status)`` per NavSatFix message on
    ``fix_topic``; ``odometry``: ``(x, y)`` per nav_msgs/Odometry message on ``/odom``; ``poses``: ``(x, y)`` per
    geometry_msgs/PoseStamped message (frame ``pose_frame``) on ``/pose`` — all at ``start + position_offset + j *
    period``. Skips the test when rosbags is not installed."""
    import io

    pytest.importorskip("rosbags", reason="rosbags is not installed (pip install 'seqnet[ros]')")
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.ROS2_HUMBLE)
    T = ts.types
    ser = ts.serialize_ros1 if kind == "ros1" else ts.serialize_cdr

    def header(i: int, frame: str):
        stamp = T["builtin_interfaces/msg/Time"](sec=i, nanosec=0)
        extra = {"seq": i} if kind == "ros1" else {}
        return T["std_msgs/msg/Header"](**extra, stamp=stamp, frame_id=frame)

    def image_msg(i: int, img: np.ndarray):
        if encoding in ("png", "jpeg"):
            from PIL import Image

            buf = io.BytesIO()
            Image.fromarray(img).save(buf, format=encoding.upper())
            return T["sensor_msgs/msg/CompressedImage"](header=header(i, "cam"), format=encoding,
                                                        data=np.frombuffer(buf.getvalue(), np.uint8))
        px = img[..., ::-1] if encoding == "bgr8" else img
        px = np.ascontiguousarray(px)
        step = px.shape[1] * (px.shape[2] if px.ndim == 3 else 1) * px.itemsize
        return T["sensor_msgs/msg/Image"](header=header(i, "cam"), height=px.shape[0], width=px.shape[1],
                                          encoding=encoding, is_bigendian=0, step=step,
                                          data=px.reshape(-1).view(np.uint8))

    def fix_msg(j: int, lat: float, lon: float, status: int):
        st = T["sensor_msgs/msg/NavSatStatus"](status=status, service=1)
        return T["sensor_msgs/msg/NavSatFix"](header=header(j, "gps"), status=st, latitude=lat, longitude=lon,
                                              altitude=0.0, position_covariance=np.zeros(9),
                                              position_covariance_type=0)

    g = "geometry_msgs/msg/"

    def pose_of(x: float, y: float):
        return T[g + "Pose"](position=T[g + "Point"](x=x, y=y, z=0.0),
                             orientation=T[g + "Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))

    def odom_msg(j: int, x: float, y: float):
        pose = pose_of(x, y)
        twist = T[g + "Twist"](linear=T[g + "Vector3"](x=0.0, y=0.0, z=0.0),
                               angular=T[g + "Vector3"](x=0.0, y=0.0, z=0.0))
        return T["nav_msgs/msg/Odometry"](header=header(j, "odom"), child_frame_id="base",
                                          pose=T[g + "PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                                          twist=T[g + "TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))

    streams = [(topic, [(start + i * period, image_msg(i, im)) for i, im in enumerate(images)])]
    if fixes is not None:
        streams.append((fix_topic, [(start + position_offset + j * period, fix_msg(j, *f)) for j, f in
                                    enumerate(fixes)]))
    if odometry is not None:
        streams.append(("/odom", [(start + position_offset + j * period, odom_msg(j, *o)) for j, o in
                                  enumerate(odometry)]))
    if poses is not None:
        streams.append(("/pose", [(start + position_offset + j * period,
                                   T[g + "PoseStamped"](header=header(j, pose_frame), pose=pose_of(*xy)))
                                  for j, xy in enumerate(poses)]))
    writer = (Writer1(path) if kind == "ros1" else
              Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3))
    with writer as w:
        for name, msgs in streams:
            conn = w.add_connection(name, msgs[0][1].__msgtype__, typestore=ts)
            for stamp, msg in msgs:
                w.write(conn, stamp, ser(msg, msg.__msgtype__))
    return path


def bag_path(tmp_path, kind: str, name: str = "run"):
    """Where :func:`write_bag` writes a bag of ``kind``: ``run.bag`` (ROS 1) or the directory ``run`` (ROS 2)."""
    return tmp_path / (f"{name}.bag" if kind == "ros1" else name)


def read_mutated(read, path: Path, data: bytes, refused: type[Exception] = DatasetError):
    """``read(path)`` after writing the fuzzed ``data`` there: its value, or None when ``read`` refused the bytes
    with ``refused``; anything else propagates, failing the fuzz case."""
    path.write_bytes(data)
    try:
        return read(path)
    except refused:
        return None


def mutated(data: bytes, max_flips: int = 8):
    """A hypothesis strategy of ``data`` damaged as a hostile or broken file would be: cut short, a few bytes
    replaced, or a few bytes inserted."""
    from hypothesis import strategies as st

    n = len(data)

    def flip(edits: list[tuple[int, int]]) -> bytes:
        out = bytearray(data)
        for pos, value in edits:
            out[pos] = value
        return bytes(out)

    def insert(at: int, chunk: bytes) -> bytes:
        return data[:at] + chunk + data[at:]

    return st.one_of(
        st.integers(0, max(n - 1, 0)).map(lambda k: data[:k]),
        st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, 255)), min_size=1, max_size=max_flips).map(flip),
        st.builds(insert, st.integers(0, n), st.binary(min_size=1, max_size=24)),
    )


# ---------------------------------------------------------------- crash points (kill -9 at each rename)


def _fresh_locks_after_fork() -> None:
    """In a forked child: new locks for a library seen hanging there on a lock the fork copied held (pyparsing's
    packrat cache, reached from matplotlib's text code: a crash-point child idle in ``ParserElement._parseCache``
    in a full run, killed by :func:`run_killed` after 120 s)."""
    core = sys.modules.get("pyparsing.core")
    if core is not None:
        core.ParserElement.packrat_cache_lock = threading.RLock()
        core.ParserElement.recursion_lock = threading.RLock()


def _crash_at(k: int, when: str, target, *args) -> None:
    """In a forked child: run ``target(*args)``, dying (as ``kill -9``) at its ``k``-th rename, before or after."""
    import torch

    import seqnet.security.dirs as dirs

    torch.set_num_threads(1)  # no OpenMP pool inherited across the fork
    _fresh_locks_after_fork()
    count = [0]

    def wrap(fn):
        def inner(*a, **kw):
            count[0] += 1
            if count[0] == k and when == "before":
                os._exit(9)
            out = fn(*a, **kw)
            if count[0] == k and when == "after":
                os._exit(9)
            return out
        return inner

    os.rename, os.replace = wrap(os.rename), wrap(os.replace)
    dirs.exchange = wrap(dirs.exchange)
    target(*args)
    os._exit(0)


def run_killed(k: int, when: str, target, *args) -> int:
    """The exit code of ``target(*args)`` killed at its ``k``-th rename (0: it made fewer renames)."""
    proc = multiprocessing.get_context("fork").Process(target=_crash_at, args=(k, when, target, *args))
    proc.start()
    proc.join(120)
    if proc.is_alive():  # a child stuck after the fork (a thread pool's lock copied held): kill it as the test would
        proc.kill()
        proc.join(30)
    return proc.exitcode


def each_crash_point(restore, target, *args, check, modes=("before", "after")) -> int:
    """``restore()``, then kill ``target(*args)`` before (with its temporary file written) and after each of its
    renames in turn; ``check()`` after every kill. Returns the number of kills."""
    tried = 0
    for when in modes:
        for k in range(1, 80):
            restore()
            code = run_killed(k, when, target, *args)
            check()
            tried += 1
            if code == 0:
                break
        else:
            pytest.fail("more renames than expected")
    return tried


def restorer(saved, out):
    """A function putting back ``out`` as the copy ``saved`` holds."""
    def restore():
        shutil.rmtree(out, ignore_errors=True)
        shutil.copytree(saved, out, symlinks=True)
    return restore


SERVE_METHOD = "hvpr-delta:raw+seqmatch"  # the method of serve_map (no model: fast)


@pytest.fixture(scope="session")
def serve_map(tmp_path_factory, synth_dataset):
    """An index map (causal windows, L = 4, Delta shortlist, raw+seqmatch re-ranking) of ``synth_dataset``."""
    from seqnet.data.io import save_dataset
    from seqnet.maps import MapConfig, build

    d = tmp_path_factory.mktemp("serve")
    conf = MapConfig(shortlist="delta", rerank="raw+seqmatch", seq_len=4, window="causal")
    return build(conf, save_dataset(synth_dataset, d / "ds"), d / "map")


@pytest.fixture(scope="session")
def serve_service(serve_map):
    """``serve_map`` loaded once as ``seqnet serve`` loads it (:func:`seqnet.serve.service.load_service`)."""
    from seqnet.localize.config import LocalizeConfig
    from seqnet.serve.service import load_service

    return load_service(LocalizeConfig(method=SERVE_METHOD, device="cpu"), serve_map)


@contextlib.contextmanager
def serving(service, **settings):
    """``service`` served by uvicorn on a thread, on a free port of 127.0.0.1 (``--no-auth`` unless a ``token`` is
    given); yields ``(url, api)`` (:class:`seqnet.serve.app.Api`: its sessions and metrics); stopped on exit."""
    import threading
    import time

    from seqnet.serve.server import build_server, listen
    from seqnet.serve.settings import ServeSettings

    settings = ServeSettings(port=0, no_auth=settings.get("token") is None, **settings)
    sock = listen("127.0.0.1", 0)
    server = build_server(service, settings)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 10
    while not server.started and thread.is_alive() and time.monotonic() < deadline:
        time.sleep(0.005)
    assert server.started, "the test server did not start"
    try:
        yield f"http://127.0.0.1:{sock.getsockname()[1]}", server.config.app.state.api
    finally:
        server.should_exit = True
        thread.join(10)
        sock.close()


def write_video(path, frames, times=None, creation_time: str | None = None, codec: str = "libx264",
                rate: int = 10, rotation: int = 0) -> Path:
    """A video of ``frames`` (uint8 [H, W, 3], even sizes) written with PyAV: at ``rate`` frames per second, or at
    ``times`` (seconds, increasing: a variable frame rate); ``creation_time`` (ISO-8601) in its metadata. x264 at
    CRF 0 (lossless) by default, so a frame decodes as it was written but for the colour conversion; ``rotation``:
    the stream's display rotation (degrees counter-clockwise, as a phone writes it)."""
    import fractions

    import av

    path = Path(path)
    with av.open(str(path), "w") as c:
        if creation_time:
            c.metadata["creation_time"] = creation_time
        s = c.add_stream(codec, rate=rate, options={"crf": "0"} if codec == "libx264" else {})
        s.width, s.height = frames[0].shape[1], frames[0].shape[0]
        s.pix_fmt = "yuv444p" if codec == "libx264" else "yuv420p"
        if rotation:
            s.set_display_rotation(rotation)
        s.codec_context.time_base = fractions.Fraction(1, 1000)
        for i, img in enumerate(frames):
            fr = av.VideoFrame.from_ndarray(np.ascontiguousarray(img), format="rgb24")
            fr.pts = int(round(1000 * (i / rate if times is None else times[i])))
            fr.time_base = fractions.Fraction(1, 1000)
            for p in s.encode(fr):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    return path


def route(n: int, spacing: float = 10.0, lat0: float = 66.0, lon0: float = 14.0) -> tuple[np.ndarray, np.ndarray]:
    """``(lat [n], lon [n])`` of ``n`` places ``spacing`` metres apart along a winding road (degrees, WGS84)."""
    heading = 0.5 + 1.8 * np.sin(np.arange(n) / 70.0)
    step = spacing * np.stack([np.sin(heading), np.cos(heading)], axis=1)
    en = np.concatenate([[[0.0, 0.0]], np.cumsum(step, axis=0)[:-1]])
    return lat0 + en[:, 1] / 111320.0, lon0 + en[:, 0] / (111320.0 * np.cos(np.radians(lat0)))


def _stamp(t0, seconds: float):
    import datetime

    return t0 + datetime.timedelta(seconds=float(seconds))


def write_gpx(path, t0, times, lat, lon) -> Path:
    """A GPX 1.1 track: one ``<trkpt>`` per sample at ``t0`` (an aware datetime) + ``times`` seconds."""
    pts = "".join(f'<trkpt lat="{a:.9f}" lon="{b:.9f}"><ele>12.5</ele><time>'
                  f'{_stamp(t0, t).strftime("%Y-%m-%dT%H:%M:%S.%fZ")}</time></trkpt>\n'
                  for t, a, b in zip(times, lat, lon, strict=True))
    Path(path).write_text('<?xml version="1.0" encoding="UTF-8"?>\n<gpx version="1.1" creator="seqnet tests" '
                          'xmlns="http://www.topografix.com/GPX/1/1">\n<trk><name>drive</name><trkseg>\n'
                          f"{pts}</trkseg></trk>\n</gpx>\n", encoding="utf-8")
    return Path(path)


def gps_videos(folder: Path, n: int, t0) -> dict[str, Path]:
    """A drive filmed twice at 10 fps (``ref.mp4``, ``query.mp4``: ``n`` frames, the query noisier) with each
    recording's GPX track (``ref.gpx``, ``query.gpx``: ``n + 1`` samples from ``t0``, an aware datetime)."""
    lat, lon = route(n + 1)
    times = np.arange(n + 1) / 10
    out = {}
    for side, seed, noise in (("ref", 1, 0), ("query", 2, 12)):
        out[side] = write_video(Path(folder) / f"{side}.mp4", drive(n, seed, noise), rate=10,
                                creation_time=t0.isoformat())
        out[f"{side}.gpx"] = write_gpx(Path(folder) / f"{side}.gpx", t0, times, lat, lon)
    return out


def _nmea_angle(value: float, width: int, hemis: str) -> tuple[str, str]:
    v = abs(value)
    deg = int(v)
    return f"{deg:0{width}d}{(v - deg) * 60:09.6f}", hemis[0] if value >= 0 else hemis[1]


def write_nmea(path, t0, times, lat, lon, gga_only: bool = False) -> Path:
    """An NMEA 0183 log: per sample a GGA sentence and (unless ``gga_only``) an RMC sentence, with checksums."""
    import pynmea2

    lines = []
    for t, a, b in zip(times, lat, lon, strict=True):
        s = _stamp(t0, t)
        hms = s.strftime("%H%M%S.") + f"{s.microsecond // 10000:02d}"
        la, ns = _nmea_angle(a, 2, "NS")
        lo, ew = _nmea_angle(b, 3, "EW")
        lines.append(str(pynmea2.GGA("GP", "GGA", (hms, la, ns, lo, ew, "1", "08", "0.9", "12.5", "M", "46.9", "M",
                                                   "", ""))))
        if not gga_only:
            lines.append(str(pynmea2.RMC("GP", "RMC", (hms, "A", la, ns, lo, ew, "022.4", "084.4",
                                                       s.strftime("%d%m%y"), "003.1", "W"))))
    Path(path).write_text("\r\n".join(lines) + "\r\n", encoding="ascii")
    return Path(path)


def write_track_csv(path, times, lat, lon, t0=None) -> Path:
    """A CSV track ``time,lat,lon``: seconds since the video's start, or ISO-8601 times from ``t0``."""
    rows = [f"{t:.6f}" if t0 is None else _stamp(t0, t).isoformat() for t in times]
    Path(path).write_text("time,lat,lon\n" + "".join(f"{r},{a:.9f},{b:.9f}\n" for r, a, b in zip(rows, lat, lon,
                                                                                               strict=True)))
    return Path(path)
