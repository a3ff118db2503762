"""DBoW2's text vocabulary format: read ORB-SLAM2/3's ``ORBvoc.txt``, write one they can load.

ORB-SLAM2 (Mur-Artal and Tardos 2017) ships its vocabulary (DBoW2, Galvez-Lopez and Tardos 2012,
trained by the ORB-SLAM authors on a large indoor/outdoor image set) as ``ORBvoc.txt``, written by
the ``saveToTextFile`` that ORB-SLAM adds to DBoW2's ``TemplatedVocabulary`` and read by its
``loadFromTextFile`` (ORB-SLAM3 uses the same reader). The format, as those functions define it:

* line 1, the header: ``k L scoring weighting`` (branching factor, depth levels, DBoW2's
  ``ScoringType`` and ``WeightingType`` enums; ORB-SLAM's reader refuses ``k > 20``, ``L`` outside
  ``1..10``, scoring outside ``0..5``, weighting outside ``0..3``). ``ORBvoc.txt`` has ``10 6 0 0``:
  ``L1_NORM`` scoring (0) and ``TF_IDF`` weighting (0), the only pair this toolkit implements;
* then one line per tree node, node ids implicit: the ``n``-th node line is node ``n`` (``1, 2, ...``;
  the root, node 0, has no line): ``parent is_leaf d_0 ... d_31 weight``, the parent's node id,
  ``1`` for a leaf (a word) else ``0``, the 32 descriptor bytes as decimal numbers, and the node's
  weight (the word's idf ``log(N / N_i)`` for a leaf, 0 for an inner node);
* children are appended to their parent in the order of their lines, and words are numbered in
  the order of their leaf lines. ORB-SLAM's reader indexes the parent as the line is read, so a
  parent must come before its children.

Two details of ORB-SLAM's reader that the writer respects: it loops ``while (!eof)`` over
``getline``, so a newline after the last node makes an extra, empty node under the root (this
writer ends the file without one; the reader here skips empty lines); and it keeps the weight of
each node as written (``double``), so weights are written with 17 significant digits (exact).

Our :class:`~dynslam_lab.slam.vocabulary.Vocabulary` keeps the same tree (``children`` in line
order, words = leaves in line order, ``idf`` = the leaves' weights). DBoW2's file does not record
the number of training images, so an imported vocabulary has ``n_images = 0``.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .vocabulary import Vocabulary

__all__ = ["read_dbow2_text", "write_dbow2_text", "DBOW2_L1_NORM", "DBOW2_TF_IDF", "canonical_order"]

DBOW2_L1_NORM = 0  # DBoW2 ScoringType L1_NORM
DBOW2_TF_IDF = 0  # DBoW2 WeightingType TF_IDF
_DESC_BYTES = 32  # ORB: DBoW2's FORB::L
_SCORING = ("L1_NORM", "L2_NORM", "CHI_SQUARE", "KL", "BHATTACHARYYA", "DOT_PRODUCT")
_WEIGHTING = ("TF_IDF", "TF", "IDF", "BINARY")


def _parse_header(path: Path, line: str) -> tuple[int, int, int, int]:
    parts = line.split()
    if len(parts) != 4:
        raise ValueError(f"{path}: line 1 must be the DBoW2 header 'k L scoring weighting', got {line.strip()!r}")
    try:
        k, depth, scoring, weighting = (int(p) for p in parts)
    except ValueError:
        raise ValueError(f"{path}: line 1 must hold four integers 'k L scoring weighting', got {line.strip()!r}") from None
    if not 2 <= k <= 20 or not 1 <= depth <= 10 or not 0 <= scoring <= 5 or not 0 <= weighting <= 3:
        raise ValueError(
            f"{path}: header k={k} L={depth} scoring={scoring} weighting={weighting} out of DBoW2's ranges "
            "(k 2..20, L 1..10, scoring 0..5, weighting 0..3)"
        )
    if scoring != DBOW2_L1_NORM or weighting != DBOW2_TF_IDF:
        raise ValueError(
            f"{path}: scoring {_SCORING[scoring]} / weighting {_WEIGHTING[weighting]}; this toolkit implements "
            "L1_NORM scoring with TF_IDF weighting (header '... 0 0', as ORBvoc.txt)"
        )
    return k, depth, scoring, weighting


def read_dbow2_text(path: str | Path) -> Vocabulary:
    """Read a DBoW2 text vocabulary (ORB-SLAM2/3's ``ORBvoc.txt`` format) into a :class:`Vocabulary`.

    Parameters
    ----------
    path : the ``.txt`` file (uncompressed; ``ORBvoc.txt.tar.gz`` must be extracted first).

    Returns
    -------
    Vocabulary
        Node ``n`` of the file is node ``n`` here; children in line order; word ``w`` is the
        ``w``-th leaf line; ``idf`` the leaves' weights; ``n_images = 0`` (not in the format).

    Raises
    ------
    FileNotFoundError, ValueError
        A missing file; a bad header, a node line without ``2 + 32 + 1`` numbers, a descriptor
        byte outside 0..255, a parent that is not an earlier inner node, more than ``k``
        children, a tree deeper than ``L``: each error names the file (and the line).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: DBoW2 vocabulary file not found")
    n_cols = 2 + _DESC_BYTES + 1
    with open(path, encoding="ascii", errors="replace") as fh:
        k, depth, _, _ = _parse_header(path, fh.readline())
        try:  # numpy's C parser: ORBvoc.txt's 1.08 M lines in seconds; empty lines are skipped
            table = np.loadtxt(fh, dtype=np.float64, ndmin=2)
        except ValueError as exc:
            raise ValueError(f"{path}: not a DBoW2 ORB node table after line 1 ({exc})") from None
    n = len(table)
    if n == 0:
        raise ValueError(f"{path}: no node lines after the header")
    if table.shape[1] != n_cols:
        raise ValueError(
            f"{path}: node lines have {table.shape[1]} fields, a DBoW2 ORB node line has {n_cols} "
            f"(parent is_leaf {_DESC_BYTES} descriptor bytes weight)"
        )
    parent = table[:, 0]
    is_leaf = table[:, 1]
    desc = table[:, 2 : 2 + _DESC_BYTES]
    weight = table[:, -1]
    node_ids = np.arange(1, n + 1)
    if np.any(parent != np.round(parent)) or np.any(parent < 0) or np.any(parent >= node_ids):
        bad = int(np.flatnonzero((parent != np.round(parent)) | (parent < 0) | (parent >= node_ids))[0])
        raise ValueError(f"{path}: line {bad + 2}: parent {parent[bad]:g} must be an earlier node id (0..{bad})")
    if np.any((is_leaf != 0) & (is_leaf != 1)):
        bad = int(np.flatnonzero((is_leaf != 0) & (is_leaf != 1))[0])
        raise ValueError(f"{path}: line {bad + 2}: is_leaf must be 0 or 1, got {is_leaf[bad]:g}")
    if np.any(desc != np.round(desc)) or np.any(desc < 0) or np.any(desc > 255):
        bad = int(np.flatnonzero(np.any((desc != np.round(desc)) | (desc < 0) | (desc > 255), axis=1))[0])
        raise ValueError(f"{path}: line {bad + 2}: descriptor bytes must be integers 0..255")
    if not np.all(np.isfinite(weight)):
        bad = int(np.flatnonzero(~np.isfinite(weight))[0])
        raise ValueError(f"{path}: line {bad + 2}: weight is not a finite number")
    parent = parent.astype(np.int64)
    leaf = is_leaf.astype(bool)
    m = n + 1
    full_parent = np.concatenate([[-1], parent]).astype(np.int32)
    full_leaf = np.concatenate([[False], leaf])
    if np.any(full_leaf[parent]):
        bad = int(np.flatnonzero(full_leaf[parent])[0])
        raise ValueError(f"{path}: line {bad + 2}: parent {parent[bad]} is a leaf (is_leaf 1)")
    # children in line order: a stable sort of the nodes by parent, then the rank among siblings
    order = np.argsort(parent, kind="stable") + 1  # node ids sorted by parent, line order kept
    n_children = np.bincount(parent, minlength=m)
    if n_children.max() > k:
        bad = int(np.argmax(n_children))
        raise ValueError(f"{path}: node {bad} has {n_children[bad]} children, more than k={k} of the header")
    inner_without_children = np.flatnonzero(~full_leaf & (n_children == 0))
    inner_without_children = inner_without_children[inner_without_children > 0]
    if len(inner_without_children):
        bad = int(inner_without_children[0])
        raise ValueError(f"{path}: line {bad + 1}: node {bad} is not a leaf but has no children")
    start = np.concatenate([[0], np.cumsum(n_children)[:-1]])
    sorted_parent = full_parent[order]
    rank = np.arange(n) - start[sorted_parent]
    children = np.full((m, k), -1, np.int32)
    children[sorted_parent, rank] = order
    # level of each node: parents come first, so one pass in id order is exact; vectorised by levels
    level = np.zeros(m, np.int32)
    for _ in range(depth + 1):  # at most L+1 sweeps (one per tree level)
        new = np.concatenate([[0], level[parent] + 1]).astype(np.int32)
        if np.array_equal(new, level):
            break
        level = new
    if level.max() > depth:
        raise ValueError(f"{path}: the tree is {level.max()} levels deep, more than L={depth} of the header")
    centres = np.zeros((m, _DESC_BYTES), np.uint8)
    centres[1:] = desc.astype(np.uint8)
    word_node = np.flatnonzero(full_leaf).astype(np.int32)
    node_word = np.full(m, -1, np.int32)
    node_word[word_node] = np.arange(len(word_node), dtype=np.int32)
    return Vocabulary(
        centres=centres,
        children=children,
        parent=full_parent,
        level=level,
        node_word=node_word,
        word_node=word_node,
        idf=weight[leaf].astype(np.float64),
        n_images=0,
    )


def canonical_order(vocabulary: Vocabulary) -> np.ndarray:
    """Node ids ``(M,)`` in breadth-first order from the root, children in their stored order.

    DBoW2's reader needs every parent before its children; breadth-first order guarantees it
    for any tree (the vocabularies trained here are already stored that way: the identity).
    """
    out = [np.zeros(1, np.int64)]
    frontier = np.zeros(1, np.int64)
    while len(frontier):  # one step per tree level
        ch = vocabulary.children[frontier].reshape(-1)
        frontier = ch[ch >= 0].astype(np.int64)
        if len(frontier):
            out.append(frontier)
    return np.concatenate(out)


def write_dbow2_text(vocabulary: Vocabulary, path: str | Path) -> Path:
    """Write ``vocabulary`` as a DBoW2 text file that ORB-SLAM2/3's ``loadFromTextFile`` reads.

    Header ``k L 0 0`` (``L1_NORM``, ``TF_IDF``), then the nodes in breadth-first order
    (:func:`canonical_order`; parents first, as the reader needs), each
    ``parent is_leaf d_0 ... d_31 weight``, the leaves' weight their idf, inner nodes 0; no newline
    after the last node (see the module notes). Written atomically (a temporary file renamed).
    Refuses to overwrite a file that is not a DBoW2 text vocabulary.

    Returns the path written.
    """
    path = Path(path)
    voc = vocabulary
    if voc.branching > 20 or voc.depth > 10 or voc.depth < 1:
        raise ValueError(
            f"write_dbow2_text: ORB-SLAM's reader accepts k <= 20 and 1 <= L <= 10, the vocabulary has "
            f"k={voc.branching}, L={voc.depth}"
        )
    if path.exists():
        with open(path, "rb") as fh:
            first = fh.readline(200).split()
        if len(first) != 4 or not all(p.isdigit() for p in first):
            raise ValueError(f"{path}: exists and is not a DBoW2 text vocabulary; refusing to overwrite it")
    order = canonical_order(voc)
    new_id = np.empty(len(voc.centres), np.int64)
    new_id[order] = np.arange(len(order))
    nodes = order[1:]
    parent = new_id[voc.parent[nodes]]
    leaf = voc.node_word[nodes] >= 0
    weight = np.zeros(len(nodes))
    weight[leaf] = voc.idf[voc.node_word[nodes[leaf]]]
    ints = np.column_stack([parent, leaf.astype(np.int64), voc.centres[nodes].astype(np.int64)])
    int_text = [" ".join(map(str, row)) for row in ints.tolist()]
    lines = [f"{a} {w!r}" if w != 0 else f"{a} 0" for a, w in zip(int_text, weight.tolist())]
    text = f"{voc.branching} {voc.depth}  {DBOW2_L1_NORM} {DBOW2_TF_IDF}\n" + "\n".join(lines)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text, encoding="ascii")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
