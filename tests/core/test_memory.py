"""Memory estimates refused before the work (one line, exit 1, nothing written)."""

from __future__ import annotations

import numpy as np
import pytest

from seqnet.cli import main as cli
from seqnet.core import memory
from seqnet.core.errors import ResourceError
from seqnet.data.io import save_dataset
from seqnet.train.config import TrainConfig
from seqnet.train.memory import train_bytes


def test_available_memory_is_the_lowest_known_limit(monkeypatch):
    free = memory.available_bytes()
    assert free is None or free > 0
    monkeypatch.setenv("SEQNET_MEMORY_MB", "10")
    assert memory.available_bytes() == 10 * 2**20
    with pytest.raises(ResourceError, match=r"x needs about 1\.0 GiB of memory, 0\.0 GiB available; hint: h"):
        memory.check_fits(2**30, "x", "h")
    memory.check_fits(2**20, "x", "h")


def test_a_refusal_with_what_the_process_holds_names_the_whole():
    with pytest.raises(ResourceError, match=r"x needs about 2\.0 GiB of memory \(0\.5 GiB held by this process "
                                            r"before it \+ 1\.5 GiB more\), 1\.5 GiB available; hint: h"):
        memory.check_fits(3 << 29, "x", "h", held=1 << 29, free=1 << 30)
    memory.check_fits(1 << 30, "x", "h", held=1 << 29, free=1 << 30)  # what is held is not needed again


def test_the_process_memory_is_its_resident_set(tmp_path, monkeypatch):
    """VmRSS (torch is imported here: over 100 MiB); without /proc its peak so far; without that a constant."""
    import resource
    import types

    status = dict(line.split(":", 1) for line in open("/proc/self/status").read().splitlines() if ":" in line)
    now = memory.rss_bytes()
    assert now > 100 << 20 and abs(now - int(status["VmRSS"].split()[0]) * 1024) < 64 << 20
    monkeypatch.setattr(memory, "Path", lambda _: tmp_path / "absent")
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    assert before <= memory.rss_bytes() <= resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # the peak
    assert before >= now - (64 << 20)
    monkeypatch.setattr(memory, "resource", types.SimpleNamespace(getrusage=lambda _: types.SimpleNamespace(
        ru_maxrss=0), RUSAGE_SELF=0))
    assert memory.rss_bytes() == memory.BASE_BYTES


def test_the_training_estimate_grows_with_the_model():
    conf = TrainConfig(seq_len=5, w=5, optimizer="adam")
    wide = train_bytes(conf, 19200, 111, 111)
    assert wide > 4 * 4 * 19200 * 19200 * 5  # the weights, their gradients and Adam's two moments
    assert train_bytes(conf.replace(out_dims=512), 19200, 111, 111) < wide / 10
    assert train_bytes(conf.replace(optimizer="sgd"), 19200, 111, 111) < wide
    s1 = TrainConfig(seq_len=1, w=1, out_dims=64, match_len=5)  # the seqmatch loss caches L_m descriptors a query
    extra = train_bytes(s1.replace(loss="seqmatch"), 16, 1000, 1000) - train_bytes(s1, 16, 1000, 1000)
    assert extra >= 4 * 1000 * 64 * (5 - 1)


def test_the_training_estimate_counts_a_spilled_mining_cache_as_not_held(monkeypatch):
    conf = TrainConfig(seq_len=1, w=1, out_dims=4096)
    held = train_bytes(conf, 4096, 100000, 1000)
    assert held > 4 * 100000 * 4096  # every reference window's descriptor
    spilled = train_bytes(conf, 4096, 100000, 1000, spill=True)
    assert spilled < held - 4 * 100000 * 4096 + 1  # the cache is in a file
    monkeypatch.setenv("SEQNET_SPILL_MB", "4096")  # a cache under the spill threshold stays held
    assert train_bytes(conf, 4096, 100000, 1000, spill=True) == held


def test_training_that_cannot_fit_is_refused_before_anything_is_written(synth_dataset, tmp_path, monkeypatch, capsys):
    data = save_dataset(synth_dataset, tmp_path / "ds")
    monkeypatch.setenv("SEQNET_MEMORY_MB", "0.01")  # 10 kB: less than this tiny run needs
    assert cli(["train", "--dataset", str(data), "--epochs", "1", "--out", str(tmp_path / "run")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs about" in err[0] and "--out-dims" in err[0], err
    assert not (tmp_path / "run").exists()


def _one_line_refusal(capsys, *hints):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "needs about" in err[0] and all(h in err[0] for h in hints), err


def test_eval_index_build_and_localize_that_cannot_fit_are_refused_before_the_work(synth_dataset, tmp_path,
                                                                                 monkeypatch, capsys):
    data = str(save_dataset(synth_dataset, tmp_path / "ds"))
    monkeypatch.setenv("SEQNET_MEMORY_MB", "0.01")
    assert cli(["eval", "--dataset", data, "--out", str(tmp_path / "ev")]) == 1
    _one_line_refusal(capsys, "evaluating", "--split")
    assert not (tmp_path / "ev" / "results.json").exists()
    assert cli(["index", "build", "--dataset", data, "--out", str(tmp_path / "map"), "--window", "causal",
                "--shortlist", "single", "--rerank", "raw+seqmatch"]) == 1
    _one_line_refusal(capsys, "index of", "ivf-pq")
    assert not (tmp_path / "map").exists()
    assert cli(["localize", "--dataset", data, "--method", "single", "--out", str(tmp_path / "t.csv")]) == 1
    _one_line_refusal(capsys, "localising against", "--dtype float16")
    assert not (tmp_path / "t.csv").exists()
    monkeypatch.delenv("SEQNET_MEMORY_MB")
    assert cli(["eval", "--dataset", data, "--out", str(tmp_path / "ev")]) == 0


def test_the_estimates_follow_the_shapes():
    import faiss

    from seqnet.search.ann import index_bytes

    n, d = 100_000, 256
    flat, hnsw = faiss.index_factory(d, "Flat"), faiss.index_factory(d, "HNSW32,Flat")
    ivfpq = faiss.index_factory(d, "IVF1024,PQ32")
    assert index_bytes(flat, n) == 4 * d * n
    assert 4 * d * n + 64 * 4 * n < index_bytes(hnsw, n) < 4 * d * n + 80 * 4 * n  # 2M level-0 links
    assert index_bytes(ivfpq, n) == (32 + 8) * n + 4 * d * n  # codes + ids, and the training sample (all n)
    assert memory.described_bytes(10, 1000, [4, 8], 1 << 30) == 4 * 10 * 12 + 4 * 1000 * 12
    assert memory.described_bytes(10, 10**6, [1000], 256 << 20) == 4 * 10 * 1000 + (256 << 20)  # spilled past
    assert memory.workspace_bytes(10, 10) < memory.workspace_bytes(10**4, 10**5) == memory.WORKSPACE_BYTES


@pytest.mark.parametrize(("budget_mb", "what", "hint"), [(0.05, "describing batches of 8 images of", "--batch-size"),
                                                         (3, "descriptors of D=", "--dim N")])
def test_describing_that_cannot_fit_is_refused_after_at_most_one_batch(tmp_path, monkeypatch, capsys, budget_mb,
                                                                       what, hint):
    """A batch's working memory is checked before its forward pass; the descriptors to hold, once their D is
    known (after the first batch: 64x64 greyscale pixels are D=4096; 300 of them 4.7 MB)."""
    from PIL import Image

    rng = np.random.default_rng(0)
    for i in range(300):
        Image.fromarray(rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)).save(tmp_path / f"{i:03d}.png")
    monkeypatch.setenv("SEQNET_MEMORY_MB", str(budget_mb))
    assert cli(["describe", str(tmp_path), "--method", "pixels", "--out", str(tmp_path / "d.npy")]) == 1
    _one_line_refusal(capsys, what, hint)
    assert not (tmp_path / "d.npy").exists()


def test_a_cgroups_page_cache_counts_as_available(tmp_path, monkeypatch):
    """``memory.current`` includes page cache the kernel gives back: its inactive part is available."""
    (tmp_path / "memory.max").write_text(str(8 << 30))
    (tmp_path / "memory.current").write_text(str(int(7.8 * 2**30)))
    (tmp_path / "memory.stat").write_text(f"anon 1000\nfile {6 << 30}\ninactive_file {5 << 30}\n")
    monkeypatch.setattr(memory, "CGROUP", tmp_path)
    assert memory._cgroup_available() == (8 << 30) - int(7.8 * 2**30) + (5 << 30)
    (tmp_path / "memory.stat").unlink()
    assert memory._cgroup_available() == (8 << 30) - int(7.8 * 2**30)
    (tmp_path / "memory.max").write_text("max")
    assert memory._cgroup_available() is None


def test_a_sharded_build_counts_one_training_sample():
    import faiss

    from seqnet.search.ann import index_bytes

    index = faiss.index_factory(64, "IVF256,PQ8")
    whole, codes = index_bytes(index, 100_000), index_bytes(index, 100_000, sample=False)
    assert codes == 100_000 * (8 + 8) and whole - codes == 4 * 64 * 65_536  # the sample: max(256 · 256, 65,536)


@pytest.mark.parametrize(("n", "text"), [(0, "0 B"), (1023, "1023 B"), (1024, "1 KiB"), (2**20 - 1, "1 MiB"),
                                         (2**20 - 600, "1023 KiB"), (2**20, "1 MiB"), (2**30 - 1, "1.0 GiB"),
                                         (5 * 2**30, "5.0 GiB"), (1.5 * 2**20, "2 MiB")])
def test_human_bytes_never_writes_1024_of_a_unit(n: float, text: str) -> None:
    from seqnet.core.memory import human_bytes

    assert human_bytes(n) == text
