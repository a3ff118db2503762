"""COCO classes and the motion priors the papers attach to them.

Every detector in this toolkit speaks the 80 COCO classes (index = class id, the order of
the COCO 2017 detection task as the YOLO families export it). The papers then say which of
those classes may move, in three different ways, all kept here as plain tables:

* **A-priori dynamic set** (Chang et al., IEEE TIM 2021, Chang et al. 2021, Sec. III-A): *person,
  bicycle, car, motorcycle, airplane, bus, train, truck, boat, bird, cat, dog, horse, sheep,
  cow, elephant, bear, zebra, giraffe*. Keypoints inside their masks are dropped at once.
* **Six motion-probability categories** (Ge et al., ASG-SLAM 2024, Ge et al. 2024, Sec. 2.4,
  Fig. 3): sturdy public facilities < household and office items < vehicles < personal
  belongings < humans < animals, "each sorted by the likelihood of motion". The paper gives
  the order but its probabilities only in a figure, so the defaults below are our reading
  (monotone in the paper's order); the class-to-category split of the 80 classes is ours too.
  The screening stage restores features of the least probable categories first while the
  static ratio ``delta = m / n`` (eq. 3) is below ``delta_1``.
* **High / medium / low dynamic levels** (Zhang et al., IJGI 2023, Zhang et al. 2023, Sec. 4): objects in
  high and medium dynamic boxes are removed directly, low-dynamic (a-priori static) objects
  are checked with the epipolar constraint. The paper names the levels but not their
  members; our split: people and animals high, vehicles and hand-carried objects medium,
  everything else low.

All tables are defaults of :class:`~dynslam_lab.detection.config.MotionPriorConfig`, which a
TOML file or a notebook can edit (``dataclasses.replace``); the functions below take that
config explicitly.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

__all__ = [
    "COCO_CLASSES",
    "APRIORI_DYNAMIC",
    "ASG_CATEGORIES",
    "ASG_CATEGORY_OF",
    "ASG_PROBABILITIES",
    "DYNAMIC_LEVELS",
    "DYNAMIC_LEVEL_OF",
    "class_id",
    "class_ids_of",
    "is_apriori_dynamic",
    "motion_probability",
    "dynamic_level",
]

#: The 80 COCO detection classes; list index = class id of every YOLO / NanoDet export.
COCO_CLASSES: list[str] = [
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat",
    "traffic light", "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat", "dog",
    "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe", "backpack", "umbrella",
    "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard", "sports ball", "kite",
    "baseball bat", "baseball glove", "skateboard", "surfboard", "tennis racket", "bottle",
    "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple", "sandwich", "orange",
    "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair", "couch", "potted plant", "bed",
    "dining table", "toilet", "tv", "laptop", "mouse", "remote", "keyboard", "cell phone",
    "microwave", "oven", "toaster", "sink", "refrigerator", "book", "clock", "vase", "scissors",
    "teddy bear", "hair drier", "toothbrush",
]

_INDEX = {name: i for i, name in enumerate(COCO_CLASSES)}

#: A-priori dynamic COCO classes of Chang et al. 2021 (Chang et al. 2021, Sec. III-A), in the paper's order.
APRIORI_DYNAMIC: tuple[str, ...] = (
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat",
    "bird", "cat", "dog", "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe",
)

_ANIMALS = ("bird", "cat", "dog", "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe")
_VEHICLES = ("bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat")
_BELONGINGS = (
    "backpack", "umbrella", "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard",
    "sports ball", "kite", "baseball bat", "baseball glove", "skateboard", "surfboard",
    "tennis racket", "cell phone",
)
_PUBLIC = ("traffic light", "fire hydrant", "stop sign", "parking meter", "bench")

#: ASG-SLAM's six categories (Ge et al. 2024, Sec. 2.4), in increasing likelihood of motion.
ASG_CATEGORIES: dict[str, tuple[str, ...]] = {
    "public_facility": _PUBLIC,
    "household_office": tuple(
        c for c in COCO_CLASSES
        if c not in (*_PUBLIC, *_VEHICLES, *_BELONGINGS, *_ANIMALS, "person")
    ),
    "vehicle": _VEHICLES,
    "personal_belonging": _BELONGINGS,
    "human": ("person",),
    "animal": _ANIMALS,
}

#: COCO class name -> ASG-SLAM category name.
ASG_CATEGORY_OF: dict[str, str] = {c: cat for cat, members in ASG_CATEGORIES.items() for c in members}

#: Default prior motion probability of each ASG-SLAM category (our reading of Fig. 3: the
#: paper fixes only the order).
ASG_PROBABILITIES: dict[str, float] = {
    "public_facility": 0.05,
    "household_office": 0.2,
    "vehicle": 0.4,
    "personal_belonging": 0.6,
    "human": 0.9,
    "animal": 0.95,
}

#: Zhang et al.'s three dynamic levels (Sec. 4); the members are our reading.
DYNAMIC_LEVELS: dict[str, tuple[str, ...]] = {
    "high": ("person", *_ANIMALS),
    "medium": (*_VEHICLES, *_BELONGINGS, "bottle", "cup", "book", "chair"),
    "low": (),
}
DYNAMIC_LEVELS["low"] = tuple(
    c for c in COCO_CLASSES if c not in DYNAMIC_LEVELS["high"] and c not in DYNAMIC_LEVELS["medium"]
)

#: COCO class name -> "high" | "medium" | "low".
DYNAMIC_LEVEL_OF: dict[str, str] = {c: lvl for lvl, members in DYNAMIC_LEVELS.items() for c in members}


def class_id(name: str) -> int:
    """COCO class id of ``name``; ``ValueError`` naming the unknown class otherwise."""
    try:
        return _INDEX[name]
    except KeyError:
        raise ValueError(f"unknown COCO class {name!r}; known classes: {', '.join(COCO_CLASSES)}") from None


def class_ids_of(names: Iterable[str]) -> np.ndarray:
    """``(K,)`` int64 COCO ids of class ``names`` (each must be a COCO class)."""
    return np.array([class_id(n) for n in names], dtype=np.int64)


def _names(class_ids: np.ndarray) -> list[str]:
    ids = np.asarray(class_ids, dtype=np.int64).reshape(-1)
    return [COCO_CLASSES[i] if 0 <= i < len(COCO_CLASSES) else "" for i in ids]


def is_apriori_dynamic(class_ids: np.ndarray, priors=None) -> np.ndarray:
    """``(N,)`` bool: whether each COCO class id is in the a-priori dynamic set (Chang et al. 2021).

    ``priors`` (a :class:`~dynslam_lab.detection.config.MotionPriorConfig`, or None for the
    paper's tables): its ``apriori_dynamic`` overrides the paper's set.
    """
    members = set(APRIORI_DYNAMIC if priors is None else priors.apriori_dynamic)
    lut = np.array([c in members for c in COCO_CLASSES], dtype=bool)
    ids = np.asarray(class_ids, dtype=np.int64).reshape(-1)
    out = np.zeros(len(ids), dtype=bool)
    ok = (ids >= 0) & (ids < len(lut))
    out[ok] = lut[ids[ok]]
    return out


def motion_probability(class_ids: np.ndarray, priors=None) -> np.ndarray:
    """``(N,)`` float64 prior motion probability of each COCO class id (ASG-SLAM, Ge et al. 2024).

    The class's category (``priors.asg_category_of``) selects a probability
    (``priors.asg_probabilities``). Ids outside COCO get 0 (treated as static).
    """
    category_of = ASG_CATEGORY_OF if priors is None else priors.asg_category_of
    probability = ASG_PROBABILITIES if priors is None else priors.asg_probabilities
    lut = np.array([float(probability.get(category_of.get(c, ""), 0.0)) for c in COCO_CLASSES])
    ids = np.asarray(class_ids, dtype=np.int64).reshape(-1)
    out = np.zeros(len(ids))
    ok = (ids >= 0) & (ids < len(lut))
    out[ok] = lut[ids[ok]]
    return out


def dynamic_level(class_ids: np.ndarray, priors=None) -> list[str]:
    """Zhang et al.'s dynamic level (``"high"``, ``"medium"``, ``"low"``) of each COCO class id."""
    level_of = DYNAMIC_LEVEL_OF if priors is None else priors.dynamic_level_of
    return [level_of.get(n, "low") for n in _names(class_ids)]
