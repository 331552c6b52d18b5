"""The query descriptors' D held to the map's: a transposed ``[D, N]`` file is named as such."""

from __future__ import annotations

import pytest

from seqnet.core.errors import ConfigError
from seqnet.localize.describing import check_query_dim


def test_a_transposed_query_file_gets_the_converters_hint():
    with pytest.raises(ConfigError) as e:
        check_query_dim((2048, 200), 2048, "the query descriptors q.npy")
    assert str(e.value) == ("dimension mismatch: query frame D=200, map D=2048 (the query descriptors q.npy); "
                            "transposed? the array is [2048, 200]; seqnet expects [N, D] (one row per frame): save "
                            "its transpose")


def test_another_dimension_is_refused_without_the_transposed_hint():
    with pytest.raises(ConfigError, match=r"query frame D=64, map D=2048 \(q.npy\); hint: describe") as e:
        check_query_dim((200, 64), 2048, "q.npy")
    assert "transposed" not in str(e.value)
    check_query_dim((200, 2048), 2048, "q.npy")  # the map's D: accepted


def test_a_datasets_own_descriptors_carry_its_provenance_into_localize(synth_dataset, tmp_path):
    """--query DS/query/descriptors.npy of another dataset: the provenance its dataset.json records is checked (it
    was 'unknown', and the run went on); --query DS (a dataset folder) names what to give."""
    import dataclasses

    import pytest

    from seqnet.core.errors import ConfigError
    from seqnet.core.provenance import make
    from seqnet.data.io import save_dataset
    from seqnet.localize.config import LocalizeConfig
    from seqnet.localize.stream import Query, stream

    ours = save_dataset(synth_dataset, tmp_path / "ours")
    prov = make("synthetic", {"seed": 2}, dim=16)
    other = dataclasses.replace(synth_dataset, query=dataclasses.replace(synth_dataset.query, provenance=prov))
    theirs = save_dataset(other, tmp_path / "theirs")
    conf = LocalizeConfig(method="single")
    with pytest.raises(ConfigError, match="made differently"):
        stream(conf, ours, Query(theirs / "query" / "descriptors.npy"), tmp_path / "t.csv")
    with pytest.raises(ConfigError, match="is a seqnet dataset .* localize --dataset"):
        stream(conf, ours, Query(theirs), tmp_path / "t.csv")
    stream(conf, ours, Query(ours / "query" / "descriptors.npy"), tmp_path / "ok.csv")  # its own: accepted
    import numpy as np

    from seqnet.localize.describing import query_file_provenance

    np.save(theirs / "query" / "mine.npy", np.load(theirs / "query" / "descriptors.npy"))  # a user's other file
    assert query_file_provenance(theirs / "query" / "mine.npy") is None  # not the traverse's: not its record
