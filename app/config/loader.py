"""Loading presets: TOML text -> validated, frozen Config, with errors that point at the line.

Owns: reading the file, ``--set section.key=value`` overrides, type/range/choice checks,
cross-key rules (a cylinder needs a radius, ...), and writing the resolved configuration.
Every problem raises ``ConfigError`` naming the file, the key and (when TOML lets us find
it) the line, with a suggestion; the CLI turns it into exit code 2 without a traceback.
"""
from __future__ import annotations

import dataclasses
import difflib
import math
import pathlib
import re
import tomllib
import types
import typing
from typing import Any

from . import schema
from .errors import ConfigError, find_line as _find_line
from .rules import check  # cross-key rules

SECTION_TYPES = {
    "run": schema.RunConfig,
    "domain": schema.DomainConfig,
    "particles": schema.ParticlesConfig,
    "vessel": schema.VesselConfig,
    "contact": schema.ContactConfig,
    "dem": schema.DemConfig,
    "output": schema.OutputConfig,
    "guard": schema.GuardConfig,
    "video": schema.VideoConfig,
    "probes": schema.ProbesConfig,
    "gas": schema.GasConfig,
    "coupling": schema.CouplingConfig,
    "boundary": schema.BoundarySpec,  # one inline table per face: see _build_boundary
}
FACES = ("x-", "x+", "y-", "y+", "z-", "z+")
FACE_ALIASES = {"bottom": "z-", "top": "z+"}
REQUIRED_SECTIONS = ("run", "domain")


# ---------------------------------------------------------------------------- type checks

def _type_name(tp) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return _type_name(args[0])
    if origin is tuple:
        return "list of numbers"
    if tp is list or origin is list:
        return "list"
    return {float: "number", int: "integer", bool: "true/false", str: "string"}.get(tp, str(tp))


def _coerce(value: Any, tp, meta: dict) -> Any:
    """Convert a TOML value to the declared type or raise ValueError with a reason."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):  # Optional[X]
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        return _coerce(value, args[0], meta)
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ValueError(f"expected true or false, got {value!r}")
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                return int(value)
            raise ValueError(f"expected an integer, got {value!r}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"expected a number (in {meta.get('unit', '-')}), got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f"expected a finite number, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ValueError(f"expected a string, got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"expected a list of {meta.get('length')} numbers, got {value!r}")
        n = meta.get("length")
        if n is not None and len(value) != n:
            raise ValueError(f"expected {n} numbers, got {len(value)}")
        return tuple(_coerce(v, float, meta) for v in value)
    if tp is list or origin is list:
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"expected a list, got {value!r}")
        return [(_coerce(v, float, meta) if isinstance(v, (int, float)) and not isinstance(v, bool) else v) for v in value]
    return value


def _check_range(value, meta: dict) -> str | None:
    if value is None:
        return None
    choices = meta.get("choices")
    if choices and value not in choices:
        close = difflib.get_close_matches(str(value), choices, n=1)
        return f"{value!r} is not one of {', '.join(map(repr, choices))}" + (f" (did you mean {close[0]!r}?)" if close else "")
    lo, hi = meta.get("lo"), meta.get("hi")
    vals = value if isinstance(value, (tuple, list)) else [value]
    for v in vals:
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            continue
        unit = meta.get("unit", "-")
        u = "" if unit == "-" else f" {unit}"
        if lo is not None and (v < lo or (meta.get("lo_open") and v <= lo)):
            op = ">" if meta.get("lo_open") else ">="
            return f"{v:g}{u} is out of range: must be {op} {lo:g}{u}"
        if hi is not None and v > hi:
            return f"{v:g}{u} is out of range: must be <= {hi:g}{u}"
    return None


# ---------------------------------------------------------------------------- building

def _build_section(name: str, cls, table: Any, file: str, text: str):
    if not isinstance(table, dict):
        raise ConfigError(f"[{name}] must be a table of keys", file, name, _find_line(text, name, None))
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for key, value in table.items():
        if key not in fields:
            close = difflib.get_close_matches(key, list(fields), n=1, cutoff=0.6)
            hint = f"did you mean '{close[0]}'?" if close else f"keys of [{name}]: {', '.join(fields)}"
            raise ConfigError(f"unknown key '{key}'", file, f"{name}.{key}", _find_line(text, name, key), hint)
        f = fields[key]
        try:
            v = _coerce(value, hints[key], f.metadata)
        except ValueError as err:
            raise ConfigError(str(err), file, f"{name}.{key}", _find_line(text, name, key),
                              f"{f.metadata.get('doc', '')} [{f.metadata.get('unit', '-')}]") from None
        problem = _check_range(v, f.metadata)
        if problem:
            raise ConfigError(problem, file, f"{name}.{key}", _find_line(text, name, key),
                              f"{f.metadata.get('doc', '')} [{f.metadata.get('unit', '-')}]")
        kwargs[key] = v
    missing = [k for k, f in fields.items() if f.default is dataclasses.MISSING
               and f.default_factory is dataclasses.MISSING and k not in kwargs]
    if missing:
        k = missing[0]
        f = fields[k]
        raise ConfigError(f"missing required key '{k}'", file, f"{name}.{k}", _find_line(text, name, None),
                          f"add `{k} = ...` under [{name}]: {f.metadata.get('doc', '')} [{f.metadata.get('unit', '-')}]")
    return cls(**kwargs)


def _build_boundary(table: Any, file: str, text: str) -> tuple:
    """[boundary] face = { kind = ..., velocity = [...], pressure = ... } -> ((face, BoundarySpec), ...)."""
    if not isinstance(table, dict):
        raise ConfigError("[boundary] must be a table of faces", file, "boundary", _find_line(text, "boundary", None))
    out = {}
    for face, spec_table in table.items():
        canon = FACE_ALIASES.get(face, face)
        if canon not in FACES:
            close = difflib.get_close_matches(face, list(FACES) + list(FACE_ALIASES), n=1)
            raise ConfigError(f"unknown face '{face}'", file, f"boundary.{face}", _find_line(text, "boundary", face),
                              f"did you mean '{close[0]}'?" if close else f"faces: {', '.join(FACES)}, bottom, top")
        if canon in out:
            raise ConfigError(f"face {canon} given twice (through an alias)", file, f"boundary.{face}",
                              _find_line(text, "boundary", face))
        if isinstance(spec_table, str):
            spec_table = {"kind": spec_table}
        out[canon] = _build_section(f"boundary.{face}", schema.BoundarySpec, spec_table, file, text)
    return tuple(sorted(out.items()))


def parse_override(item: str) -> tuple[list[str], Any]:
    """``section.key=value`` -> (["section", "key"], value); the value is read as TOML, else as a string."""
    if "=" not in item:
        raise ConfigError(f"override {item!r} is not of the form section.key=value", "--set", item)
    path, raw = item.split("=", 1)
    parts = path.strip().split(".")
    if len(parts) == 3 and parts[0] == "boundary":  # boundary.bottom.velocity=[0,0,1]
        return parts, _override_value(raw)
    if len(parts) != 2 or not all(parts):
        raise ConfigError(f"override {item!r}: the key must be section.key (e.g. run.duration=0.05)", "--set", path)
    return parts, _override_value(raw)


def _override_value(raw: str) -> Any:
    try:
        return tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        return raw.strip()


def load_text(text: str, file: str = "<preset>", overrides: list[str] | tuple = ()) -> schema.Config:
    """Parse and validate preset text (``file`` is used in messages and to resolve relative paths)."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        m = re.search(r"line (\d+)", str(err))
        raise ConfigError(f"not valid TOML: {err}", file, "", int(m.group(1)) if m else None,
                          "check quotes, brackets and `key = value` syntax on that line") from None
    overridden = {}
    for item in overrides:
        parts, value = parse_override(item)
        overridden[".".join(parts[:2])] = item
        section, key = parts[0], parts[1]
        if section == "boundary":  # the face as the table names it: 'bottom' is 'z-' (a resumed run's config.toml
            faces = data.setdefault("boundary", {})  # says 'z-': --set boundary.bottom.velocity clashed with it)
            if not isinstance(faces, dict):
                raise ConfigError("[boundary] must be a table of faces", file, "boundary")
            canon = FACE_ALIASES.get(key, key)
            named = [k for k in faces if FACE_ALIASES.get(k, k) == canon]
            if len(parts) == 2:  # a whole face: it replaces the face under any of its names
                for k in named:
                    del faces[k]
            elif named:
                key = named[0]
        if len(parts) == 3:  # boundary.<face>.<key>
            face = data.setdefault("boundary", {}).setdefault(key, {})
            if isinstance(face, str):
                face = data["boundary"][key] = {"kind": face}
            face[parts[2]] = value
            continue
        if section not in SECTION_TYPES:
            close = difflib.get_close_matches(section, list(SECTION_TYPES), n=1)
            raise ConfigError(f"unknown section '{section}'", "--set", item,
                              hint=f"did you mean '{close[0]}'?" if close else f"sections: {', '.join(SECTION_TYPES)}")
        data.setdefault(section, {})[key] = value
    try:
        return build(data, file, text)
    except ConfigError as err:
        item = overridden.get(err.key) or next((v for k, v in overridden.items() if err.key.startswith(k)), None)
        if item is None:
            raise
        raise ConfigError(err.message, f"--set {item}", err.key, None, err.hint) from None


def build(data: dict, file: str = "<preset>", text: str = "") -> schema.Config:
    sections = {}
    for name, table in data.items():
        if name not in SECTION_TYPES:
            close = difflib.get_close_matches(name, list(SECTION_TYPES), n=1)
            raise ConfigError(f"unknown section [{name}]", file, name, _find_line(text, name, None),
                              f"did you mean [{close[0]}]?" if close else f"sections: {', '.join(SECTION_TYPES)}")
        if name == "boundary":
            sections[name] = _build_boundary(table, file, text)
        else:
            sections[name] = _build_section(name, SECTION_TYPES[name], table, file, text)
    for name in REQUIRED_SECTIONS:
        if name not in sections:
            raise ConfigError(f"missing section [{name}]", file, name, None,
                              "every preset needs [run] (with duration, in s) and [domain] (lo, hi in m)")
    cfg = schema.Config(**sections, source=str(pathlib.Path(file).resolve().parent) if file and not file.startswith("<") else "")

    check(cfg, file, text)
    return cfg


def load(path: str | pathlib.Path, overrides: list[str] | tuple = ()) -> schema.Config:
    """Read a preset file and validate it (with ``--set`` overrides applied)."""
    p = pathlib.Path(path)
    if not p.exists():
        near = ""
        if p.parent.is_dir():
            close = difflib.get_close_matches(p.name, [q.name for q in p.parent.glob("*.toml")], n=1)
            near = f"did you mean {p.parent / close[0]}?" if close else f"presets there: {', '.join(sorted(q.name for q in p.parent.glob('*.toml'))) or 'none'}"
        raise ConfigError("no such preset file", str(p), hint=near or "give the path to a .toml preset")
    if p.is_dir():
        raise ConfigError("is a folder, not a preset file", str(p), hint="give the path to a .toml preset")
    try:
        text = p.read_text(encoding="utf-8-sig")  # a byte-order mark (Windows editors) is not TOML: dropped
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"cannot read: {err}", str(p)) from None
    return load_text(text, str(p), overrides)


def resolve_path(cfg: schema.Config, path: str) -> pathlib.Path:
    """A path written in a preset, relative to the preset's folder."""
    p = pathlib.Path(path).expanduser()
    if not p.is_absolute() and cfg.source:
        p = pathlib.Path(cfg.source) / p
    return p


# ---------------------------------------------------------------------------- writing

def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(v)


def sections_of(cfg: schema.Config) -> dict:
    return {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg) if not f.metadata.get("internal")}


def dump(cfg: schema.Config) -> str:
    """The fully resolved configuration as TOML, each key commented with its unit and doc."""
    lines = ["# fbed resolved configuration: every key with the value used, its unit and meaning", ""]
    for name, section in sections_of(cfg).items():
        if section is None:
            continue
        if name == "boundary":
            if section:
                lines.append("[boundary]  # per domain face; faces not listed are no-slip walls")
                for face, b in section:
                    keys = [f for f in dataclasses.fields(b) if f.name == "kind" or getattr(b, f.name) != f.default
                            and not (f.default_factory is not dataclasses.MISSING and not getattr(b, f.name))]
                    items = ", ".join(f"{f.name} = {_toml_value(getattr(b, f.name))}" for f in keys)
                    units = ", ".join(f"{f.name} [{f.metadata.get('unit', '-')}]" for f in keys if f.name != "kind")
                    lines.append(f'"{face}" = {{ {items} }}' + (f"  # {units}" if units else ""))
                lines.append("")
            continue
        lines.append(f"[{name}]")
        for f in dataclasses.fields(section):
            v = getattr(section, f.name)
            unit = f.metadata.get("unit", "-")
            comment = f"  # [{unit}] {f.metadata.get('doc', '')}"
            if v is None:
                lines.append(f"# {f.name} = (default){comment}")
            else:
                if f.name in ("initial_state", "sdf_file", "start_from") and v:
                    v = str(resolve_path(cfg, v))
                lines.append(f"{f.name} = {_toml_value(v)}{comment}")
        lines.append("")
    return "\n".join(lines)
