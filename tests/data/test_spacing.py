"""How positions advance (seqnet.data.spacing): rows out of route order, different sampling rates and positions
in degrees are each one warning line; a route in order, sampled alike, in metres, is not."""

from __future__ import annotations

import numpy as np

from seqnet.data.spacing import looks_like_degrees, out_of_order, spacing, step_rates, steps


def route(n: int, step: float = 1.0) -> np.ndarray:
    """``[n, 2]`` positions along a gently curving road, ``step`` apart."""
    t = np.arange(n) * step
    return np.stack([t, 30 * np.sin(t / 200)], axis=1)


def test_steps_and_spacing_vs_a_loop(rng):
    pos = rng.random((50, 2)) * 100
    bounds = np.repeat([[0, 20], [20, 50]], [20, 30], axis=0)
    naive = [np.linalg.norm(pos[i + 1] - pos[i]) for i in range(49) if i + 1 < bounds[i, 1]]
    np.testing.assert_allclose(steps(pos, bounds), naive)
    nearest = [min(np.linalg.norm(pos[j] - pos[i]) for j in range(50) if j != i) for i in range(50)]
    assert spacing(pos, samples=50) == np.median(nearest)
    assert len(steps(pos[:1])) == 0 and spacing(pos[:1]) == 0.0


def test_shuffled_rows_are_warned(rng):
    pos = route(400, 2.0)
    assert out_of_order(pos, None, 5.0, "metres", "query") is None
    said = out_of_order(pos[rng.permutation(400)], None, 5.0, "metres", "query")
    assert said is not None and "may not be in route order" in said and "of the query's consecutive" in said
    frames = np.arange(300, dtype=float)[:, None]
    assert "median step" in out_of_order(frames[rng.permutation(300)], None, 1.0, "frames", "query")


def test_sequences_far_apart_or_sparse_sampling_are_not_warned():
    two = np.concatenate([route(100), route(100) + 5000])  # two sequences, one jump between them
    assert out_of_order(two, np.repeat([[0, 100], [100, 200]], 100, axis=0), 5.0, "metres", "q") is None
    assert out_of_order(route(100, 50.0), None, 5.0, "metres", "q") is None  # sparse, but in order
    still = np.zeros((100, 2))  # a vehicle standing still
    assert out_of_order(still, None, 5.0, "metres", "q") is None


def test_different_sampling_rates_are_warned():
    said = step_rates(route(300, 10.0), None, route(150, 20.0), None, "metres")
    assert "ratio 0.5" in said and "raw+vseqmatch" in said and "--resample-every 2 --resample-side query" in said
    said = step_rates(route(100, 30.0), None, route(300, 10.0), None, "metres")
    assert "--resample-every 3 --resample-side reference" in said
    assert step_rates(route(300, 10.0), None, route(300, 12.0), None, "metres") is None
    assert step_rates(np.zeros((9, 2)), None, route(300, 12.0), None, "metres") is None


def test_degrees_are_told_from_metres():
    lat = 63 + np.arange(300) * 9e-5
    assert looks_like_degrees(np.stack([np.full(300, 10.0), lat], axis=1))
    assert not looks_like_degrees(np.stack([540000 + np.arange(300.0), 7e6 + np.zeros(300)], axis=1))  # UTM
    assert not looks_like_degrees(np.zeros((5, 2)))  # constant, whole numbers: no sign of degrees
    assert not looks_like_degrees(np.arange(5.0)[:, None])  # frames
    assert not looks_like_degrees(np.stack([np.full(9, 10.5), np.linspace(60, 62, 9)], axis=1))  # spans 2
