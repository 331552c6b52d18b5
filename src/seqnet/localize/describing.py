"""The map's describer, rebuilt for query images: only one without fitted state of its own (a dataset's train-split
PCA of ``--pca D`` is applied after it), and no code a file names."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import ConfigError, SeqnetError
from ..core.log import logger
from ..core.provenance import check_same
from ..core.provenance import make as make_provenance
from ..methods.protocol import Reference

if TYPE_CHECKING:
    from ..describe.config import DescribeConfig
    from ..describe.describer import Describer
    from ..describe.images import ImageRef
    from ..describe.pca import PCA


def map_describer(ref_map: Reference, allow: bool, describer: str | None = None, map_dir: str | Path | None = None,
                  resize: tuple[int, int] | None = None
                  ) -> tuple[Describer | ReducedDescriber, Callable[[np.ndarray, str], None]]:
    """The describer the map was described with (rebuilt from its provenance; with the dataset's train-split PCA
    applied when it was built with ``--pca``: :func:`dataset_pca`) and ``check(descriptors [1, D], what)``, which
    holds the first query descriptors' D and provenance to the map's (a call after one that passed returns
    at once: a stream may call it on every frame). A plug-in describer the map's
    files name is imported only when the user names the same one (``describer``, ``--describer``): seqnet runs
    no code a file names. ``map_dir``: the ``--map`` given (a dataset directory or an index map). ``resize``
    (``--resize WxH``): the size of the map's reference images, when they were described at their own (native)
    size and the query images are another size: the query images are resized to it, their provenance is the map's."""
    from ..describe import DescribeConfig, make_describer

    prov = ref_map.provenance
    if not prov or prov.get("kind") != "describe":
        raise ConfigError("the map's descriptors do not record how they were described (no 'describe' provenance), "
                          "so query images cannot be described alike; describe them yourself and pass the "
                          "descriptor file as --query")
    derived = ("dim", "whiten", "describer_provenance", "pca_on")  # not options: the PCA's, a plug-in module's own
    settings = prov.get("settings") if isinstance(prov.get("settings"), dict) else {}
    check_named_code(settings, describer)
    conf = DescribeConfig.from_dict({k: v for k, v in settings.items() if k not in derived})
    pca_on = settings.get("pca_on")
    if conf.needs_fit or ("dim" in settings and pca_on is None):
        raise ConfigError(fitted_state_refusal(conf.method, settings.get("dim")))
    native = conf.resolved().size == "native"
    if resize is not None and not native:
        raise ConfigError(f"--resize {resize[0]}x{resize[1]}: the map's images were resized to {conf.resolved().size} "
                          "when described, and localize resizes the query images alike; drop --resize")
    d: Describer | ReducedDescriber = make_describer(conf if resize is None else dataclasses.replace(conf, size=resize))
    if pca_on is not None:
        check_reduced_once(map_dataset(ref_map, map_dir))
        d = ReducedDescriber(d, dataset_pca(ref_map, map_dir, prov),
                             size_hint(native, resize, prov.get("image_size")))
    checked: list[bool] = []

    def check(first: np.ndarray, what: str) -> None:
        if checked:  # one describer's outputs share their provenance: checked (or warned about) once
            return
        if isinstance(prov.get("dim"), int) and first.shape[1] != prov["dim"] and (native or resize):
            raise ConfigError(f"{what} have D={first.shape[1]}, the map's descriptors D={prov['dim']}: "
                              f"{size_hint(native, resize, prov.get('image_size'))}")
        check_same(prov, query_provenance(conf, d.pca, pca_on, prov, first, d.seen_size), "the map's descriptors",
                   what, allow)
        checked.append(True)

    return d, check


def check_query_dim(shape: tuple[int, ...], map_dim: int, what: str, route: str | None = None) -> None:
    """Refuse query descriptors of shape ``[N, D]`` whose D is not the map's ``map_dim``, one line naming both; a
    ``[D, N]`` array (its first axis is the map's D, as a transposed file has it) gets the converters' hint; a map
    whose descriptors a PCA reduced names its ``route`` (:func:`pca_route`)."""
    if len(shape) != 2 or shape[1] == map_dim:
        return
    hint = (f"; transposed? the array is [{shape[0]}, {shape[1]}]; seqnet expects [N, D] (one row per frame): save "
            "its transpose" if shape[0] == map_dim else f"; hint: {route}" if route else
            "; hint: describe the query frames as the map's reference was")
    raise ConfigError(f"dimension mismatch: query frame D={shape[1]}, map D={map_dim} ({what}){hint}")


def size_hint(native: bool, resize: tuple[int, int] | None, seen: object = None) -> str:
    """Why query images of a map described at the images' own size can give another D, and what to do; ``seen``:
    ``[W, H]`` of the map's images as described (its provenance's ``image_size``), named in the hint when known."""
    known = isinstance(seen, list | tuple) and len(seen) == 2 and all(type(v) is int and v > 0 for v in seen)
    fix = f"--resize {seen[0]}x{seen[1]}" if known else "--resize WxH, their width and height"
    if resize is not None:
        return (f"--resize {resize[0]}x{resize[1]} is not the size of the map's reference images (they were described "
                f"at their own size); hint: {fix}")
    return ("the map's reference images were described at their own size (native), and these images are another "
            f"size; hint: {fix}" if native else "")


class ReducedDescriber:
    """The map's describer ``inner`` followed by its dataset's train-split ``pca`` (``--pca D``): ``load`` and call
    as a :class:`~seqnet.describe.describer.Describer`. Raw descriptors of another D than the PCA reduces are
    refused (images of another size than a native-size map's, ``hint``; or a dataset reduced twice: ``seqnet train
    --pca`` on a ``--pca`` dataset)."""

    def __init__(self, inner: Describer, pca: PCA, hint: str = "") -> None:
        self.inner, self.pca, self.hint = inner, pca, hint

    @property
    def seen_size(self) -> tuple[int, int] | None:
        """``(W, H)`` of the images the describer last loaded."""
        return self.inner.seen_size

    def load(self, paths: list[ImageRef]) -> np.ndarray:
        """The images as ``inner`` reads them."""
        return self.inner.load(paths)

    def __call__(self, images: np.ndarray) -> np.ndarray:
        """``[B, dims]`` float32: ``inner``'s descriptors of ``images`` projected by ``pca`` (L2-normalised)."""
        raw = self.inner(images)
        if raw.shape[1] != self.pca.input_dim:
            twice = ("its dataset was reduced from an already reduced one (localize applies one PCA: build the map "
                     "from a dataset reduced once, --pca D on the unreduced dataset)")
            raise ConfigError(f"the map's PCA reduces {self.pca.input_dim}-D descriptors, but its describer "
                              f"({self.inner.method}) makes {raw.shape[1]}-D ones of these images: "
                              + (f"{self.hint}; or {twice}" if self.hint else twice))
        return self.pca.transform(raw)


def fitted_state_refusal(method: str, dim: object) -> str:
    """The refusal of a map described with fitted state of its own (``--dim``, NetVLAD clusters), with the command
    that describes query images alike: ``seqnet describe`` refits the same state on the same images."""
    state = f"--dim {dim}" if isinstance(dim, int) else "its fitted clusters"
    return (f"the map was described with fitted state ({method}, {state}), which localize cannot rebuild from the "
            f"map; describe the query images as the reference was: seqnet describe IMAGES --method {method}"
            f"{f' --dim {dim}' if isinstance(dim, int) else ''} --fit-on REFERENCE_IMAGES (the images its state was "
            "fitted on; the reference's other describe options) --out FRAMES.npy, then --query FRAMES.npy "
            "(or build the dataset with --pca D, whose PCA localize applies)")


def map_dataset(ref_map: Reference, map_dir: str | Path | None) -> str | Path | None:
    """The dataset directory a map was built from (an index map's ``map.json`` names it), else ``map_dir`` (the
    ``--map`` given: a dataset directory)."""
    meta = getattr(ref_map, "meta", None)
    source = meta.get("source") if isinstance(meta, dict) and isinstance(meta.get("source"), dict) else {}
    return source.get("dataset_path") if isinstance(source.get("dataset_path"), str) else map_dir


def check_reduced_once(dataset: str | Path | None) -> None:
    """Refuse to describe query images for a map whose dataset was reduced twice (``seqnet train --pca`` on a dataset
    already reduced by ``--pca``: its ``extra["pca"]["input_pca"]``, or, recorded before that, the ``<DIR>`` of a
    ``<DIR>-pca<D>`` that its PCA reduced, holding a PCA of its own): localize applies one PCA, the last, to what the
    describer makes, which is the first PCA's input."""
    from ..describe.pca import pca_record, reduced_from, unreduced_source

    here = pca_record(Path(dataset)) if dataset is not None else None
    if here is None or here[0] is None:
        return
    pca = here[0]
    before = pca.get("input_pca")
    if not isinstance(before, dict):
        found = reduced_from(Path(dataset), pca)
        before = found[1][0] if found is not None else None
    if not isinstance(before, dict):
        return
    dims, source = pca.get("dims"), unreduced_source(dataset)
    unreduced = f"seqnet train --dataset {source} --pca {dims} (its unreduced descriptors)" if source else \
        f"seqnet dataset from-images --pca {dims}, or seqnet train --pca {dims} on a dataset built without --pca"
    raise ConfigError(f"the map's descriptors were reduced twice ({before.get('input_dim')}-D to "
                      f"{pca.get('input_dim')}-D to {dims}-D: its dataset {Path(dataset).name} was made by --pca "
                      f"{dims} on an already reduced dataset), and localize applies one PCA, the last, to the "
                      f"describer's {before.get('input_dim')}-D descriptors, so it cannot describe query images; "
                      f"hint: build the map from a dataset reduced once: {unreduced}")


def dataset_pca(ref_map: Reference, map_dir: str | Path | None, prov: dict) -> PCA:
    """The train-split PCA (``--pca D``) that reduced the map's descriptors: an index map's own copy (``pca.npz``,
    :attr:`seqnet.maps.Map.pca_file`), else ``<DATASET>.pca.npz`` beside the dataset directory given as ``--map`` or
    (a map built before maps held it) beside the dataset the map was built from; checked to be that PCA (its tag
    and D: :func:`seqnet.describe.pca.load_dataset_pca`)."""
    from ..describe.pca import dataset_pca_path, load_dataset_pca

    own = getattr(ref_map, "pca_file", None)
    if own is not None:
        return load_dataset_pca(own, prov)
    meta = getattr(ref_map, "meta", None)  # an index map: map.json names the dataset it was built from
    dataset = map_dataset(ref_map, map_dir)
    if dataset is None:
        raise ConfigError("the map's descriptors were reduced by a dataset's PCA (--pca), but the map names no "
                          "dataset to read it from; describe the query images yourself and pass the file as --query")
    source = meta.get("source") if isinstance(meta, dict) and isinstance(meta.get("source"), dict) else None
    missing = dataset_pca_path(dataset)
    if source is not None and source.get("pca_not_copied"):  # this map tried: the file was missing or foreign
        logger.warning("map %s holds no copy of its dataset's PCA: %s.pca.npz was missing or not that PCA when the "
                       "map was built; reading it beside the dataset again, %s (hint: put the dataset's own "
                       "%s back and rebuild the map to carry it, or give --query a descriptor file described as "
                       "the map's)", getattr(ref_map, "path", map_dir), Path(dataset).name, missing, missing.name)
    elif source is not None:
        logger.info("map %s holds no copy of its dataset's PCA (built before seqnet index build copied it): reading "
                    "it beside the dataset it was built from, %s (rebuild the map to carry it)",
                    getattr(ref_map, "path", map_dir), dataset)
    return load_dataset_pca(missing, prov)


def query_provenance(conf: DescribeConfig, pca: PCA | None, pca_on: str | None, prov: dict,
                     out: np.ndarray, image_size: tuple[int, int] | None = None) -> dict:
    """The provenance of query descriptors ``out [N, D]`` described by ``conf`` (and reduced by the map's ``pca``
    fitted on the split ``pca_on``, recorded as :func:`seqnet.pipelines.pca.reduce_dataset` records it: the
    describer's settings with ``dim`` and ``pca_on``, the map's fit hash), from images of ``image_size`` (W, H)."""
    from ..describe.stage import describe_provenance

    if pca is None:
        return describe_provenance(conf, None, out, image_size)
    raw = describe_provenance(conf, None, np.empty((0, pca.input_dim), np.float32))
    return make_provenance(raw["kind"], {**raw["settings"], "dim": pca.dims, "pca_on": pca_on}, dim=int(out.shape[1]),
                           fit=prov.get("fit_images"), image_size=image_size)


def check_named_code(settings: Mapping[str, object], describer: str | None) -> None:
    """Refuse to rebuild a describer that would run code or read a file named in the map's files: a plug-in
    module (unless the user names the same one with ``--describer``) or a NetVLAD checkpoint."""
    named = settings.get("describer")
    if named and named != describer:
        raise ConfigError(f"the map's descriptors were made by the plug-in describer {str(named)[:80]!r}, named in the "
                          "map's files; seqnet imports no code a file names: pass --describer "
                          f"{str(named)[:80]} if you trust that module")
    if settings.get("checkpoint"):
        raise ConfigError("the map was described with a checkpoint named in its files, which localize does not open; "
                          "describe the query images with `seqnet describe` and that checkpoint, and pass the "
                          "descriptor file as --query")


def query_file_provenance(path: Path) -> dict | None:
    """The provenance of a query descriptor file: its sidecar (:func:`seqnet.data.readers.read_provenance`), else,
    for a traverse's descriptors inside a seqnet dataset (``DS/query/descriptors.npy``), the provenance its
    ``dataset.json`` records for that traverse; None when neither says."""
    from ..data.readers import read_provenance
    from ..data.traverse import DESCRIPTOR_FILES
    from ..security.jsonfile import read_json_object

    prov = read_provenance(path)
    meta_path = path.parent.parent / "dataset.json"
    if prov or path.name not in DESCRIPTOR_FILES or not meta_path.is_file():  # another file there is not the
        return prov  # traverse's descriptors: its provenance stays its own
    try:
        meta = read_json_object(meta_path, "dataset.json")
    except SeqnetError:
        return None
    folders = meta.get("traverses") if isinstance(meta.get("traverses"), dict) else {}
    side = next((s for s in ("reference", "query") if folders.get(s, s) == path.parent.name), None)
    recorded = (meta.get("provenance") or {}).get(side) if isinstance(meta.get("provenance"), dict) else None
    return recorded if isinstance(recorded, dict) else None


def check_not_dataset(path: Path) -> None:
    """Refuse a seqnet dataset folder given as query images (it holds descriptors, no images), naming what to give."""
    if path.is_dir() and (path / "dataset.json").is_file():
        raise ConfigError(f"--query {path} is a seqnet dataset (it holds descriptors, not images): give its query "
                          f"descriptors (--query {path / 'query' / 'descriptors.npy'}), or replay it with seqnet "
                          f"localize --dataset {path}")


def pca_route(ref_map: Reference, map_dir: str | Path | None) -> str | None:
    """For a map whose descriptors its dataset's train-split PCA reduced (``--pca D``), what a query descriptor file
    cannot follow and what works: ``seqnet describe`` does not apply that PCA, ``--query IMAGES`` does (localize
    describes them as the map's reference was and reduces them); None for any other map."""
    from ..describe.pca import dataset_pca_path

    prov = ref_map.provenance or {}
    settings = prov.get("settings") if isinstance(prov.get("settings"), dict) else {}
    if prov.get("kind") != "describe" or settings.get("pca_on") is None:
        return None
    where = getattr(ref_map, "pca_file", None)
    if where is None and map_dataset(ref_map, map_dir) is not None:
        where = dataset_pca_path(map_dataset(ref_map, map_dir))
    try:
        raw = f"{dataset_pca(ref_map, map_dir, prov).input_dim}-D "
    except (SeqnetError, OSError, ValueError):
        raw = ""
    return (f"the map's descriptors are {raw}{settings.get('method', 'image')} descriptors reduced to "
            f"{prov.get('dim', settings.get('dim'))}-D by its dataset's train-split PCA"
            f"{f' ({where})' if where else ''}, which seqnet describe does not apply: give the query images instead, "
            "--query IMAGES (a folder, a list file, a video), which localize describes as the map's reference was "
            "and reduces with that PCA")


def check_known_file(prov: dict | None, route: str | None, what: str, allow: bool) -> None:
    """Refuse query descriptors of unknown making (``prov`` None: no sidecar) against a map whose descriptors a PCA
    reduced (``route``: :func:`pca_route`): of the map's D, they pass the D check alone, and descriptors not
    reduced by that very PCA localise at chance; ``allow`` (``--allow-mismatch``): a warning, and on."""
    if prov or route is None:
        return
    said = (f"{what} record no provenance (no <stem>.provenance.json beside them), and {route}; descriptors of the "
            "map's D made otherwise localise at chance")
    if allow:
        logger.warning("%s; going on as asked (--allow-mismatch): only D is checked", said)
        return
    raise ConfigError(f"{said}; or, if they were reduced by that very PCA, pass --allow-mismatch")
