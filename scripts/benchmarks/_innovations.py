"""The odometry's innovations against the steps' true errors (scripts/benchmarks/covariance.py's ``innovations:``
line): what ``--sweep-floor adaptive`` (core/floor_scale.py) can see of the steps' rotation errors."""

from __future__ import annotations

import numpy as np


def innovation_line(steps: list, chain: list, floors: list) -> str:
    """Per rotation axis (roll, pitch, yaw), the mean of the innovations' squares over the two steps' GICP variances
    (``nu_k^2 / (g_k + g_{k-1})``; ``nu_k`` the rotation the registration moved scan ``k`` from the constant-velocity
    prediction, ``log(D_{k-1}^-1 D_k)``, ``D`` the steps' motions; ``g`` a step's covariance less its floor), and of
    the steps' true errors' squares over their own (``e_k^2 / g_k``): ``adaptive``'s premises (no motion change,
    independent steps) make the two equal; the innovations show less of the steps' errors where the first is
    smaller."""
    from scipy.spatial.transform import Rotation

    g = []
    for (_, cov), (T_prev, _, _, _), fl in zip(steps, chain, floors):
        B = np.zeros((6, 6))
        B[:3, :3] = B[3:, 3:] = T_prev[:3, :3].T
        g.append(np.maximum(np.diag(cov - B @ fl @ B.T)[3:], 1e-30))
    D = [c[1] for c in chain]
    nu = [Rotation.from_matrix((np.linalg.inv(a) @ b)[:3, :3]).as_rotvec() for a, b in zip(D[:-1], D[1:])]
    inn = np.mean([n ** 2 / (g[k] + g[k + 1]) for k, n in enumerate(nu) if k >= 1], axis=0)  # not the first motion
    err = np.mean([d[3:] ** 2 / g[k] for k, (d, _) in enumerate(steps) if k >= 1], axis=0)
    return ("innovations over the GICP parts (roll, pitch, yaw) " + ", ".join(f"{x:.2f}" for x in inn)
            + "; the steps' errors over theirs " + ", ".join(f"{x:.2f}" for x in err) + " (adaptive's premises: equal)")
