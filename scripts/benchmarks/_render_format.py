"""The formatting render_docs.py's sections share: numbers, tables, footnotes, the command a benchmark recorded."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
NOT_RUN = "not run"


def num(v, digits: int) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def pct(v, n=None) -> str:
    if v is None:
        return "-"
    return f"{v:.1f} %" + (f" ({n})" if n is not None else "")


def ratio(v) -> str:
    return "-" if v is None else f"x{v:.2f}"


def ms(v) -> str:
    return "-" if v is None else f"{v:.0f}"


class Notes:
    """Footnotes of one table: ``mark(reason)`` -> `` (a)``, the same mark for the same reason."""

    def __init__(self):
        self.reasons: list[str] = []

    def mark(self, reason: str) -> str:
        if reason not in self.reasons:
            self.reasons.append(reason)
        return f" ({chr(ord('a') + self.reasons.index(reason))})"

    def lines(self) -> list[str]:
        return ["", *(f"- ({chr(ord('a') + i)}) {r}" for i, r in enumerate(self.reasons))] if self.reasons else []


def table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header), *("| " + " | ".join(r) + " |" for r in rows)]


def not_run_table(header: list[str], labels: list[str]) -> list[str]:
    return table(header, [[label] + [NOT_RUN] * (len(header) - 1) for label in labels])


def short_path(token: str) -> str:
    """A path in a recorded command: relative to the repository, or PATH/TO/<its last two parts> outside it (an
    absolute one, one in the home folder, or a relative one leading out of the repository: ``../data/kitti/00``)."""
    if token.startswith("../"):
        path = (ROOT / token).resolve()  # the benchmarks run from the repository's root
    elif token.startswith(("/", "~/")):
        path = Path(token).expanduser()
    else:
        return token
    if path == ROOT or ROOT in path.parents:
        return str(path.relative_to(ROOT))
    return "PATH/TO/" + "/".join(path.parts[-2:])


def command(doc: dict | None) -> list[str]:
    if doc is None:
        return []
    when = (doc.get("machine") or {}).get("date_utc") or "date not recorded"
    if not doc.get("command"):
        return [f"Command not recorded ({when}).", ""]
    cmd = " ".join(short_path(t) for t in doc["command"].split(" "))
    return [f"Measured by `python {cmd}` ({when}).", ""]
