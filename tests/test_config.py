"""Config trees: nested overrides, TOML files, and clear errors naming the parameter."""

from dataclasses import dataclass, field

import pytest

from dynslam_lab.config import config_to_dict, load_config, with_overrides


@dataclass(frozen=True)
class _Inner:
    threshold: float = 0.43
    iterations: int = 10
    enabled: bool = True


@dataclass(frozen=True)
class _Root:
    inner: _Inner = field(default_factory=_Inner)
    name: str = "x"
    sizes: tuple = (1, 2)


def test_nested_override_returns_new_frozen_copy():
    base = _Root()
    cfg = with_overrides(base, {"inner": {"threshold": 1, "iterations": 20}, "sizes": [3, 4]})
    assert cfg.inner.threshold == 1.0 and isinstance(cfg.inner.threshold, float)
    assert cfg.inner.iterations == 20 and cfg.sizes == (3, 4)
    assert base.inner.threshold == 0.43  # the original is untouched


@pytest.mark.parametrize(
    "overrides,message",
    [
        ({"inner": {"bogus": 1}}, r"config\.inner\.bogus: unknown parameter"),
        ({"inner": {"iterations": 2.5}}, r"config\.inner\.iterations: expected an integer"),
        ({"inner": {"enabled": 1}}, r"config\.inner\.enabled: expected true/false"),
        ({"inner": 3}, r"config\.inner: expected a table"),
        ({"name": 5}, r"config\.name: expected a string"),
    ],
)
def test_bad_overrides_name_the_parameter(overrides, message):
    with pytest.raises(ValueError, match=message):
        with_overrides(_Root(), overrides)


def test_toml_file(tmp_path):
    p = tmp_path / "c.toml"
    p.write_text("name = 'y'\n[inner]\nthreshold = 0.1\n")
    cfg = load_config(p, _Root())
    assert cfg.name == "y" and cfg.inner.threshold == 0.1
    assert config_to_dict(cfg)["inner"]["threshold"] == 0.1
    p.write_text("[inner\n")
    with pytest.raises(ValueError, match=r"c\.toml: invalid TOML"):
        load_config(p, _Root())
    with pytest.raises(ValueError, match="config file not found"):
        load_config(tmp_path / "missing.toml", _Root())
