"""The zero-order-hold integrals of a continuous linear system (Åström & Wittenmark, §2.3).

For ``x' = A x + B u`` with ``u`` held constant over ``[0, h]``::

    x(h) = Φ(h) x(0) + Γ(h) u,    Φ(h) = e^{A h},    Γ(h) = ∫_0^h e^{A σ} dσ B,

both from one matrix exponential of the block matrix ``[[A, B], [0, 0]] h`` (Van Loan). Used by
the sampled loop of ``latency.margins`` and the MPC's discrete law (``latency.mpc_law``).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray


def zoh_integrals(
    A: ArrayLike, B: ArrayLike, h: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(Φ(h), Γ(h)) = (e^{A h}, ∫_0^h e^{A σ} dσ B)`` for a hold of ``h`` (s).

    Parameters
    ----------
    A : (n, n) state matrix, 1/s.
    B : (n, m) input matrix.
    h : hold duration, s (0 gives ``(I, 0)``).
    """
    A = np.atleast_2d(np.asarray(A, dtype=float))
    B = np.atleast_2d(np.asarray(B, dtype=float))
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = scipy.linalg.expm(M * h)
    return E[:n, :n], E[:n, n:]
