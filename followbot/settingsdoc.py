"""Generate docs/settings.md from the settings classes, so the reference cannot drift.

Every service's settings class is found from the ``followbot.services`` entry points (the class
its ``main`` hands to ``service_main``), every plugin's from its ``settings_type``. A field's
description is the string literal written under it in the class body (read with :mod:`ast`);
types and defaults come from ``msgspec.inspect``. Nested settings structs are expanded into
dotted keys (``association.gate_m``), as ``--set`` spells them.

``followbot settings --markdown docs/settings.md`` rewrites the file; a test checks it is current
and that no setting is without a description.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import inspect
import itertools
import math
import sys
import textwrap
from collections.abc import Iterator
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path

import msgspec
import msgspec.inspect as mi

__all__ = ["Setting", "main", "plugin_roles", "service_settings", "settings_markdown", "walk"]

#: Plugin roles: entry-point group -> (service, the service setting naming the plugin, the one
#: holding its overrides).
_ROLES = {
    "detectors": ("laser_legs", "detector", "detector_settings"),
    "estimators": ("tracker", "estimator", "estimator_settings"),
    "verifiers": ("vision_verify", "verifier", "verifier_settings"),
}


@dataclass(frozen=True)
class Setting:
    key: str
    """Dotted key as ``--set`` and settings files spell it."""
    type: str
    default: str
    doc: str
    owner: str
    """The class that declares it, ``module:Class``."""


def service_settings() -> dict[str, type]:
    """Service name -> its settings class, for every installed service."""
    out: dict[str, type] = {}
    for ep in sorted(entry_points(group="followbot.services"), key=lambda e: e.name):
        module = importlib.import_module(ep.value.split(":")[0])
        cls = _service_main_settings(module)
        if cls is None:
            raise LookupError(
                f"service {ep.name!r} ({ep.value}): no service_main(NAME, SettingsType, ...) call "
                "found in its module, so its settings cannot be documented"
            )
        out[ep.name] = cls
    return out


def _service_main_settings(module) -> type | None:
    tree = ast.parse(inspect.getsource(module))
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and getattr(node.func, "id", getattr(node.func, "attr", None)) == "service_main"
            and len(node.args) >= 2
            and isinstance(node.args[1], ast.Name)
        ):
            return getattr(module, node.args[1].id)
    return None


def plugin_roles() -> dict[str, dict[str, type]]:
    """Role -> {plugin name: its settings class}."""
    out: dict[str, dict[str, type]] = {}
    for role in _ROLES:
        found = {}
        for ep in sorted(entry_points(group=f"followbot.{role}"), key=lambda e: e.name):
            found[ep.name] = ep.load().settings_type
        out[role] = found
    return out


def _field_docs(cls: type) -> dict[str, str]:
    """Field name -> the string literal under it, through the class's bases."""
    docs: dict[str, str] = {}
    core = getattr(cls, "core_settings", None)
    classes = [*reversed(cls.__mro__), *([core] if core is not None else [])]
    for klass in classes:
        if klass in (object, msgspec.Struct) or not isinstance(klass, type):
            continue
        try:
            source = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        body = ast.parse(source).body[0].body
        lines = source.splitlines()
        for a in body:
            target = getattr(a, "target", None)
            if isinstance(a, ast.AnnAssign) and isinstance(target, ast.Name):
                line = lines[a.lineno - 1]
                trailing = line.split("#", 1)[1].strip() if "#" in line else ""
                above = _comment_above(lines, a.lineno - 1)
                if above or trailing:
                    docs[target.id] = " ".join(x for x in (above, trailing) if x)
        for a, b in itertools.pairwise(body):
            target = getattr(a, "target", None)
            if (
                isinstance(a, ast.AnnAssign)
                and isinstance(target, ast.Name)
                and isinstance(b, ast.Expr)
                and isinstance(b.value, ast.Constant)
                and isinstance(b.value.value, str)
            ):
                docs[target.id] = inspect.cleandoc(b.value.value)
    return docs


def _comment_above(lines: list[str], index: int) -> str:
    """The ``#`` comment lines directly above line ``index`` (0-based), joined."""
    out: list[str] = []
    i = index - 1
    while i >= 0 and lines[i].strip().startswith("#"):
        out.insert(0, lines[i].strip().lstrip("#").strip())
        i -= 1
    return " ".join(out)


def _owner(cls: type, name: str) -> type:
    for klass in cls.__mro__:
        if name in getattr(klass, "__annotations__", {}):
            return klass
    return cls


def walk(cls: type, prefix: str = "", skip: frozenset[str] = frozenset()) -> Iterator[Setting]:
    """Every setting of ``cls``, nested structs expanded into dotted keys."""
    info = mi.type_info(cls)
    docs = _field_docs(cls)
    for f in info.fields:
        if f.name in skip:
            continue
        key = f"{prefix}{f.name}"
        inner = _struct_of(f.type)
        if inner is not None:
            yield from walk(inner, f"{key}.")
            continue
        owner = _owner(cls, f.name)
        yield Setting(
            key=key,
            type=_type_name(f.type),
            default=_default(f),
            doc=docs.get(f.name, ""),
            owner=f"{owner.__module__}:{owner.__qualname__}",
        )


def _struct_of(t) -> type | None:
    return t.cls if isinstance(t, mi.StructType) else None


def _type_name(t) -> str:
    simple = {
        mi.IntType: "int",
        mi.FloatType: "float",
        mi.StrType: "str",
        mi.BoolType: "bool",
        mi.NoneType: "null",
        mi.AnyType: "any",
        mi.BytesType: "bytes",
    }
    for kind, name in simple.items():
        if isinstance(t, kind):
            return name + _bounds(t)
    if isinstance(t, mi.LiteralType):
        return " \\| ".join(repr(v) for v in t.values)
    if isinstance(t, mi.UnionType):
        return " \\| ".join(_type_name(x) for x in t.types)
    if isinstance(t, (mi.ListType, mi.SetType, mi.FrozenSetType, mi.VarTupleType)):
        return f"list[{_type_name(t.item_type)}]"
    if isinstance(t, mi.TupleType):
        return "[" + ", ".join(_type_name(x) for x in t.item_types) + "]"
    if isinstance(t, mi.DictType):
        return f"map[{_type_name(t.key_type)}, {_type_name(t.value_type)}]"
    if isinstance(t, mi.StructType):
        return t.cls.__name__
    return type(t).__name__.removesuffix("Type").lower()


def _bounds(t) -> str:
    parts = []
    for attr, sym in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<")):
        v = getattr(t, attr, None)
        if v is not None:
            parts.append(f"{sym} {v:g}" if isinstance(v, float) else f"{sym} {v}")
    if getattr(t, "min_length", None) is not None or getattr(t, "max_length", None) is not None:
        parts.append(f"length {t.min_length or 0}..{t.max_length if t.max_length else ''}")
    return f" ({', '.join(parts)})" if parts else ""


def _default(f) -> str:
    if f.default is not msgspec.NODEFAULT:
        value = f.default
    elif f.default_factory is not msgspec.NODEFAULT:
        value = f.default_factory()
    else:
        return "required"
    value = msgspec.to_builtins(value)
    if isinstance(value, float):
        return "inf" if math.isinf(value) else f"{value:g}"
    return "`" + msgspec.json.encode(value).decode() + "`"


def _node_base() -> type:
    from followbot.services.runtime.settings import NodeSettings

    return NodeSettings


_INTRO = """\
# Settings reference

<!-- Generated by `followbot settings --markdown docs/settings.md` from the settings classes.
     Edit the field docstrings in the code, not this file; a test fails when they diverge. -->

Every service takes its settings from, lowest first: its defaults (below), the compose file's
preset, a settings file (`--config FILE`, YAML), and `--set key=value` (repeatable; nested keys
are dotted, e.g. `--set association.gate_m=0.4`). Unknown keys are refused; a key that was
removed or renamed is refused with a message naming what replaced it (listed per service below).
`followbot run SERVICE --print-settings` prints the merged result. Units are SI (m, s, rad)
unless a key says otherwise (`_deg`, `_ms`, `_px`).

{counts}

## Every service

Settings every service has (`NodeSettings`): the network, the clock guard, logging.

{common}
"""


def _table(rows: list[Setting]) -> str:
    out = ["| key | type | default | meaning |", "|---|---|---|---|"]
    for s in rows:
        doc = " ".join(s.doc.split()).replace("|", "\\|") or "(undocumented)"
        out.append(f"| `{s.key}` | {s.type} | {s.default} | {doc} |")
    return "\n".join(out)


def _top_level(cls: type, skip: frozenset[str]) -> int:
    return sum(1 for f in mi.type_info(cls).fields if f.name not in skip)


def settings_markdown() -> str:
    base = _node_base()
    common = frozenset(f.name for f in mi.type_info(base).fields)
    services = service_settings()
    roles = plugin_roles()
    lines_counts = [
        "| service | top-level settings | all settings (nested expanded) |",
        "|---|---|---|",
    ]
    sections = []
    total = len(list(walk(base)))
    for name, cls in services.items():
        own = list(walk(cls, skip=common))
        total += len(own)
        lines_counts.append(f"| {name} | {_top_level(cls, common)} | {len(own)} |")
        text = [f"## {name}", "", f"`{cls.__module__}:{cls.__qualname__}`", ""]
        text.append(_table(own) if own else "Only the settings every service has.")
        retired = getattr(cls, "retired_settings", None) or {}
        text += _retired_list({**retired, **_nested_retired(cls)})
        for role, (service, key, overrides) in _ROLES.items():
            if service != name:
                continue
            for plugin, stype in roles[role].items():
                rows = list(walk(stype, prefix=f"{overrides}."))
                total += len(rows)
                text += ["", f"### {key}: {plugin}", ""]
                text.append(_table(rows) if rows else "No settings of its own.")
                text += _retired_list(getattr(stype, "retired_settings", None) or {}, overrides)
        sections.append("\n".join(text))
    lines_counts.append(f"| **all, with every plugin and the common ones** | | {total} |")
    head = _INTRO.format(counts="\n".join(lines_counts), common=_table(list(walk(base))))
    return head + "\n" + "\n\n".join(sections) + "\n"


def _retired_list(retired: dict[str, str], prefix: str = "") -> list[str]:
    """Markdown lines listing ``retired`` keys (under ``prefix``, dotted), or none."""
    if not retired:
        return []
    head = "Retired keys (a settings file naming one is refused with this message):"
    lines = [
        f"- `{prefix}{'.' if prefix else ''}{k}`: {' '.join(v.split())}"
        for k, v in sorted(retired.items())
    ]
    return ["", head, "", *lines]


def _nested_retired(cls: type, prefix: str = "") -> dict[str, str]:
    out: dict[str, str] = {}
    for f in mi.type_info(cls).fields:
        inner = _struct_of(f.type)
        if inner is None:
            continue
        for k, v in (getattr(inner, "retired_settings", None) or {}).items():
            out[f"{prefix}{f.name}.{k}"] = v
        out.update(_nested_retired(inner, f"{prefix}{f.name}."))
    return out


def undocumented() -> list[str]:
    """``service: key`` of every setting without a description."""
    base = _node_base()
    common = frozenset(f.name for f in mi.type_info(base).fields)
    out = [f"(every service): {s.key} ({s.owner})" for s in walk(base) if not s.doc]
    for name, cls in service_settings().items():
        out += [f"{name}: {s.key} ({s.owner})" for s in walk(cls, skip=common) if not s.doc]
    for role, plugins in plugin_roles().items():
        for plugin, stype in plugins.items():
            out += [f"{role[:-1]} {plugin}: {s.key} ({s.owner})" for s in walk(stype) if not s.doc]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="followbot settings",
        description="The reference of every service's and plugin's settings: key, type, default "
        "and meaning, read from the settings classes.",
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument("--markdown", metavar="FILE", help="write the reference to FILE")
    g.add_argument(
        "--check", metavar="FILE", help="exit 1 when FILE differs from the generated reference"
    )
    p.add_argument(
        "--undocumented", action="store_true", help="list settings without a description"
    )
    args = p.parse_args(argv)
    if args.undocumented:
        missing = undocumented()
        print("\n".join(missing) or "every setting has a description")
        return 1 if missing else 0
    text = settings_markdown()
    if args.check:
        current = Path(args.check).read_text() if Path(args.check).exists() else ""
        if current != text:
            print(
                f"{args.check} is out of date: run `followbot settings --markdown {args.check}`",
                file=sys.stderr,
            )
            return 1
        return 0
    if args.markdown:
        Path(args.markdown).write_text(text)
        return 0
    sys.stdout.write(text)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
