"""The files of a ROS bag, checked before ``rosbags`` opens any of them.

``rosbags`` opens what it is given as it finds it: a FIFO named ``run.db3`` (or ``metadata.yaml``, or a
``.bag``) blocks the process waiting for a writer; ``metadata.yaml`` is trusted (its counts and names are
stored as they are, and a string where a number belongs fails later, outside ``rosbags``' own error
handling); and a bag compressed file by file (``compression_mode: file``) is decompressed whole into a
temporary folder before anything is read, however large it inflates. Here (:func:`check_bag`):

* every file ``rosbags`` will open is a regular file (``stat``, never opened): the ``.bag``, the lone
  ``.db3`` / ``.mcap``, or ``metadata.yaml`` and each storage file it lists;
* ``metadata.yaml`` is read bounded (:data:`MAX_METADATA`) and parsed as ``rosbags`` parses it (ruamel,
  safe), then every field ``rosbags`` uses has its type and range: counts and times integers in
  ``0..2**63-1``, names text, at most :data:`MAX_FILES` storage files, each once, inside the bag's folder;
* a bag compressed file by file is refused, with the command that decompresses it.

``rosbags`` allocates nothing from the counts of ``metadata.yaml`` (it stores and sums them): the checks keep
their types right. A lone ``.db3`` or ``.mcap`` (no ``metadata.yaml`` beside it) is read by ``rosbags`` as the
storage file it is.
"""

from __future__ import annotations

from pathlib import Path, PurePath
from typing import Any

from ..core.errors import DatasetError
from .inputs import inside, kind_of, read_text
from .limits import number

MAX_METADATA = 16 << 20
MAX_FILES = 4096
TIME_MAX = 2**63 - 1
STORAGES = ("sqlite3", "mcap")
DECOMPRESS_HINT = "hint: `ros2 bag decompress BAG` writes an uncompressed copy, which seqnet reads"


def check_bag(path: str | Path) -> Path:
    """What ``AnyReader`` opens for the bag ``path`` (a ``.bag`` file, a ROS 2 bag directory, or a lone ``.db3`` /
    ``.mcap``), after the checks of the module docstring."""
    p = Path(path)
    if p.is_dir():
        root = p
    elif p.suffix.lower() in (".db3", ".mcap") and (p.parent / "metadata.yaml").exists():
        root = p.parent  # a storage file of a bag directory: the whole bag
    else:
        regular(p, "bag")
        return p
    meta = read_metadata(root / "metadata.yaml")
    names = meta["relative_file_paths"]
    for name in names:
        regular(inside(root, PurePath(name).name, f"{root}/metadata.yaml: storage file"), "bag storage file")
    mode = str(meta.get("compression_mode") or "").lower()
    if mode == "file":
        raise DatasetError(f"the bag {root} is compressed file by file ({meta.get('compression_format')!s:.20}): "
                           f"rosbags would decompress each file whole into a temporary folder first; "
                           f"{DECOMPRESS_HINT}")
    return root


def regular(p: Path, what: str) -> None:
    """``p`` exists and is a regular file (checked with ``stat``, never opened: a FIFO would block)."""
    try:
        mode = p.stat().st_mode
    except FileNotFoundError as e:
        raise DatasetError(f"{what} not found: {p}") from e
    kind = kind_of(mode)
    if kind != "a regular file":
        raise DatasetError(f"{what} {p} is {kind}, not a regular file (hint: a pipe is read once only: save it to "
                           "a file first)")


def read_metadata(path: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of a bag's ``metadata.yaml``, every field rosbags uses checked."""
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    regular(path, "bag metadata")
    text = read_text(path, MAX_METADATA, "bag metadata", DatasetError)
    try:
        doc = YAML(typ="safe").load(text)
    except (YAMLError, RecursionError, ValueError, TypeError) as e:
        raise DatasetError(f"{path}: not valid YAML ({' '.join(str(e).split())[:200]})") from e
    meta = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(meta, dict):
        raise DatasetError(f"{path}: no 'rosbag2_bagfile_information' mapping (not a ROS 2 bag's metadata)")
    where = f"{path}: rosbag2_bagfile_information"
    number(meta.get("version"), f"{where}.version", 1, 9)
    _text(meta.get("storage_identifier"), f"{where}.storage_identifier", STORAGES)
    for key in ("compression_mode", "compression_format", "ros_distro"):
        if meta.get(key) is not None:
            _text(meta[key], f"{where}.{key}")
    files = meta.get("relative_file_paths")
    if not isinstance(files, list) or not 1 <= len(files) <= MAX_FILES:
        raise DatasetError(f"{where}.relative_file_paths must list 1..{MAX_FILES} storage files")
    names = [PurePath(_text(f, f"{where}.relative_file_paths[{i}]")).name for i, f in enumerate(files)]
    if len(set(names)) != len(names):
        raise DatasetError(f"{where}.relative_file_paths names a storage file twice")
    number(meta.get("message_count"), f"{where}.message_count", 0, TIME_MAX)
    number(_field(meta, "duration", "nanoseconds", where), f"{where}.duration.nanoseconds", 0, TIME_MAX)
    number(_field(meta, "starting_time", "nanoseconds_since_epoch", where),
           f"{where}.starting_time.nanoseconds_since_epoch", 0, TIME_MAX)
    _topics(meta.get("topics_with_message_count"), f"{where}.topics_with_message_count")
    return meta


def _topics(topics: Any, where: str) -> None:
    if not isinstance(topics, list):
        raise DatasetError(f"{where} must be a list of topics")
    for i, t in enumerate(topics):
        info = t.get("topic_metadata") if isinstance(t, dict) else None
        if not isinstance(info, dict):
            raise DatasetError(f"{where}[{i}] has no topic_metadata mapping")
        number(t.get("message_count"), f"{where}[{i}].message_count", 0, TIME_MAX)
        for key in ("name", "type", "serialization_format"):
            _text(info.get(key), f"{where}[{i}].topic_metadata.{key}")
        qos = info.get("offered_qos_profiles", [])
        if not isinstance(qos, (str, list)) or (isinstance(qos, list) and not all(isinstance(q, dict) for q in qos)):
            raise DatasetError(f"{where}[{i}].topic_metadata.offered_qos_profiles must be text or a list of mappings")


def _field(meta: dict[str, Any], key: str, sub: str, where: str) -> Any:
    value = meta.get(key)
    if not isinstance(value, dict):
        raise DatasetError(f"{where}.{key} must be a mapping with {sub}")
    return value.get(sub)


def _text(value: Any, what: str, valid: tuple[str, ...] = ()) -> str:
    """``value`` when it is text of at most 4096 characters (and one of ``valid``, when given)."""
    if not isinstance(value, str) or len(value) > 4096 or (valid and value not in valid):
        want = f"one of {', '.join(valid)}" if valid else "text"
        raise DatasetError(f"{what} must be {want}, got {str(value)[:60]!r}")
    return value
