"""The robustness benchmark's tables by kind of scene, and the issue's coverage scope, on hand-made rows
(no runs: every number below is counted by hand)."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from dynslam_lab.experiments.robustness import (_derived, _sequence_labels, by_kind, robustness_markdown, robustness_plot,
                                               scene_kind)


def _rows() -> pd.DataFrame:
    base = {"detector": "none", "precision": 0.8, "recall": 0.7, "precision_at_rest_ok": 0.9, "lost": 0, "loops": 0,
            "keyframes": 5, "ms_per_frame": 50.0, "screen_ms": 20.0, "coverage_mean": 0.2}
    runs = [  # sequence, room, camera, movers' largest image share, ATE (m)
        ("a", "flat", "xyz", 0.30, 0.200),
        ("b", "flat", "rpy", 0.50, 0.010),
        ("c", "noise", "xyz", 0.20, 0.004),
        ("d", "noise", "xyz", 0.60, 0.060),
    ]
    rows = [{**base, "sequence": s, "filter": "geometry", "room": room, "camera": cam, "coverage_max": cover,
             "ate_rmse_m": ate} for s, room, cam, cover, ate in runs]
    rows[1]["precision"], rows[1]["recall"] = 0.4, 0.3
    return _derived(pd.DataFrame(rows))


def test_by_kind_counts_each_room_and_camera_motion():
    rooms = by_kind(_rows(), "room").set_index("room")
    assert list(rooms.index) == ["flat", "noise"]
    assert rooms.loc["flat", "sequences"] == 2 and rooms.loc["flat", "within"] == 1  # 0.010 m within 0.05, 0.200 not
    assert rooms.loc["flat", "ate_median"] == pytest.approx(0.105) and rooms.loc["flat", "ate_worst"] == pytest.approx(0.2)
    assert rooms.loc["flat", "precision_median"] == pytest.approx(0.6) and rooms.loc["flat", "recall_median"] == pytest.approx(0.5)
    assert rooms.loc["noise", "within"] == 1 and rooms.loc["noise", "ate_worst"] == pytest.approx(0.06)
    cams = by_kind(_rows(), "camera").set_index("camera")
    assert cams.loc["xyz", "sequences"] == 3 and cams.loc["xyz", "within"] == 1
    assert cams.loc["xyz", "ate_median"] == pytest.approx(0.06)
    assert cams.loc["rpy", "within"] == 1


def test_markdown_scopes_the_ate_target_to_the_issues_coverage():
    md = robustness_markdown(_rows())
    # all four: b and c within 0.05 m; in scope (movers <= 45% of the image): a and c, of which c meets it
    assert "ATE <= 0.05 m: met on 2 of 4 (missed on: a, d)" in md
    assert "on the 2 sequences whose movers cover at most 45% of the image (the issue's scope): met on 1" in md
    assert "## By room surfaces" in md and "| geometry | flat | 2 | 1 | 0.1050 | 0.2000 | 0.600 | 0.500 |" in md
    assert "## By camera motion" in md and "| geometry | xyz | 3 | 1 | 0.0600 | 0.2000 |" in md


def test_markdown_of_rows_without_the_kind_columns_still_lists_every_run():
    df = _rows().drop(columns=["room", "camera"])
    md = robustness_markdown(df)
    assert "## By room surfaces" not in md and md.count("| geometry |") == 1 + 4  # the summary, then each run


def test_scene_kind_reads_the_renderers_metadata(tmp_path):
    stress_dir, office_dir, other = tmp_path / "s", tmp_path / "o", tmp_path / "tum"
    for d in (stress_dir, office_dir, other):
        d.mkdir()
    (stress_dir / "synthetic.json").write_text(json.dumps({"kind": "stress", "preset": {"style": "flat", "motion": "rpy"}}))
    (office_dir / "synthetic.json").write_text(json.dumps({"kind": "office", "preset": {"scene": "walking", "motion": "xyz"}}))
    assert scene_kind(stress_dir) == ("flat", "rpy")
    assert scene_kind(office_dir) == ("office", "xyz")
    assert scene_kind(other) == ("-", "-")  # a real sequence: no renderer metadata
    (other / "synthetic.json").write_text("{not json")
    assert scene_kind(other) == ("-", "-")


def test_plot_labels_each_sequence_with_its_room_and_camera(tmp_path):
    df = _rows()
    assert _sequence_labels(df, ["a", "c"]) == ["a\nflat, xyz", "c\nnoise, xyz"]
    df.loc[df["sequence"] == "c", "room"] = "-"  # a sequence the renderer did not make: its name alone
    assert _sequence_labels(df, ["a", "c"]) == ["a\nflat, xyz", "c"]
    assert _sequence_labels(df.drop(columns=["room"]), ["a"]) == ["a"]
    out = robustness_plot(df, tmp_path / "r.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_markdown_names_a_path_without_movers_that_does_not_track():
    df = _rows()
    ref = df.iloc[[0, 2]].copy()
    ref["filter"], ref["frames"], ref["lost"] = "no movers", 240, [240, 10]  # a: not one frame; c: 4 %
    md = robustness_markdown(_derived(pd.concat([df.assign(frames=240), ref], ignore_index=True)))
    assert "the same path without movers lost more than 50% of its frames on: a (" in md
    assert "on: a, c" not in md


def test_markdown_shows_the_scores_away_from_the_outlines_and_takes_tables_without_them():
    df = _rows()
    df["precision_away"] = [0.9, 0.5, 0.95, 0.85]
    df["recall_away"] = [0.8, 0.6, 0.7, 0.9]
    md = robustness_markdown(df)
    head = next(line for line in md.splitlines() if line.startswith("| filter | n |"))
    assert "| P rest | P away | R away |" in head
    row = next(line for line in md.splitlines() if line.startswith("| geometry | 4 |"))
    # worst / typical by hand: precision_away min 0.5, median 0.875; recall_away min 0.6, median 0.75
    assert "| 0.500 / 0.875 | 0.600 / 0.750 |" in row
    old = robustness_markdown(_rows())  # rows of runs made before the columns existed
    row = next(line for line in old.splitlines() if line.startswith("| geometry | 4 |"))
    assert "| - / - | - / - |" in row
