"""The parameter tables of the docs, generated from the config schema (``deepbbs_ros/config/``).

Every field of a section is one row: its dotted name, type, default and description. The description is the
field's comment in its section's module (``config/node.py``, ...): the comment on its line, then the comment lines
right above it (a blank line keeps a comment about a group of fields out); comment lines below a field that lead to no
other field continue its description. A field without any comment is an error, so a new parameter cannot reach the
docs undocumented.

The tables live in Markdown pages between ``<!-- params:SECTION[,SECTION...] -->`` and ``<!-- /params -->``
markers::

    python -m deepbbs_ros.config_doc           # rewrite the tables in docs/*.md
    python -m deepbbs_ros.config_doc --check   # exit 1 when a table differs from the schema
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import io
import re
import sys
import tokenize
import typing
from pathlib import Path

from deepbbs_ros.config import Config
from deepbbs_ros.errors import ConfigError

MARKER = re.compile(r"(<!-- params:([a-z_,]+) -->\n)(.*?)(<!-- /params -->)", re.S)


def _section_classes() -> dict[str, type]:
    return {f.name: type(getattr(Config(), f.name)) for f in dataclasses.fields(Config)}


def field_comments(cls: type) -> dict[str, str]:
    """``{field name: description}`` from the comments around each field in the class's source."""
    lines = inspect.getsource(cls).splitlines()
    fields = {f.name for f in dataclasses.fields(cls)}
    comments: dict[int, str] = {}  # line index -> comment text (trailing or whole-line)
    code_lines: set[int] = set()
    for tok in tokenize.generate_tokens(io.StringIO("\n".join(lines) + "\n").readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0] - 1] = tok.string.lstrip("#").strip()
        elif tok.type not in (tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
                              tokenize.ENDMARKER):
            code_lines.add(tok.start[0] - 1)
    field_re = re.compile(r"\s+(\w+)\s*:")
    docs: dict[str, list[str]] = {}
    block: list[str] = []  # whole-line comments since the last code line
    last: str | None = None  # the field defined on the previous code line
    for i, line in enumerate(lines):
        m = field_re.match(line)
        if i in code_lines and m and m.group(1) in fields:
            name = m.group(1)
            trailing = comments.get(i)
            docs[name] = [trailing + ";", *block] if trailing and block else [trailing] if trailing else block
            block, last = [], name
        elif i in code_lines:  # another statement: a pending block belongs to the field above it
            if block and last:
                docs[last] = docs[last] + block
            block, last = [], None
        elif i in comments:
            block = [*block, comments[i]]
        elif not line.strip():  # a blank line ends a block that continues the field above
            if block and last:
                docs[last] = docs[last] + block
            block, last = [], None
    return {name: " ".join(parts).strip() for name, parts in docs.items()}


def _type_name(hint: typing.Any) -> str:
    origin = typing.get_origin(hint)
    if origin is list:
        return f"list[{_type_name(typing.get_args(hint)[0])}]"
    return getattr(hint, "__name__", str(hint))


def _default(value: typing.Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def parameter_table(sections: list[str]) -> str:
    """A Markdown table of every field of ``sections`` (``["node", "odometry"]``), in schema order."""
    classes = _section_classes()
    defaults = Config()
    rows = ["| parameter | type | default | description |", "|---|---|---|---|"]
    for section in sections:
        if section not in classes:
            raise ConfigError(f"config: unknown section {section!r} (known: {', '.join(classes)})")
        cls = classes[section]
        hints = typing.get_type_hints(cls)
        notes = field_comments(cls)
        for f in dataclasses.fields(cls):
            note = notes.get(f.name, "")
            if not note:
                raise ConfigError(f"config: {section}.{f.name} has no comment in {cls.__module__} "
                                  "(write what it does, with its unit, on its line)")
            value = getattr(getattr(defaults, section), f.name)
            rows.append(f"| `{section}.{f.name}` | {_type_name(hints[f.name])} | `{_default(value)}` | "
                        f"{_cell(note)} |")
    return "\n".join(rows) + "\n"


def render(text: str) -> str:
    """``text`` with every marked table regenerated."""
    return MARKER.sub(lambda m: m.group(1) + parameter_table(m.group(2).split(",")) + m.group(4), text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m deepbbs_ros.config_doc", description=__doc__.split("\n")[0])
    parser.add_argument("pages", nargs="*", type=Path, help="Markdown pages (default: docs/*.md of the repository)")
    parser.add_argument("--check", action="store_true", help="only compare; exit 1 if a table is out of date")
    args = parser.parse_args(argv)
    pages = args.pages or sorted((Path(__file__).resolve().parents[1] / "docs").glob("*.md"))
    stale = []
    try:
        for page in pages:
            text = page.read_text()
            new = render(text)
            if new != text:
                stale.append(page)
                if not args.check:
                    page.write_text(new)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    for page in stale:
        print(f"{'out of date' if args.check else 'updated'}: {page}")
    return 1 if (args.check and stale) else 0


if __name__ == "__main__":
    sys.exit(main())
