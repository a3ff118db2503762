"""A vocabulary of binary words: hierarchical k-majority clustering of ORB descriptors, tf-idf.

ORB-SLAM2 (Mur-Artal and Tardos, T-RO 2017, Sec. V) recognises places with DBoW2, the bag of
binary words of Galvez-Lopez and Tardos ("Bags of Binary Words for Fast Place Recognition in
Image Sequences", IEEE T-RO 28(5), 2012, Sec. III). No DBoW wheel exists for current Python,
so this module is our own reading of that paper, in numpy.

**The tree** (Galvez-Lopez and Tardos 2012, Sec. III; Nister and Stewenius, CVPR 2006).
The training descriptors are clustered into ``k`` groups, each group again into ``k``, down
to ``depth`` levels; the leaves are the *words*. For binary descriptors the cluster centre
is the bitwise *majority* of its members (k-majority, Grana et al. 2013; the Hamming
analogue of the mean), the distance the Hamming distance, and the seeds are chosen by
k-means++ (Arthur and Vassilvitskii 2007): each next seed with probability proportional to
the squared distance to the nearest seed chosen so far. A node with fewer than ``k``
descriptors is not split further (it becomes a leaf, a word, at a shallower level).

**A descriptor's word** is found greedily: from the root, go to the child whose centre is
nearest (Hamming), down to a leaf; ``depth`` steps of ``k`` distances each instead of one
distance per word.

**Weights** (Sec. III, eq. 1): the bag-of-words vector ``v_t`` of image ``t`` has, for word
``i``, the tf-idf weight

.. math::

    v_t^i = \\frac{n_{it}}{n_t} \\log \\frac{N}{N_i}

with ``n_it`` the occurrences of word ``i`` in the image, ``n_t`` the image's descriptors,
``N`` the training images and ``N_i`` the training images containing word ``i``. The
vector is L1-normalised.

**Score** (Sec. III, eq. 2): the L1 similarity of two normalised vectors

.. math::

    s(v_1, v_2) = 1 - \\frac{1}{2} \\left\\lVert v_1 - v_2 \\right\\rVert_1
                = \\sum_i \\min(v_1^i, v_2^i) ,

in ``[0, 1]``; the second form (true for non-negative unit-L1 vectors) only needs the words
the two images share, which is what the inverted index of the keyframe database delivers.

A vocabulary is saved as one ``.npz`` (arrays below); the package ships a default one trained on
varied imagery by the recipe ``resources/vocabulary_recipe.toml`` (:func:`default_vocabulary`;
:mod:`.vocabulary_recipe`), and ``dynslam vocab build SEQDIR...`` trains one on any data.
"""

from __future__ import annotations

import dataclasses
import functools
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from ..features.matching import check_descriptors, hamming_distance

__all__ = [
    "VocabularyConfig",
    "Vocabulary",
    "BowVector",
    "train_vocabulary",
    "k_majority",
    "kmeanspp_seeds",
    "majority_centres",
    "hamming_to_centres",
    "bow_score",
    "bow_score_many",
    "load_vocabulary",
    "default_vocabulary",
    "DEFAULT_VOCABULARY_FILE",
]

DEFAULT_VOCABULARY_FILE = "orb_vocabulary.npz"  # in dynslam_lab/resources/, built from vocabulary_recipe.toml
_FORMAT_VERSION = 1


@dataclass(frozen=True)
class VocabularyConfig:
    """Parameters of vocabulary training (DBoW2 / ORB-SLAM2 defaults where they exist)."""

    branching: int = 10  # k, children per node; ORB-SLAM2's ORBvoc.txt: 10 (Galvez-Lopez 2012, Sec. III)
    depth: int = 4  # levels below the root, up to k**depth words; ORBvoc.txt: 6 (ours: 4, a small vocabulary)
    max_iterations: int = 10  # k-majority iterations per node (ours; DBoW2 iterates to convergence)
    max_descriptors: int = 200_000  # training descriptors kept (random subset; ours, bounds memory/time)

    def __post_init__(self) -> None:
        if self.branching < 2:
            raise ValueError(f"VocabularyConfig.branching must be >= 2, got {self.branching}")
        if self.depth < 1:
            raise ValueError(f"VocabularyConfig.depth must be >= 1, got {self.depth}")
        if self.max_iterations < 1:
            raise ValueError(f"VocabularyConfig.max_iterations must be >= 1, got {self.max_iterations}")
        if self.max_descriptors < self.branching:
            raise ValueError(
                f"VocabularyConfig.max_descriptors must be >= branching ({self.branching}), got {self.max_descriptors}"
            )


# --------------------------------------------------------------------------- clustering
def hamming_to_centres(desc: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Hamming distances ``(N, K)`` int32 from descriptors ``(N, 32)`` to centres ``(K, 32)`` (uint8):
    :func:`~dynslam_lab.features.matching.hamming_distance` under the name clustering uses."""
    return hamming_distance(desc, centres)


def majority_centres(desc: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray:
    """Bitwise majority ``(k, 32)`` uint8 of the descriptors of each cluster (k-majority update).

    Bit ``b`` of centre ``j`` is 1 when at least half of the members of cluster ``j`` have it set
    (DBoW2's ``FORB::meanValue`` rounds ties up the same way). Empty clusters get all-zero centres.
    """
    bits = np.unpackbits(desc, axis=1)  # (N, 256) 0/1
    order = np.argsort(labels, kind="stable")
    counts = np.bincount(labels, minlength=k)
    sums = np.zeros((k, 256), np.int64)
    nonempty = np.flatnonzero(counts)
    if len(nonempty):
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])[nonempty]
        sums[nonempty] = np.add.reduceat(bits[order].astype(np.int64), starts, axis=0)
    centre_bits = (2 * sums >= counts[:, None]) & (counts[:, None] > 0)
    return np.packbits(centre_bits.astype(np.uint8), axis=1)


def kmeanspp_seeds(desc: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Indices ``(k,)`` of ``k`` seed descriptors chosen by k-means++ with the Hamming distance.

    The first seed is uniform; each next one is drawn with probability ``D(x)^2 / sum D^2``,
    ``D(x)`` the distance of ``x`` to its nearest seed so far (Arthur and Vassilvitskii 2007).
    Where all remaining distances are zero (duplicates), the next seed is uniform.
    """
    n = len(desc)
    seeds = [int(rng.integers(n))]
    nearest = hamming_to_centres(desc, desc[seeds[0] : seeds[0] + 1])[:, 0].astype(np.float64)
    for _ in range(1, k):  # a loop over the k seeds, each step vectorised over descriptors
        p = nearest**2
        total = p.sum()
        nxt = int(rng.choice(n, p=p / total)) if total > 0 else int(rng.integers(n))
        seeds.append(nxt)
        nearest = np.minimum(nearest, hamming_to_centres(desc, desc[nxt : nxt + 1])[:, 0])
    return np.asarray(seeds, dtype=np.int64)


def k_majority(
    desc: np.ndarray, k: int, rng: np.random.Generator, max_iterations: int = 10
) -> tuple[np.ndarray, np.ndarray]:
    """Cluster binary descriptors ``(N, 32)`` into ``k`` groups (k-means++ seeds, majority update).

    Returns ``(centres (k, 32) uint8, labels (N,) int64)``. Stops when no label changes or after
    ``max_iterations``. Clusters that end empty are dropped (fewer than ``k`` centres returned,
    labels renumbered), so every returned centre has at least one member.
    """
    desc = check_descriptors(desc, "k_majority")
    if len(desc) < k:
        raise ValueError(f"k_majority: need at least k={k} descriptors, got {len(desc)}")
    centres = desc[kmeanspp_seeds(desc, k, rng)].copy()
    labels = np.argmin(hamming_to_centres(desc, centres), axis=1)
    for _ in range(max_iterations):
        centres = majority_centres(desc, labels, k)
        new = np.argmin(hamming_to_centres(desc, centres), axis=1)
        if np.array_equal(new, labels):
            break
        labels = new
    used, labels = np.unique(labels, return_inverse=True)
    centres = majority_centres(desc, labels, len(used))
    return centres, labels.astype(np.int64)


# --------------------------------------------------------------------------- bag of words
@dataclass(frozen=True)
class BowVector:
    """A sparse, L1-normalised tf-idf vector.

    Attributes
    ----------
    words : ``(n,)`` int64 sorted word ids with non-zero weight.
    weights : ``(n,)`` float64 weights (sum 1 unless empty).
    """

    words: np.ndarray
    weights: np.ndarray

    def __len__(self) -> int:
        return len(self.words)

    def dense(self, n_words: int) -> np.ndarray:
        """The vector as a dense ``(n_words,)`` array."""
        v = np.zeros(n_words)
        v[self.words] = self.weights
        return v


def bow_score(a: BowVector, b: BowVector) -> float:
    """L1 similarity ``s = 1 - |a - b|_1 / 2 = sum_i min(a_i, b_i)`` in ``[0, 1]`` (DBoW2 eq. 2)."""
    common, ia, ib = np.intersect1d(a.words, b.words, assume_unique=True, return_indices=True)
    if len(common) == 0:
        return 0.0
    return float(np.minimum(a.weights[ia], b.weights[ib]).sum())


def bow_score_many(vectors: list[BowVector], n_words: int) -> np.ndarray:
    """Similarity matrix ``(K, K)`` of the L1 score between all pairs of vectors (for plots).

    Sparse: the entries ``(word, vector, weight)`` sorted by word give each word's posting list;
    row ``i`` sums ``min`` over the posting lists of its words only (so a 10^6-word vocabulary costs
    no more than a small one).
    """
    k = len(vectors)
    out = np.zeros((k, k))
    if k == 0:
        return out
    words = np.concatenate([v.words for v in vectors]).astype(np.int64)
    if len(words) and (words.min() < 0 or words.max() >= n_words):
        raise ValueError(f"bow_score_many: word ids outside [0, {n_words})")
    owner = np.repeat(np.arange(k), [len(v) for v in vectors])
    weight = np.concatenate([v.weights for v in vectors]).astype(np.float64)
    order = np.argsort(words, kind="stable")
    w_sorted, o_sorted, x_sorted = words[order], owner[order], weight[order]
    for i, v in enumerate(vectors):  # loop over vectors (K), each row vectorised
        if len(v) == 0:
            continue
        lo = np.searchsorted(w_sorted, v.words, side="left")
        hi = np.searchsorted(w_sorted, v.words, side="right")
        length = hi - lo
        idx = np.repeat(lo - (np.cumsum(length) - length), length) + np.arange(int(length.sum()))
        vals = np.minimum(np.repeat(v.weights, length), x_sorted[idx])
        out[i] = np.bincount(o_sorted[idx], weights=vals, minlength=k)
    return out


# --------------------------------------------------------------------------- the vocabulary
@dataclass(frozen=True)
class Vocabulary:
    """A tree of binary words with idf weights.

    Attributes
    ----------
    centres : ``(M, 32)`` uint8 centre descriptor of every node (node 0, the root, is unused).
    children : ``(M, k)`` int32 child node ids, ``-1`` where none (leaves have none).
    parent : ``(M,)`` int32 parent node, ``-1`` for the root.
    level : ``(M,)`` int32 depth of each node (root 0).
    node_word : ``(M,)`` int32 word id of each leaf, ``-1`` for inner nodes.
    word_node : ``(W,)`` int32 leaf node of each word.
    idf : ``(W,)`` float64 inverse document frequency ``log(N / N_i)`` of each word.
    n_images : ``N``, the number of training images.
    """

    centres: np.ndarray
    children: np.ndarray
    parent: np.ndarray
    level: np.ndarray
    node_word: np.ndarray
    word_node: np.ndarray
    idf: np.ndarray
    n_images: int

    @property
    def branching(self) -> int:
        return int(self.children.shape[1])

    @property
    def depth(self) -> int:
        return int(self.level.max()) if len(self.level) else 0

    @property
    def n_words(self) -> int:
        return int(len(self.word_node))

    def __repr__(self) -> str:
        return f"Vocabulary(k={self.branching}, depth={self.depth}, words={self.n_words}, images={self.n_images})"

    # ------------------------------------------------------------------ lookup
    @functools.cached_property
    def _descent_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Tables of the vectorised descent, built once per vocabulary, one row per inner node plus a
        last row shared by the leaves: ``row (M,)`` each node's row; ``child (R + 1, k)`` the child in
        each column (a missing child repeats the first one); ``penalty (R + 1, k)`` int32 added to the
        distance of the missing children (never the nearest); ``centres (R + 1, k, 4)`` uint64 the
        children's centres as 64-bit words (3 MB for the default vocabulary's ~10 k inner nodes)."""
        ch = self.children.astype(np.int64)
        inner = np.flatnonzero(ch[:, 0] >= 0)
        r = len(inner)
        row = np.full(len(ch), r, np.int64)
        row[inner] = np.arange(r)
        child = np.zeros((r + 1, ch.shape[1]), np.int64)
        c = ch[inner]
        child[:r] = np.where(c < 0, c[:, :1], c)
        penalty = np.zeros((r + 1, ch.shape[1]), np.int32)
        penalty[:r] = np.where(c < 0, 1 << 20, 0)
        centres = np.ascontiguousarray(self.centres).view(np.uint64)[child]
        return row, child, penalty, centres

    def transform_nodes(self, descriptors: np.ndarray, level: int | None = None) -> np.ndarray:
        """Node ``(N,)`` reached by each descriptor, stopping at tree ``level`` (None: the leaf).

        The greedy descent of DBoW2: at each node go to the child with the nearest centre
        (ties: the first child). Vectorised over descriptors, one step per tree level: the
        children's centres of every descriptor's node are gathered at once (``(N, k, 4)`` 64-bit
        words, :attr:`_descent_tables`), their Hamming distances are popcounts of the XOR, the
        nearest an argmin; a descriptor that reached a leaf stays there.
        """
        desc = check_descriptors(descriptors, "Vocabulary.transform")
        stop = self.depth if level is None else int(level)
        if not 0 <= stop <= self.depth:
            raise ValueError(f"Vocabulary.transform_nodes: level must be in [0, {self.depth}], got {level}")
        node = np.zeros(len(desc), np.int64)
        if len(desc) == 0:
            return node
        row_of, child, penalty, centres = self._descent_tables
        leaf_row = len(child) - 1
        d64 = np.ascontiguousarray(desc).view(np.uint64)[:, None, :]  # (N, 1, 4)
        for _ in range(stop):  # one step per tree level, all descriptors at once
            row = row_of[node]
            bits = np.bitwise_count(centres[row] ^ d64).astype(np.int32)  # (N, k, 4) popcounts
            dist = bits[..., 0] + bits[..., 1] + bits[..., 2] + bits[..., 3] + penalty[row]
            node = np.where(row == leaf_row, node, child[row, np.argmin(dist, axis=1)])
        return node

    def transform(self, descriptors: np.ndarray) -> np.ndarray:
        """Word id ``(N,)`` int64 of each descriptor ``(N, 32)`` uint8."""
        return self.node_word[self.transform_nodes(descriptors)].astype(np.int64)

    def bow(self, descriptors: np.ndarray) -> BowVector:
        """The L1-normalised tf-idf vector of one image's descriptors (eq. 1)."""
        words = self.transform(descriptors)
        return self.bow_from_words(words)

    def bow_from_words(self, words: np.ndarray) -> BowVector:
        """tf-idf vector from word ids ``(N,)`` (``n_t = N``), L1-normalised, zero weights dropped."""
        words = np.asarray(words, dtype=np.int64)
        if len(words) == 0:
            return BowVector(np.zeros(0, np.int64), np.zeros(0))
        uniq, counts = np.unique(words, return_counts=True)
        w = counts / len(words) * self.idf[uniq]
        keep = w > 0
        uniq, w = uniq[keep], w[keep]
        total = w.sum()
        return BowVector(uniq, w / total if total > 0 else w)

    # ------------------------------------------------------------------ files
    def save(self, path: str | Path, recipe: str | None = None) -> Path:
        """Write the vocabulary as one compressed ``.npz``, atomically; returns the path.

        ``recipe`` (text, e.g. the TOML recipe of ``dynslam vocab build``) is stored beside the
        arrays so the file says how it was made. An existing file is replaced only when it is a
        vocabulary itself (nothing else is overwritten).
        """
        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_suffix(path.suffix + ".npz") if path.suffix else path.with_suffix(".npz")
        if path.exists():
            try:
                with np.load(path, allow_pickle=False) as old:
                    is_voc = all(k in old.files for k in _KEYS)
            except (OSError, EOFError, ValueError, AttributeError):
                is_voc = False
            if not is_voc:
                raise ValueError(f"{path}: exists and is not a vocabulary file; refusing to overwrite it")
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {k: getattr(self, k) for k in _ARRAYS}
        extra = {} if recipe is None else {"recipe": np.array(recipe)}
        tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.npz")
        try:
            np.savez_compressed(
                tmp, format_version=np.int64(_FORMAT_VERSION), n_images=np.int64(self.n_images), **arrays, **extra
            )
            tmp.replace(path)
        finally:
            tmp.unlink(missing_ok=True)
        return path


#: The arrays of a vocabulary file and the dtype each has in a :class:`Vocabulary`.
_ARRAYS = {
    "centres": np.uint8,
    "children": np.int32,
    "parent": np.int32,
    "level": np.int32,
    "node_word": np.int32,
    "word_node": np.int32,
    "idf": np.float64,
}
_KEYS = (*_ARRAYS, "n_images")


def load_vocabulary(path: str | Path) -> Vocabulary:
    """Read a vocabulary written by :meth:`Vocabulary.save`; a clear error names the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: vocabulary file not found")
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, EOFError, ValueError) as exc:
        raise ValueError(f"{path}: cannot read vocabulary, not an .npz archive ({exc})") from exc
    if not hasattr(z, "files"):
        raise ValueError(f"{path}: not a dynslam vocabulary (a single array, not an .npz archive)")
    with z:
        missing = [k for k in _KEYS if k not in z.files]
        if missing:
            raise ValueError(f"{path}: not a dynslam vocabulary, missing arrays {missing}")
        a = {k: z[k] for k in _KEYS}
    m = len(a["centres"])
    if a["centres"].shape != (m, 32) or a["centres"].dtype != np.uint8:
        raise ValueError(f"{path}: centres must be (M, 32) uint8, got {a['centres'].shape} {a['centres'].dtype}")
    for k in ("children", "parent", "level", "node_word"):
        if len(a[k]) != m:
            raise ValueError(f"{path}: {k} has {len(a[k])} rows for {m} nodes")
    if len(a["idf"]) != len(a["word_node"]):
        raise ValueError(f"{path}: idf has {len(a['idf'])} entries for {len(a['word_node'])} words")
    return Vocabulary(
        **{k: a[k].astype(dtype, copy=False) for k, dtype in _ARRAYS.items()}, n_images=int(a["n_images"])
    )


_DEFAULT_CACHE: dict[str, Vocabulary] = {}


def default_vocabulary() -> Vocabulary:
    """The vocabulary shipped in ``dynslam_lab/resources/`` (built by ``resources/vocabulary_recipe.toml``).

    Loaded once per process and shared (a :class:`Vocabulary` is immutable).
    """
    if "default" not in _DEFAULT_CACHE:
        ref = resources.files("dynslam_lab").joinpath("resources", DEFAULT_VOCABULARY_FILE)
        with resources.as_file(ref) as p:
            if not Path(p).is_file():
                raise FileNotFoundError(
                    f"{p}: default vocabulary missing from the package; build one with `dynslam vocab build`"
                )
            _DEFAULT_CACHE["default"] = load_vocabulary(p)
    return _DEFAULT_CACHE["default"]


# --------------------------------------------------------------------------- training
def train_vocabulary(
    descriptor_sets: list[np.ndarray],
    config: VocabularyConfig = VocabularyConfig(),
    rng: np.random.Generator | int | None = 0,
) -> Vocabulary:
    """Train a vocabulary on the descriptors of a set of training images.

    Parameters
    ----------
    descriptor_sets : one ``(n_t, 32)`` uint8 array per training image (the images give the
        idf: ``N`` = number of sets).
    config : branching, depth, iterations, subsample size.
    rng : Generator or seed for the k-means++ seeds and the subsample.

    Returns
    -------
    Vocabulary
        Breadth-first built tree: every node with at least ``k`` distinct descriptors is split by
        :func:`k_majority`, down to ``config.depth``; idf from the word counts of each image.
    """
    rng = np.random.default_rng(rng)
    if len(descriptor_sets) == 0:
        raise ValueError("train_vocabulary: no training images given")
    sets = [check_descriptors(d, f"train_vocabulary image {i}") for i, d in enumerate(descriptor_sets)]
    all_desc = np.concatenate(sets) if sets else np.zeros((0, 32), np.uint8)
    k = config.branching
    if len(all_desc) < k:
        raise ValueError(f"train_vocabulary: {len(all_desc)} descriptors in total, need at least branching={k}")
    train = all_desc
    if len(train) > config.max_descriptors:
        train = train[np.sort(rng.choice(len(train), config.max_descriptors, replace=False))]

    centres = [np.zeros(32, np.uint8)]
    children: list[list[int]] = [[]]
    parent = [-1]
    level = [0]
    # Breadth-first: a queue of (node, member indices into `train`).
    frontier = [(0, np.arange(len(train)))]
    for depth in range(1, config.depth + 1):
        nxt = []
        for node, members in frontier:  # loop over tree nodes; each clustering is vectorised
            sub = train[members]
            if len(np.unique(sub, axis=0)) < k:
                continue  # too few distinct descriptors: this node stays a leaf
            c, lab = k_majority(sub, k, rng, config.max_iterations)
            for j in range(len(c)):
                nid = len(centres)
                centres.append(c[j])
                children.append([])
                parent.append(node)
                level.append(depth)
                children[node].append(nid)
                nxt.append((nid, members[lab == j]))
        frontier = nxt
        if not frontier:
            break

    m = len(centres)
    child_arr = np.full((m, k), -1, np.int32)
    for i, ch in enumerate(children):
        child_arr[i, : len(ch)] = ch
    is_leaf = child_arr[:, 0] < 0
    is_leaf[0] = m == 1  # a root without children would be the single word
    word_node = np.flatnonzero(is_leaf).astype(np.int32)
    node_word = np.full(m, -1, np.int32)
    node_word[word_node] = np.arange(len(word_node), dtype=np.int32)
    voc = Vocabulary(
        centres=np.stack(centres).astype(np.uint8),
        children=child_arr,
        parent=np.asarray(parent, np.int32),
        level=np.asarray(level, np.int32),
        node_word=node_word,
        word_node=word_node,
        idf=np.zeros(len(word_node)),
        n_images=len(sets),
    )
    # idf (eq. 1): N_i = number of training images in which word i occurs.
    img_of = np.repeat(np.arange(len(sets)), [len(s) for s in sets])
    words = voc.transform(all_desc)
    pairs = np.unique(words * len(sets) + img_of)
    n_i = np.bincount(pairs // len(sets), minlength=len(word_node))
    idf = np.log(len(sets) / np.maximum(n_i, 1))
    return dataclasses.replace(voc, idf=idf)
