"""The report's sections beside the results table (:mod:`seqnet.report.notes`): the ``--extra-radius`` results."""

from __future__ import annotations

from seqnet.report.notes import choices_section, radii_section, warnings_section


def _results(r1: dict[str, float], queries: int = 100) -> dict:
    methods = {n: {"recall@1": v, "recall@5": v, "queries": queries} for n, v in r1.items()}
    return {"methods": methods, "config": {"seq_len": 5, "radius": 1.0}}


def test_the_report_has_the_extra_radius_results():
    res = _results({"single": 0.5, "delta": 0.6})
    assert radii_section(res) == []
    res["config"].update(extra_radii=[3.0, 10.0], ks=[1, 5])
    for i, entry in enumerate(res["methods"].values()):
        entry["radii"] = {"3.0": {"recall@1": 0.61 + i / 10, "recall@5": 0.7},
                          "10.0": {"recall@1": 0.9, "recall@5": 1.0}}
    (section,) = radii_section(res)
    assert section.id == "radii" and "at other localisation radii (--extra-radius) than the results' 1.</p>" in \
        section.body
    assert "<th>method</th><th>radius</th><th>R@1</th><th>R@5</th>" in section.body
    assert "<tr><td>single</td><td>3</td><td>0.610</td><td>0.700</td></tr>" in section.body
    assert "<tr><td>delta</td><td>10</td><td>0.900</td><td>1.000</td></tr>" in section.body
    res["config"]["ground_truth"] = "explicit positives"
    assert "within each radius of one of the query's positives" in radii_section(res)[0].body


def test_a_selection_warning_is_said_once():
    """Session 54: 'HVPR settings chosen on 36 val queries ...' stood both under Warnings (the results' warnings) and
    under Chosen on val (the selection's warning), two sections apart on one screen; said once, in Warnings."""
    said = "HVPR settings chosen on 36 val queries (1 query = 0.03 of R@1): the choice is mostly chance"
    res = _results({"hvpr": 0.9})
    res["selection"] = {"hvpr": [{"method": "hvpr", "reason": "hvpr: K 20 chosen on the val split"}], "warning": said}
    (choices,) = choices_section(res)
    assert said in choices.body  # not in the warnings: said here
    res["warnings"] = [said]
    (warned,), (choices,) = warnings_section(res), choices_section(res)
    assert said in warned.body and said not in choices.body and "K 20 chosen" in choices.body


def test_the_summary_says_the_ground_truth_in_the_datasets_unit():
    """Session 54, a frame-aligned dataset from 300 Nordland64 images: the Summary read 'radius 1.0', no unit and
    no word of what is correct; now the row names the frame alignment and the radius in frames."""
    from types import SimpleNamespace

    import numpy as np

    from seqnet.report.html import ReportConfig, summary_section

    res = {"methods": {"single": {"queries": 60}}, "config": {"dataset": "ds[test]", "radius": 1.0,
                                                              "ground_truth": "radius"}}
    ev = SimpleNamespace(results=res, r_items=np.arange(3))
    aligned = SimpleNamespace(position_unit="frames", extra={"ground_truth": "frames"})
    body = summary_section(ev, ReportConfig(), aligned).body
    assert ("<td>ground truth</td><td>frame-aligned (query frame i shows the place of reference frame i): a "
            "reference within 1 frame of it is correct</td>") in body, body
    metres = SimpleNamespace(position_unit="metres", extra={})
    res["config"]["radius"] = 25.0
    assert "<td>radius</td><td>25 metres: a reference at most this far from the query&#x27;s position is correct" \
        in summary_section(ev, ReportConfig(), metres).body
    assert "<td>radius</td><td>25</td>" in summary_section(ev, ReportConfig()).body  # no dataset: no unit known
    res["config"]["ground_truth"] = "explicit positives"
    assert "<td>ground truth</td><td>explicit positives</td>" in summary_section(ev, ReportConfig(), metres).body
