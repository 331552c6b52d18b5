"""What a folder given as images holds besides them: said when left out, and where its images are when it has
none of its own (sub-folders: a camera's split recording, KITTI's ``image_02/data``)."""

from __future__ import annotations

import shlex
from pathlib import Path

from ..core.log import counted, logger
from ..data.order import name_order

MAX_LOOKED = 1000  # sub-folders looked into for images when a folder holds none


def say_left_out(src: Path, others: list[Path], extensions: tuple[str, ...]) -> None:
    """Say (INFO) what of the folder ``src`` is not taken as an image: hidden files (macOS ``._*`` AppleDouble
    files, ``.DS_Store``), sub-folders and files of other extensions, counted by kind."""
    if not others:
        return
    hidden = sum(p.name.startswith(".") for p in others)
    folders = sum(p.is_dir() and not p.name.startswith(".") for p in others)
    kinds: dict[str, int] = {}
    for p in others:
        if not p.name.startswith(".") and not p.is_dir():
            kinds[p.suffix.lower() or "no extension"] = kinds.get(p.suffix.lower() or "no extension", 0) + 1
    parts = ([f"{counted(sum(kinds.values()), 'file')} of other extensions ("
              + ", ".join(f"{k}: {n}" for k, n in sorted(kinds.items(), key=lambda kv: -kv[1])[:5]) + ")"]
             if kinds else []) + ([counted(hidden, "hidden file")] if hidden else []) + \
        ([counted(folders, "sub-folder")] if folders else [])
    logger.info("%s: left out %s (images are %s files)", src, ", ".join(parts), " ".join(extensions))


def empty_folder_hint(src: Path, extensions: tuple[str, ...]) -> str:
    """The hint for a folder ``src`` without images of its own: the one sub-folder that holds them (``pass
    image_02/data``), a command that lists several in order, else a folder or list file in general."""
    subs = [p for p in sorted(src.iterdir())[:MAX_LOOKED] if p.is_dir() and not p.name.startswith(".")]
    holding = [d for d in subs if any(f.suffix.lower() in extensions and not f.name.startswith(".")
                                      for f in d.iterdir())]
    if len(holding) == 1:
        return f"hint: its images are in the sub-folder {holding[0].name}/: pass {holding[0]}"
    if holding:
        names = [holding[i].name for i in name_order([d.name for d in holding])]
        ext = max(extensions, key=lambda e: sum(f.suffix.lower() == e for f in holding[0].iterdir()))
        shown = ", ".join(f"{n}/" for n in names[:3]) + (", ..." if len(names) > 3 else "")
        return (f"hint: its images are in {len(names)} sub-folders ({shown}); pass one, or list them all in "
                f"order in a text file: find {shlex.quote(str(src))} -name '*{ext}' | sort -V > images.txt")
    return "hint: pass a folder of images or a text file listing them"
