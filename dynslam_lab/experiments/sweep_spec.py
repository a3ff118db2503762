"""The sweep spec: sequences x filters x detectors x a parameter grid, read from TOML and checked.

A sweep is the sensitivity study of the papers (how ATE and the keypoint verdicts change with a
threshold) done over many sequences and seeds. Its spec is a TOML file::

    [sweep]
    filters = ["geometry", "full"]        # filter names (dynslam run --filters)
    detectors = ["auto"]                  # detector specs; auto = oracle where the truth exists
    max_frames = 60                       # optional: frames per run (default all)
    loop_closing = true                   # optional (default true, like dynslam run)

    [[sequences]]                         # a synthetic preset, rendered and cached by each worker
    preset = "walking_xyz"
    n_frames = 60
    seeds = [0, 1, 2]

    [[sequences]]                         # a folder in the TUM layout (relative to the spec file)
    path = "data/rgbd_dataset_freiburg3_walking_xyz"
    camera = "tum_fr3"                    # optional; name = "..." sets its label in the table

    [grid]                                # dotted config keys: a list, or a range
    "screening.epipolar.threshold_px" = [0.5, 1.0, 2.0]
    "screening.multiview.reprojection_px" = {start = 2.0, stop = 8.0, num = 4}   # linspace, stop included
    "screening.depth_ransac.var_threshold" = {start = 0.1, stop = 1.0, num = 3, scale = "log"}

    [config]                              # fixed overrides of every run (as in dynslam run --config)
    "tracking.pnp_min_inliers" = 20

    [dask]                                # optional: run on a Dask cluster (or --scheduler)
    scheduler = "tcp://10.0.0.5:8786"

Every key is checked before the first run: an unknown section, key, preset, filter, detector or
config parameter, or a value of the wrong type, raises ``ValueError`` naming the file, the
section and the key (config keys through :func:`dynslam_lab.config.with_overrides`).

Each combination (sequence x seed x filter x detector x grid point) is one :class:`RunTask`,
named by :func:`run_id`: a hash of everything that decides its result, so a run folder can be
recognised (and skipped) when a sweep is started again, and the same run is never done twice.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .. import __version__
from ..config import Config, config_to_dict, with_overrides
from ..datasets.synthetic import cache_key, get_preset
from ..datasets.tum import TumSequence
from ..dynamic.screening import parse_filters
from ..pipeline import detector_stages

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = [
    "SequenceSpec",
    "SweepSpec",
    "RunTask",
    "load_spec",
    "parse_spec",
    "expand_values",
    "run_id",
    "run_inputs",
]

_SECTIONS = ("sweep", "sequences", "grid", "config", "dask")
_SWEEP_KEYS = ("filters", "detectors", "max_frames", "loop_closing", "name")
_SEQUENCE_KEYS = ("preset", "n_frames", "seed", "seeds", "path", "camera", "name", "max_frames")
_DASK_KEYS = ("scheduler",)
_RANGE_KEYS = ("start", "stop", "num", "scale")
#: Files of a sequence folder that decide its frames (hashed into the run identity).
_FOLDER_FILES = ("rgb.txt", "depth.txt", "associations.txt", "groundtruth.txt", "camera.json")


# ------------------------------------------------------------------------- values
def expand_values(value: Any, where: str) -> list:
    """The values of one grid axis: a list as it is, or a range table.

    ``{start, stop, num}`` is ``numpy.linspace(start, stop, num)`` (``stop`` included);
    ``scale = "log"`` spaces the values evenly in log (``numpy.geomspace``). Integer ``start``
    and ``stop`` on a linear scale whose values all fall on integers give integers. Values are
    rounded to 12 significant digits so that ``0.1 * 3`` and ``0.3`` name the same run.
    """
    if isinstance(value, list):
        if not value:
            raise ValueError(f"{where}: empty list of values")
        out = [_canonical(v) for v in value]
    elif isinstance(value, dict):
        unknown = [k for k in value if k not in _RANGE_KEYS]
        if unknown or not {"start", "stop", "num"} <= set(value):
            raise ValueError(f"{where}: a range is {{start, stop, num}} with optional scale = 'linear' | 'log', "
                             f"got keys {sorted(value)}")
        start, stop, num = value["start"], value["stop"], value["num"]
        scale = value.get("scale", "linear")
        for name, v in (("start", start), ("stop", stop)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{where}: range {name} must be a finite number, got {v!r}")
        if isinstance(num, bool) or not isinstance(num, int) or num < 1:
            raise ValueError(f"{where}: range num must be an integer >= 1, got {num!r}")
        if scale not in ("linear", "log"):
            raise ValueError(f"{where}: range scale must be 'linear' or 'log', got {scale!r}")
        if scale == "log" and not (start > 0 and stop > 0):
            raise ValueError(f"{where}: a log range needs start and stop > 0, got {start!r}, {stop!r}")
        if num == 1:
            raw = [float(start)]
        elif scale == "linear":
            raw = [start + (stop - start) * i / (num - 1) for i in range(num)]
        else:
            raw = [start * (stop / start) ** (i / (num - 1)) for i in range(num)]
        out = [_canonical(float(v)) for v in raw]
        if scale == "linear" and isinstance(start, int) and isinstance(stop, int) and all(float(v).is_integer() for v in out):
            out = [int(v) for v in out]
    else:
        raise ValueError(f"{where}: expected a list of values or a range {{start, stop, num}}, got {value!r}")
    seen = []
    for v in out:
        if v in seen:
            raise ValueError(f"{where}: value {v!r} appears twice")
        seen.append(v)
    return out


def _canonical(v: Any) -> Any:
    """Floats rounded to 12 significant digits; lists kept (TOML gives no tuples)."""
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"value {v!r} is not finite")
        return float(f"{v:.12g}")
    if isinstance(v, list):
        return [_canonical(x) for x in v]
    return v


def _nest(dotted: str, value: Any) -> dict:
    """``"a.b.c", v`` -> ``{"a": {"b": {"c": v}}}``."""
    parts = dotted.split(".")
    if not all(parts):
        raise ValueError(f"{dotted!r}: empty part in a dotted key")
    out: dict = {parts[-1]: value}
    for p in reversed(parts[:-1]):
        out = {p: out}
    return out


def _merge(a: dict, b: dict) -> dict:
    """Deep merge of nested override dicts (``b`` wins)."""
    out = dict(a)
    for k, v in b.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _undot(table: dict) -> dict:
    """Nested overrides from a table whose keys may be dotted (``"tracking.pnp_min_inliers" = 20``)."""
    out: dict = {}
    for k, v in table.items():
        out = _merge(out, _nest(k, _undot(v) if isinstance(v, dict) else v))
    return out


def _grid_leaves(table: dict, prefix: str = "") -> list[tuple[str, Any]]:
    """``(dotted key, list or range table)`` pairs of a ``[grid]`` table, nested or dotted."""
    out = []
    for k, v in table.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and not ({"start", "stop"} <= set(v)):
            out += _grid_leaves(v, key + ".")
        else:
            out.append((key, v))
    return out


# ------------------------------------------------------------------------- sequences
@dataclass(frozen=True)
class SequenceSpec:
    """One sequence of a sweep: a synthetic preset at one seed, or a folder.

    Attributes
    ----------
    label : its name in the table and the plots (the preset, the folder name, or ``name``).
    preset, n_frames, seed : the synthetic sequence (``preset`` None for a folder).
    path : the folder (absolute), for a folder sequence.
    camera : camera preset for a folder (None: from the folder name).
    max_frames : frames per run (None: all).
    identity : what names the sequence in the run hash (the synthetic cache key, or the folder's
        path and a hash of its listing files).
    """

    label: str
    preset: str | None = None
    n_frames: int | None = None
    seed: int | None = None
    path: str | None = None
    camera: str | None = None
    max_frames: int | None = None
    identity: dict = field(default_factory=dict, compare=False)

    @property
    def synthetic(self) -> bool:
        return self.preset is not None

    def current_identity(self) -> dict:
        """The identity as this process computes it now (the renderer's cache key, or the folder's
        listing files hashed); equal to :attr:`identity` unless the code or the files changed."""
        if self.synthetic:
            return {"kind": "synthetic", "preset": self.preset, "n_frames": self.n_frames, "seed": self.seed,
                    "cache_key": cache_key(self.preset, self.n_frames, self.seed)}
        return _folder_identity(Path(self.path), self.camera)

    def has_truth(self) -> bool:
        """Per-pixel truth (instance masks) exists: synthetic sequences, and folders with ``masks/``."""
        return self.synthetic or (Path(self.path) / "masks").is_dir()


def _int(value: Any, where: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{where}: expected an integer >= {minimum}, got {value!r}")
    return value


def _folder_identity(path: Path, camera: str | None) -> dict:
    h = hashlib.sha256()
    for name in _FOLDER_FILES:
        p = path / name
        if p.is_file():
            h.update(name.encode() + b"\0" + p.read_bytes() + b"\0")
    return {"kind": "folder", "path": str(path), "camera": camera, "listing_sha256": h.hexdigest()}


def _parse_sequences(entries: Any, base: Path, where: str) -> list[SequenceSpec]:
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{where}: [[sequences]] must list at least one sequence (preset = ... or path = ...)")
    out: list[SequenceSpec] = []
    for i, e in enumerate(entries):
        w = f"{where}: [[sequences]] #{i + 1}"
        if not isinstance(e, dict):
            raise ValueError(f"{w}: expected a table, got {e!r}")
        unknown = [k for k in e if k not in _SEQUENCE_KEYS]
        if unknown:
            raise ValueError(f"{w}: unknown keys {unknown}; known: {list(_SEQUENCE_KEYS)}")
        if ("preset" in e) == ("path" in e):
            raise ValueError(f"{w}: give exactly one of preset = NAME or path = FOLDER")
        max_frames = _int(e["max_frames"], f"{w} max_frames", 2) if "max_frames" in e else None
        if "preset" in e:
            try:
                preset = get_preset(str(e["preset"])).name
            except ValueError as exc:
                raise ValueError(f"{w}: {exc}") from exc
            n = _int(e.get("n_frames", get_preset(preset).n_frames), f"{w} n_frames", 2)
            if "seed" in e and "seeds" in e:
                raise ValueError(f"{w}: give seed or seeds, not both")
            seeds = e.get("seeds", [e.get("seed", 0)])
            if not isinstance(seeds, list) or not seeds:
                raise ValueError(f"{w} seeds: expected a non-empty list of integers, got {seeds!r}")
            seeds = [_int(s, f"{w} seeds", 0) for s in seeds]
            if len(set(seeds)) != len(seeds):
                raise ValueError(f"{w} seeds: a seed appears twice in {seeds}")
            label = str(e.get("name", preset))
            for s in seeds:
                seq = SequenceSpec(label, preset=preset, n_frames=n, seed=s, max_frames=max_frames)
                out.append(dataclasses.replace(seq, identity=seq.current_identity()))
        else:
            for k in ("n_frames", "seed", "seeds"):
                if k in e:
                    raise ValueError(f"{w}: {k} applies to synthetic presets only, not to path = ...")
            path = Path(str(e["path"])).expanduser()
            path = (base / path if not path.is_absolute() else path).resolve()
            camera = str(e["camera"]) if "camera" in e else None
            try:
                TumSequence(path, camera=camera)  # the folder, its listings and the camera are readable
            except (ValueError, FileNotFoundError) as exc:
                raise ValueError(f"{w}: {exc}") from exc
            label = str(e.get("name", path.name))
            seq = SequenceSpec(label, path=str(path), camera=camera, max_frames=max_frames)
            out.append(dataclasses.replace(seq, identity=seq.current_identity()))
    folders = {}
    for s in out:
        key = s.path or s.preset
        if folders.setdefault(s.label, key) != key:
            raise ValueError(f"{where}: two sequences share the label {s.label!r}: give one of them name = ...")
    return out


# ------------------------------------------------------------------------- detectors
def _resolve_detector(spec: str, base: Path, where: str) -> str:
    """A detector spec with its paths made absolute (relative to the spec file); checked."""
    spec = str(spec).strip()
    kind, _, arg = spec.partition(":")
    kind = kind.lower()
    if kind in ("none", "oracle", "auto") and not arg:
        return kind
    if kind == "onnx" or spec.lower().endswith(".onnx"):
        p = Path(arg if kind == "onnx" else spec).expanduser()
        p = (base / p if not p.is_absolute() else p).resolve()
        if not p.is_file():
            raise ValueError(f"{where}: detector model {p} not found")
        return f"onnx:{p}"
    if kind == "cache":
        d, eq, inner = arg.partition("=")
        if not d:
            raise ValueError(f"{where}: detector spec 'cache:' needs a directory, e.g. cache:runs/dets")
        p = Path(d).expanduser()
        p = (base / p if not p.is_absolute() else p).resolve()
        return f"cache:{p}" + (f"={_resolve_detector(inner, base, where)}" if eq else "")
    raise ValueError(f"{where}: unknown detector spec {spec!r}: expected auto, none, oracle, onnx:PATH or cache:DIR")


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _detector_identity(detector: str) -> dict:
    """The detector spec, and the hash of its model file for ``onnx:``."""
    out: dict[str, Any] = {"spec": detector}
    models = [part[5:] for part in detector.replace("=", " ").split() if part.startswith("onnx:")]
    if models:
        out["model_sha256"] = [_file_sha256(Path(m)) for m in models]
    return out


# ------------------------------------------------------------------------- runs
def run_inputs(sequence: SequenceSpec, filters: str, detector: dict, config: Config, loop_closing: bool) -> dict:
    """Everything that decides a run's result: what :func:`run_id` hashes.

    The sequence identity, the filter, the detector (and its model file's hash), the whole
    effective config (every stage's parameters, not only the swept ones), loop closing, the
    frames per run and the package version. ``detection.num_threads`` is left out: it sets the
    speed of the detector, never its output, and the sweep sets it per worker.
    """
    cfg = config_to_dict(config)
    cfg["detection"] = {k: v for k, v in cfg["detection"].items() if k != "num_threads"}
    return {
        "sequence": sequence.identity,
        "max_frames": sequence.max_frames,
        "filters": filters,
        "detector": detector,
        "loop_closing": bool(loop_closing),
        "config": json.loads(json.dumps(cfg)),  # tuples -> lists, as in the JSON files
        "dynslam_lab": __version__,
    }


def run_id(inputs: dict) -> str:
    """16 hex digits of the SHA-256 of ``inputs`` as canonical JSON (sorted keys, no spaces)."""
    text = json.dumps(inputs, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class RunTask:
    """One run of a sweep: what a worker needs to do it, and the hash naming its folder.

    Attributes
    ----------
    run_id : :func:`run_id` of ``inputs``.
    run_dir : the run folder (absolute path, ``OUT/runs/RUN_ID``).
    sequence : the sequence.
    filters, detector : pipeline choices (``detector`` resolved: ``none`` for filters that
        use no detection).
    params : the grid point, ``(dotted key, value)`` pairs in grid order.
    overrides : nested config overrides (``[config]`` and the grid point) on top of ``Config()``.
    loop_closing : build the loop closer.
    inputs : what ``run_id`` hashes (:func:`run_inputs`).
    """

    run_id: str
    run_dir: str
    sequence: SequenceSpec
    filters: str
    detector: str
    params: tuple
    overrides: dict
    loop_closing: bool
    inputs: dict

    def config(self) -> Config:
        return with_overrides(Config(), self.overrides)


@dataclass(frozen=True)
class SweepSpec:
    """A parsed, checked sweep spec (see the module docstring).

    Attributes
    ----------
    source : the spec file (or ``"<spec>"``); name : its title.
    sequences : one entry per sequence and seed.
    filters, detectors : the filter names and detector specs (absolute paths).
    grid : ``(dotted key, values)`` per axis, in file order.
    overrides : nested fixed overrides (``[config]``).
    loop_closing : build the loop closer.
    scheduler : Dask scheduler address of ``[dask]`` (None: the local process pool).
    """

    source: str
    name: str
    sequences: tuple[SequenceSpec, ...]
    filters: tuple[str, ...]
    detectors: tuple[str, ...]
    grid: tuple[tuple[str, tuple], ...]
    overrides: dict
    loop_closing: bool = True
    scheduler: str | None = None

    @property
    def params(self) -> list[str]:
        """The swept config keys."""
        return [k for k, _ in self.grid]

    def tasks(self, out: str | Path) -> list[RunTask]:
        """Every run, in table order (sequence, seed, filter, detector, then the grid), with its
        folder under ``out/runs``. Combinations that would repeat a run (a detector given to a
        filter that uses no detection) appear once."""
        runs_dir = Path(out).resolve() / "runs"
        base = with_overrides(Config(), self.overrides)
        detector_ids = {d: _detector_identity(d) for d in self.detectors if d not in ("auto", "none", "oracle")}
        keys = [k for k, _ in self.grid]
        points = list(itertools.product(*[vals for _, vals in self.grid]))
        tasks: list[RunTask] = []
        seen: set[str] = set()
        for seq in self.sequences:
            for filt in self.filters:
                for det in self.detectors:
                    for point in points:
                        grid_over: dict = {}
                        for k, v in zip(keys, point):
                            grid_over = _merge(grid_over, _nest(k, v))
                        overrides = _merge(self.overrides, grid_over)
                        where = f"{self.source}: run {seq.label} {filt} " + " ".join(f"{k}={v!r}" for k, v in zip(keys, point))
                        try:
                            config = with_overrides(base, grid_over)
                            needs = detector_stages(filt, config)
                        except ValueError as exc:
                            raise ValueError(f"{where}: {exc}") from exc
                        detector = det if needs else "none"
                        if detector == "auto":
                            detector = "oracle" if seq.has_truth() else "none"
                        if needs and detector == "none":
                            raise ValueError(
                                f"{where}: filter {filt!r} runs {needs}, which judge "
                                f"keypoints from detections, but the detector is none for {seq.label} (no synthetic masks "
                                "there for 'auto'): set [sweep] detectors = ['onnx:MODEL'] or ['cache:DIR']")
                        det_id = detector_ids.get(detector, {"spec": detector})
                        inputs = run_inputs(seq, filt, det_id, config, self.loop_closing)
                        rid = run_id(inputs)
                        if rid in seen:
                            continue
                        seen.add(rid)
                        tasks.append(RunTask(rid, str(runs_dir / rid), seq, filt, detector, tuple(zip(keys, point)),
                                             overrides, self.loop_closing, inputs))
        return tasks


def _as_list(value: Any, where: str) -> list[str]:
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise ValueError(f"{where}: expected a name or a non-empty list of names, got {value!r}")
    return list(dict.fromkeys(v.strip() for v in value))


def _section(data: dict, name: str, keys: tuple[str, ...], source: str) -> dict:
    """The table ``[name]`` of the spec (empty when absent), with only ``keys`` allowed."""
    table = data.get(name, {})
    if not isinstance(table, dict):
        raise ValueError(f"{source}: [{name}] must be a table")
    unknown = [k for k in table if k not in keys]
    if unknown:
        raise ValueError(f"{source}: [{name}] unknown keys {unknown}; known: {list(keys)}")
    return table


def parse_spec(data: dict, source: str = "<spec>", base: str | Path = ".") -> SweepSpec:
    """Check a spec given as a dict (TOML tables) and return it; ``base`` resolves relative paths."""
    base = Path(base)
    unknown = [k for k in data if k not in _SECTIONS]
    if unknown:
        raise ValueError(f"{source}: unknown sections {unknown}; known: {list(_SECTIONS)}")
    sweep = _section(data, "sweep", _SWEEP_KEYS, source)
    filters = [f.lower() for f in _as_list(sweep.get("filters", ["none"]), f"{source}: [sweep] filters")]
    for f in filters:
        try:
            parse_filters(f)
        except ValueError as exc:
            raise ValueError(f"{source}: [sweep] filters: {exc}") from exc
    detectors = [_resolve_detector(d, base, f"{source}: [sweep] detectors")
                 for d in _as_list(sweep.get("detectors", ["auto"]), f"{source}: [sweep] detectors")]
    max_frames = _int(sweep["max_frames"], f"{source}: [sweep] max_frames", 2) if "max_frames" in sweep else None
    loop = sweep.get("loop_closing", True)
    if not isinstance(loop, bool):
        raise ValueError(f"{source}: [sweep] loop_closing: expected true/false, got {loop!r}")
    sequences = _parse_sequences(data.get("sequences"), base, source)
    if max_frames is not None:
        sequences = [s if s.max_frames is not None else dataclasses.replace(s, max_frames=max_frames)
                     for s in sequences]

    config_table = data.get("config", {})
    if not isinstance(config_table, dict):
        raise ValueError(f"{source}: [config] must be a table of parameters")
    overrides = _undot(config_table)
    try:
        base_config = with_overrides(Config(), overrides)
    except ValueError as exc:
        raise ValueError(f"{source}: [config] {exc}") from exc

    grid_table = data.get("grid", {})
    if not isinstance(grid_table, dict):
        raise ValueError(f"{source}: [grid] must be a table of dotted keys")
    grid = []
    for key, value in _grid_leaves(grid_table):
        where = f"{source}: [grid] {key}"
        values = expand_values(value, where)
        for v in values:  # each value alone: unknown keys and wrong types are named here
            try:
                with_overrides(base_config, _nest(key, v))
            except ValueError as exc:
                raise ValueError(f"{where} = {v!r}: {exc}") from exc
        grid.append((key, tuple(values)))

    dask = _section(data, "dask", _DASK_KEYS, source)
    scheduler = dask.get("scheduler")
    if scheduler is not None and (not isinstance(scheduler, str) or "://" not in scheduler):
        raise ValueError(f"{source}: [dask] scheduler: expected an address like tcp://HOST:8786, got {scheduler!r}")
    name = str(sweep.get("name", Path(source).stem))
    return SweepSpec(source, name, tuple(sequences), tuple(filters), tuple(detectors), tuple(grid), overrides, loop,
                     scheduler)


def load_spec(path: str | Path) -> SweepSpec:
    """Read and check a spec file (clear errors naming the file and the key)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: sweep spec not found")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: invalid TOML ({exc})") from exc
    return parse_spec(data, str(path), path.parent.resolve())
