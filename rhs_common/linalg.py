"""Small batched linear algebra shared by the radar's estimators (numpy only)."""

from __future__ import annotations

import numpy as np

__all__ = ["batched_lstsq"]


def batched_lstsq(atoms: np.ndarray, iota: np.ndarray) -> np.ndarray:
    """Batched least squares ``argmin_s ||A s - y||^2`` by the normal equations.

    atoms ``A`` (D, I, L), iota ``y`` (D, I, ...) -> ``s`` (D, L, ...):
    ``s = (A^H A + 1e-12 I)^-1 A^H y`` per batch entry; the tiny ridge keeps a
    Gram matrix of coincident atoms solvable.

    Examples:
        >>> a = np.eye(3)[None, :, :2]  # two orthonormal atoms in C^3
        >>> batched_lstsq(a, np.array([[[2.0], [3.0], [5.0]]]))[0, :, 0].round(6).tolist()
        [2.0, 3.0]
    """
    ah = np.conj(np.swapaxes(atoms, 1, 2))
    gram = ah @ atoms + 1e-12 * np.eye(atoms.shape[2])[None]
    return np.linalg.solve(gram, ah @ iota)
