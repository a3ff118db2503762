"""DBoW2 text vocabularies (ORB-SLAM2/3's ORBvoc.txt format): read, write, round trip, and a file
the exporter writes read back by an independent reader of the format written here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dynslam_lab.cli import main as cli_main
from dynslam_lab.slam.vocabulary import VocabularyConfig, load_vocabulary, train_vocabulary
from dynslam_lab.slam.vocabulary_io import read_dbow2_text, write_dbow2_text


def _small_vocabulary(seed: int = 0):
    rng = np.random.default_rng(seed)
    centres = rng.integers(0, 256, (12, 32), dtype=np.uint8)
    sets = []
    for _ in range(30):  # 30 "images" of noisy copies of a few of the centres
        pick = rng.choice(12, 5, replace=False)
        bits = np.unpackbits(centres[np.repeat(pick, 20)], axis=1)
        flip = rng.random(bits.shape) < 0.06
        sets.append(np.packbits(bits ^ flip, axis=1))
    return train_vocabulary(sets, VocabularyConfig(branching=4, depth=3), rng=seed), rng


# --------------------------------------------------------------------------- an independent reader
def _independent_read(path):
    """The format as ORB-SLAM's loadFromTextFile reads it, in plain Python: the header, then node
    n on the n-th line (root 0 implicit), children appended in line order, words numbered in leaf
    order. Returns (k, L, scoring, weighting, nodes) with nodes[id] = dict(parent, leaf, desc, weight,
    children, word)."""
    with open(path) as fh:
        text = fh.read()
    lines = text.split("\n")
    k, L, scoring, weighting = (int(x) for x in lines[0].split())
    nodes = {0: {"parent": -1, "leaf": False, "desc": None, "weight": 0.0, "children": [], "word": -1}}
    n_words = 0
    for nid, line in enumerate(lines[1:], start=1):
        f = line.split()
        assert len(f) == 35, f"line {nid + 1}: {len(f)} fields"
        parent, leaf = int(f[0]), int(f[1]) > 0
        nodes[nid] = {"parent": parent, "leaf": leaf, "desc": bytes(int(x) for x in f[2:34]),
                      "weight": float(f[34]), "children": [], "word": -1}
        nodes[parent]["children"].append(nid)
        if leaf:
            nodes[nid]["word"] = n_words
            n_words += 1
    return k, L, scoring, weighting, nodes


def _independent_word(nodes, desc: bytes) -> tuple[int, float]:
    """DBoW2's transform: from the root to the nearest child (Hamming, first on ties) down to a leaf."""
    nid = 0
    while nodes[nid]["children"]:
        best, best_d = None, None
        for c in nodes[nid]["children"]:
            d = bin(int.from_bytes(bytes(a ^ b for a, b in zip(desc, nodes[c]["desc"])), "big")).count("1")
            if best_d is None or d < best_d:
                best, best_d = c, d
        nid = best
    return nodes[nid]["word"], nodes[nid]["weight"]


def test_exported_file_read_by_an_independent_reader(tmp_path):
    voc, rng = _small_vocabulary()
    path = write_dbow2_text(voc, tmp_path / "voc.txt")
    raw = path.read_bytes()
    assert not raw.endswith(b"\n")  # ORB-SLAM's reader would make an empty node of a final newline
    k, L, scoring, weighting, nodes = _independent_read(path)
    assert (k, L, scoring, weighting) == (voc.branching, voc.depth, 0, 0)  # L1_NORM, TF_IDF
    assert len(nodes) == len(voc.centres)
    leaves = [n for n in nodes.values() if n["leaf"]]
    assert len(leaves) == voc.n_words
    for n in nodes.values():  # parents before children, inner nodes weigh 0, every inner node has children
        if n["parent"] >= 0:
            assert not nodes[n["parent"]]["leaf"]
        if not n["leaf"]:
            assert n["weight"] == 0.0 and (n["children"] or n["parent"] < 0)
    # The same words and weights for fresh descriptors: ours against the independent descent
    desc = rng.integers(0, 256, (200, 32), dtype=np.uint8)
    ours = voc.transform(desc)
    for d, w in zip(desc, ours):
        word, weight = _independent_word(nodes, bytes(d.tolist()))
        assert word == w
        assert weight == voc.idf[w]  # written with 17 digits: exact


def test_round_trip_is_exact(tmp_path):
    voc, rng = _small_vocabulary(1)
    back = read_dbow2_text(write_dbow2_text(voc, tmp_path / "v.txt"))
    for name in ("centres", "children", "parent", "level", "node_word", "word_node", "idf"):
        np.testing.assert_array_equal(getattr(back, name), getattr(voc, name), err_msg=name)
    desc = rng.integers(0, 256, (300, 32), dtype=np.uint8)
    np.testing.assert_array_equal(back.transform(desc), voc.transform(desc))
    assert back.n_images == 0  # not part of the DBoW2 format


def test_hand_written_file(tmp_path):
    """A tree typed by hand, in the order ORB-SLAM's saveToTextFile writes (and with the final
    newline it leaves): root -> {1 inner, 2 leaf}, 1 -> {3 leaf, 4 leaf}."""
    z = " ".join(["0"] * 32)
    ones = " ".join(["255"] * 32)
    half = " ".join(["255"] * 16 + ["0"] * 16)
    text = (f"2 2  0 0\n0 0 {z} 0\n0 1 {ones} 0.5\n1 1 {z} 1.25\n1 1 {half} 2\n")
    p = tmp_path / "hand.txt"
    p.write_text(text)
    voc = read_dbow2_text(p)
    assert voc.n_words == 3 and voc.branching == 2 and voc.depth == 2
    np.testing.assert_array_equal(voc.children[0], [1, 2])
    np.testing.assert_array_equal(voc.children[1], [3, 4])
    np.testing.assert_array_equal(voc.word_node, [2, 3, 4])  # words in leaf-line order
    np.testing.assert_allclose(voc.idf, [0.5, 1.25, 2.0])
    d = np.array([[0] * 32, [255] * 32, [255] * 10 + [0] * 22], np.uint8)
    # all-zero -> node 1 (distance 0) -> node 3; all-ones -> node 2; ten 255 bytes -> 1 -> 4 (80 vs 48 bits)
    np.testing.assert_array_equal(voc.transform(d), [1, 0, 2])


@pytest.mark.parametrize(
    "text, match",
    [
        ("10 6 0\n", "header"),
        ("10 6 1 0\n0 1 " + " ".join(["0"] * 32) + " 1", "L2_NORM"),
        ("30 6 0 0\n0 1 " + " ".join(["0"] * 32) + " 1", "ranges"),
        ("2 2 0 0\n0 1 " + " ".join(["0"] * 31) + " 1", "fields"),
        ("2 2 0 0\n3 1 " + " ".join(["0"] * 32) + " 1", "earlier node"),
        ("2 2 0 0\n0 1 " + " ".join(["300"] * 32) + " 1", "0..255"),
        ("2 2 0 0\n0 0 " + " ".join(["0"] * 32) + " 0", "no children"),
    ],
)
def test_bad_files_are_named(tmp_path, text, match):
    p = tmp_path / "bad.txt"
    p.write_text(text)
    with pytest.raises(ValueError, match=match) as err:
        read_dbow2_text(p)
    assert "bad.txt" in str(err.value)


def test_writer_never_overwrites_other_files(tmp_path):
    voc, _ = _small_vocabulary()
    other = tmp_path / "notes.txt"
    other.write_text("my notes\n")
    with pytest.raises(ValueError, match="refusing"):
        write_dbow2_text(voc, other)
    assert other.read_text() == "my notes\n"
    out = write_dbow2_text(voc, tmp_path / "v.txt")
    write_dbow2_text(voc, out)  # replacing its own kind of file is fine


def test_import_export_commands(tmp_path, capsys):
    voc, rng = _small_vocabulary(2)
    voc.save(tmp_path / "v.npz")
    assert cli_main(["vocab", "export", str(tmp_path / "v.npz"), "--format", "dbow2", "--out", str(tmp_path / "v.txt")]) == 0
    assert cli_main(["vocab", "import", str(tmp_path / "v.txt"), "--out", str(tmp_path / "w.npz")]) == 0
    back = load_vocabulary(tmp_path / "w.npz")
    desc = rng.integers(0, 256, (100, 32), dtype=np.uint8)
    np.testing.assert_array_equal(back.transform(desc), voc.transform(desc))
    np.testing.assert_array_equal(back.idf, voc.idf)
    # the shipped default exports too (what the ORB-SLAM3 peer benchmark loads)
    assert cli_main(["vocab", "export", "default", "--out", str(tmp_path / "d.txt")]) == 0
    k, L, s, w = (int(x) for x in (tmp_path / "d.txt").read_text().split("\n", 1)[0].split())
    assert 2 <= k <= 20 and 1 <= L <= 10 and (s, w) == (0, 0)
    assert math.isfinite(float((tmp_path / "d.txt").read_text().rsplit(" ", 1)[1]))
