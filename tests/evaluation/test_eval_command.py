"""``dynslam eval``: table and JSON output, errors naming the file and line."""

from __future__ import annotations

import json

import pytest

from dynslam_lab.cli import main
from dynslam_lab.evaluation import evaluate, read_tum_trajectory, write_tum_trajectory


@pytest.fixture
def files(tmp_path, synth):
    make, noisy = synth
    gt = make(n=300, rate=100.0)
    est = noisy(make(n=90, rate=30.0), sigma_t=0.02)
    g, e = tmp_path / "gt.txt", tmp_path / "est.txt"
    write_tum_trajectory(gt, g)
    write_tum_trajectory(est, e)
    return g, e


def test_json_matches_api(files, capsys):
    g, e = files
    assert main(["eval", "--gt", str(g), "--est", str(e), "--align", "sim3", "--delta", "5", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    ref = evaluate(read_tum_trajectory(g), read_tum_trajectory(e), align="sim3", delta=5,
                   gt_name=str(g), est_name=str(e))
    assert out == json.loads(json.dumps(ref))
    assert out["rpe"]["delta"] == 5 and out["align"]["method"] == "sim3"


def test_table_and_seconds(files, capsys):
    g, e = files
    assert main(["eval", "--gt", str(g), "--est", str(e), "--delta", "0.5", "--delta-unit", "seconds"]) == 0
    out = capsys.readouterr().out
    assert "ATE (m)" in out and "RPE trans. (m)" in out and "delta 0.5 seconds" in out
    ref = evaluate(read_tum_trajectory(g), read_tum_trajectory(e))
    assert f"{ref['ate']['rmse']:.4f}" in out


def test_bad_file_names_file_and_line(tmp_path, files, capsys):
    g, _ = files
    bad = tmp_path / "bad.txt"
    bad.write_text("# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    assert main(["eval", "--gt", str(g), "--est", str(bad)]) == 1
    err = capsys.readouterr().err
    assert f"{bad}:3" in err and "expected 8 values" in err


def test_missing_file_and_no_overlap(tmp_path, files, capsys):
    g, e = files
    assert main(["eval", "--gt", str(g), "--est", str(tmp_path / "nope.txt")]) == 1
    assert "nope.txt" in capsys.readouterr().err
    far = tmp_path / "far.txt"
    far.write_text("5000.0 0 0 0 0 0 0 1\n5001.0 0 0 0 0 0 0 1\n5002.0 0 0 0 0 0 0 1\n")
    assert main(["eval", "--gt", str(g), "--est", str(far)]) == 1
    err = capsys.readouterr().err
    assert "no matching timestamps" in err and "gt.txt" in err and "far.txt" in err


def test_bad_delta(files, capsys):
    g, e = files
    assert main(["eval", "--gt", str(g), "--est", str(e), "--delta", "1.5"]) == 2  # usage error
    assert "whole number" in capsys.readouterr().err


def test_all_pairs_and_no_alignment(files, capsys):
    from dynslam_lab.evaluation import compute_rpe

    g, e = files
    assert main(["eval", "--gt", str(g), "--est", str(e), "--align", "none", "--delta", "3",
                 "--all-pairs", "--max-diff", "0.01", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    rpe = compute_rpe(read_tum_trajectory(g), read_tum_trajectory(e), delta=3, all_pairs=True,
                      align="none", max_diff=0.01)
    assert out["rpe"]["all_pairs"] is True and out["rpe"]["trans"]["n"] == len(rpe.trans_errors)
    assert out["rpe"]["trans"]["rmse"] == pytest.approx(rpe.trans.rmse, abs=1e-12)
    assert out["align"]["method"] == "none" and out["max_diff"] == 0.01


def _with_row_repeated(path, k, pose_from=None):
    """The file with data row ``k`` repeated after itself (another pose when ``pose_from`` is a row)."""
    lines = path.read_text().splitlines()
    rows = [i for i, ln in enumerate(lines) if ln and not ln.startswith("#")]
    ts = lines[rows[k]].split()[0]
    dup = ts + " " + " ".join(lines[rows[pose_from if pose_from is not None else k]].split()[1:])
    lines.insert(rows[k] + 1, dup)
    out = path.with_name(path.stem + "_dup.txt")
    out.write_text("\n".join(lines) + "\n")
    return out, rows[k] + 1, rows[k] + 2


@pytest.mark.parametrize("which", ["est", "gt"])
def test_duplicate_timestamps_are_an_error_naming_the_lines(files, capsys, which):
    """Issue 13 item 8: one duplicated row (another pose at the same time) is refused, naming both
    lines; --dedupe first keeps the first row of each and equals the file without the duplicate."""
    g, e = files
    clean = json.loads(json.dumps(evaluate(read_tum_trajectory(g), read_tum_trajectory(e))))
    src = e if which == "est" else g
    bad, line_a, line_b = _with_row_repeated(src, 40, pose_from=10)
    args = {"gt": str(g), "est": str(e), which: str(bad)}
    assert main(["eval", "--gt", args["gt"], "--est", args["est"], "--json"]) == 1
    err = capsys.readouterr().err
    assert f"{bad.name}: 1 duplicated timestamp(s)" in err and f"on lines {line_a} and {line_b}" in err
    assert "--dedupe first" in err and err.count("\n") == 1
    assert main(["eval", "--gt", args["gt"], "--est", args["est"], "--json", "--dedupe", "first"]) == 0
    assert json.loads(capsys.readouterr().out)["ate"]["rmse"] == pytest.approx(clean["ate"]["rmse"], abs=1e-12)


def test_json_output_is_strict(files, capsys):
    g, e = files
    assert main(["eval", "--gt", str(g), "--est", str(e), "--json"]) == 0
    text = capsys.readouterr().out
    assert "NaN" not in text and "Infinity" not in text
    json.loads(text, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
