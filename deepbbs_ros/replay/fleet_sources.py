"""The recordings of a fleet run: paths, quoted globs and list files expanded in order, and a unique folder name for
each (see :mod:`deepbbs_ros.replay.fleet`)."""

from __future__ import annotations

import glob
import os
import re
from pathlib import Path

from deepbbs_ros.errors import DatasetError

LIST_SUFFIXES = (".txt", ".list")  # a source with this suffix is a text file naming one source per line


# --------------------------------------------------------------------------------------------------
# sources
# --------------------------------------------------------------------------------------------------
def expand_sources(items: list[str]) -> list[str]:
    """Paths as given, globs (``'drives/*.mcap'``, quoted so the shell leaves them) and list files
    (``*.txt`` / ``*.list``: one source per line, ``#`` comments, paths relative to the list's folder)
    -> the recordings in order, duplicates dropped. A glob that matches nothing or a missing list file is
    a :class:`DatasetError`; a missing recording is left for its own run to report."""
    out: list[str] = []

    def add(item: str, base: Path | None) -> None:
        path = Path(item)
        if base is not None and not path.is_absolute():
            path = Path(os.path.normpath(base / path))
        text = str(path)
        if path.suffix.lower() in LIST_SUFFIXES and not path.is_dir():
            if not path.is_file():
                raise DatasetError(f"{text}: no such source list")
            for ln in path.read_text().splitlines():
                ln = ln.split("#", 1)[0].strip()
                if ln:
                    add(ln, path.parent)
            return
        if any(c in item for c in "*?[") and not path.exists():
            hits = sorted(glob.glob(text))
            if not hits:
                raise DatasetError(f"{text}: the pattern matches no recording")
            for h in hits:
                add(h, None)
            return
        if text not in out:
            out.append(text)

    for item in items:
        add(item, None)
    if not out:
        raise DatasetError("no recording given (empty source list)")
    return out


def recording_names(sources: list[str]) -> list[str]:
    """A folder name per recording: its file or folder name (``drive_03.mcap``), made filesystem-safe,
    suffixed ``_2``, ``_3`` ... when two recordings share a name."""
    names: list[str] = []
    for src in sources:
        base = re.sub(r"[^A-Za-z0-9._+-]", "_", Path(src.rstrip("/")).name) or "recording"
        if base in ("metrics.json", "recordings.csv"):
            base = "_" + base
        name, n = base, 2
        while name in names:
            name, n = f"{base}_{n}", n + 1
        names.append(name)
    return names


