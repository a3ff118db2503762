"""Vocabulary of binary words: k-majority, tree lookup, tf-idf, L1 score, files, database."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from dynslam_lab.features.matching import hamming_distance
from dynslam_lab.features.orb import OrbConfig, extract_features
from dynslam_lab.slam.keyframe_database import CandidateQueryConfig, KeyframeDatabase
from dynslam_lab.slam.vocabulary import (
    BowVector,
    Vocabulary,
    VocabularyConfig,
    bow_score,
    bow_score_many,
    default_vocabulary,
    k_majority,
    load_vocabulary,
    majority_centres,
    train_vocabulary,
)
from tests.conftest import shared_file


def noisy_copies(centres: np.ndarray, n_each: int, flips: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n_each`` descriptors per centre, each with ``flips`` random bits flipped; returns (desc, label)."""
    bits = np.unpackbits(centres, axis=1)
    lab = np.repeat(np.arange(len(centres)), n_each)
    b = bits[lab].copy()
    cols = np.argsort(rng.random((len(b), 256)), axis=1)[:, :flips]
    np.put_along_axis(b, cols, 1 - np.take_along_axis(b, cols, axis=1), axis=1)
    return np.packbits(b, axis=1), lab


def test_majority_centres_by_hand():
    d = np.zeros((3, 32), np.uint8)
    d[0, 0] = 0b1100_0000
    d[1, 0] = 0b1010_0000
    d[2, 0] = 0b0000_0001
    c = majority_centres(d, np.zeros(3, np.int64), 1)
    # bit 7 set in 2/3, bit 6 in 1/3, bit 5 in 1/3, bit 0 in 1/3
    assert c[0, 0] == 0b1000_0000 and not c[0, 1:].any()
    # a tie (1 of 2) rounds up
    c2 = majority_centres(d[:2], np.zeros(2, np.int64), 1)
    assert c2[0, 0] == 0b1110_0000


def test_k_majority_separates_clusters():
    rng = np.random.default_rng(0)
    truth = rng.integers(0, 256, (6, 32), dtype=np.uint8)
    desc, lab = noisy_copies(truth, 40, 12, rng)
    centres, labels = k_majority(desc, 6, np.random.default_rng(1))
    # every found cluster is exactly one true cluster
    for j in range(len(centres)):
        assert len(np.unique(lab[labels == j])) == 1
    assert len(centres) == 6
    # the majority of the noisy copies recovers the true centre
    d = hamming_distance(centres, truth)
    assert d.min(axis=1).max() == 0


def test_tree_words_purity_and_idf():
    rng = np.random.default_rng(2)
    # a two-level truth: 4 parents far apart, 4 children each 40 bits from their parent
    parents = rng.integers(0, 256, (4, 32), dtype=np.uint8)
    truth, _ = noisy_copies(parents, 4, 40, rng)
    desc, lab = noisy_copies(truth, 30, 6, rng)
    # 4 "images": image t holds clusters with (cluster % 4) <= t  -> N_i known per cluster
    img_sets, img_clusters = [], []
    for t in range(4):
        sel = (lab % 4) <= t
        img_sets.append(desc[sel])
        img_clusters.append(set(np.unique(lab[sel]).tolist()))
    voc = train_vocabulary(img_sets, VocabularyConfig(branching=4, depth=2), rng=3)
    assert voc.branching == 4 and voc.depth == 2
    words = voc.transform(desc)
    # one word per true cluster (purity), words of different clusters differ
    for c in range(16):
        assert len(np.unique(words[lab == c])) == 1
    cluster_word = np.array([words[lab == c][0] for c in range(16)])
    assert len(np.unique(cluster_word)) == 16
    # idf = log(N / N_i), N_i = images containing the cluster
    for c in range(16):
        n_i = sum(c in s for s in img_clusters)
        assert voc.idf[cluster_word[c]] == pytest.approx(math.log(4 / n_i))


def test_transform_is_greedy_descent():
    """Vectorised lookup equals a per-descriptor walk down the tree (reference loop)."""
    rng = np.random.default_rng(4)
    desc = rng.integers(0, 256, (600, 32), dtype=np.uint8)
    voc = train_vocabulary([desc[:300], desc[300:]], VocabularyConfig(branching=5, depth=3), rng=0)
    query = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    got = voc.transform(query)
    for q, w in zip(query, got):
        node = 0
        while voc.children[node, 0] >= 0:
            ch = voc.children[node][voc.children[node] >= 0]
            node = ch[np.argmin(hamming_distance(q[None], voc.centres[ch])[0])]
        assert voc.node_word[node] == w
    # a level-1 lookup returns the first-level ancestor of the leaf
    lvl1 = voc.transform_nodes(query, level=1)
    leaf = voc.word_node[got]
    anc = leaf.copy()
    while np.any(voc.level[anc] > 1):
        anc = np.where(voc.level[anc] > 1, voc.parent[anc], anc)
    np.testing.assert_array_equal(lvl1, anc)


def _greedy_descent(voc: Vocabulary, desc: np.ndarray) -> np.ndarray:
    """Reference: one descriptor at a time, the child of least Hamming distance (first on ties)."""
    out = np.zeros(len(desc), np.int64)
    for i, q in enumerate(desc):
        node = 0
        while voc.children[node, 0] >= 0:
            ch = voc.children[node][voc.children[node] >= 0]
            d = [int(np.unpackbits(q ^ voc.centres[c]).sum()) for c in ch]
            node = int(ch[int(np.argmin(d))])
        out[i] = node
    return out


def test_default_vocabulary_lookup_is_greedy_descent():
    """The vectorised lookup on the shipped vocabulary (depth 5, k 10, leaves at several levels)
    equals the plain descent: random descriptors, noisy copies of leaf centres (deep paths), copies
    of inner-node centres (ties between siblings are likely), and exact shallow-leaf centres."""
    voc = default_vocabulary()
    rng = np.random.default_rng(7)
    inner = np.flatnonzero(voc.children[:, 0] >= 0)[1:]
    leaves = voc.word_node
    shallow = leaves[voc.level[leaves] < voc.depth]
    assert len(shallow)  # the tree has leaves above the last level: the case the descent must keep
    sets = [
        rng.integers(0, 256, (150, 32), dtype=np.uint8),
        voc.centres[rng.choice(leaves, 150)],
        voc.centres[rng.choice(inner, 100)],
        voc.centres[rng.choice(shallow, 50)],
    ]
    noisy, _ = noisy_copies(voc.centres[rng.choice(leaves, 150)], 1, 10, rng)
    desc = np.concatenate([*sets, noisy])
    got = voc.transform_nodes(desc)
    np.testing.assert_array_equal(got, _greedy_descent(voc, desc))
    assert np.all(voc.node_word[got] >= 0)
    np.testing.assert_array_equal(voc.transform(desc), voc.node_word[got])
    # a stop at level 2: the level-2 ancestor (or a shallower leaf)
    lvl2 = voc.transform_nodes(desc, level=2)
    anc = got.copy()
    while np.any(voc.level[anc] > 2):
        anc = np.where(voc.level[anc] > 2, voc.parent[anc], anc)
    np.testing.assert_array_equal(lvl2, anc)
    assert len(voc.transform_nodes(np.zeros((0, 32), np.uint8))) == 0


def test_bow_weights_and_l1_score_by_hand():
    voc = Vocabulary(
        centres=np.zeros((4, 32), np.uint8),
        children=np.array([[1, 2, 3], [-1, -1, -1], [-1, -1, -1], [-1, -1, -1]], np.int32),
        parent=np.array([-1, 0, 0, 0], np.int32),
        level=np.array([0, 1, 1, 1], np.int32),
        node_word=np.array([-1, 0, 1, 2], np.int32),
        word_node=np.array([1, 2, 3], np.int32),
        idf=np.array([1.0, 2.0, 0.0]),
        n_images=3,
    )
    v = voc.bow_from_words(np.array([0, 0, 1, 2]))
    # tf-idf: word 0: 2/4*1 = 0.5, word 1: 1/4*2 = 0.5, word 2: idf 0 -> dropped; then L1-normalised
    np.testing.assert_array_equal(v.words, [0, 1])
    np.testing.assert_allclose(v.weights, [0.5, 0.5])
    u = voc.bow_from_words(np.array([0, 0, 0, 2]))
    assert bow_score(v, v) == pytest.approx(1.0)
    # 1 - 0.5 * |v - u|_1 with v = (.5, .5), u = (1, 0): 1 - 0.5 * (0.5 + 0.5) = 0.5
    assert bow_score(v, u) == pytest.approx(1 - 0.5 * np.abs(v.dense(3) - u.dense(3)).sum())
    assert bow_score(v, BowVector(np.zeros(0, np.int64), np.zeros(0))) == 0.0
    S = bow_score_many([v, u], 3)
    np.testing.assert_allclose(S, [[1.0, 0.5], [0.5, 1.0]])


def test_save_load_roundtrip_and_errors(tmp_path):
    rng = np.random.default_rng(5)
    desc = rng.integers(0, 256, (400, 32), dtype=np.uint8)
    voc = train_vocabulary([desc[:200], desc[200:]], VocabularyConfig(branching=4, depth=2), rng=0)
    path = voc.save(tmp_path / "v.npz")
    back = load_vocabulary(path)
    np.testing.assert_array_equal(back.transform(desc), voc.transform(desc))
    np.testing.assert_allclose(back.idf, voc.idf)
    with pytest.raises(FileNotFoundError, match="not found"):
        load_vocabulary(tmp_path / "missing.npz")
    np.savez(tmp_path / "bad.npz", centres=np.zeros((3, 32), np.uint8))
    with pytest.raises(ValueError, match="bad.npz.*missing arrays"):
        load_vocabulary(tmp_path / "bad.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="junk.npz"):
        load_vocabulary(tmp_path / "junk.npz")
    with pytest.raises(ValueError, match="branching"):
        VocabularyConfig(branching=1)
    with pytest.raises(ValueError, match=r"\(N, 32\) uint8"):
        voc.transform(np.zeros((3, 16), np.uint8))


def test_default_vocabulary_ships_small_and_records_its_recipe():
    from importlib import resources

    from dynslam_lab.slam.vocabulary import DEFAULT_VOCABULARY_FILE
    from dynslam_lab.slam.vocabulary_recipe import vocabulary_recipe

    voc = default_vocabulary()
    assert voc.n_words >= 10_000 and voc.branching >= 2 and voc.depth <= 6
    assert np.all(voc.idf >= 0)
    with resources.as_file(resources.files("dynslam_lab").joinpath("resources", DEFAULT_VOCABULARY_FILE)) as p:
        assert p.stat().st_size < 5e6  # a few MB at most
        stored = vocabulary_recipe(p)
    with resources.as_file(resources.files("dynslam_lab").joinpath("resources", "vocabulary_recipe.toml")) as r:
        assert stored == r.read_text()  # the shipped file was built by the shipped recipe


def _tum_descriptors(path):
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    return gray, extract_features(gray, OrbConfig(n_features=1000)).descriptors


def test_real_frames_same_place_scores_higher(shared_data):
    """A TUM frame and a warped copy (same place) score higher than frames of other views."""
    names = ["fr3_walking_xyz_1341846313.553992_rgb.png"] + [f"fr3_walking_{c}_rgb.png" for c in "abcd"]
    grays, descs = zip(*[_tum_descriptors(shared_file(f"tum/frames/{n}")) for n in names])
    voc = default_vocabulary()
    H = cv2.getRotationMatrix2D((320, 240), 5.0, 1.05)
    warped = cv2.warpAffine(grays[0], H, (640, 480), borderMode=cv2.BORDER_REFLECT)
    wd = extract_features(warped, OrbConfig(n_features=1000)).descriptors
    v0 = voc.bow(descs[0])
    same = bow_score(v0, voc.bow(wd))
    others = [bow_score(v0, voc.bow(d)) for d in descs[1:]]
    assert same > max(others)
    assert 0.0 < min(others) and same < 1.0


def test_database_scores_match_direct_scores_and_candidates():
    rng = np.random.default_rng(6)
    n_words = 50
    vecs = []
    for _ in range(12):
        w = np.sort(rng.choice(n_words, 8, replace=False))
        x = rng.random(8)
        vecs.append(BowVector(w, x / x.sum()))
    db = KeyframeDatabase(n_words)
    for i, v in enumerate(vecs):
        db.add(i, v)
    q = vecs[3]
    ids, common, score = db.scores(q)
    for i, c, s in zip(ids, common, score):
        assert s == pytest.approx(bow_score(q, vecs[i]))
        assert c == len(np.intersect1d(q.words, vecs[i].words))
    # keyframes sharing no word do not appear
    assert set(ids) == {i for i, v in enumerate(vecs) if len(np.intersect1d(q.words, v.words))}
    db.remove(5)
    assert 5 not in db.scores(q)[0]
    # prune by the map's keyframes (a dict) or any container: the others go, removed ones stay gone
    db.prune({k: None for k in range(12) if k not in (2, 7)})
    assert db.ids() == [k for k in range(12) if k not in (2, 5, 7)] and 7 not in db
    db.prune(set(range(12)) - {9})
    assert db.ids() == [k for k in range(12) if k not in (2, 5, 7, 9)] and len(db) == 8
    assert set(db.scores(q)[0]).isdisjoint({2, 5, 7, 9})
    # the query itself, excluded, is never a candidate; a near copy of it is the best
    near = BowVector(q.words, q.weights)
    db.add(20, near)
    cands = db.detect_loop_candidates(q, exclude={3}, min_score=0.0, neighbours=lambda i: [], config=CandidateQueryConfig())
    assert cands and cands[0].kf_id == 20 and cands[0].score == pytest.approx(1.0)
    assert all(c.kf_id != 3 for c in cands)
    # min_score above every score: no candidate
    assert db.detect_loop_candidates(q, exclude={3, 20}, min_score=1.01, neighbours=lambda i: []) == []
    with pytest.raises(ValueError, match="already added"):
        db.add(20, near)
    with pytest.raises(ValueError, match="word ids"):
        db.add(21, BowVector(np.array([n_words]), np.array([1.0])))


@pytest.mark.parametrize("reindex_min", [0, 10**9], ids=["posting_lists", "linear_scan"])
def test_database_posting_lists_equal_direct_scores(reindex_min):
    """Scores through the sorted posting lists (plus the unsorted tail) equal direct L1 scores."""
    rng = np.random.default_rng(8)
    n_words = 200
    db = KeyframeDatabase(n_words)
    db.reindex_min, db.reindex_ratio = reindex_min, 0.5
    vecs = []
    for i in range(60):
        w = np.sort(rng.choice(n_words, 25, replace=False))
        x = rng.random(25)
        vecs.append(BowVector(w, x / x.sum()))
        db.add(i, vecs[-1])
        if i % 7 == 0:  # queries between additions: indexed part and tail both in use
            q = vecs[int(rng.integers(i + 1))]
            ids, common, score = db.scores(q)
            ref = np.array([bow_score(q, v) for v in vecs])
            np.testing.assert_array_equal(ids, np.flatnonzero(ref > 0))
            np.testing.assert_allclose(score, ref[ids])
            assert np.array_equal(common, [len(np.intersect1d(q.words, vecs[j].words)) for j in ids])
    if reindex_min == 0:
        assert 0 < db._indexed <= db.n_entries


def test_database_group_accumulates_neighbours():
    """ORB-SLAM2's grouping: a candidate whose covisible neighbours also score wins over a lone one."""
    words = np.arange(10)
    base = BowVector(words, np.full(10, 0.1))
    db = KeyframeDatabase(10)
    # keyframe 1 scores alone; keyframes 2, 3, 4 score less each but are neighbours
    db.add(1, BowVector(words, np.r_[np.full(5, 0.12), np.full(5, 0.08)]))
    for i in (2, 3, 4):
        db.add(i, BowVector(words, np.r_[np.full(5, 0.02), np.full(5, 0.18)]))
    s1 = bow_score(base, db.bow(1))
    s2 = bow_score(base, db.bow(2))
    assert s1 > s2
    nb = {1: [], 2: [3, 4], 3: [2, 4], 4: [2, 3]}
    cands = db.detect_loop_candidates(base, exclude=set(), min_score=0.0, neighbours=lambda i: nb[i],
                                      config=CandidateQueryConfig(accumulated_ratio=0.75))
    # group {2,3,4} accumulates 3 * s2 > s1; 1 survives only if s1 > 0.75 * 3 * s2
    assert cands[0].kf_id in (2, 3, 4)
    assert cands[0].accumulated_score == pytest.approx(3 * s2)
    assert (1 in [c.kf_id for c in cands]) == (s1 > 0.75 * 3 * s2)


def test_relocalisation_candidates_by_hand():
    """ORB-SLAM2 ``DetectRelocalizationCandidates``: no keyframe excluded, no s_min; shared words above
    0.8 x the most, groups of covisible keyframes accumulated, best of each group above 0.75 x best."""
    rng = np.random.default_rng(11)
    n_words = 40
    q = BowVector(np.arange(10), np.full(10, 0.1))
    db = KeyframeDatabase(n_words)
    # keyframes 0-2: one place (covisible), sharing 9-10 words with the frame; 3: a lone keyframe
    # sharing 9 words but weakly; 4: shares 5 words (below 0.8 x 10), 5: none
    w = {0: np.arange(10), 1: np.arange(1, 10), 2: np.r_[0:5, 6:10], 3: np.arange(9), 4: np.arange(5),
         5: np.arange(20, 30)}
    for k, words in w.items():
        x = rng.random(len(words)) + (1.0 if k < 3 else 0.1)
        if k == 3:
            x = np.r_[np.full(len(words) - 1, 0.001), 1.0]  # nearly all weight on one word
        db.add(k, BowVector(words, x / x.sum()))
    nb = {0: [1, 2], 1: [0, 2], 2: [0, 1], 3: [], 4: [], 5: []}
    cands = db.detect_relocalisation_candidates(q, neighbours=lambda i: nb[i])
    score = {k: bow_score(q, db.bow(k)) for k in w}
    pool = [k for k in w if len(np.intersect1d(q.words, w[k])) > 0.8 * 10]
    assert sorted(pool) == [0, 1, 2, 3]
    group = score[0] + score[1] + score[2]
    best_of_group = max((0, 1, 2), key=lambda k: score[k])
    assert cands[0].kf_id == best_of_group and cands[0].accumulated_score == pytest.approx(group)
    assert [c.kf_id for c in cands] == [best_of_group] + ([3] if score[3] > 0.75 * group else [])
    assert 4 not in [c.kf_id for c in cands] and 5 not in [c.kf_id for c in cands]
    # the loop query of the same vector with s_min = 0 and nothing excluded gives the same answer
    assert db.detect_loop_candidates(q, exclude=(), min_score=0.0, neighbours=lambda i: nb[i]) == cands
    # excluded (culled) keyframes are never returned
    assert best_of_group not in [c.kf_id for c in db.detect_relocalisation_candidates(
        q, neighbours=lambda i: nb[i], exclude=[best_of_group])]


def _tiny_sequence(root, n=3, seed=0):
    """A TUM-layout folder of ``n`` textured frames (blurred noise) with constant 2 m depth."""
    rng = np.random.default_rng(seed)
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    rgb_lines, depth_lines = [], []
    for i in range(n):
        ts = 100.0 + i / 30
        img = cv2.GaussianBlur((rng.random((240, 320, 3)) * 255).astype(np.uint8), (0, 0), 1.5)
        cv2.imwrite(str(root / "rgb" / f"{ts:.6f}.png"), img)
        cv2.imwrite(str(root / "depth" / f"{ts:.6f}.png"), np.full((240, 320), 10000, np.uint16))
        rgb_lines.append(f"{ts:.6f} rgb/{ts:.6f}.png")
        depth_lines.append(f"{ts:.6f} depth/{ts:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rgb_lines) + "\n")
    (root / "depth.txt").write_text("\n".join(depth_lines) + "\n")
    return root


def test_vocab_build_command(tmp_path, capsys):
    from dynslam_lab.cli import main

    seq = _tiny_sequence(tmp_path / "seq")
    out = tmp_path / "voc.npz"
    rc = main(["vocab", "build", str(seq), "--out", str(out), "--stride", "1", "--branching", "4", "--depth", "2",
               "--n-features", "300"])
    assert rc == 0
    voc = load_vocabulary(out)
    assert voc.n_images == 3 and voc.branching == 4 and voc.n_words > 4
    assert main(["vocab", "info", str(out)]) == 0
    assert "words per level" in capsys.readouterr().out
    # bad input: one clear line naming the parameter
    assert main(["vocab", "build", str(seq), "--out", str(tmp_path / "other.npz"), "--stride", "0"]) == 1
    assert "--stride" in capsys.readouterr().err
    # never over a folder (once wrote FOLDER.npz), a user's file, or without the suffix
    before = out.read_bytes()
    assert main(["vocab", "build", str(seq), "--out", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err and not Path(str(tmp_path) + ".npz").exists()
    assert main(["vocab", "build", str(seq), "--out", str(out)]) == 2
    assert "exists" in capsys.readouterr().err and out.read_bytes() == before
    assert main(["vocab", "build", str(seq), "--out", str(tmp_path / "vocab")]) == 2
    assert ".npz" in capsys.readouterr().err and not (tmp_path / "vocab.npz").exists()
    assert main(["vocab", "info", str(tmp_path / "nope.npz")]) == 1
    assert "nope.npz" in capsys.readouterr().err


def test_bow_score_many_equals_pairwise_scores():
    """The sparse similarity matrix against the pairwise L1 score (DBoW2 eq. 2), empty vectors included."""
    rng = np.random.default_rng(0)
    vectors = []
    for _ in range(20):
        w = np.unique(rng.integers(0, 500, rng.integers(0, 80)))
        x = rng.random(len(w))
        vectors.append(BowVector(w, x / max(x.sum(), 1e-12)))
    S = bow_score_many(vectors, 500)
    ref = np.array([[bow_score(a, b) for b in vectors] for a in vectors])
    np.testing.assert_allclose(S, ref, atol=1e-12)
    with pytest.raises(ValueError, match="word ids"):
        bow_score_many([BowVector(np.array([600]), np.array([1.0]))], 500)


def test_recipe_build_is_reproducible(tmp_path, capsys):
    """A small recipe (matplotlib's photographs and a missing image glob) builds the same vocabulary
    twice; the recipe text travels inside the .npz; bad recipes are named."""
    from dynslam_lab.cli import main as cli_main
    from dynslam_lab.slam.vocabulary_recipe import build_vocabulary, read_recipe, vocabulary_recipe

    text = """
[vocabulary]
branching = 4
depth = 2
n_features = 300
seed = 3

[[source]]
kind = "matplotlib"
files = ["grace_hopper.jpg"]
reliefs = 2
scales = [1.0, 0.5]

[[source]]
kind = "images"
paths = ["%s/nothing_here/*.png"]
""" % tmp_path
    rp = tmp_path / "recipe.toml"
    rp.write_text(text)
    recipe = read_recipe(rp)
    a = build_vocabulary(recipe, log=lambda s: None)
    b = build_vocabulary(recipe, log=lambda s: None)
    np.testing.assert_array_equal(a.centres, b.centres)
    np.testing.assert_array_equal(a.idf, b.idf)
    assert a.n_images == 6  # 1 photograph + 2 reliefs, 2 scales each
    assert cli_main(["vocab", "build", "--recipe", str(rp), "--out", str(tmp_path / "v.npz")]) == 0
    assert vocabulary_recipe(tmp_path / "v.npz") == text
    np.testing.assert_array_equal(load_vocabulary(tmp_path / "v.npz").centres, a.centres)
    assert "none found" in capsys.readouterr().out
    bad = tmp_path / "bad.toml"
    bad.write_text('[[source]]\nkind = "video"\n')
    with pytest.raises(ValueError, match="bad.toml.*video"):
        read_recipe(bad)
