"""Fuzz every reader of files from strangers: mutated valid files in, a value or a seqnet error out.

Each reader gets valid seed files (written here, in the layouts seqnet and the tools it reads produce) that
are mutated at random: bytes flipped, runs truncated, inserted or repeated, and 1/2/4/8-byte fields
overwritten with extreme integers (0, -1, 2**31-1, 2**32, 2**63-1, ...: the header fields that declare
sizes). Every case runs in a forked child of this process, limited in memory (``RLIMIT_AS``) and time, and
must end in a value or a :class:`seqnet.core.errors.SeqnetError`; anything else — another exception, a
crash (signal), a hang, running out of the memory bound — is a finding, saved with its bytes.

    python benchmarks/fuzz_readers.py --cases 40                   # every reader, 40 cases each (CI does this)
    python benchmarks/fuzz_readers.py --reader hdf5 --seconds 3600  # one reader for an hour (nightly)

Exit code 0 when nothing was found, 1 otherwise (findings listed, files under ``--out``).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import shutil
import signal
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path

import numpy as np

MEMORY = 3 << 30  # per case: a reader may not need more (the seed files are tiny)
TIMEOUT = 60.0  # per case, seconds (a sandboxed reader starts a child Python)
EXTREMES = [0, 1, 0xFF, 0x7F, 0x80, 0xFFFF, 0x7FFF_FFFF, 0xFFFF_FFFF, 2**32, 2**40, 2**62, 2**63 - 1, 2**64 - 1]


def mutate(data: bytes, rng: random.Random) -> bytes:
    """One random mutation (or a few) of ``data``."""
    b = bytearray(data)
    for _ in range(rng.choice((1, 1, 2, 4))):
        op = rng.randrange(6)
        if not b:
            b += bytes([rng.randrange(256)])
        pos = rng.randrange(len(b))
        if op == 0:  # flip bytes
            for i in range(pos, min(len(b), pos + rng.randint(1, 8))):
                b[i] = rng.randrange(256)
        elif op == 1:  # truncate
            del b[pos:]
        elif op == 2:  # insert
            b[pos:pos] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        elif op == 3:  # repeat a run
            b[pos:pos] = b[pos : pos + rng.randint(1, 64)] * rng.randint(1, 4)
        else:  # an extreme integer in a 1/2/4/8-byte field
            width = rng.choice((1, 2, 4, 8))
            value = rng.choice(EXTREMES) % (1 << (8 * width))
            b[pos : pos + width] = value.to_bytes(width, rng.choice(("little", "big")))
    return bytes(b)


# ----------------------------------------------------------------------------- seeds and readers, by reader


def _seed_arrays(d: Path) -> list[Path]:
    np.save(d / "a.npy", np.random.default_rng(0).random((6, 4), dtype=np.float32))
    np.save(d / "b.npy", np.asfortranarray(np.arange(12, dtype=">i8").reshape(3, 4)))
    np.savez(d / "c.npz", indptr=np.array([0, 1, 3]), indices=np.array([4, 1, 2]))
    np.savez_compressed(d / "d.npz", GThard=np.eye(4, dtype=bool))
    return [d / n for n in ("a.npy", "b.npy", "c.npz", "d.npz")]


def _read_arrays(p: Path) -> object:
    from seqnet.security.arrays import read_npy, read_npz

    return read_npz(p) if p.suffix == ".npz" else (read_npy(p, False), read_npy(p, True))


def _seed_hdf5(d: Path) -> list[Path]:
    import h5py

    with h5py.File(d / "a.h5", "w") as h:
        h["descriptors"] = np.random.default_rng(0).random((6, 4), dtype=np.float32)
        h.create_dataset("names", data=np.array([f"n{i}.png" for i in range(6)], dtype=object),
                         dtype=h5py.string_dtype())
        h.attrs["provenance"] = json.dumps({"kind": "external", "id": "x"})
    with h5py.File(d / "b.h5", "w") as h:  # hloc's global features, compressed chunks
        for i in range(3):
            h.create_dataset(f"db/img{i}.jpg/global_descriptor", data=np.ones(8, np.float32), compression="gzip")
    return [d / "a.h5", d / "b.h5"]


def _read_hdf5(p: Path) -> object:
    from seqnet.data.readers import read_descriptor_file, read_provenance

    return read_descriptor_file(p), read_provenance(p)


def _seed_dataset(d: Path) -> list[Path]:
    from seqnet.data.io import save_dataset
    from seqnet.data.synth import make_synthetic

    save_dataset(make_synthetic(places=100, dim=8, seed=0), d / "ds")
    return [d / "ds" / "dataset.json", d / "ds" / "query" / "names.txt", d / "ds" / "query" / "positions.npy"]


def _read_dataset(p: Path) -> object:
    from seqnet.data.io import load_dataset

    root = p.parent if p.name == "dataset.json" else p.parent.parent
    return load_dataset(root)


def _seed_torch(d: Path) -> list[Path]:
    import torch

    from seqnet.sequence.checkpoints import save_checkpoint
    from seqnet.sequence.model import SeqNet

    torch.manual_seed(0)
    save_checkpoint(d / "s.pt", SeqNet(8, 6, 3, 2), best_score=np.float64(0.5), epoch=np.int64(3))
    torch.save({"state_dict": {"pool.0.conv.weight": torch.ones(6, 8, 2), "pool.0.conv.bias": torch.ones(6)},
                "epoch": 1}, d / "model_best.pth.tar")
    return [d / "s.pt", d / "model_best.pth.tar"]


def _read_torch(p: Path) -> object:
    from seqnet.sequence.checkpoints import load_model

    return load_model(p, seq_len=3)


def _seed_faiss(d: Path) -> list[Path]:
    import faiss

    x = np.random.default_rng(0).random((1000, 8), dtype=np.float32)
    for name, spec in (("hnsw.faiss", "HNSW8"), ("ivf.faiss", "IVF4,Flat"), ("pq.faiss", "IVF4,PQ4x4")):
        index = faiss.index_factory(8, spec)
        index.train(x)
        index.add(x)
        faiss.write_index(index, str(d / name))
    return [d / n for n in ("hnsw.faiss", "ivf.faiss", "pq.faiss")]


def _read_faiss(p: Path) -> object:
    from seqnet.security.faissfile import read_faiss

    return read_faiss(p, 1000, 8)


def _seed_positives(d: Path) -> list[Path]:
    import pickle

    obj = np.empty((3, 2), dtype=object)
    for q in range(3):
        obj[q, 0], obj[q, 1] = q, np.array([q, q + 1])
    np.save(d / "gt.npy", obj, allow_pickle=True)
    (d / "plain.pkl").write_bytes(pickle.dumps([[0, range(1, 3)], [1, [2]], [2, []]], protocol=2))
    (d / "p.csv").write_text("query,reference\n0,1\n1,2\n2,0\n")
    (d / "p.json").write_text("[[0, 1], [2], []]")
    return [d / n for n in ("gt.npy", "plain.pkl", "p.csv", "p.json")]


def _read_positives(p: Path) -> object:
    from seqnet.data.positives import read_positives

    return read_positives(p)


def _seed_text(d: Path) -> list[Path]:
    (d / "names.txt").write_text("a.png\nb.png\nc.png\n")
    (d / "positions.csv").write_text("1.5,2.5\n3,4\n5,6e3\n")
    (d / "flags.json").write_text(json.dumps({"seqL": 5, "w": 3, "outDims": 4096, "pooling": "seqnet"}))
    return [d / n for n in ("names.txt", "positions.csv", "flags.json")]


def _read_text(p: Path) -> object:
    from seqnet.data.readers import read_names, read_positions_file
    from seqnet.security.jsonfile import read_json

    return {".txt": read_names, ".csv": read_positions_file, ".json": read_json}[p.suffix](p)


def _seed_map(d: Path) -> list[Path]:
    from seqnet.data.io import save_dataset
    from seqnet.data.synth import make_synthetic
    from seqnet.maps.build import build
    from seqnet.maps.config import MapConfig
    from seqnet.search.ann import AnnConfig

    save_dataset(make_synthetic(places=100, dim=8, seed=0), d / "ds")
    conf = MapConfig(shortlist="single", rerank="raw+seqmatch", seq_len=3, ann=AnnConfig(kind="hnsw"), split="all")
    build(conf, d / "ds", d / "map")
    m = d / "map"
    return [m / "map.json", m / "index.faiss", m / "frames.npy", m / "items.npy", m / "names.txt"]


def _read_map(p: Path) -> object:
    from seqnet.maps import load_map
    from seqnet.security.digests import file_digest

    if p.name != "map.json":  # a crafted map records the checksums of its crafted files
        meta = json.loads((p.parent / "map.json").read_text())
        meta["checksums"][p.name] = file_digest(p, full=True)
        (p.parent / "map.json").write_text(json.dumps(meta))
    return load_map(p.parent)


def _seed_foreign(d: Path) -> list[Path]:
    shared = Path(__file__).resolve().parents[2] / "shared" / "data" / "seqnet_structfiles"
    out = []
    for name in ("nordland_val_d-1_d2-1.db", "msls_amman_query_seqBounds.txt"):
        if (shared / name).is_file():
            shutil.copy(shared / name, d / name)
            out.append(d / name)
    (d / "ins.csv").write_text("timestamp,northing,easting,down,status\n1418381798076682,5735985.5,619979.1,0,INS\n"
                               "1418381798126682,5735986.5,619980.1,0,INS\n")
    return out + [d / "ins.csv"]


def _read_foreign(p: Path) -> object:
    from seqnet.data.convert import read_seq_bounds
    from seqnet.data.gps import read_robotcar_ins
    from seqnet.data.structfiles import read_db_struct

    return {".db": read_db_struct, ".txt": read_seq_bounds, ".csv": read_robotcar_ins}[p.suffix](p)


def _seed_bags(d: Path) -> list[Path]:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from conftest import write_bag  # the tests' writer of tiny bags (rosbags' own writers)

    images = [np.full((8, 8, 3), 40 * i, np.uint8) for i in range(4)]
    fixes = [(63.43 + 1e-4 * j, 10.39, 0) for j in range(4)]
    write_bag(d / "run.bag", images, "ros1", fixes=fixes)
    write_bag(d / "ros2", images, "ros2", fixes=fixes)
    write_bag(d / "mcap", images, "mcap", fixes=fixes)
    return [d / "run.bag", *sorted((d / "ros2").iterdir()), *sorted((d / "mcap").iterdir())]


def _read_bags(p: Path) -> object:
    from seqnet.security.pictures import decode
    from seqnet.sources.bags.images import bag_images
    from seqnet.sources.bags.positions import read_positions

    bag = p if p.suffix == ".bag" else p.parent
    frames, names, positions = bag_images(bag, "/camera/image_raw", "/gps/fix")  # one pass, as localize reads
    return read_positions(bag, "/gps/fix"), positions, [decode(f.open, f) for f in frames], names


READERS: dict[str, tuple[Callable[[Path], list[Path]], Callable[[Path], object]]] = {
    "arrays": (_seed_arrays, _read_arrays), "hdf5": (_seed_hdf5, _read_hdf5), "dataset": (_seed_dataset, _read_dataset),
    "torch": (_seed_torch, _read_torch), "faiss": (_seed_faiss, _read_faiss),
    "positives": (_seed_positives, _read_positives), "text": (_seed_text, _read_text), "map": (_seed_map, _read_map),
    "foreign": (_seed_foreign, _read_foreign), "bags": (_seed_bags, _read_bags),
}


# ----------------------------------------------------------------------------- running cases


def _vm_size() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmSize:"):
            return int(line.split()[1]) * 1024
    return 0


def run_case(read: Callable[[Path], object], path: Path, timeout: float) -> dict:
    """``read(path)`` in a forked child bounded in memory and time: ``{"outcome": ok|finding, ...}``."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: limits, the read, one JSON line on the pipe, _exit
        os.close(r)
        resource.setrlimit(resource.RLIMIT_AS, (_vm_size() + MEMORY, resource.getrlimit(resource.RLIMIT_AS)[1]))
        signal.alarm(int(timeout))
        import warnings

        from seqnet.core.errors import SeqnetError

        warnings.simplefilter("ignore")
        try:
            read(path)
            out = {"outcome": "ok", "result": "value"}
        except SeqnetError as e:
            out = {"outcome": "ok", "result": type(e).__name__, "message": " ".join(str(e).split())[:300]}
        except BaseException as e:  # noqa: BLE001 - anything else is what the fuzzer looks for
            out = {"outcome": "finding", "result": type(e).__name__, "message": " ".join(str(e).split())[:300],
                   "trace": traceback.format_exc()[-1500:]}
        os.write(w, json.dumps(out).encode())
        os._exit(0)
    os.close(w)
    with os.fdopen(r, "rb") as f:
        data = f.read()
    _, status = os.waitpid(pid, 0)
    if os.WIFSIGNALED(status):
        sig = signal.Signals(os.WTERMSIG(status)).name
        return {"outcome": "finding", "result": "hang" if sig == "SIGALRM" else f"crash {sig}"}
    try:
        return json.loads(data)
    except ValueError:
        return {"outcome": "finding", "result": "no answer", "message": data[-300:].decode("utf-8", "replace")}


def fuzz(name: str, cases: int, seconds: float | None, seed: int, out: Path) -> dict:
    """Run one reader's cases; findings saved under ``out/name``. Returns counts and findings."""
    make, read = READERS[name]
    rng = random.Random(seed)
    work = Path(tempfile.mkdtemp(prefix=f"fuzz-{name}-"))
    try:
        seeds = make(work)
        originals = {p: p.read_bytes() for p in seeds}
        counts: dict[str, int] = {}
        findings = []
        start, done = time.perf_counter(), 0
        while (done < cases) if seconds is None else (time.perf_counter() - start < seconds):
            target = rng.choice(seeds)
            data = mutate(originals[target], rng)
            target.write_bytes(data)
            res = run_case(read, target, TIMEOUT)
            counts[res["result"]] = counts.get(res["result"], 0) + 1
            if res["outcome"] != "ok":
                keep = out / name / f"case{done:06d}{target.suffix}"
                keep.parent.mkdir(parents=True, exist_ok=True)
                keep.write_bytes(data)
                findings.append({**res, "file": str(keep), "seed_file": target.name})
            for s, original in originals.items():  # a reader may have changed another seed file (the map)
                s.write_bytes(original)
            done += 1
        return {"reader": name, "cases": done, "seconds": round(time.perf_counter() - start, 1), "outcomes": counts,
                "findings": findings}
    finally:
        shutil.rmtree(work, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reader", default="all", help=f"one of {', '.join(READERS)}, or all (default)")
    ap.add_argument("--cases", type=int, default=40, help="cases per reader (default 40)")
    ap.add_argument("--seconds", type=float, help="run each reader this long instead of --cases")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="fuzz-findings", help="folder for the findings' files")
    ap.add_argument("--json", help="write the summary here as JSON")
    args = ap.parse_args(argv)
    names = list(READERS) if args.reader == "all" else args.reader.split(",")
    summary = [fuzz(n, args.cases, args.seconds, args.seed, Path(args.out)) for n in names]
    for s in summary:
        sys.stdout.write(f"{s['reader']:10s} {s['cases']:6d} cases {s['seconds']:8.1f} s  {s['outcomes']}\n")
        for f in s["findings"][:5]:
            sys.stdout.write(f"  FINDING {f['result']}: {f.get('message', '')[:200]} ({f['file']})\n")
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2))
    return 1 if any(s["findings"] for s in summary) else 0


if __name__ == "__main__":
    sys.exit(main())
