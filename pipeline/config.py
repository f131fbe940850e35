"""Typed configuration: frozen dataclasses as defaults, YAML files and ``--set key=value`` as overrides.

Unknown keys are errors everywhere (a mistyped key must not be silently ignored), and so is a key given
twice in one YAML mapping. Numbers are finite and never negative (weights, rates, iteration counts,
distances, sizes), except in fields marked ``metadata=SIGNED`` (cosine thresholds). A field whose type is a
tuple of dataclasses (a schedule of stages) is given in YAML as a list of mappings, each checked the same
way.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import typing
from pathlib import Path
from typing import Any, TypeVar

from rig.errors import InputError
from rig.io.inputs import regular_file

T = TypeVar("T")
MAX_CONFIG_BYTES = 16 << 20
"""The largest configuration file read (16 MiB; jnr's own are a few kB)."""


class ConfigError(InputError):
    """A configuration file or override that does not match the typed defaults."""


SIGNED = {"signed": True}
"""``dataclasses.field(metadata=SIGNED)``: a numeric setting that may be negative (e.g. a cosine threshold)."""


def _negative(value) -> bool:
    if isinstance(value, bool):
        return False
    if isinstance(value, int | float):
        return value < 0
    if isinstance(value, tuple):
        return any(_negative(v) for v in value)
    return False


def _build(cls: type[T], values: dict, where: str) -> T:
    if not isinstance(values, dict):
        raise ConfigError(f"{where}: expected a mapping of {cls.__name__} fields, got {type(values).__name__}")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ConfigError(f"{where}: unknown setting(s) {unknown}; known: {sorted(known)}")
    out: dict[str, Any] = {}
    fields = {f.name: f for f in dataclasses.fields(cls)}
    for name, value in values.items():
        # a partial mapping for a nested config overrides that field's own default, not its class's
        value = _merged(_default(fields[name]), value)
        out[name] = _coerce(hints[name], value, f"{where}.{name}")
        if _negative(out[name]) and not fields[name].metadata.get("signed"):
            raise ConfigError(f"{where}.{name}: must not be negative, got {value!r}")
    try:
        return cls(**out)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def _merged(base, value):
    """``value`` (a partial mapping) over a nested config's default instance ``base``, level by level: a mapping
    for a field that is itself a config keeps that field's values in ``base`` (e.g. the photo fit's landmark
    prior), not its class's defaults. Anything else: ``value`` as given."""
    if not (isinstance(value, dict) and dataclasses.is_dataclass(base) and not isinstance(base, type)):
        return value
    names = {f.name for f in dataclasses.fields(base)}
    out = {name: getattr(base, name) for name in names}
    for key, item in value.items():
        out[key] = _merged(getattr(base, key), item) if key in names else item  # unknown keys: _build's error
    return out


def _default(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def _coerce(hint, value, where: str):
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if dataclasses.is_dataclass(hint):
        return value if isinstance(value, hint) else _build(hint, value, where)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        inner = args[0] if args else Any
        return tuple(_coerce(inner, v, f"{where}[{i}]") for i, v in enumerate(value))
    if hint is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false", "yes", "no", "1", "0"):
            return value.lower() in ("true", "yes", "1")
        raise ConfigError(f"{where}: expected true/false, got {value!r}")
    if hint in (int, float):
        if isinstance(value, bool):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        try:
            number = hint(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{where}: expected {hint.__name__}, got {value!r}") from None
        if not math.isfinite(number):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
        if hint is int and isinstance(value, float) and not value.is_integer():
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return number
    if hint is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


def parse_overrides(items: list[str] | None) -> dict:
    """``["a=1", "b.c=x"]`` -> ``{"a": 1, "b.c": "x"}`` (values parsed as YAML scalars)."""
    import yaml

    out: dict = {}
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"--set expects KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise ConfigError(f"--set {item}: the value is not valid YAML ({_yaml_problem(exc)})") from None
        except RecursionError:
            raise ConfigError(f"--set {item}: the value is nested too deeply") from None
    return out


def load_config(cls: type[T], path: str | Path | None = None, overrides: dict | None = None) -> T:
    """Defaults of ``cls``, overridden by a YAML file and then by ``overrides`` (``"a"`` or, for a nested
    config dataclass, ``"group.a"``).

    Raises:
        ConfigError: unknown keys, values of the wrong type, a file that is not a mapping.
        FileNotFoundError: ``path`` does not exist.
    """
    values: dict = {}
    if path is not None:
        import yaml

        path = regular_file(path, "config file", MAX_CONFIG_BYTES)  # a FIFO or a device is not "not found"
        try:
            data = yaml.load(path.read_text(), Loader=_unique_key_loader())  # a SafeLoader
        except _DuplicateKey as exc:
            raise ConfigError(f"{path}: {exc}") from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"{path}: not valid YAML ({_yaml_problem(exc)})") from None
        except UnicodeDecodeError:
            raise ConfigError(f"{path}: not a text (YAML) file") from None
        except RecursionError:
            raise ConfigError(f"{path}: nested too deeply to be a jnr configuration") from None
        data = data or {}
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: expected a mapping of {cls.__name__} fields")
        values.update(data)
    for key, value in (overrides or {}).items():
        # "landmarks.prior.lambda_m=0.5" sets a field of a nested config group
        *parents, leaf = key.split(".")
        node = values
        for part in parents:
            child = node.get(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"--set {key}: {part!r} is not a nested group of settings")
            node[part] = child = dict(child)
            node = child
        node[leaf] = value
    return _build(cls, values, cls.__name__ if path is None else str(path))


class _DuplicateKey(Exception):
    pass


@functools.cache
def _unique_key_loader():
    """yaml's SafeLoader, refusing a key given twice in one mapping (the last would win silently); the class is
    made once (yaml is imported lazily)."""
    import yaml

    class Loader(yaml.SafeLoader):
        def construct_mapping(self, node, deep=False):
            seen = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                if key in seen:
                    line = key_node.start_mark.line + 1
                    raise _DuplicateKey(f"the key {key!r} is given twice (again on line {line})")
                try:
                    seen.add(key)
                except TypeError:
                    pass  # an unhashable key: SafeLoader reports it
            return super().construct_mapping(node, deep=deep)

    return Loader


def _yaml_problem(exc) -> str:
    """A YAML error in one line: what and where (line, column; 1-based)."""
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
    mark = getattr(exc, "problem_mark", None)
    return f"{problem} at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else problem


def config_to_dict(config) -> dict:
    """A config dataclass as plain JSON/YAML-ready data (nested groups as mappings, tuples as lists)."""

    def plain(value):
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [plain(v) for v in value]
        return value

    return plain(dataclasses.asdict(config))


CONFIG_FILE = "config.yaml"
"""The resolved configuration every fit writes beside its outputs."""


def dump_config(config, path: str | Path, *, command: str | None = None) -> None:
    """Write ``config`` (a config dataclass, every field resolved) as YAML that :func:`load_config`
    reads back to an equal config: ``jnr fit ... --config OUT/config.yaml`` repeats a fit."""
    import yaml

    header = f"# The settings of this fit ({type(config).__module__}.{type(config).__name__}), every field resolved.\n"
    if command:  # one comment line, whatever the command line held (a newline in a file name)
        header += f"# Made by: {command.encode('unicode_escape').decode('ascii')}\n"
    header += "# Repeat it with --config on this file.\n"
    Path(path).write_text(header + yaml.safe_dump(config_to_dict(config), sort_keys=False, width=100))
