"""Dotted parameter names: the validation check every section uses, and the did-you-mean of unknown names."""

from __future__ import annotations

from typing import Any

from deepbbs_ros.errors import ConfigError


def _check(cond: bool, key: str, msg: str) -> None:
    if not cond:
        raise ConfigError(f"config: {key} {msg}")


def nearest_keys(name: str, known: Any) -> list[str]:
    """The known dotted names closest to ``name``: those whose last part equals its last part (flat,
    KISS-ICP-style names such as ``mode`` or ``voxel_size``), else the closest spelling (``eval.strid`` ->
    ``eval.stride``), else the key whose last part is spelt closest. Empty when nothing is close."""
    import difflib

    known = list(known)
    leaf = name.rpartition(".")[2]
    same = [k for k in known if k.rpartition(".")[2] == leaf]
    if same:
        return same
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    if close:
        return close
    leaves = {k.rpartition(".")[2]: k for k in known}
    return [leaves[m] for m in difflib.get_close_matches(leaf, list(leaves), n=1, cutoff=0.6)]


def did_you_mean(name: str, known: Any) -> str:
    """``"; did you mean a.b?"`` (or ``"a.b or c.b"``) for :func:`nearest_keys`, ``""`` when none is close."""
    near = nearest_keys(name, known)
    return f"; did you mean {' or '.join(near)}?" if near else ""
