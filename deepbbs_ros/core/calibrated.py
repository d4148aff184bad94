"""The calibrated verdict: the probability that a pose is right (no ROS).

The features of a pose (core/visibility.py: how much of the source the target saw, how much it saw through,
how tightly the seen part fits) go through a logistic regression fitted on simulated pairs of every sensor,
mount and place (``scripts/calibrate_verdict.py``; right: within 1 degree / 0.3 m of the truth). The
coefficients ship in ``deepbbs_ros/resources/verdict_model.json``, read once: ``"good_start"``, for a spread
subset of the source's GICP voxels (ground included), is the one the registration's verdicts use (the pair verdict
and the good start); ``"pair"``, for the network's sampled non-ground points, is fitted beside it for comparison
(it carried worse to real scans). The file may set ``"min_pinned"``: a pose whose ``pinned`` (core/visibility.py: how
well the fit pins its weakest direction) is under it has probability 0, whatever the regression says (the fit leaves
it free by more than ``sqrt(1 / min_pinned - 1)`` tolerances: 0.02, seven, about 2 m or 7 degrees); with
``"min_anchored_far"`` as well, only where nothing else holds it either (its ``anchored_far``, core/anchoring.py, is
under that: moved 1.5 m or 5 degrees along that direction it keeps as many close points). The file may set
``"relative"``: ``{"shares": ["fitness", "observable"], "held_pinned": a, "held_anchored_far": b}`` and models
``"pair_relative"`` and ``"good_start_relative"``, fitted with those shares read over ``in_view`` (at most 1), the
overlap the pose itself expects (core/visibility.py), so that a right pose of a narrow sensor that turned between its
scans is not taken for a loose one. They judge only a pose the fit holds where it is (``pinned`` at least ``a`` or
``anchored_far`` at least ``b``): a pose that can slide is judged on its plain overlap, by ``"pair"`` /
``"good_start"``. A missing or damaged file raises :class:`~deepbbs_ros.errors.VerdictModelError`.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np

from deepbbs_ros.core.visibility import FEATURES
from deepbbs_ros.errors import VerdictModelError

DEFAULT_PATH = Path(__file__).resolve().parents[1] / "resources" / "verdict_model.json"
#: how the features enter the regression: shares as log-odds (clipped), so that 0.9 -> 0.99 weighs like 0.5 -> 0.9
TRANSFORM = "logit(clip(x, 0.005, 0.995))"
_EPS = 0.005
_PINNED = FEATURES.index("pinned")
_ANCHORED_FAR = FEATURES.index("anchored_far")
_IN_VIEW = FEATURES.index("in_view")
#: the shares a file may name ``"relative"``: read over ``in_view``
RELATIVE = ("fitness", "observable")
_FLOORS: dict[str | None, tuple[float, float]] = {}  # the floors (pinned, anchored_far) of each ``path`` load read
#: of each ``path`` load read: (the columns of its ``"relative"`` shares, held_pinned, held_anchored_far)
_RELATIVE: dict[str | None, tuple[tuple[int, ...], float, float]] = {}


def design(rows: np.ndarray) -> np.ndarray:
    """Feature rows (K, len(FEATURES)) -> the regression's inputs (K, len(FEATURES)) (:data:`TRANSFORM`)."""
    x = np.clip(np.atleast_2d(np.asarray(rows, np.float64)), _EPS, 1 - _EPS)
    return np.log(x / (1 - x))


def relative(rows: np.ndarray, names: tuple[str, ...] | list[str]) -> np.ndarray:
    """Feature rows (K, len(FEATURES)) with the shares ``names`` (of :data:`RELATIVE`) over ``in_view`` (at most 1;
    0 where nothing is in view): the overlap measured against the one the pose expects. A copy, float64."""
    x = np.array(np.atleast_2d(rows), np.float64)
    view = x[:, _IN_VIEW]
    for n in names:
        i = FEATURES.index(n)
        x[:, i] = np.where(view > 0, np.minimum(1.0, x[:, i] / np.maximum(view, 1e-12)), 0.0)
    return x


@functools.lru_cache(maxsize=4)
def load(path: str | None = None) -> dict[str, tuple[np.ndarray, float]]:
    """The coefficients {verdict: (coef (F,), intercept)} from ``path`` (the shipped file when None); read once
    (:func:`min_pinned`: the file's floor on ``pinned``)."""
    p = Path(path) if path else DEFAULT_PATH
    try:
        doc = json.loads(p.read_text())
        if list(doc["features"]) != list(FEATURES) or doc["transform"] != TRANSFORM:
            raise ValueError("fitted for other features")
        out = {}
        for name, m in doc["models"].items():
            coef = np.asarray(m["coef"], np.float64)
            if coef.shape != (len(FEATURES),) or not np.all(np.isfinite(coef)) or not np.isfinite(m["intercept"]):
                raise ValueError(f"model {name!r} is not {len(FEATURES)} finite coefficients")
            out[name] = (coef, float(m["intercept"]))
        if not {"pair", "good_start"} <= set(out):
            raise ValueError("needs the 'pair' and 'good_start' models")
        floor, held = float(doc.get("min_pinned", 0.0)), float(doc.get("min_anchored_far", 1.0))
        if not 0.0 <= floor < 1.0:
            raise ValueError(f"min_pinned {floor} is not within [0, 1)")
        if not 0.0 < held <= 1.0:
            raise ValueError(f"min_anchored_far {held} is not within (0, 1]")
        spec = doc.get("relative", {"shares": []})
        rel = [str(n) for n in spec["shares"]]
        held_pin, held_far = float(spec.get("held_pinned", 0.0)), float(spec.get("held_anchored_far", 1.0))
        if not set(rel) <= set(RELATIVE):
            raise ValueError(f"relative shares {rel} are not within {list(RELATIVE)}")
        if rel and not {"pair_relative", "good_start_relative"} <= set(out):
            raise ValueError("relative shares need the 'pair_relative' and 'good_start_relative' models")
        if not (0.0 <= held_pin < 1.0 and 0.0 < held_far <= 1.0):
            raise ValueError(f"relative held_pinned {held_pin} / held_anchored_far {held_far} not within [0, 1)/(0, 1]")
        _FLOORS[path] = (floor, held)  # keyed as load's cache is
        _RELATIVE[path] = (tuple(FEATURES.index(n) for n in rel), held_pin, held_far)
        return out
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise VerdictModelError(f"calibrated verdict {p}: {e} (refit: python scripts/calibrate_verdict.py)") from None


def min_pinned(path: str | None = None) -> float:
    """The floor on ``pinned`` of the coefficients at ``path`` (the shipped file when None): 0 when the file sets
    none."""
    load(path)
    return _FLOORS[path][0]


def min_anchored_far(path: str | None = None) -> float:
    """The bound on ``anchored_far`` under which :func:`min_pinned` applies (1 when the file sets none: always)."""
    load(path)
    return _FLOORS[path][1]


def weighs(names: tuple[str, ...], verdict: str = "pair", path: str | None = None, floor: bool = True) -> bool:
    """Whether the ``verdict`` model at ``path`` (the shipped file when None) gives any of the features ``names`` a
    coefficient other than 0 (or its ``_relative`` model), or its floor or the ``"relative"`` models' bound reads it
    (unless ``floor`` is False), or it reads ``"relative"`` shares over ``in_view`` (a feature it does not read need
    not be measured)."""
    models = load(path)
    cols, held_pin, held_far = _RELATIVE[path]
    coefs = [models[verdict][0], *([models[verdict + "_relative"][0]] if cols else [])]
    floor = floor and "anchored_far" in names and anchored_below(path) > 0
    over = "in_view" in names and bool(cols)
    return bool(floor or over or any(c[FEATURES.index(n)] != 0.0 for c in coefs for n in names))


def anchored_below(path: str | None = None) -> float:
    """The ``pinned`` under which the file reads ``anchored_far`` (its floor, or the bound of its ``"relative"``
    models): 0 when it never does. A pose pinned at least this much needs no ``anchored_far``."""
    load(path)
    floor, held = _FLOORS[path]
    cols, held_pin, held_far = _RELATIVE[path]
    return max(floor if held < 1 else 0.0, held_pin if cols and held_far < 1 else 0.0)


def probability(rows: np.ndarray, verdict: str = "pair", path: str | None = None) -> np.ndarray | float:
    """P(right) of feature rows (K, F) -> (K,), or of one row (F,) -> float, by the ``verdict`` model
    ("pair" or "good_start"; its ``_relative`` model for a row the fit holds, where the file sets one); 0 for a row
    whose ``pinned`` is under :func:`min_pinned` (and ``anchored_far`` under :func:`min_anchored_far`)."""
    models = load(path)
    coef, icpt = models[verdict]
    x = np.atleast_2d(np.asarray(rows, np.float64))
    z = design(x) @ coef + icpt
    cols, held_pin, held_far = _RELATIVE[path]
    held = (x[:, _PINNED] >= held_pin) | (x[:, _ANCHORED_FAR] >= held_far)
    if cols and held.any():  # a pose the fit holds: its overlap against the one it expects
        rcoef, ricpt = models[verdict + "_relative"]
        z[held] = design(relative(x[held], [FEATURES[i] for i in cols])) @ rcoef + ricpt
    p = 1.0 / (1.0 + np.exp(-np.clip(z, -50, 50)))
    p = np.where((x[:, _PINNED] < min_pinned(path)) & (x[:, _ANCHORED_FAR] < min_anchored_far(path)), 0.0, p)
    return float(p[0]) if np.ndim(rows) == 1 else p
