"""A reproducible vocabulary build: a TOML recipe naming every training image source.

DBoW2's and ORB-SLAM2's vocabularies generalise because they were trained on many varied images
(Galvez-Lopez and Tardos 2012, Sec. VI: 10 K images of indoor and outdoor sequences, unrelated to
the test sequences). The shipped vocabulary is built from the recipe
``dynslam_lab/resources/vocabulary_recipe.toml`` by ``dynslam vocab build --recipe FILE --out VOC.npz``;
the recipe's text is stored inside the ``.npz`` (``vocabulary_recipe(path)`` reads it back).

A recipe has a ``[vocabulary]`` table (``branching``, ``depth``, ``max_iterations``,
``max_descriptors``, ``seed``, ``n_features``) and a list of ``[[source]]`` tables, one per kind:

* ``kind = "office"``: office presets of the synthetic renderer (``presets``, ``seeds`` paired one
  to one, ``n_frames``, ``stride``); keypoints on any instance mask (people, moved objects) left out;
* ``kind = "random_rooms"``: rooms of the seeded random scene generator
  (:func:`~dynslam_lab.datasets.stress.random_scene_preset`; ``seeds = [first, last]``, ``styles``
  cycled over the seeds, ``motion``, ``n_frames``, ``stride``), rendered without movers;
* ``kind = "images"``: image files (``paths``, globs; ``shared:`` means ``$DYNSLAM_SHARED_DATA``
  or ``../shared/data`` beside the clone; skipped with a note where absent), each at ``scales``;
* ``kind = "matplotlib"``: photographs shipped with matplotlib (``files``) and ``reliefs`` hill-shaded
  crops of its elevation models (:mod:`~dynslam_lab.datasets.photos`), each at ``scales``.
"""

from __future__ import annotations

import glob
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..datasets import photos
from ..datasets.stress import random_scene_preset
from ..datasets.synthetic import synthetic_sequence
from ..datasets.tum import TumSequence
from ..features.orb import OrbConfig, extract_features
from .vocabulary import Vocabulary, VocabularyConfig, train_vocabulary

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["Recipe", "read_recipe", "training_descriptors", "build_vocabulary", "vocabulary_recipe", "shared_data_dir"]

_SOURCE_KINDS = ("office", "random_rooms", "images", "matplotlib")


@dataclass(frozen=True)
class Recipe:
    """A parsed recipe: the vocabulary parameters, the ORB keypoints per image, the seed, the sources."""

    config: VocabularyConfig
    n_features: int
    seed: int
    sources: list = field(default_factory=list)
    text: str = ""


def read_recipe(path: str | Path) -> Recipe:
    """Parse a TOML recipe; a clear error names the file and the bad entry."""
    path = Path(path)
    text = path.read_text()
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None
    voc = dict(data.get("vocabulary", {}))
    n_features = int(voc.pop("n_features", 1000))
    seed = int(voc.pop("seed", 0))
    try:
        cfg = VocabularyConfig(**voc)
    except TypeError as exc:
        raise ValueError(f"{path}: [vocabulary] {exc}") from None
    sources = data.get("source", [])
    if not sources:
        raise ValueError(f"{path}: no [[source]] tables")
    for i, s in enumerate(sources):
        if s.get("kind") not in _SOURCE_KINDS:
            raise ValueError(f"{path}: source {i + 1} has kind {s.get('kind')!r}, expected one of {_SOURCE_KINDS}")
    return Recipe(cfg, n_features, seed, sources, text)


def shared_data_dir() -> Path:
    """``$DYNSLAM_SHARED_DATA`` or ``../shared/data`` beside the clone (real data; may be absent)."""
    env = os.environ.get("DYNSLAM_SHARED_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[3] / "shared" / "data"


def _descriptors(gray: np.ndarray, n_features: int, mask: np.ndarray | None = None) -> np.ndarray:
    return extract_features(gray, OrbConfig(n_features=n_features), mask=mask).descriptors


def _sequence_descriptors(root: Path, stride: int, n_features: int) -> list[np.ndarray]:
    out = []
    for frame in TumSequence(root, stride=stride):  # one ORB extraction per frame
        dyn = frame.dynamic_mask()
        d = _descriptors(frame.gray, n_features, None if dyn is None else (~dyn).astype(np.uint8))
        if len(d):
            out.append(d)
    return out


def _image_descriptors(rgb_or_gray: np.ndarray, scales, n_features: int) -> list[np.ndarray]:
    img = rgb_or_gray
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    out = []
    for s in scales:  # a few scales of the same photograph: more, different keypoints
        g = img if s == 1 else cv2.resize(img, None, fx=float(s), fy=float(s), interpolation=cv2.INTER_AREA)
        d = _descriptors(g, n_features)
        if len(d):
            out.append(d)
    return out


def training_descriptors(recipe: Recipe, log=print) -> tuple[list[np.ndarray], list[str]]:
    """One descriptor array per training image, and a line per source saying what it gave."""
    sets: list[np.ndarray] = []
    notes: list[str] = []
    for s in recipe.sources:  # a handful of sources
        kind = s["kind"]
        before = len(sets)
        if kind == "office":
            for preset, seed in zip(s["presets"], s["seeds"]):
                root = synthetic_sequence(preset, int(s["n_frames"]), int(seed))
                sets += _sequence_descriptors(root, int(s.get("stride", 2)), recipe.n_features)
        elif kind == "random_rooms":
            first, last = (int(v) for v in s["seeds"])
            styles = list(s["styles"])
            for k, seed in enumerate(range(first, last + 1)):
                preset = random_scene_preset(seed, name=f"vocab_room_{seed}", motion=str(s.get("motion", "loop")),
                                             style=styles[k % len(styles)], n_frames=int(s["n_frames"]), n_movers=0)
                root = synthetic_sequence(preset)
                sets += _sequence_descriptors(root, int(s.get("stride", 2)), recipe.n_features)
        elif kind == "images":
            files: list[str] = []
            for pattern in s["paths"]:
                p = str(pattern)
                if p.startswith("shared:"):
                    p = str(shared_data_dir() / p.removeprefix("shared:"))
                files += sorted(glob.glob(p))
            if not files:
                notes.append(f"images {s['paths']}: none found, skipped")
                log(notes[-1])
                continue
            for f in files:
                img = cv2.imread(f, cv2.IMREAD_GRAYSCALE)
                if img is None:
                    raise ValueError(f"{f}: cannot read image (recipe source 'images')")
                sets += _image_descriptors(img, s.get("scales", [1.0]), recipe.n_features)
        elif kind == "matplotlib":
            rng = np.random.default_rng(recipe.seed)
            for name in s.get("files", []):
                img = cv2.imread(str(photos.sample_data_path(name)), cv2.IMREAD_GRAYSCALE)
                sets += _image_descriptors(img, s.get("scales", [1.0]), recipe.n_features)
            for _ in range(int(s.get("reliefs", 0))):
                relief = (np.clip(photos.relief_image(480, 640, rng), 0, 1) * 255).astype(np.uint8)
                sets += _image_descriptors(relief, s.get("scales", [1.0]), recipe.n_features)
        n = sum(len(d) for d in sets[before:])
        notes.append(f"{kind}: {len(sets) - before} images, {n} descriptors")
        log(notes[-1])
    if not sets:
        raise ValueError("the recipe gave no training descriptors")
    return sets, notes


def build_vocabulary(recipe: Recipe, log=print) -> Vocabulary:
    """Train the vocabulary a recipe describes (deterministic: every random choice is seeded)."""
    sets, _ = training_descriptors(recipe, log)
    log(f"training on {len(sets)} images, {sum(len(s) for s in sets)} descriptors "
        f"(k={recipe.config.branching}, depth={recipe.config.depth})")
    return train_vocabulary(sets, recipe.config, rng=recipe.seed)


def vocabulary_recipe(path: str | Path) -> str | None:
    """The recipe text stored in a vocabulary ``.npz`` (None for a vocabulary built without one)."""
    with np.load(path, allow_pickle=False) as z:
        return str(z["recipe"]) if "recipe" in z.files else None
