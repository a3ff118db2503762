"""``dynslam vocab``: train a vocabulary of binary words on sequences, or describe one.

Examples::

    dynslam vocab build data/rgbd_dataset_freiburg3_walking_xyz --out my_vocab.npz
    dynslam vocab build SEQ1 SEQ2 --stride 5 --branching 10 --depth 4 --out voc.npz
    dynslam vocab info voc.npz
    dynslam vocab import ORBvoc.txt --out orbvoc.npz         # ORB-SLAM2/3's vocabulary (DBoW2 text)
    dynslam vocab export default --format dbow2 --out voc.txt  # loads in ORB-SLAM2/3

Only static keypoints feed the vocabulary: where a sequence has instance masks (the synthetic
scenes), keypoints on any instance (people, moving objects) are left out.
"""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "vocab",
        help="train a bag-of-binary-words vocabulary on sequences, or describe one",
        description="Hierarchical k-majority vocabulary over ORB descriptors with tf-idf weights (DBoW2-style).",
    )
    sub = p.add_subparsers(dest="vocab_command", metavar="ACTION")
    b = sub.add_parser("build", help="train a vocabulary on the frames of one or more sequences (TUM layout)")
    b.add_argument("sequences", nargs="*", metavar="SEQDIR", help="sequence folders (TUM layout: rgb.txt, depth.txt)")
    b.add_argument("--recipe", help="a TOML recipe of training sources instead of SEQDIRs "
                   "(the shipped vocabulary: dynslam_lab/resources/vocabulary_recipe.toml)")
    b.add_argument("--out", required=True, help="output .npz file")
    b.add_argument("--force", action="store_true", help="replace an existing vocabulary file of that name")
    b.add_argument("--stride", type=int, default=5, help="use every N-th frame (default 5)")
    b.add_argument("--max-frames", type=int, default=None, help="at most this many frames per sequence")
    b.add_argument("--branching", type=int, default=10, help="children per node k (default 10, as ORB-SLAM2)")
    b.add_argument("--depth", type=int, default=4, help="tree levels (default 4: up to k^4 words)")
    b.add_argument("--n-features", type=int, default=1000, help="ORB keypoints per frame (default 1000)")
    b.add_argument("--max-descriptors", type=int, default=200_000, help="training descriptors kept (random subset)")
    b.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    b.set_defaults(func=run_build)
    i = sub.add_parser("info", help="print the size of a vocabulary file")
    i.add_argument("path", help="vocabulary .npz, or 'default' (the one shipped with the package)")
    i.set_defaults(func=run_info)
    im = sub.add_parser("import", help="read a DBoW2 text vocabulary (ORB-SLAM2/3's ORBvoc.txt) into an .npz")
    im.add_argument("path", help="DBoW2 text file (python -m data_fetch get orbvoc, then the extracted ORBvoc.txt)")
    im.add_argument("--out", required=True, help="output .npz file")
    im.add_argument("--force", action="store_true", help="replace an existing vocabulary file of that name")
    im.set_defaults(func=run_import)
    ex = sub.add_parser("export", help="write a vocabulary in another format (DBoW2 text: loads in ORB-SLAM2/3)")
    ex.add_argument("path", help="vocabulary .npz, or 'default' (the one shipped with the package)")
    ex.add_argument("--format", choices=("dbow2",), default="dbow2", help="output format (default dbow2: DBoW2 text)")
    ex.add_argument("--out", required=True, help="output file (e.g. voc.txt)")
    ex.add_argument("--force", action="store_true", help="replace an existing vocabulary file of that name")
    ex.set_defaults(func=run_export)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def static_descriptors(frame, n_features: int):
    """ORB descriptors ``(N, 32)`` of one frame, without keypoints on instance masks (if any)."""
    import numpy as np

    from ..features.orb import OrbConfig, extract_features

    mask = None
    dyn = frame.dynamic_mask()
    if dyn is not None:
        mask = (~dyn).astype(np.uint8)
    return extract_features(frame.gray, OrbConfig(n_features=n_features), mask=mask).descriptors


def run_build(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from ..runs import check_output_file

    check_output_file(args.out, ".npz", force=args.force)  # before the long work: never over a folder or a user's file

    if args.recipe:
        from ..slam.vocabulary_recipe import build_vocabulary, read_recipe

        if args.sequences:
            raise ValueError("give either SEQDIRs or --recipe, not both")
        recipe = read_recipe(args.recipe)
        voc = build_vocabulary(recipe)
        out = voc.save(args.out, recipe=recipe.text)
        print(f"{voc} -> {out} ({out.stat().st_size / 1e6:.2f} MB; recipe stored inside)")
        return 0
    if not args.sequences:
        raise ValueError("give SEQDIRs to train on, or --recipe FILE")

    from ..datasets.tum import TumSequence
    from ..slam.vocabulary import VocabularyConfig, train_vocabulary

    if args.stride < 1:
        raise ValueError(f"--stride must be >= 1, got {args.stride}")
    if args.n_features < 1:
        raise ValueError(f"--n-features must be >= 1, got {args.n_features}")
    cfg = VocabularyConfig(branching=args.branching, depth=args.depth, max_descriptors=args.max_descriptors)
    sets = []
    for root in args.sequences:
        seq = TumSequence(root, stride=args.stride, max_frames=args.max_frames)
        for frame in tqdm(seq, desc=f"ORB {seq.name}", unit="frame", leave=False):
            d = static_descriptors(frame, args.n_features)
            if len(d):
                sets.append(d)
    if not sets:
        raise ValueError(f"no ORB features found in {args.sequences}")
    n_desc = sum(len(s) for s in sets)
    print(f"training on {len(sets)} frames, {n_desc} descriptors (k={cfg.branching}, depth={cfg.depth})")
    voc = train_vocabulary(sets, cfg, rng=args.seed)
    out = voc.save(args.out)
    print(f"{voc} -> {out} ({out.stat().st_size / 1e6:.2f} MB)")
    return 0


def _load(path: str):
    from ..slam.vocabulary import default_vocabulary, load_vocabulary

    return default_vocabulary() if path == "default" else load_vocabulary(path)


def run_import(args: argparse.Namespace) -> int:
    from ..runs import check_output_file
    from ..slam.vocabulary_io import read_dbow2_text

    check_output_file(args.out, ".npz", force=args.force)
    voc = read_dbow2_text(args.path)
    out = voc.save(args.out)
    print(f"{voc} -> {out} ({out.stat().st_size / 1e6:.2f} MB)")
    return 0


def run_export(args: argparse.Namespace) -> int:
    from ..runs import check_output_file
    from ..slam.vocabulary_io import write_dbow2_text

    check_output_file(args.out, ".txt", force=args.force)
    voc = _load(args.path)
    out = write_dbow2_text(voc, args.out)
    print(f"{voc} -> {out} (DBoW2 text, {out.stat().st_size / 1e6:.2f} MB; ORB-SLAM2/3 load it with loadFromTextFile)")
    return 0


def run_info(args: argparse.Namespace) -> int:
    import numpy as np

    voc = _load(args.path)
    per_level = np.bincount(voc.level[voc.word_node], minlength=voc.depth + 1)
    print(voc)
    print("words per level:", {int(l): int(c) for l, c in enumerate(per_level) if c})
    print(f"idf: min {voc.idf.min():.3f}, median {np.median(voc.idf):.3f}, max {voc.idf.max():.3f}")
    return 0
