"""Synthetic scenes of axis-aligned planes for the verdict's geometry tests (shared helper, not a test)."""

from __future__ import annotations

import numpy as np

#: a plane: (normal axis, offset along it in m, (min, max) along the first other axis, (min, max) along the second)
FLOOR = [(2, -1.0, (-10, 10), (-10, 10))]
STREET = [(0, 6.0, (-30, 30), (-1, 4)), (0, -6.0, (-30, 30), (-1, 4)), (2, -1.0, (-6, 6), (-30, 30)),
          (1, 20.0, (-6, 6), (-1, 4)), (1, -25.0, (-6, 6), (-1, 4))]


def scene(planes, rng: np.random.Generator, per: int) -> np.ndarray:
    """``per`` points on each plane (1 cm of noise along its normal) -> (len(planes) * per, 3)."""
    out = []
    for axis, offset, (a0, a1), (b0, b1) in planes:
        other = [i for i in range(3) if i != axis]
        p = np.empty((per, 3))
        p[:, axis] = offset + rng.normal(0.0, 0.01, per)
        p[:, other[0]], p[:, other[1]] = rng.uniform(a0, a1, per), rng.uniform(b0, b1, per)
        out.append(p)
    return np.vstack(out)
