"""Where a calibration script writes its fitted coefficients: a file in the working directory's results/ unless told,
and a file inside the package (a shipped model) only with ``--force``, refused before anything runs."""

from __future__ import annotations

import argparse
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "deepbbs_ros"  # files in it are shipped: replaced only with --force


def shipped(path: Path) -> bool:
    """Whether ``path`` names a file inside the package (a shipped model or beside it)."""
    return Path(path).resolve().is_relative_to(PACKAGE.resolve())


def add_out(ap: argparse.ArgumentParser, name: str, shipped_path: Path) -> None:
    """``--out`` (default ``results/<name>`` in the working directory) and ``--force`` on ``ap``."""
    default = Path("results") / name
    ap.add_argument("--out", type=Path, default=default,
                    help=f"where to write the fitted coefficients (default {default}, in the working directory); the "
                    f"shipped file is {shipped_path.relative_to(PACKAGE.parent)}")
    ap.add_argument("--force", action="store_true", help="allow --out to replace a file inside the package (the "
                    "shipped coefficients); without it such an --out is refused before anything runs")


def check_out(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse (argparse's usage error, exit 2) an ``--out`` inside the package without ``--force``."""
    if shipped(args.out) and not args.force:
        ap.error(f"--out {args.out} is a shipped file of the package; add --force to replace it")


def write(path: Path, text: str) -> None:
    """``text`` into ``path``, its folder made first."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
