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
