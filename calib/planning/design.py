"""D-optimal selection of calibration poses: greedy start, then Fedorov exchange.

The information of a design (a set of candidate rows) about the scaled base parameters is
``M = M_fixed + Σ_{i∈design} x_i x_iᵀ``, with ``x_i`` (shape ``(k,)``) the i-th candidate's
row of the cable-length Jacobian restricted to the base parameters and divided by fixed column
scales, and ``M_fixed`` the information of poses already measured plus a small ridge (so that
the first picks are well defined). The D-criterion is ``log det M``; it does not depend on the
column scales except through the ridge. When some parameters are nuisance (the anchors' P0 and
offset: needed, but of no interest once the robot is calibrated), the Ds-criterion
``log det M − log det M[ν, ν]`` is the ``log det`` of the information about the others once the
nuisance parameters ``ν`` are eliminated (Schur complement). Both terms update with the same
formulas below, the second with the nuisance columns only and a minus sign.

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


def _systems(
    rows: FloatArray, fixed: FloatArray, nuisance: IndexArray | None
) -> list[tuple[FloatArray, FloatArray, float]]:
    """``(rows (n, k_s), fixed (k_s, k_s), weight)`` per term of ``Φ``."""
    out = [(rows[h], fixed[h], 1.0) for h in range(rows.shape[0])]
    if nuisance is not None and len(nuisance):
        nu = np.asarray(nuisance)
        out += [(rows[h][:, nu], fixed[h][np.ix_(nu, nu)], -1.0) for h in range(rows.shape[0])]
    return out


def criterion(
    rows: FloatArray, fixed: FloatArray, design: IndexArray, nuisance: IndexArray | None = None
) -> float:
    """``Φ = Σ_h [log det M_h − log det M_h[ν, ν]]`` of a design.

    Parameters
    ----------
    rows : ndarray, shape (H, n, k)
        Scaled Jacobian rows of every candidate under each of the H anchor hypotheses.
    fixed : ndarray, shape (H, k, k)
        Information of the start data plus the ridge.
    design : ndarray of int, shape (m,)
    nuisance : ndarray of int, optional
        Columns ``ν`` of nuisance parameters (the anchors): with them ``Φ`` is the
        Ds-criterion of the others (``log det`` of the Schur complement), without them the
        plain D-criterion.
    """
    total = 0.0
    for x, f, w in _systems(rows, fixed, nuisance):
        sub = x[design]
        total += w * log_det(f + sub.T @ sub)
    return total


def greedy(
    rows: FloatArray, fixed: FloatArray, n_pick: int, nuisance: IndexArray | None = None
) -> list[int]:
    """Pick ``n_pick`` distinct candidates one at a time, each maximising the increase of
    ``Φ`` (shapes as :func:`criterion`)."""
    systems = _systems(rows, fixed, nuisance)
    invs: list[FloatArray] = [np.asarray(np.linalg.inv(f), dtype=float) for _, f, _ in systems]
    chosen: list[int] = []
    taken = np.zeros(rows.shape[1], dtype=bool)
    for _ in range(n_pick):
        gain = np.zeros(rows.shape[1])
        for (x, _, w), v in zip(systems, invs, strict=True):
            d = np.einsum("np,np->n", x @ v, x)  # xᵀ V x per candidate
            gain += w * np.log1p(np.maximum(d, 0.0))
        gain[taken] = -np.inf
        j = int(np.argmax(gain))
        chosen.append(j)
        taken[j] = True
        invs = [_sm_add(v, x[j], +1.0) for (x, _, _), v in zip(systems, invs, strict=True)]
    return chosen


def fedorov_exchange(
    rows: FloatArray,
    fixed: FloatArray,
    design: list[int],
    max_exchanges: int = 200,
    nuisance: IndexArray | None = None,
) -> tuple[list[int], int]:
    """Improve a design by single-row exchanges until no exchange gains more than
    :data:`EXCHANGE_TOL` (relative in ``det``) or ``max_exchanges`` were made.

    Each step evaluates every (design row, candidate) pair and makes the best exchange.
    Returns the new design (candidate indices, same length) and the number of exchanges made.
    Deterministic: ties go to the lowest indices.
    """
    design = list(design)
    systems = _systems(rows, fixed, nuisance)
    invs: list[FloatArray] = []
    for x, f, _ in systems:
        sub = x[design]
        invs.append(np.asarray(np.linalg.inv(f + sub.T @ sub), dtype=float))
    made = 0
    shape = (len(design), rows.shape[1])
    for _ in range(max_exchanges):
        # det ratio of each exchange: Π over the terms of r_s^{w_s}, w_s = ±1 (no logs).
        num, den = np.ones(shape), np.ones(shape)
        for (x, _, w), v in zip(systems, invs, strict=True):
            xv = x @ v  # (n, k)
            d_cand = np.einsum("np,np->n", xv, x)  # d(x_j)
            ratio = xv[design] @ x.T  # (m, n): d(x_i, x_j), then the det ratio in place
            np.square(ratio, out=ratio)
            ratio += np.outer(1.0 - d_cand[design], 1.0 + d_cand)
            np.maximum(ratio, 1e-300, out=ratio)
            (num if w > 0 else den)[...] *= ratio
        gain = np.divide(num, den, out=num)
        gain[:, design] = 0.0  # no duplicates
        i, j = divmod(int(np.argmax(gain)), rows.shape[1])
        if gain[i, j] <= 1.0 + EXCHANGE_TOL:
            break
        old = design[i]
        design[i] = j
        invs = [
            _sm_add(_sm_add(v, x[j], +1.0), x[old], -1.0)
            for (x, _, _), v in zip(systems, invs, strict=True)
        ]
        made += 1
    return design, made


def select(
    rows: FloatArray,
    fixed: FloatArray,
    n_pick: int,
    max_exchanges: int = 200,
    nuisance: IndexArray | None = None,
) -> tuple[list[int], int]:
    """Greedy start, then Fedorov exchange. Returns ``(design, exchanges made)``."""
    if n_pick < 1:
        raise ValueError(f"n: need at least one pose to plan, got {n_pick}")
    if n_pick > rows.shape[1]:
        raise ValueError(f"n: {n_pick} poses requested but only {rows.shape[1]} candidates")
    start = greedy(rows, fixed, n_pick, nuisance)
    return fedorov_exchange(rows, fixed, start, max_exchanges, nuisance)


def tcp_trace(rows: FloatArray, fixed: FloatArray, weight: FloatArray, design: IndexArray) -> float:
    """``Σ_h tr(W M_h⁻¹)``: the summed mean aligned TCP variance per unit noise variance.

    ``weight`` (k, k) is ``W = D⁻¹ BᵀB D⁻¹ / m`` for the rigid-motion-free TCP Jacobian ``B``
    (3m, k) of a workspace sample and the column scales ``D``, so that ``σ² tr(W M⁻¹)`` is the
    predicted mean square aligned TCP error (what :func:`calib.tcp.tcp_uncertainty` reports
    as ``rms²``). Other shapes as :func:`criterion`.
    """
    total = 0.0
    for x, f in zip(rows, fixed, strict=True):
        sub = x[design]
        total += float(np.trace(np.linalg.solve(f + sub.T @ sub, weight)))
    return total


def tcp_exchange(
    rows: FloatArray,
    fixed: FloatArray,
    weight: FloatArray,
    design: list[int],
    max_exchanges: int = 200,
) -> tuple[list[int], int]:
    """Improve a design by single-row exchanges that lower :func:`tcp_trace` (I-optimality).

    Exchanging design row ``x_i`` for candidate ``x_j`` is evaluated exactly for all pairs at
    once: add ``x_j`` (``V_j = V − V x_j x_jᵀ V / (1 + d_j)``), then remove ``x_i``
    (``tr(W V') = tr(W V_j) + (V_j x_i)ᵀ W (V_j x_i) / (1 − x_iᵀ V_j x_i)``), with
    ``V_j x_i = V x_i − V x_j d_ij / (1 + d_j)``. Stops when the best exchange lowers the trace
    by less than :data:`EXCHANGE_TOL` (relative) or after ``max_exchanges``.
    Returns the new design and the number of exchanges made.
    """
    design = list(design)
    made = 0
    for _ in range(max_exchanges):
        lower = np.zeros((len(design), rows.shape[1]))
        current = 0.0
        for x, f in zip(rows, fixed, strict=True):
            v = np.linalg.inv(f + x[design].T @ x[design])
            current += float(np.sum(v * weight))
            b = x @ v  # (n, k): V x_j
            a = b[design]  # (m, k): V x_i
            d_j = np.einsum("nk,nk->n", b, x)
            d_ij = a @ x.T  # (m, n)
            bw, aw = b @ weight, a @ weight
            bwb = np.einsum("nk,nk->n", bw, b)
            c = d_ij / (1.0 + d_j)
            vjx_w = np.einsum("mk,mk->m", aw, a)[:, None] - 2.0 * c * (aw @ b.T) + c**2 * bwb
            keep = 1.0 - (d_j[design][:, None] - d_ij * c)
            lower += bwb / (1.0 + d_j) - vjx_w / np.maximum(keep, 1e-12)
        lower[:, design] = -np.inf
        i, j = divmod(int(np.argmax(lower)), rows.shape[1])
        if lower[i, j] <= EXCHANGE_TOL * current:
            break
        design[i] = j
        made += 1
    return design, made
