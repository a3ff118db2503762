"""Every parameter of the system in one tree of frozen dataclasses.

Each stage defines its own frozen parameter dataclass beside the algorithm that uses it
(``features.orb.OrbConfig``, ``dynamic.depth_ransac.DepthRansacConfig``, ...), with the unit,
default and source paper of every field. :class:`Config` gathers them. Nothing here is
global or mutable: pass a config explicitly, and change a value with
``dataclasses.replace`` (a notebook slider does exactly that) or :func:`with_overrides`.

A TOML file overrides any subset of fields, by section::

    [tracking]
    min_local_inliers = 20
    [screening.depth_ransac]
    var_threshold = 0.43

Every value is checked when it is loaded: its type against the field's annotation (an integer
where an integer is expected, a finite number, a list of the right length and element type),
then its range by the stage's own ``__post_init__`` (negative thresholds, empty ranges); the
error names the file and the dotted field, e.g. ``my.toml: tracking.min_depth: must be >= 0``.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import types
import typing
from dataclasses import dataclass, field
from functools import lru_cache
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
    loop_closing: LoopClosingConfig = field(default_factory=LoopClosingConfig)  # loop closing (slam/loop_closing/)
    dense_map: DenseMapConfig = field(default_factory=DenseMapConfig)  # dense static map (mapping/dense.py)


def with_overrides(cfg: Any, overrides: dict[str, Any], where: str = "config") -> Any:
    """Return a copy of dataclass ``cfg`` with nested ``overrides`` applied.

    Unknown keys, values of the wrong type (against the field's annotation) and values out of
    range (the dataclass's ``__post_init__``) raise ``ValueError`` naming the dotted key.
    """
    if not dataclasses.is_dataclass(cfg):
        raise TypeError(f"{where}: expected a dataclass, got {type(cfg).__name__}")
    if not isinstance(overrides, dict):
        raise ValueError(f"{where}: expected a table of parameters, got {overrides!r}")
    fields = {f.name: f for f in dataclasses.fields(cfg)}
    hints = _type_hints(type(cfg))
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
        hint = hints.get(key)
        value = _coerce(current, value, dotted) if hint is None else _check(value, hint, dotted)
        if isinstance(current, dict) and isinstance(value, dict):
            value = {**current, **value}
        changes[key] = value
    try:
        return dataclasses.replace(cfg, **changes)
    except (ValueError, TypeError) as exc:
        msg = str(exc)
        raise ValueError(msg if msg.startswith(where) else f"{where}: {msg}") from None


@lru_cache(maxsize=None)
def _type_hints(cls: type) -> dict[str, Any]:
    """The resolved field annotations of a dataclass (empty when they cannot be resolved)."""
    try:
        return typing.get_type_hints(cls)
    except Exception:  # an annotation naming something the module does not define at run time
        return {}


def _type_name(hint: Any) -> str:
    return {bool: "true/false", int: "an integer", float: "a number", str: "a string"}.get(hint, str(hint))


def _check(value: Any, hint: Any, dotted: str) -> Any:
    """``value`` checked (and converted: int -> float, list -> tuple) against a type annotation."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if hint in (tuple, dict):  # bare annotations
        origin = hint
    if hint is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _check(value, a, dotted)
            except ValueError:
                pass
        raise ValueError(f"{dotted}: expected {' or '.join(_type_name(a) for a in args)}, got {value!r}")
    if hint is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{dotted}: expected true/false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{dotted}: expected an integer, got {value!r}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{dotted}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"{dotted}: expected a finite number, got {value!r}")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise ValueError(f"{dotted}: expected a string, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{dotted}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_check(v, args[0], f"{dotted}[{i}]") for i, v in enumerate(value))
        if args:
            if len(value) != len(args):
                raise ValueError(f"{dotted}: expected a list of {len(args)} values, got {value!r}")
            return tuple(_check(v, a, f"{dotted}[{i}]") for i, (v, a) in enumerate(zip(value, args)))
        return tuple(value)
    if origin is dict:
        if not isinstance(value, dict):
            raise ValueError(f"{dotted}: expected a table, got {value!r}")
        if len(args) == 2:
            return {_check(k, args[0], dotted): _check(v, args[1], f"{dotted}.{k}") for k, v in value.items()}
        return dict(value)
    return value


def _coerce(current: Any, value: Any, dotted: str) -> Any:
    """``value`` checked against the type of the field's current value (fields without a usable annotation)."""
    if current is None or value is None:
        return value
    for t in (bool, int, float, str):
        if isinstance(current, t):
            return _check(value, t, dotted)
    if isinstance(current, tuple):
        return _check(value, tuple, dotted)
    if isinstance(current, dict):
        return _check(value, dict, dotted)
    return value


def load_config(path: str | Path, base: Any) -> Any:
    """Read a TOML file and apply it on top of ``base`` (clear error naming the file)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: config file not found")
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (byte {raw[exc.start]:#04x} at offset {exc.start}); "
                         "TOML files must be UTF-8") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: invalid TOML ({exc})") from None
    try:
        return with_overrides(base, data)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc


def config_to_dict(cfg: Any) -> dict[str, Any]:
    """A plain dict of a config tree (for ``summary.json`` and notebooks)."""
    return dataclasses.asdict(cfg)
