"""Questions asked of an identified model, without fitting anything: is it stable at rest?

The search ranks grid points by these checks, the diagnosis asks them of the models it
extends, and the examples of the models they pick; none of them needs the search to ask.
"""

from __future__ import annotations

import numpy as np

from identification.sindy.library import FeatureLibrary
from identification.sindy.model import SindyModel

STABILITY_TOL = 1e-9  # largest real part of an eigenvalue of J_f_x at rest still counted as stable


def max_re_eig_at_rest(library: FeatureLibrary, coef: np.ndarray) -> np.ndarray:
    """Return the largest real part of the eigenvalues of ``J_f_x`` at rest (x = 0, u = 0) for
    coefficient arrays ``coef (..., 3, k)`` of ``library`` (``J_f_x = coef @ d_theta/dx``)."""
    _, d_theta0 = library.transform_with_jacobian(np.zeros(5))
    J = np.einsum("...ek,vk->...ev", coef, d_theta0[:3])
    with np.errstate(invalid="ignore"):
        eig = np.where(np.isfinite(J).all(axis=(-2, -1)), np.linalg.eigvals(np.nan_to_num(J)).real.max(axis=-1),
                       np.inf)
    return eig


def stable_at_rest(model: SindyModel) -> bool:
    """Return whether the model comes to rest by itself: :func:`max_re_eig_at_rest` <= :data:`STABILITY_TOL`."""
    return bool(max_re_eig_at_rest(model.library, model.coef) <= STABILITY_TOL)
