"""IVF indexes built in shards and merged on disk (``seqnet.maps.shards``, ``index build --shards N``): the
merged index answers exactly as one index built in one process with the same quantizer."""

from __future__ import annotations

import shutil

import faiss
import numpy as np
import pytest

from seqnet.cli import main as cli
from seqnet.core.errors import ConfigError
from seqnet.maps import MapConfig, build, load_map
from seqnet.maps.shards import (
    build_sharded_index,
    check_ivf,
    ivfdata_file,
    open_merged,
    sample_rows,
    split_rows,
    train_ivf,
)
from seqnet.search.ann import AnnConfig, search


def data(n=3000, d=16, seed=0):
    rng = np.random.default_rng(seed)
    centres = rng.standard_normal((40, d)).astype(np.float32) * 3
    x = centres[rng.integers(0, 40, n)] + rng.standard_normal((n, d), dtype=np.float32)
    q = x[rng.integers(0, n, 50)] + 0.1 * rng.standard_normal((50, d), dtype=np.float32)
    return x, q.astype(np.float32)


@pytest.mark.parametrize("kind", ["IVF32,Flat", "IVF16,PQ4x4", "IVF16,SQ8"])
def test_merged_index_equals_one_index_with_the_same_quantizer(tmp_path, kind):
    x, q = data()
    conf = AnnConfig(kind=kind, nprobe=4)
    trained = train_ivf(sample_rows(x, 1000), len(x), conf)
    one = faiss.clone_index(trained)
    one.add(x)
    one.nprobe = 4
    parts = [x[a:b] for a, b in split_rows(len(x), 4)]
    path = build_sharded_index(parts, conf, tmp_path / "index.faiss",
                               workers=2, trained=faiss.clone_index(trained))
    assert ivfdata_file(path).is_file() and not list(tmp_path.glob(".*.tmp"))  # shard files removed
    merged = open_merged(path, conf)
    assert merged.ntotal == len(x)
    d1, i1 = search(one, q, 10)
    d2, i2 = search(merged, q, 10)
    np.testing.assert_array_equal(i1, i2)
    np.testing.assert_array_equal(d1, d2)


def test_merged_index_opens_memory_mapped_after_its_folder_moved(tmp_path, capfd):
    x, q = data(1200, 8)
    conf = AnnConfig(kind="IVF8,Flat", nprobe=8)
    (tmp_path / "a").mkdir()
    build_sharded_index([x[:500], x[500:]], conf, tmp_path / "a" / "index.faiss")  # trained here, on all rows
    shutil.move(tmp_path / "a", tmp_path / "b")
    (tmp_path / "b" / "index.ivfdata").chmod(0o444)  # read-only lists open read-only
    merged = open_merged(tmp_path / "b" / "index.faiss", conf)
    invlists = faiss.downcast_InvertedLists(faiss.extract_index_ivf(merged).invlists)
    assert isinstance(invlists, faiss.OnDiskInvertedLists) and invlists.read_only
    assert invlists.filename == str(tmp_path / "b" / "index.ivfdata")
    _, ids = search(merged, x[:5], 1)
    assert ids[:, 0].tolist() == [0, 1, 2, 3, 4]
    assert "IO_FLAG" not in capfd.readouterr().out  # FAISS's chatter goes to the debug log


def test_only_ivf_indexes_shard():
    with pytest.raises(ConfigError, match="--shards needs an IVF index.*'HNSW32'"):
        check_ivf(faiss.index_factory(8, "HNSW32"), "HNSW32")
    with pytest.raises(ConfigError, match=r"shards must be in 1\.\.3 for 3 vectors, got 4"):
        split_rows(3, 4)
    assert split_rows(10, 3) == [(0, 3), (3, 6), (6, 10)]


def test_map_built_in_shards_answers_as_one(synth_dir, tmp_path, capsys):
    conf = MapConfig(shortlist="delta", rerank="raw+seqmatch", seq_len=4, ann=AnnConfig(kind="ivf-flat", nlist=4))
    one = load_map(build(conf, synth_dir, tmp_path / "one"))
    assert cli(["-q", "index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank",
                "raw+seqmatch", "--seq-len", "4", "--index", "ivf-flat", "--nlist", "4", "--shards", "3",
                "--out", str(tmp_path / "sharded")]) == 0
    sharded = load_map(tmp_path / "sharded")
    assert sharded.config.shards == 3 and (tmp_path / "sharded" / "index.ivfdata").is_file()
    q = np.asarray(one.shortlist[::7], dtype=np.float32) + 0.01
    for exact in (False, True):
        d1, i1 = one.search("delta", q, 10, exact=exact)
        d2, i2 = sharded.search("delta", q, 10, exact=exact)
        np.testing.assert_array_equal(np.asarray(i1), np.asarray(i2))
        np.testing.assert_array_equal(np.asarray(d1), np.asarray(d2))
    capsys.readouterr()
    assert cli(["index", "check", str(tmp_path / "sharded"), "--full"]) == 0
    assert "every byte hashed" in capsys.readouterr().out
    assert cli(["index", "build", "--dataset", str(synth_dir), "--shortlist", "delta", "--rerank", "raw+seqmatch",
                "--seq-len", "4", "--index", "hnsw", "--shards", "2", "--out", str(tmp_path / "h")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--shards needs an IVF index" in err and not (tmp_path / "h").exists()
