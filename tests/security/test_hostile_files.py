"""One test per class of attack in docs/security.md, each with a real hostile file, through the CLI a user types.

Every test asserts the promise: the file is refused with one line (exit 2; exit 1 for the environment), no
code runs (a marker file is never written), nothing outside the paths the user named is read or written,
and the interpreter survives.
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from seqnet.cli import main
from seqnet.data.io import save_dataset
from seqnet.data.synth import make_synthetic

SEQNET = [sys.executable, "-m", "seqnet"]


def run(capsys, argv: list[str]) -> tuple[int, str]:
    code = main(argv)
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) <= 1, err
    return code, err


@pytest.fixture
def ds(tmp_path):
    return save_dataset(make_synthetic(places=100, dim=8, seed=0), tmp_path / "ds")


def _edit_json(path: Path, **changes) -> None:
    meta = json.loads(path.read_text())
    meta.update(changes)
    path.write_text(json.dumps(meta))


# ----------------------------------------------------------------------------- code named in files


def test_a_describer_named_by_a_map_is_never_imported(tmp_path, folder):
    """A dataset (as a localize map) whose provenance names a plug-in describer in a module beside it: localize
    from the map's folder (so the module is importable) refuses to import it unless the user names it."""
    ds = save_dataset(make_synthetic(places=100, dim=8, seed=0), tmp_path / "map")
    marker = tmp_path / "pwned"
    (tmp_path / "evil_mod.py").write_text(f"open({str(marker)!r}, 'w').write('x')\ndef factory():\n    return None\n")
    prov = {"kind": "describe", "settings": {"method": "plugin", "describer": "evil_mod:factory"}, "id": "x"}
    _edit_json(ds / "dataset.json", provenance={"reference": prov, "query": prov})
    p = subprocess.run([*SEQNET, "localize", "--map", str(ds), "--query", str(folder), "--method", "single", "--out",
                        str(tmp_path / "t.csv")], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and "imports no code a file names" in p.stderr and "--describer" in p.stderr, p.stderr
    assert not marker.exists() and len(p.stderr.strip().splitlines()) == 1


def test_a_checkpoint_named_by_a_map_is_never_opened(tmp_path, folder):
    ds = save_dataset(make_synthetic(places=100, dim=8, seed=0), tmp_path / "map")
    prov = {"kind": "describe", "settings": {"method": "netvlad", "checkpoint": "/etc/hostname"}, "id": "x"}
    _edit_json(ds / "dataset.json", provenance={"reference": prov, "query": prov})
    code = main(["localize", "--map", str(ds), "--query", str(folder), "--method", "single", "--out",
                 str(tmp_path / "t.csv")])
    assert code == 2


# ----------------------------------------------------------------------------- pickles


class _Evil:
    def __reduce__(self):
        return (os.system, ("touch pwned-by-pickle",))


def test_pickled_ground_truth_never_runs_code(tmp_path, monkeypatch):
    from seqnet.core.errors import DatasetError
    from seqnet.data.positives import read_positives

    monkeypatch.chdir(tmp_path)
    obj = np.empty((1, 2), dtype=object)
    obj[0, 0], obj[0, 1] = 0, _Evil()
    np.save(tmp_path / "gt.npy", obj, allow_pickle=True)
    (tmp_path / "gt.pkl").write_bytes(pickle.dumps([[0, _Evil()]], protocol=2))
    for f in ("gt.npy", "gt.pkl"):
        with pytest.raises(DatasetError, match=r"refusing (posix|os)\.system"):
            read_positives(tmp_path / f)
    assert not (tmp_path / "pwned-by-pickle").exists()


FIELDS = b"N(X\x01\x00\x00\x00atN"  # subarray None, names ('a',), fields None: a dtype state numpy would act on


def _with_dtype_fields(data: bytes) -> bytes:
    """A pickle whose numpy dtype state declares fields (numpy's own ``dtype.__setstate__`` is where crafted
    states crash the interpreter; seqnet never calls it)."""
    i = data.index(b"NNNJ\xff\xff\xff\xff")
    return data[:i] + FIELDS + data[i + 3:]


def test_a_crafted_numpy_dtype_state_is_refused_not_run(ds, tmp_path, capsys):
    """The class that crashed the old restricted unpickler, in ground truth and inside a checkpoint."""
    import zipfile

    from seqnet.core.errors import DatasetError
    from seqnet.data.positives import read_positives
    from seqnet.sequence.checkpoints import save_checkpoint
    from seqnet.sequence.model import SeqNet

    (tmp_path / "gt.pkl").write_bytes(_with_dtype_fields(pickle.dumps([[0, np.float64(1.0)]], protocol=2)))
    with pytest.raises(DatasetError, match="gt.pkl"):
        read_positives(tmp_path / "gt.pkl")
    save_checkpoint(tmp_path / "m.pt", SeqNet(8, 4, 1, 1), best_score=np.float64(0.5))
    with zipfile.ZipFile(tmp_path / "m.pt") as z:
        items = [(info, z.read(info)) for info in z.infolist()]
    with zipfile.ZipFile(tmp_path / "crafted.pt", "w", zipfile.ZIP_STORED) as z:
        for info, data in items:
            z.writestr(info, _with_dtype_fields(data) if info.filename.endswith("data.pkl") else data)
    code, err = run(capsys, ["eval", "--dataset", str(ds), "--rerank-model", str(tmp_path / "crafted.pt")])
    assert code == 2 and "crafted.pt" in err


# ----------------------------------------------------------------------------- symbolic links


def test_a_planted_lock_link_is_refused_and_its_target_untouched(tmp_path, capsys):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / ".ds.lock").symlink_to(victim)
    code, err = run(capsys, ["synth", str(tmp_path / "ds")])
    assert code == 2 and "symbolic link" in err and victim.read_text() == "precious"


def test_a_partial_file_link_is_neither_followed_nor_deleted(tmp_path, folder, capsys):
    victim = tmp_path / "victim.h5"
    victim.write_bytes(b"precious")
    (tmp_path / ".out.h5.seqnet-partial.h5").symlink_to(victim)
    code, err = run(capsys, ["describe", str(folder), "--method", "pixels", "--out", str(tmp_path / "out.h5")])
    assert code == 2 and "link" in err and victim.read_bytes() == b"precious"
    assert (tmp_path / ".out.h5.seqnet-partial.h5").is_symlink()


# ----------------------------------------------------------------------------- deleting what is not ours


def test_a_users_old_and_tmp_folders_are_never_deleted(tmp_path, capsys):
    for name in (".ds.old", ".ds.backup.tmp", ".ds.1234.tmp"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "mine.txt").write_text("mine")
    assert main(["-q", "synth", str(tmp_path / "ds")]) == 0
    assert main(["-q", "synth", str(tmp_path / "ds"), "--overwrite"]) == 0
    for name in (".ds.old", ".ds.backup.tmp", ".ds.1234.tmp"):
        assert (tmp_path / name / "mine.txt").read_text() == "mine"


def test_a_users_file_named_like_a_lock_is_not_truncated(tmp_path, capsys):
    (tmp_path / ".ds.lock").write_text("my notes")
    code, err = run(capsys, ["synth", str(tmp_path / "ds")])
    assert code == 2 and "not a seqnet lock file" in err and (tmp_path / ".ds.lock").read_text() == "my notes"


def test_a_users_sidecars_beside_a_describe_output_are_kept(tmp_path, folder, capsys):
    (tmp_path / "d.names.txt").write_text("my names")
    code, err = run(capsys, ["describe", str(folder), "--method", "pixels", "--out", str(tmp_path / "d.npy")])
    assert code == 2 and "not written by seqnet" in err and (tmp_path / "d.names.txt").read_text() == "my names"


# ----------------------------------------------------------------------------- paths read from files


@pytest.mark.parametrize("traverse", ["/etc", "../other", "link"])
def test_dataset_traverses_stay_in_the_dataset(ds, tmp_path, capsys, traverse):
    other = save_dataset(make_synthetic(places=100, dim=8, seed=1), tmp_path / "other")
    (ds / "link").symlink_to(other / "reference")
    _edit_json(ds / "dataset.json", traverses={"reference": traverse, "query": "query"})
    code, err = run(capsys, ["eval", "--dataset", str(ds), "--method", "single"])
    assert code == 2 and "outside" in err


def test_checksum_keys_stay_in_the_dataset(ds, tmp_path, capsys):
    (tmp_path / "secret.txt").write_text("secret")
    meta = json.loads((ds / "dataset.json").read_text())
    meta["checksums"]["../secret.txt"] = {"size": 6, "sample": "0" * 32}
    (ds / "dataset.json").write_text(json.dumps(meta))
    code, err = run(capsys, ["dataset", "check", str(ds)])
    assert code == 2 and "outside" in err


def _map(tmp_path: Path, kind: str = "hnsw", models: bool = False) -> Path:
    ds = save_dataset(make_synthetic(places=120, dim=8, seed=0), tmp_path / "mds")
    argv = ["-q", "index", "build", "--dataset", str(ds), "--shortlist", "single", "--rerank", "raw+seqmatch",
            "--seq-len", "3", "--index", kind, "--split", "all", "--out", str(tmp_path / "map")]
    assert main(argv) == 0
    return tmp_path / "map"


def _recheck(m: Path, *names: str) -> None:
    """Record the current checksums of ``names`` in map.json (a crafted map carries matching ones)."""
    from seqnet.security.digests import file_digest

    meta = json.loads((m / "map.json").read_text())
    for n in names:
        meta["checksums"][n] = file_digest(m / n, full=True)
    (m / "map.json").write_text(json.dumps(meta))


def test_map_models_stay_in_the_map(tmp_path, capsys, map_models):
    m = _map(tmp_path)
    meta = json.loads((m / "map.json").read_text())
    meta["models"] = {"s1": str(map_models[1])}  # an absolute path to a checkpoint elsewhere
    (m / "map.json").write_text(json.dumps(meta))
    from seqnet.maps import load_map
    from seqnet.maps.map import MapError

    with pytest.raises(MapError, match="outside"):
        load_map(m)


def test_on_disk_lists_are_read_only_from_the_maps_folder(tmp_path, capsys):
    """A sharded map's index names its inverted lists file; one that names another file (here the lists of
    another map, elsewhere) is refused, and the lists are never opened for writing."""
    from seqnet.maps import load_map
    from seqnet.maps.map import MapError

    ds = save_dataset(make_synthetic(places=400, dim=8, seed=0), tmp_path / "mds")
    assert main(["-q", "index", "build", "--dataset", str(ds), "--shortlist", "single", "--rerank", "raw+seqmatch",
                 "--seq-len", "3", "--index", "IVF4,Flat", "--shards", "2", "--split", "all", "--out",
                 str(tmp_path / "map")]) == 0
    m = tmp_path / "map"
    before = (m / "index.ivfdata").read_bytes()
    load_map(m)  # the map's own lists: read-only, unchanged
    assert (m / "index.ivfdata").read_bytes() == before
    data = (m / "index.faiss").read_bytes()
    (m / "index.faiss").write_bytes(data.replace(b"index.ivfdata", b"other.ivfdata"))
    (m / "other.ivfdata").write_bytes(before)
    _recheck(m, "index.faiss")
    with pytest.raises(MapError, match="ivfdata"):
        load_map(m)


# ----------------------------------------------------------------------------- HDF5


def _h5_dataset(ds: Path, make) -> None:  # noqa: ANN001 - make(h5py.File)
    q = ds / "query"
    (q / "descriptors.npy").unlink()
    with h5py.File(q / "descriptors.h5", "w") as h:
        make(h)


@pytest.mark.parametrize("layout", ["external-link", "external-storage", "virtual", "huge", "garbage", "fifo"])
def test_hdf5_layouts_that_read_other_files_or_bomb_are_refused(ds, tmp_path, capsys, layout):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as h:
        h["descriptors"] = np.ones((100, 8), np.float32)
    if layout == "external-link":
        _h5_dataset(ds, lambda h: h.__setitem__("descriptors", h5py.ExternalLink(str(other), "descriptors")))
    elif layout == "external-storage":
        _h5_dataset(ds, lambda h: h.create_dataset("descriptors", shape=(100, 8), dtype="f4",
                                                   external=[(str(other), 0, 3200)]))
    elif layout == "virtual":
        vl = h5py.VirtualLayout(shape=(100, 8), dtype="f4")
        vl[:] = h5py.VirtualSource(str(other), "descriptors", shape=(100, 8))
        _h5_dataset(ds, lambda h: h.create_virtual_dataset("descriptors", vl))
    elif layout == "huge":
        _h5_dataset(ds, lambda h: h.create_dataset("descriptors", shape=(10**7, 4096), dtype="f4",
                                                   chunks=(1, 4096), compression="gzip"))
    elif layout == "garbage":
        (ds / "query" / "descriptors.npy").unlink()
        (ds / "query" / "descriptors.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + os.urandom(4000))
    else:
        (ds / "query" / "descriptors.npy").unlink()
        os.mkfifo(ds / "query" / "descriptors.h5")
    code, err = run(capsys, ["eval", "--dataset", str(ds), "--method", "single"])
    assert code == 2 and "descriptors.h5" in err


# ----------------------------------------------------------------------------- allocation bombs


def test_an_npy_header_cannot_allocate_more_than_the_file_holds(ds, capsys):
    with open(ds / "query" / "positions.npy", "wb") as f:
        np.lib.format.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": (10**12, 2)})
        f.write(b"\0" * 64)
    code, err = run(capsys, ["eval", "--dataset", str(ds), "--method", "single"])
    assert code == 2 and "declares" in err


def test_an_npz_member_cannot_allocate_more_than_it_decompresses_to(tmp_path):
    import zipfile

    from seqnet.core.errors import DatasetError
    from seqnet.data.positives import read_positives

    with zipfile.ZipFile(tmp_path / "GT.npz", "w", zipfile.ZIP_DEFLATED) as z:
        with z.open("GThard.npy", "w") as m:
            np.lib.format.write_array_header_1_0(m, {"descr": "|b1", "fortran_order": False, "shape": (10**6, 10**6)})
            m.write(b"\0" * 1000)
    with pytest.raises(DatasetError, match="GThard.npy: its header declares"):
        read_positives(tmp_path / "GT.npz")


def test_a_checkpoint_cannot_allocate_beyond_its_weights(tmp_path, ds, capsys):
    import torch

    from seqnet.sequence.checkpoints import save_checkpoint
    from seqnet.sequence.model import SeqNet

    save_checkpoint(tmp_path / "m.pt", SeqNet(8, 4, 3, 2))
    payload = torch.load(tmp_path / "m.pt", weights_only=False)
    payload["model"]["out_dims"] = 10**9  # the architecture entry lies
    torch.save(payload, tmp_path / "big.pt")
    payload["model"]["out_dims"] = 4
    payload["state_dict"]["conv.weight"] = torch.zeros(1).expand(4, 8, 2)  # stride 0: 1 number stored
    torch.save(payload, tmp_path / "stride0.pt")
    for f in ("big.pt", "stride0.pt"):
        code, err = run(capsys, ["eval", "--dataset", str(ds), "--shortlist-model", str(tmp_path / f)])
        assert code == 2 and f in err


@pytest.mark.parametrize("field, value", [("ef_search", 10**12), ("ef_search", 10**8), ("nprobe", 2**63)])
def test_search_settings_from_a_map_have_a_range(tmp_path, field, value):
    from seqnet.maps import load_map
    from seqnet.maps.map import MapError

    m = _map(tmp_path)
    meta = json.loads((m / "map.json").read_text())
    meta["config"]["ann"][field] = value
    (m / "map.json").write_text(json.dumps(meta))
    with pytest.raises(MapError, match=field):
        load_map(m)


def test_a_faiss_header_cannot_allocate_beyond_the_file(tmp_path):
    from seqnet.maps import load_map
    from seqnet.maps.map import MapError

    m = _map(tmp_path)
    data = bytearray((m / "index.faiss").read_bytes())
    data[37:45] = (2**39).to_bytes(8, "little")  # a vector size field of the HNSW storage
    (m / "index.faiss").write_bytes(bytes(data))
    _recheck(m, "index.faiss")
    with pytest.raises(MapError):
        load_map(m)


# ----------------------------------------------------------------------------- output injection


def test_names_cannot_inject_formulas_or_escape_sequences(tmp_path, capsys):
    d = make_synthetic(places=100, dim=8, seed=0)
    evil = ["=HYPERLINK(\"http://x\")", "+cmd|' /C calc'!A0", "@SUM(1+1)", "-2+3", "\x1b[2Jclear"]
    d.query.names = [evil[i % len(evil)] + str(i) for i in range(len(d.query))]
    d.reference.names = [evil[i % len(evil)] + f"r{i}" for i in range(len(d.reference))]
    d.name = "evil\x1b]0;PWNED\x07name"
    ds = save_dataset(d, tmp_path / "ds")
    assert main(["-q", "localize", "--dataset", str(ds), "--method", "single", "--out", str(tmp_path / "t.csv")]) == 0
    import csv

    for row in csv.DictReader((tmp_path / "t.csv").open()):
        for key in ("name", "estimate_name"):
            assert not row[key] or not row[key].startswith(("=", "+", "-", "@")), row[key]
    assert main(["eval", "--dataset", str(ds), "--method", "single"]) == 0
    out = capsys.readouterr()
    assert "\x1b" not in out.out and "\x07" not in out.out and "\x1b" not in out.err


def test_a_nul_in_a_name_is_a_clear_error(ds, capsys):
    names = (ds / "query" / "names.txt").read_text().splitlines()
    names[3] = "a\x00b"
    (ds / "query" / "names.txt").write_text("\n".join(names) + "\n")
    code, err = run(capsys, ["eval", "--dataset", str(ds), "--method", "single"])
    assert code == 2 and "NUL" in err
