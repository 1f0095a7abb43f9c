"""The user guide's reference of every command's keys and config groups (docs/guide/keys.md), made
from the configs in conf/ and their comments, so that it says what the configs hold.

Example::

    python -m experiments.apps.config_reference            # rewrites docs/guide/keys.md
    python -m experiments.apps.config_reference --check    # exits 1 where docs/guide/keys.md is out of date
"""

from __future__ import annotations

import argparse
import re
from dataclasses import dataclass
from pathlib import Path

import conf

__all__ = ["Key", "config_keys", "group_options", "keys_page"]

COMMANDS = (("sfc-reconstruct", "reconstruct"), ("sfc-design", "design"), ("sfc-simulate", "simulate"))
SKIPPED = ("defaults", "hydra")  # sections that are Hydra's, not the command's
PAGE = Path("docs/guide/keys.md")
LINE = re.compile(r"^(?P<indent> *)(?P<key>[A-Za-z_][\w]*):(?P<value>[^#]*?)\s*(?:#\s?(?P<comment>.*))?$")
COMMENT = re.compile(r"^(?P<indent> *)#\s?(?P<text>.*)$")


@dataclass(frozen=True)
class Key:
    """One key of a config: its dotted path, its default as written, what its comment says."""

    path: str
    default: str
    meaning: str


def config_keys(text: str) -> list[Key]:
    """Every key of a config file's ``text`` with a value (sections are named in their keys' paths),
    its default and its comment (with the comment lines that continue it below)."""
    keys: list[Key] = []
    parents: list[tuple[int, str]] = []
    skipping: int | None = None
    column: int | None = None  # where the last key's comment starts: a comment line there continues it
    for line in text.splitlines():
        found = LINE.match(line)
        if found is None:
            more = COMMENT.match(line)
            if more and column is not None and line.index("#") == column:
                last = keys[-1]
                keys[-1] = Key(last.path, last.default, f"{last.meaning} {more['text'].strip()}")
            elif line.strip():
                column = None
            continue
        column = None
        indent = len(found["indent"])
        if skipping is not None and indent > skipping:
            continue
        skipping = None
        while parents and parents[-1][0] >= indent:
            parents.pop()
        key, value = found["key"], found["value"].strip()
        if not parents and key in SKIPPED:
            skipping = indent
            continue
        path = ".".join([*(name for _, name in parents), key])
        if value:
            keys.append(Key(path, value, (found["comment"] or "").strip()))
            column = line.index("#") if found["comment"] is not None else None
        else:
            parents.append((indent, key))
    return keys


def group_options(group: Path) -> list[tuple[str, str]]:
    """(option, the first sentence of the comment that opens its file) of a config group's folder."""
    options = []
    for path in sorted(group.glob("*.yaml")):
        header = []
        for line in path.read_text().splitlines():
            found = COMMENT.match(line)
            if found is None:
                break
            if not found["text"].startswith("@package"):
                header.append(found["text"].strip())
        text = " ".join(header)
        end = re.search(r"(?<!\bal)(?<!e\.g)(?<!i\.e)\.(\s|$)", text)  # not at "et al.", "e.g.", "i.e."
        options.append((path.stem, text[: end.start() + 1] if end else text))
    return options


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def keys_page(root: Path) -> str:
    """The page: per command, its keys with their defaults and meanings; then every config group's options."""
    out = ["# Every command's keys", "",
           "Made from the configs in `conf/` and their comments by `python -m experiments.apps.config_reference`;",
           "give any key on the command line as `key=value`, a config group's option as `group=option`.", ""]
    for command, name in COMMANDS:
        out += [f"## `{command}` (conf/{name}.yaml)", "", "| key | default | meaning |", "|---|---|---|"]
        out += [f"| `{k.path}` | `{_cell(k.default)}` | {_cell(k.meaning)} |"
                for k in config_keys((root / f"{name}.yaml").read_text())]
        out.append("")
    out += ["## Config groups", ""]
    for group in sorted({path.parent for path in root.rglob("*.yaml")} - {root}):
        name = group.relative_to(root).as_posix()
        out += [f"### `{name}`", "", "| option | what it is |", "|---|---|"]
        out += [f"| `{name}={option}` | {_cell(text)} |" for option, text in group_options(group)]
        out.append("")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    """Command line: rewrite docs/guide/keys.md, or with --check say whether it is up to date."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="exit 1 where the page differs from the configs")
    parser.add_argument("--out", type=Path, default=PAGE, help="the page to write or check")
    args = parser.parse_args(argv)
    page = keys_page(Path(conf.DIRECTORY))
    if args.check:
        if not args.out.is_file() or args.out.read_text() != page:
            print(f"error: {args.out} is out of date; rewrite it with python -m experiments.apps.config_reference")
            return 1
        return 0
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(page)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
