"""Every parameter of the system in one tree of frozen dataclasses.

Each stage defines its own frozen parameter dataclass beside the algorithm that uses it
(``features.orb.OrbConfig``, ``dynamic.depth_ransac.DepthRansacConfig``, ...), with the unit,
default and source paper of every field. :class:`Config` gathers them. Nothing here is
global or mutable: pass a config explicitly, and change a value with
``dataclasses.replace`` (a notebook slider does exactly that) or :func:`with_overrides`.

A TOML file overrides any subset of fields, by section::

    [tracking]
    min_inliers = 20
    [screening.depth_ransac]
    var_threshold = 0.43
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .detection.config import DetectionConfig
from .dynamic.config import ScreeningConfig
from .features.orb import OrbConfig
from .mapping.dense import DenseMapConfig
from .slam.local_mapping import LocalMappingConfig
from .slam.loop_closing import LoopClosingConfig
from .slam.tracking import TrackingConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["Config", "with_overrides", "load_config", "config_to_dict"]


@dataclass(frozen=True)
class Config:
    """Root of the parameter tree: one section per stage (TOML ``[orb]``, ``[tracking]``,
    ``[local_mapping]``, ``[detection]``, ``[screening.*]``, ``[loop_closing]``, ``[dense_map]``)."""

    orb: OrbConfig = field(default_factory=OrbConfig)  # ORB extraction (features/orb.py)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)  # tracking (slam/tracking.py)
    local_mapping: LocalMappingConfig = field(default_factory=LocalMappingConfig)  # local mapping (slam/local_mapping.py)
    detection: DetectionConfig = field(default_factory=DetectionConfig)  # detectors, NMS, motion priors (detection/config.py)
    screening: ScreeningConfig = field(default_factory=ScreeningConfig)  # dynamic-feature screening (dynamic/config.py)
    loop_closing: LoopClosingConfig = field(default_factory=LoopClosingConfig)  # loop closing (slam/loop_closing.py)
    dense_map: DenseMapConfig = field(default_factory=DenseMapConfig)  # dense static map (mapping/dense.py)


def with_overrides(cfg: Any, overrides: dict[str, Any], where: str = "config") -> Any:
    """Return a copy of dataclass ``cfg`` with nested ``overrides`` applied.

    Unknown keys and values of the wrong type raise ``ValueError`` naming the dotted key.
    """
    if not dataclasses.is_dataclass(cfg):
        raise TypeError(f"{where}: expected a dataclass, got {type(cfg).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cfg)}
    changes: dict[str, Any] = {}
    for key, value in overrides.items():
        dotted = f"{where}.{key}"
        if key not in fields:
            raise ValueError(f"{dotted}: unknown parameter; known: {sorted(fields)}")
        current = getattr(cfg, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ValueError(f"{dotted}: expected a table of parameters, got {value!r}")
            changes[key] = with_overrides(current, value, dotted)
            continue
        changes[key] = _coerce(current, value, dotted)
    return dataclasses.replace(cfg, **changes)


def _coerce(current: Any, value: Any, dotted: str) -> Any:
    if current is None or value is None:
        return value
    if isinstance(current, bool):
        if not isinstance(value, bool):
            raise ValueError(f"{dotted}: expected true/false, got {value!r}")
        return value
    if isinstance(current, int) and not isinstance(current, bool):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{dotted}: expected an integer, got {value!r}")
        return value
    if isinstance(current, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{dotted}: expected a number, got {value!r}")
        return float(value)
    if isinstance(current, str):
        if not isinstance(value, str):
            raise ValueError(f"{dotted}: expected a string, got {value!r}")
        return value
    if isinstance(current, tuple):
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{dotted}: expected a list, got {value!r}")
        return tuple(value)
    if isinstance(current, dict):
        if not isinstance(value, dict):
            raise ValueError(f"{dotted}: expected a table, got {value!r}")
        return {**current, **value}
    return value


def load_config(path: str | Path, base: Any) -> Any:
    """Read a TOML file and apply it on top of ``base`` (clear error naming the file)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: config file not found")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: invalid TOML ({exc})") from exc
    try:
        return with_overrides(base, data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc


def config_to_dict(cfg: Any) -> dict[str, Any]:
    """A plain dict of a config tree (for ``summary.json`` and notebooks)."""
    return dataclasses.asdict(cfg)
