"""What ``python -m data_fetch`` can fetch: datasets and models, with their official URLs.

Every entry names its source, its licence and, where the publisher states them, its size
(bytes) and SHA-256. Where the catalog does not know the checksum, the downloader records
the SHA-256 of what it fetched in ``DEST/manifest.json`` so that a later fetch can be
compared against it.

URLs are built from a base per source (:data:`BASE_URLS`) and a file name, so tests can
point a whole source at a local HTTP server (``monkeypatch.setitem(BASE_URLS, "tum", ...)``).

Sources
-------
* TUM RGB-D benchmark (Sturm et al., IROS 2012, CC BY 4.0):
  ``https://cvg.cit.tum.de/rgbd/dataset/freiburgN/rgbd_dataset_freiburgN_NAME.tgz``.
* Bonn RGB-D Dynamic dataset (Palazzolo et al., IROS 2019; terms on the project page):
  ``https://www.ipb.uni-bonn.de/html/projects/rgbd_dynamic2019/rgbd_bonn_NAME.zip``.
* YOLOX ONNX models, Megvii GitHub release ``0.1.1rc0`` (Apache-2.0; listed in YOLOX's
  ``demo/ONNXRuntime/README.md``).
* NanoDet-Plus ONNX models, RangiLyu/nanodet GitHub release ``v1.0.0-alpha-1`` (Apache-2.0).
  The original NanoDet-m has no ONNX release asset (its v0.0.1 release ships ncnn files,
  the PyTorch weights are on Google Drive): its entry prints the export command instead.
* ORB-SLAM2's ORB vocabulary ``ORBvoc.txt.tar.gz`` (DBoW2 text format, 10^6 words; GPL-3.0 with
  ORB-SLAM2), from the ``Vocabulary/`` folder of the official raulmur/ORB_SLAM2 repository (the
  project publishes no release assets; its build script extracts this file). Import it with
  ``dynslam vocab import DEST/ORBvoc.txt --out orbvoc.npz``.
* Ultralytics YOLOv8 / YOLO11 (AGPL-3.0): no official ONNX download; the entry prints the
  documented export command ``yolo export model=NAME.pt format=onnx``.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass

__all__ = ["Entry", "BASE_URLS", "CATALOG", "url_for", "get_entry", "CatalogError"]


class CatalogError(KeyError):
    """A name that is not in the catalog."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


#: Base URL of each source; an entry's URL is ``BASE_URLS[entry.source] + entry.path``.
BASE_URLS: dict[str, str] = {
    "tum": "https://cvg.cit.tum.de/rgbd/dataset/",
    "bonn": "https://www.ipb.uni-bonn.de/html/projects/rgbd_dynamic2019/",
    "yolox": "https://github.com/Megvii-BaseDetection/YOLOX/releases/download/0.1.1rc0/",
    "nanodet": "https://github.com/RangiLyu/nanodet/releases/download/v1.0.0-alpha-1/",
    "orbslam2": "https://github.com/raulmur/ORB_SLAM2/raw/master/",
}


@dataclass(frozen=True)
class Entry:
    """One fetchable item.

    Attributes
    ----------
    name : catalog key, e.g. ``"fr3_walking_xyz"``, ``"bonn_crowd"``, ``"yolox_nano"``.
    kind : ``"tum"``, ``"bonn"`` (archives of a sequence), ``"model"`` (an ONNX file), or
        ``"export"`` (no download: ``note`` says how to make the file).
    source : key into :data:`BASE_URLS` (empty for ``"export"``).
    path : file name relative to the source's base URL.
    licence : licence of the data or weights.
    size : bytes, when the publisher states it (checked after download), else None.
    sha256 : hex digest, when the publisher states it (checked), else None.
    note : a line shown by ``list``/``get`` (for ``"export"``: the command to run).
    """

    name: str
    kind: str
    source: str
    path: str
    licence: str
    size: int | None = None
    sha256: str | None = None
    note: str = ""

    @property
    def is_archive(self) -> bool:
        """True when the file is a .tgz/.tar.gz/.zip to extract after download."""
        return self.path.endswith((".tgz", ".tar.gz", ".zip"))


# --------------------------------------------------------------------------------------
# TUM RGB-D: sequence names as they appear in the official file names; the 47 sequences of the
# dataset's download page (its *_validation and calibration archives are not listed).
TUM_SEQUENCES = {
    1: ["xyz", "rpy", "360", "floor", "desk", "desk2", "room", "plant", "teddy"],
    2: [
        "xyz", "rpy", "360_hemisphere", "360_kidnap", "desk", "desk_with_person",
        "large_no_loop", "large_with_loop", "pioneer_360", "pioneer_slam", "pioneer_slam2",
        "pioneer_slam3", "coke", "dishes", "flowerbouquet", "flowerbouquet_brownbackground",
        "metallic_sphere", "metallic_sphere2",
    ],
    3: [
        "walking_xyz", "walking_static", "walking_halfsphere", "walking_rpy",
        "sitting_xyz", "sitting_static", "sitting_halfsphere", "sitting_rpy",
        "long_office_household", "cabinet", "large_cabinet", "teddy",
        "nostructure_notexture_far", "nostructure_notexture_near_withloop",
        "nostructure_texture_far", "nostructure_texture_near_withloop",
        "structure_notexture_far", "structure_notexture_near",
        "structure_texture_far", "structure_texture_near",
    ],
}

# Bonn RGB-D Dynamic: the 24 dynamic and 2 static sequences of the project page (rgbd_bonn_NAME.zip).
BONN_SEQUENCES = [
    "balloon", "balloon2", "balloon_tracking", "balloon_tracking2",
    "crowd", "crowd2", "crowd3",
    "moving_nonobstructing_box", "moving_nonobstructing_box2",
    "moving_obstructing_box", "moving_obstructing_box2",
    "person_tracking", "person_tracking2",
    "placing_nonobstructing_box", "placing_nonobstructing_box2", "placing_nonobstructing_box3",
    "placing_obstructing_box",
    "removing_nonobstructing_box", "removing_nonobstructing_box2", "removing_obstructing_box",
    "synchronous", "synchronous2",
    "kidnapping_box", "kidnapping_box2",
    "static", "static_close_far",
]

_TUM_LICENCE = "CC BY 4.0 (TUM RGB-D benchmark, Sturm et al. 2012)"
_BONN_LICENCE = "Bonn RGB-D Dynamic dataset (Palazzolo et al. 2019), see the project page for terms"
_NANODET_LICENCE = "Apache-2.0 (RangiLyu NanoDet)"
_NANODET_M_NOTE = (
    "the NanoDet releases ship no NanoDet-m ONNX file (v0.0.1 has ncnn models; the "
    "PyTorch weights are linked from the README's legacy model zoo). Export it from a "
    "NanoDet checkout: `python tools/export_onnx.py --cfg_path CONFIG --model_path "
    "nanodet_m.ckpt`, or use nanodet_plus_m_320 (downloadable)."
)
_ORBVOC_LICENCE = "GPL-3.0 (ORB-SLAM2, Mur-Artal and Tardos 2017; DBoW2 vocabulary format)"
_ORBVOC_NOTE = (
    "ORB-SLAM2's ORB vocabulary (ORBvoc.txt, DBoW2 text, k=10 L=6); extracted into DEST, then "
    "`dynslam vocab import DEST/ORBvoc.txt --out orbvoc.npz` (about 1 minute)"
)
_ULTRALYTICS_NOTE = (
    "no official ONNX download; export it yourself (pip install ultralytics): "
    "`yolo export model={stem}.pt format=onnx`{extra}. Ultralytics weights are AGPL-3.0: "
    "software that uses them must be released under the AGPL-3.0 (or an Ultralytics "
    "enterprise licence)."
)


def _rows():
    """One ``(name, kind, source, path, licence, note)`` row per catalog entry."""
    for n, names in TUM_SEQUENCES.items():
        for s in names:
            path = f"freiburg{n}/rgbd_dataset_freiburg{n}_{s}.tgz"
            yield f"fr{n}_{s}", "tum", "tum", path, _TUM_LICENCE, f"TUM RGB-D freiburg{n}/{s}"
    for s in BONN_SEQUENCES:
        yield f"bonn_{s}", "bonn", "bonn", f"rgbd_bonn_{s}.zip", _BONN_LICENCE, f"Bonn RGB-D Dynamic {s}"
    for v, size_note in (("nano", "416x416"), ("tiny", "416x416"), ("s", "640x640")):
        note = f"YOLOX-{v.capitalize()} COCO detector, input {size_note} BGR 0..255"
        yield f"yolox_{v}", "model", "yolox", f"yolox_{v}.onnx", "Apache-2.0 (Megvii YOLOX)", note
    for res in (320, 416):
        note = f"NanoDet-Plus-m COCO detector, input {res}x{res}"
        yield f"nanodet_plus_m_{res}", "model", "nanodet", f"nanodet-plus-m_{res}.onnx", _NANODET_LICENCE, note
    yield "nanodet_m", "export", "", "nanodet_m.onnx", _NANODET_LICENCE, _NANODET_M_NOTE
    yield "orbvoc", "model", "orbslam2", "Vocabulary/ORBvoc.txt.tar.gz", _ORBVOC_LICENCE, _ORBVOC_NOTE
    for stem, extra in (
        ("yolov8n-seg", " (add imgsz=320 for a 320x320 input)"),
        ("yolov8n", ""),
        ("yolo11n-seg", ""),
        ("yolo11n", ""),
    ):
        note = _ULTRALYTICS_NOTE.format(stem=stem, extra=extra)
        yield stem.replace("-", "_"), "export", "", f"{stem}.onnx", "AGPL-3.0 (Ultralytics)", note


def _build() -> dict[str, Entry]:
    return {
        name: Entry(name=name, kind=kind, source=source, path=path, licence=licence, note=note)
        for name, kind, source, path, licence, note in _rows()
    }


#: Every fetchable item by name.
CATALOG: dict[str, Entry] = _build()


def get_entry(name: str) -> Entry:
    """The entry called ``name``; a clear error suggesting close names otherwise."""
    if name in CATALOG:
        return CATALOG[name]
    close = difflib.get_close_matches(name, CATALOG, n=5, cutoff=0.5)
    hint = f"; did you mean {', '.join(close)}?" if close else "; see `python -m data_fetch list`"
    raise CatalogError(f"{name!r} is not in the catalog{hint}")


def url_for(entry: Entry) -> str:
    """The download URL of ``entry`` (``BASE_URLS[source] + path``)."""
    if entry.kind == "export":
        raise CatalogError(f"{entry.name} has no download URL: {entry.note}")
    return BASE_URLS[entry.source] + entry.path
