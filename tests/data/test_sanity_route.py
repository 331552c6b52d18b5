"""Route checks of a dataset (seqnet.data.sanity.route): a vehicle standing still over a large share of a split, a
jump inside one sequence and a radius below the reference's frame spacing are one warning line each, at build /
check (dataset_warnings) and per evaluated split (route_warnings); clean routes, station stops and the synthetic
dataset are silent."""

from __future__ import annotations

import numpy as np

from seqnet.data.sanity import dataset_warnings
from seqnet.data.sanity.route import jumps, route_checks, standstills
from seqnet.data.traverse import Dataset, Traverse
from seqnet.methods.route import route_warnings
from seqnet.metrics.recall import GroundTruth

METHODS = ["single", "raw+seqmatch"]


def place(i: np.ndarray) -> np.ndarray:
    """``[N, 2]`` the position of place ``i`` (fractional: between places) on the report's route: 10 m per place."""
    i = np.asarray(i, np.float64)
    return np.stack([500000 + 10.0 * i, 7000000 + 30 * np.sin(i / 40)], axis=1)


def dataset(q_pos: np.ndarray, r_pos: np.ndarray, radius: float = 12.0, splits=None, q_bounds=None,
            r_bounds=None) -> Dataset:
    rng = np.random.default_rng(0)
    return Dataset(Traverse(rng.random((len(r_pos), 8), dtype=np.float32), r_pos, seq_bounds=r_bounds,
                            name="reference"),
                   Traverse(rng.random((len(q_pos), 8), dtype=np.float32), q_pos, seq_bounds=q_bounds, name="query"),
                   radius, name="d", splits=splits or {})


def noisy(pos: np.ndarray, sd: float = 1.0, seed: int = 0) -> np.ndarray:
    return pos + np.random.default_rng(seed).normal(0, sd, pos.shape)


def standing_query(seed: int = 4) -> np.ndarray:
    """The report's H2 query: places 0..199 with 1 m GPS noise, 80 rows at place 150 (GPS jitter 0.8 m)."""
    rng = np.random.default_rng(seed)
    idx = np.r_[np.arange(151), np.full(79, 150), np.arange(151, 200)]
    jitter = np.r_[np.zeros(151), np.ones(79), np.zeros(49)][:, None] * rng.normal(0, 0.8, (279, 2))
    return noisy(place(idx), 1.0, seed) + jitter


def station_stop(stop: int, n: int = 300, ramp: int = 5, at: int = 150, sd: float = 1.0) -> np.ndarray:
    """``[n, 2]`` a train at 10 m per frame that slows over ``ramp`` frames, stands ``stop`` frames at ``at`` and
    speeds up again, with GPS noise ``sd``."""
    v = np.ones(n)
    v[at - ramp:at] = np.linspace(1, 0, ramp + 1)[1:]
    v[at:at + stop] = 0
    v[at + stop:at + stop + ramp] = np.linspace(0, 1, ramp + 1)[1:]
    return noisy(place(np.cumsum(v)), sd)


def naive_standstills(pos: np.ndarray, step: float, window: int = 10) -> list[list[int]]:
    still = np.zeros(len(pos), bool)
    for i in range(len(pos) - window):
        if np.linalg.norm(pos[i + window] - pos[i]) < step:
            still[i:i + window + 1] = True
    out, i = [], 0
    while i < len(pos):
        if still[i]:
            j = i
            while j < len(pos) and still[j]:
                j += 1
            out.append([i, j])
            i = j
        else:
            i += 1
    return out


def test_standstills_and_jumps_vs_a_loop():
    rng = np.random.default_rng(1)
    for _ in range(20):
        pos = np.cumsum(rng.choice([0.0, 0.05, 1.0, 30.0], size=(120, 2), p=[0.3, 0.3, 0.35, 0.05]), axis=0)
        assert standstills(pos, None, 1.0).tolist() == naive_standstills(pos, 1.0)
        d = np.linalg.norm(np.diff(pos, axis=0), axis=1)
        far = [i for i in range(119) if d[i] > 10 and (i == 0 or np.linalg.norm(pos[i + 1] - pos[i - 1]) > 10)
               and (i == 118 or np.linalg.norm(pos[i + 2] - pos[i]) > 10)]
        assert jumps(pos, None, 1.0).tolist() == far


def test_a_standing_query_is_said_with_its_share_of_each_split():
    """The report's H2: 80 query rows at one place, 45% of the test split's queries: one line at build / check,
    and at evaluation of the split (rows numbered in the split)."""
    ds = dataset(standing_query(), place(np.arange(300)), splits={"test": {"query": (100, 279)}})
    [line] = dataset_warnings(ds)
    assert line.startswith("d: 80 consecutive query rows (150:230) lie within ") and "the vehicle stood still" in line
    assert "they are 45% of split test's queries" in line and "constant-speed assumption of SeqMatch" in line
    assert "(hint: drop those rows but one, or thin the frames by distance travelled)" in line
    test = ds.split("test")
    truth = GroundTruth(test.query.positions, test.reference.positions, 12.0)
    [said] = route_warnings(test, truth, np.arange(179), ["single"])  # a single-image method: its R@1 is skewed too
    assert said.startswith("80 consecutive query rows (50:130 of d[test])") and "45% of d[test]'s query rows" in said


def test_a_video_sampled_by_time_is_told_every_metres():
    ds = dataset(standing_query(), place(np.arange(300)))
    ds.extra["sampling"] = {"fps": 1.0, "every_metres": None}
    [line] = route_checks(ds)
    assert "29% of the query's rows" in line and line.endswith("or sample the videos by distance travelled: "
                                                              "from-video --every-metres M)")


def test_station_stops_clean_routes_and_synthetic_data_are_silent(synth_dataset):
    r = place(np.arange(300))
    assert dataset_warnings(dataset(noisy(r), r)) == []  # Nordland-like spacing, 1 m GPS noise
    for stop in (5, 8, 10):  # a train slowing at a station over 5 frames, standing 5-10: a few % of the route
        assert route_checks(dataset(station_stop(stop), r)) == [], stop
    assert route_checks(dataset(station_stop(80), r))  # standing 80 frames of 300: said
    assert route_checks(synth_dataset) == [] and route_checks(synth_dataset, sequence=False) == []


def test_a_frozen_fix_is_said_once_as_frozen():
    """Rows at exactly one position while the images change: the frozen-GPS line, not a second standstill line."""
    q = noisy(place(np.arange(200)))
    q[100:160] = q[100]
    ds = dataset(q, place(np.arange(200)))
    [line] = dataset_warnings(ds)
    assert "a frozen GPS fix?" in line


def test_a_gap_inside_one_sequence_is_said_where_and_how_far():
    """The report's M4: 60 reference frames dropped (a tunnel) inside one sequence: one line naming the frames, the
    jump in metres and in usual steps, and the sequence-column hint; split there, it is silent."""
    keep = np.r_[np.arange(100), np.arange(160, 300)]
    q = noisy(place(np.arange(300)))
    [line] = dataset_warnings(dataset(q, place(keep)))
    assert line.startswith("d: the reference's positions jump 611.4 metres (61× its usual step of 10 metres) between "
                           "frames 99 and 100 inside one sequence: a tunnel, a logger outage or dropped frames?")
    assert "split the sequence there, e.g. a sequence column in the reference's positions CSV with a new value from " \
           "frame 100" in line
    bounds = np.repeat([[0, 100], [100, 240]], [100, 140], axis=0)
    assert dataset_warnings(dataset(q, place(keep), r_bounds=bounds)) == []
    gapped, truth = dataset(place(keep), r := place(np.arange(300))), GroundTruth(place(keep), r, 12.0)
    [said] = route_warnings(gapped, truth, np.arange(240), METHODS)  # the query's gap, at evaluation
    assert said.startswith("the query's positions jump 611.4 metres") and "frames 99 and 100 of d inside" in said
    assert route_warnings(gapped, truth, np.arange(240), ["single"]) == []  # no window to straddle it


def test_a_stray_position_and_sparse_rows_in_order_are_no_gap():
    r = place(np.arange(300))
    stray = noisy(r)
    stray[50] += [0.0, 500.0]  # one wrong fix: away and back, not a gap to split at
    assert route_checks(dataset(stray, r)) == []
    assert route_checks(dataset(noisy(place(np.arange(0, 300, 3))), r)) == []  # every 3rd place: even steps


def test_a_radius_below_the_reference_spacing_is_said():
    """The report's M3: reference every 10 m, queries 4.5 m along: radius 5 (at most half the spacing) and 8 (below
    it) are said, with the usual radius; 10 and 12 m, frame radii of one frame and explicit positives are not."""
    r, q = place(np.arange(300)), noisy(place(np.arange(300) + 0.45), seed=3)
    [line] = dataset_warnings(dataset(q, r, radius=5.0))
    assert line == ("d: the radius 5 metres is at most half the reference's frame spacing (10 metres between "
                    "neighbouring frames, median): each query has at most one correct reference, and one between two "
                    "reference frames may have none (hint: a radius of at least the spacing is usual, e.g. --radius 10 "
                    "or more)")
    [line] = route_checks(dataset(q, r, radius=8.0))
    assert line.startswith("the radius 8 metres is below the reference's frame spacing (10 metres")
    assert "may have none" not in line
    for radius in (10.0, 12.0):
        assert route_checks(dataset(q, r, radius=radius)) == []
    frames = np.arange(300.0)[:, None]
    ones = np.ones((300, 2), np.float32)
    assert route_checks(Dataset(Traverse(ones, frames), Traverse(ones, frames), 1.0, "frames")) == []
    ds = dataset(q, r, radius=12.0)  # built at 12 m, evaluated at 4 m: said for the radius evaluated
    [said] = route_warnings(ds, GroundTruth(q, r, 4.0), np.arange(300), ["single"])
    assert said.startswith("the radius 4 metres is at most half the reference's frame spacing")


def unpadded_order(n: int) -> np.ndarray:
    """The places ``0 .. n-1`` in the order of their names ``@<10 i>@...`` sorted as text (unpadded local metres,
    VPR-methods-evaluation's sorted glob): 0, 1000, 100, 1010, ... (the report's M2)."""
    return np.asarray(sorted(range(n), key=lambda i: f"@{10 * i}@0@33@V@x.png"))


def naive_crossing(pos: np.ndarray, long: float = 3.0, across: float = 0.25) -> list[int]:
    """The steps ``i → i+1`` longer than ``long`` times the 75th-percentile step with another frame within ``across``
    of their length from their middle, by a loop."""
    d = [float(np.linalg.norm(pos[i + 1] - pos[i])) for i in range(len(pos) - 1)]
    usual = float(np.percentile(d, 75))
    return [i for i in range(len(pos) - 1) if d[i] > long * usual and
            min(np.linalg.norm(p - (pos[i] + pos[i + 1]) / 2) for p in pos) < across * d[i]]


def test_rows_sorted_by_unpadded_names_are_said_as_an_order_not_a_tunnel():
    """The report's M2: 40 of the 199 steps jump, and the one line named the largest as a tunnel, with a hint
    (split the sequence there) that fixes nothing; now one line of the one order detector, counted as a loop."""
    from seqnet.data.spacing import crossing_steps

    order = unpadded_order(200)
    pos = place(order)
    at, n, step = crossing_steps(pos, None)
    assert list(at) == naive_crossing(pos) and len(at) == 40 and n == 199 and round(step) == 10
    ds = dataset(pos, pos)
    ds.query.names = ds.reference.names = [f"@{10 * i}@0@33@V@x{i}.png" for i in order]
    lines = [line for line in dataset_warnings(ds) if "steps" in line]
    assert len(lines) == 2 and not any("a tunnel, a logger outage" in line for line in lines)
    assert lines[0].startswith("d: 40 of the 199 steps between consecutive query frames pass over other frames of "
                               "the route (longer than 3 usual steps of 10 metres")
    assert "its rows are not in route order" in lines[0] and "names that sort in route order" in lines[0]
    said = route_warnings(ds, GroundTruth(pos, pos, 12.0), np.arange(200), METHODS)
    assert sum("not in route order" in line for line in said) == 2 and not any("tunnel" in line for line in said)


def drive(speeds: np.ndarray, sd: float = 0.0) -> np.ndarray:
    """``[N, 2]`` a drive in order, one frame a second at ``speeds [N]`` metres per second, with GPS noise ``sd``."""
    return noisy(place(np.cumsum(speeds) / 10.0), sd) if sd else place(np.cumsum(speeds) / 10.0)


def test_correct_drives_that_change_speed_stop_or_cross_a_tunnel_are_not_out_of_order():
    """The review's M1: a drive in order with a 60-frame highway stretch at 3.5x its town speed (and a tunnel) was
    said 'the rows are likely not in route order' (61 long steps), and the tunnel line was dropped."""
    town, fast = np.full(600, 10.0), np.r_[np.full(300, 10.0), np.full(60, 35.0), np.full(240, 10.0)]
    tunnel = fast.copy()
    tunnel[450] = 400.0
    ds = dataset(drive(tunnel), place(np.arange(3000)))
    [line] = [line for line in route_checks(ds) if "jump" in line]
    assert line.startswith("the query's positions jump 401 metres (40× its usual step") and "a tunnel" in line
    from seqnet.data.spacing import crossing_steps, out_of_order

    stops = np.r_[np.full(200, 10.0), np.zeros(40), np.full(200, 10.0), np.full(80, 30.0), np.zeros(30), town[:50]]
    for speeds in (fast, tunnel, stops, np.r_[town[:200], np.linspace(10, 40, 100), np.full(200, 40.0)]):
        for pos in (drive(speeds), drive(speeds, 1.0)):
            assert len(crossing_steps(pos, None)[0]) == 0
            assert out_of_order(pos, None, 12.0, "metres", "query") is None


def grid(i: np.ndarray) -> np.ndarray:
    """``[N, 2]`` frames exactly 10 m apart on a straight diagonal route, stored to the millimetre (as a CSV)."""
    i = np.asarray(i, np.float64)[:, None]
    return np.round([500000.0, 7000000.0] + 10.0 * i * [np.cos(0.5), np.sin(0.5)], 3)


def test_a_radius_at_the_frame_spacing_is_said_when_rounding_decides_the_positives():
    """Hunt 6 F4: frames exactly 10 m apart, queries on the reference's frames: radius 9.99 / 10 / 10.01 gave 1 /
    1-3 / 3 positives per query (single R@1 0.216 / 0.231 / 0.261 in the report) and nothing said; now one line
    at build, check and eval, with a radius between multiples of the spacing as the hint (twice the spacing too);
    15 m, 1 m GPS noise, queries between frames and frame radii stay silent."""
    r = grid(np.arange(300))
    q = r[20:200]
    positives = {rad: set(np.bincount(GroundTruth(q, r, rad).pairs()[0]).tolist()) for rad in (9.99, 10.0, 10.01)}
    assert positives[9.99] == {1} and positives[10.01] == {3} and len(positives[10.0]) > 1  # by the millimetre
    for rad in (9.99, 10.0, 10.01):
        [line] = dataset_warnings(dataset(q, r, radius=rad))
        assert line == (f"d: the radius {rad:g} metres matches the reference's frame spacing (10 metres between "
                        f"neighbouring frames, median) and 100% of the queries have a reference at the radius itself "
                        f"({rad - 0.1:.4g}..{rad + 0.1:.4g} metres away): whether it is a positive hangs on the "
                        "positions' rounding (1 to 3 positives per query across that band; hint: a radius between "
                        "whole multiples of the spacing, e.g. --radius 15)")
    [line] = route_checks(dataset(q, r, radius=20.0))
    assert "matches twice the reference's frame spacing" in line and line.endswith("e.g. --radius 25)")
    [said] = route_warnings(dataset(q, r, radius=15.0), GroundTruth(q, r, 10.0), np.arange(len(q)), ["single"])
    assert said.startswith("the radius 10 metres matches the reference's frame spacing")  # the radius evaluated
    for rad in (12.0, 15.0, 30.5):
        assert route_checks(dataset(q, r, radius=rad)) == [], rad
    for seed in range(5):  # 1 m GPS noise on both sides: 8-15% of the queries at the radius, by chance
        for rad in (10.0, 20.0):
            assert route_checks(dataset(noisy(q, 1.0, seed), noisy(r, 1.0, seed + 50), radius=rad)) == [], (seed, rad)
    assert route_checks(dataset(grid(np.arange(20, 200) + 0.45), r, radius=10.0)) == []  # between frames
    frames = np.arange(300.0)[:, None]
    ones = np.ones((300, 2), np.float32)
    assert route_checks(Dataset(Traverse(ones, frames), Traverse(ones, frames), 1.0, "frames")) == []
