"""dynslam_lab.experiments.room_witness: the room's large planes, and the list of movers."""

from __future__ import annotations

import numpy as np
import pytest

from dynslam_lab.experiments import room_witness


def _room_with_a_box(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Camera points of a floor (y = 1 m, below the camera), a back wall (z = 4 m), the front face of a box standing
    in the room (z = 2 m, 1.2 x 1.2 m) and a cloud of scattered points (a person: no plane). Returns the points and
    the part each belongs to (0 floor, 1 wall, 2 box face, 3 cloud)."""
    floor = np.column_stack([rng.uniform(-1.5, 1.5, 1500), np.full(1500, 1.0), rng.uniform(1.0, 4.0, 1500)])
    wall = np.column_stack([rng.uniform(-2.0, 2.0, 1500), rng.uniform(-1.5, 1.0, 1500), np.full(1500, 4.0)])
    box = np.column_stack([rng.uniform(-0.6, 0.6, 600), rng.uniform(-0.2, 1.0, 600), np.full(600, 2.0)])
    cloud = rng.uniform([-1.0, -0.5, 2.5], [1.0, 1.0, 3.5], size=(400, 3))
    P = np.vstack([floor, wall, box, cloud])
    P += rng.normal(0.0, 0.002, P.shape)  # 2 mm of noise, within the planes' tolerance
    part = np.repeat([0, 1, 2, 3], [1500, 1500, 600, 400])
    # the wall behind the box face is hidden by it: drop the wall points the box covers from the camera
    ray = P[:, :2] / P[:, 2:3]
    hidden = (part == 1) & (np.abs(ray[:, 0]) < 0.3) & (ray[:, 1] > -0.1) & (ray[:, 1] < 0.5)
    return P[~hidden], part[~hidden]


def test_large_planes_find_the_floor_the_wall_and_the_box_face_and_only_the_room_bounds_the_scene():
    rng = np.random.default_rng(3)
    P, part = _room_with_a_box(rng)
    labels = room_witness.large_planes(P, min_share=0.08)
    # each of the three planes is one label and holds (nearly) all its points (where the wall meets the floor a
    # point is within the tolerance of both); the cloud is on none
    for k in (0, 1, 2):
        on = labels[part == k]
        assert (on > 0).mean() > 0.97
        assert np.bincount(on[on > 0]).max() > 0.95 * len(on)
    assert len({int(np.bincount(labels[part == k]).argmax()) for k in (0, 1, 2)}) == 3
    assert (labels[part == 3] > 0).mean() < 0.1
    # the box face has the wall behind it; the floor and the wall have nothing behind them
    room = room_witness.bounding_planes(P, labels)
    box_label = np.bincount(labels[part == 2]).argmax()
    assert not (room == box_label).any()
    assert (room[part == 2] > 0).mean() < 0.03  # only where the box stands on the floor
    assert (room[part == 0] > 0).mean() > 0.97 and (room[part == 1] > 0).mean() > 0.97
    # too few points for any plane: none
    assert (room_witness.large_planes(P[:2]) == 0).all()


def test_movers_of_reads_every_instance_that_moves_and_names_a_missing_list(tmp_path):
    (tmp_path / "moving.txt").write_text("# instances that moved\n# timestamp id id ...\n1.0\n1.03 2\n1.07 2 5\n")
    assert room_witness.movers_of(tmp_path) == {2, 5}
    with pytest.raises(FileNotFoundError, match="nowhere.*moving.txt"):
        room_witness.movers_of(tmp_path / "nowhere")


@pytest.mark.slow
def test_several_pixel_sets_on_one_run_give_the_rows_of_separate_runs():
    """The notebook measures three pixel sets on one run: each set's rows are those of a run of its own."""
    from dynslam_lab.config import Config
    from dynslam_lab.datasets.tum import TumSequence
    from dynslam_lab.experiments.robustness import synthetic_root
    from dynslam_lab.pipeline import build_pipeline

    seq = TumSequence(synthetic_root("static_xyz", n_frames=12))

    def run(pixels):
        system = build_pipeline(Config(), seq.camera, detector="none", filters="geometry", loop_closing=False)
        return list(room_witness.measure_witness(seq, system, 12, offset=4, pixels=pixels))

    both = run(("planes", "all"))
    assert [r.pixels for r in both] == ["planes", "all"] * 8
    assert [r for r in both if r.pixels == "planes"] == run("planes")
    assert [r for r in both if r.pixels == "all"] == run("all")
    with pytest.raises(ValueError, match="pixels must be one or more of"):
        run(("planes", "walls"))
