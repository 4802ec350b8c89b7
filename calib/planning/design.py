"""D-optimal selection of calibration poses: greedy start, then Fedorov exchange.

The information of a design (a set of candidate rows) about the scaled base parameters is
``M = M_fixed + Σ_{i∈design} x_i x_iᵀ``, with ``x_i`` (shape ``(k,)``) the i-th candidate's
row of the cable-length Jacobian restricted to the base parameters and divided by fixed column
scales, and ``M_fixed`` the information of poses already measured plus a small ridge (so that
the first picks are well defined). The D-criterion is ``log det M``; it does not depend on the
column scales except through the ridge.

Robustness to the anchor guess: the Jacobian depends on the anchor only through the cable
direction, so the criterion is summed over ``K`` Jacobian sets (the guess and anchors drawn
around it): ``Φ = Σ_k log det M_k``. ``K = 1`` is the plain D-criterion.

Updates use the matrix determinant lemma. With ``V = M⁻¹``, ``d(x) = xᵀ V x`` and
``d(x, y) = xᵀ V y``:

- adding ``x``: ``det`` is multiplied by ``1 + d(x)``;
- exchanging design row ``x_i`` for candidate ``x_j``: by
  ``(1 + d(x_j))(1 − d(x_i)) + d(x_i, x_j)²`` (Fedorov, 1972).

Both are evaluated for all candidates at once (matrix products), and the inverse is updated
with Sherman–Morrison after each accepted move.
"""

from __future__ import annotations

import numpy as np

from calib.kinematics import FloatArray, IndexArray

#: Relative improvement of the D-criterion below which the exchange stops.
EXCHANGE_TOL = 1e-6


def _sm_add(v: FloatArray, x: FloatArray, sign: float) -> FloatArray:
    """Sherman–Morrison: inverse of ``M + sign · x xᵀ`` from ``V = M⁻¹`` (k, k), ``x`` (k,)."""
    vx = v @ x
    return v - sign * np.outer(vx, vx) / (1.0 + sign * float(x @ vx))


def log_det(info: FloatArray) -> float:
    """``log det`` of a symmetric positive (semi)definite matrix (``-inf`` if singular)."""
    sign, value = np.linalg.slogdet(info)
    return float(value) if sign > 0 else float("-inf")


def criterion(rows: FloatArray, fixed: FloatArray, design: IndexArray) -> float:
    """``Φ = Σ_k log det(M_fixed,k + X_k[design]ᵀ X_k[design])``.

    Parameters
    ----------
    rows : ndarray, shape (K, n, k)
        Scaled Jacobian rows of every candidate for each of the K anchor hypotheses.
    fixed : ndarray, shape (K, k, k)
    design : ndarray of int, shape (m,)
    """
    total = 0.0
    for x_k, f_k in zip(rows, fixed, strict=True):
        sub = x_k[design]
        total += log_det(f_k + sub.T @ sub)
    return total


def greedy(rows: FloatArray, fixed: FloatArray, n_pick: int) -> list[int]:
    """Pick ``n_pick`` candidates one at a time, each maximising the increase of ``Φ``.

    A candidate may be picked more than once only if nothing else improves the criterion
    (never in practice with thousands of candidates). Shapes as :func:`criterion`.
    """
    inv = np.linalg.inv(fixed)  # (K, k, k)
    chosen: list[int] = []
    taken = np.zeros(rows.shape[1], dtype=bool)
    for _ in range(n_pick):
        # gain_j = Σ_k log(1 + x_jkᵀ V_k x_jk)
        d = np.einsum("knp,kpq,knq->kn", rows, inv, rows, optimize=True)
        gain = np.log1p(np.maximum(d, 0.0)).sum(axis=0)
        gain[taken] = -np.inf
        j = int(np.argmax(gain))
        chosen.append(j)
        taken[j] = True
        for k in range(rows.shape[0]):
            inv[k] = _sm_add(inv[k], rows[k, j], +1.0)
    return chosen


def fedorov_exchange(
    rows: FloatArray, fixed: FloatArray, design: list[int], max_exchanges: int = 200
) -> tuple[list[int], int]:
    """Improve a design by single-row exchanges until no exchange gains more than
    :data:`EXCHANGE_TOL` (relative in ``det``) or ``max_exchanges`` were made.

    Each step evaluates every (design row, candidate) pair and makes the best exchange.
    Returns the new design (candidate indices, same length) and the number of exchanges made.
    Deterministic: ties go to the lowest indices.
    """
    design = list(design)
    n_k = rows.shape[0]
    info = np.array(fixed)
    for k in range(n_k):
        sub = rows[k, design]
        info[k] += sub.T @ sub
    inv = np.linalg.inv(info)
    made = 0
    for _ in range(max_exchanges):
        log_ratio = np.zeros((len(design), rows.shape[1]))
        for k in range(n_k):
            xv = rows[k] @ inv[k]  # (n, k)
            d_cand = np.einsum("np,np->n", xv, rows[k])  # (n,)
            d_cross = xv[design] @ rows[k].T  # (m, n): d(x_i, x_j)
            d_des = d_cand[design]  # (m,)
            ratio = (1.0 + d_cand)[None, :] * (1.0 - d_des)[:, None] + d_cross**2
            log_ratio += np.log(np.maximum(ratio, 1e-300))
        log_ratio[:, design] = -np.inf  # no duplicates
        flat = int(np.argmax(log_ratio))
        i, j = divmod(flat, rows.shape[1])
        if log_ratio[i, j] <= np.log1p(EXCHANGE_TOL):
            break
        old = design[i]
        design[i] = j
        for k in range(n_k):
            inv[k] = _sm_add(inv[k], rows[k, j], +1.0)
            inv[k] = _sm_add(inv[k], rows[k, old], -1.0)
        made += 1
    return design, made


def select(
    rows: FloatArray, fixed: FloatArray, n_pick: int, max_exchanges: int = 200
) -> tuple[list[int], int]:
    """Greedy start, then Fedorov exchange. Returns ``(design, exchanges made)``."""
    if n_pick < 1:
        raise ValueError(f"n: need at least one pose to plan, got {n_pick}")
    if n_pick > rows.shape[1]:
        raise ValueError(f"n: {n_pick} poses requested but only {rows.shape[1]} candidates")
    start = greedy(rows, fixed, n_pick)
    return fedorov_exchange(rows, fixed, start, max_exchanges)
