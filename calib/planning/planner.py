"""Plan calibration poses: D-optimal on the identifiable parameters, robust to the anchor guess.

Entry point :func:`plan` (what ``cablecal plan`` calls). Steps:

1. **Candidates**: ``options.candidates`` random poses within the joint limits that reach each
   anchor within the cable stroke (shrunk by the anchor's uncertainty) above the floor
   (:mod:`calib.planning.candidates`).
2. **Parameters**: the cable-length Jacobian (:func:`calib.cable.length_jacobian`) at the
   nominal model and the anchor guesses; the base set is what
   :func:`calib.identifiability.analyse` keeps on the candidates (well-spread poses, so the
   structural base set) plus the start data.
3. **Criterion**: ``Σ_h log det`` of the information of start data plus design about the
   kinematic base parameters (anchors eliminated: Ds-optimality; or the whole base set,
   D-optimality) under anchor hypothesis ``h`` (the guess and ``anchor_draws`` anchors at
   ``anchor_uncertainty_mm`` from it). Selection: greedy, then Fedorov exchange
   (:mod:`calib.planning.design`); then (``criterion="tcp"``, the default) exchanges that
   lower the predicted mean aligned TCP variance over the workspace sample, summed over the
   same hypotheses (I-optimality: the figure a calibration is judged by; against the D
   design on emulated cells: bench/plan_results.md).
4. **Order** per anchor by nearest neighbour plus 2-opt in joint-move time
   (:mod:`calib.planning.order`).
5. **Summary**: condition number, predicted 1σ per base parameter for ``noise_mm``, predicted
   aligned TCP σ (:mod:`calib.tcp`) of the plan and of random poses of the same count.

With several anchors the candidates of all anchors compete in one selection (each anchor has
its own P0 and offset to pay for); the gain is reported as the kinematic D-efficiency and the
TCP σ of the plan against the best plan made at one anchor only. The report counts the final
plan's poses per anchor: the optimum often puts them all at one anchor (a second anchor's four
parameters cost more than its other cable directions give at 30–40 poses), and then
``plan_uses`` names that anchor and a note says so.

Base set: the plan's is the rank (``rtol``) base set at the nominal model, where the hook is
on the flange axis and ``d5``/``theta5`` are exactly redundant with the tool point; identify,
at the fitted tool point, may keep ``d5`` instead of ``alpha5`` after its noise-level
threshold (:mod:`calib.identifiability`). Same count and the same TCP figures (the
comparison: bench/design_figures.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits  # type: ignore[import-untyped]

from calib.cable import N_KIN, ParamLayout, length_jacobian
from calib.dataset import SampleSet, validate_joint_limits
from calib.identifiability import analyse
from calib.kinematics import FloatArray, IndexArray
from calib.models import RobotModel
from calib.planning import design
from calib.planning.candidates import draw_candidates, flange_and_tool_mm, reading_window_mm
from calib.planning.options import PlanOptions
from calib.planning.order import campaign_time_s, order_poses
from calib.planning.result import PlanResult
from calib.planning.start import plan_anchor_ids, start_anchors_mm
from calib.problem import BoolArray
from calib.tcp import (
    TcpUncertainty,
    aligned_tcp_jacobian,
    tcp_uncertainty,
    workspace_sample_deg,
)
from calib.timing import Clock, Timer


@dataclass(frozen=True)
class _Setup:
    """The linearised problem shared by the main plan and the comparisons."""

    layout: ParamLayout
    theta: FloatArray  # (p,) nominal kinematics, anchor guesses (offsets 0)
    free: BoolArray  # (p,) base set
    scale: FloatArray  # (k,) column scales
    cand_q_deg: FloatArray  # (c, 6)
    cand_anchor: IndexArray  # (c,) index into layout.anchors
    rows: FloatArray  # (H, c, k) scaled Jacobian rows per anchor hypothesis
    start_jac: FloatArray  # (s, k) unscaled start rows
    plan_anchor_index: IndexArray  # (m,) layout index of each plan anchor
    nuisance: IndexArray | None  # columns of rows that are anchor parameters (Ds), or None


def _setup(
    model: RobotModel, anchors_mm: FloatArray, opts: PlanOptions, start: SampleSet | None
) -> _Setup:
    rng = np.random.default_rng(opts.seed)
    m = anchors_mm.shape[0]
    plan_ids = plan_anchor_ids(opts.anchor_ids, m)
    start_ids = start.anchor_ids if start is not None else ()
    ids = tuple(start_ids) + tuple(a for a in plan_ids if a not in start_ids)
    layout = ParamLayout(ids)
    theta = np.zeros(layout.size)
    plan_index = np.array([ids.index(a) for a in plan_ids])
    for k, li in enumerate(plan_index):
        theta[layout.anchor_slice(int(li))][:3] = anchors_mm[k]
    start_theta = theta.copy()
    if start is not None:
        for aid, p0 in start_anchors_mm(model, start).items():
            start_theta[layout.anchor_slice(ids.index(aid))][:3] = p0
            if aid not in plan_ids:
                theta[layout.anchor_slice(ids.index(aid))][:3] = p0
    q_c, a_c = draw_candidates(
        model,
        anchors_mm,
        opts.candidates,
        rng,
        opts.extension_mm,
        opts.min_z_mm,
        opts.anchor_uncertainty_mm,
        offsets_mm=opts.offsets_mm,
    )
    cand_anchor = plan_index[a_c]
    q_rad = model.table_rad(q_c)
    _, jac0 = length_jacobian(model, theta, q_rad, cand_anchor)
    if start is not None:
        start_idx = np.array([ids.index(a) for a in start.anchor])
        _, start_full = length_jacobian(
            model, start_theta, model.table_rad(start.joints_deg), start_idx
        )
    else:
        start_full = np.zeros((0, layout.size))
    ident = analyse(
        np.vstack([jac0, start_full]), layout.names, np.ones(layout.size, bool), rtol=opts.rtol
    )
    free = np.array([nm in ident.base for nm in layout.names])
    if not free[:N_KIN].any():  # e.g. one candidate: its one row pins an anchor, no joint
        raise ValueError(
            f"candidates: {len(q_c)} candidate poses identify none of the robot's parameters "
            f"with these anchors; draw more (at least {layout.size}, the parameters solved)"
        )
    scale = np.linalg.norm(jac0[:, free], axis=0) / np.sqrt(jac0.shape[0])
    scale = np.where(scale > 0, scale, 1.0)
    jacs = [jac0]
    for _ in range(opts.anchor_draws):
        th = theta.copy()
        for li in plan_index:
            step = rng.normal(size=3)
            step *= opts.anchor_uncertainty_mm / np.linalg.norm(step)
            th[layout.anchor_slice(int(li))][:3] += step
        jacs.append(length_jacobian(model, th, q_rad, cand_anchor)[1])
    rows = np.stack([j[:, free] / scale for j in jacs])
    nuisance = np.flatnonzero(np.flatnonzero(free) >= N_KIN) if opts.anchors_nuisance else None
    return _Setup(
        layout,
        theta,
        free,
        scale,
        q_c,
        cand_anchor,
        rows,
        start_full[:, free],
        plan_index,
        nuisance,
    )


def covariance(jac: FloatArray, noise_mm: float) -> FloatArray:
    """``noise² (JᵀJ)⁻¹`` (k, k) for Jacobian rows ``jac`` (n, k), internal units.

    Inverted on unit columns by eigen-decomposition; directions with no information
    (eigenvalue below 1e-15 of the largest) get zero variance instead of infinity.
    """
    d = np.linalg.norm(jac, axis=0)
    d = np.where(d > 0, d, 1.0)
    u = jac / d
    evals, evecs = np.linalg.eigh(u.T @ u)
    keep = evals > evals.max() * 1e-15
    inv = np.where(keep, 1.0 / np.where(keep, evals, 1.0), 0.0)
    out: FloatArray = noise_mm**2 * ((evecs * inv) @ evecs.T) / np.outer(d, d)
    return out


def condition_number(jac: FloatArray) -> float:
    """``σ_max/σ_min`` of ``jac`` (n, k) with unit-norm columns (inf when rank-deficient)."""
    if jac.shape[0] == 0:
        return float("inf")
    d = np.linalg.norm(jac, axis=0)
    if np.any(d == 0):
        return float("inf")
    s = np.linalg.svd(jac / d, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def _kinematic_log_det(s: _Setup, jac: FloatArray) -> float:
    """Per-parameter ``log det`` of the kinematic block's information once the anchors are
    eliminated (Schur complement), scaled columns: comparable across anchor allocations."""
    u = jac / s.scale
    info = u.T @ u
    names = np.flatnonzero(s.free)
    kin = names < N_KIN
    a = info[np.ix_(~kin, ~kin)]
    schur = (
        info[np.ix_(kin, kin)]
        - info[np.ix_(kin, ~kin)] @ np.linalg.pinv(a) @ info[np.ix_(~kin, kin)]
    )
    return design.log_det(schur) / int(np.count_nonzero(kin))


def _tcp_weight(model: RobotModel, s: _Setup, ws_q_deg: FloatArray) -> FloatArray:
    """``W`` (k, k) of :func:`design.tcp_trace` for the scaled base set at the nominal model."""
    b = aligned_tcp_jacobian(model, s.layout, s.theta, s.free, ws_q_deg) / s.scale
    out: FloatArray = b.T @ b / ws_q_deg.shape[0]
    return out


def _select(
    s: _Setup,
    fixed: FloatArray,
    opts: PlanOptions,
    weight: FloatArray,
    among: IndexArray | None = None,
) -> tuple[IndexArray, int]:
    """Design (candidate indices) among ``among`` (default all): D/Ds-optimal, then, for
    ``criterion="tcp"``, TCP-variance exchanges. Returns it and the exchanges made."""
    sub = np.arange(s.rows.shape[1]) if among is None else among
    rows = s.rows[:, sub]
    chosen, made = design.select(rows, fixed, opts.n, opts.max_exchanges, s.nuisance)
    if opts.criterion == "tcp":
        chosen, more = design.tcp_exchange(rows, fixed, weight, chosen, opts.max_exchanges)
        made += more
    return sub[np.asarray(chosen)], made


def _fixed(s: _Setup, ridge: float) -> FloatArray:
    """Start-data information plus ridge, scaled, one copy per anchor hypothesis (H, k, k)."""
    u = s.start_jac / s.scale
    base = u.T @ u + ridge * np.eye(s.scale.size)
    return np.repeat(base[None], s.rows.shape[0], axis=0)


def _predict(
    model: RobotModel, s: _Setup, chosen: IndexArray, opts: PlanOptions, ws_q_deg: FloatArray
) -> tuple[FloatArray, FloatArray, TcpUncertainty]:
    """Unscaled Jacobian (plan + start), its covariance and the TCP σ of a design."""
    jac = np.vstack([s.rows[0][chosen] * s.scale, s.start_jac])
    cov = covariance(jac, opts.noise_mm)
    tcp = tcp_uncertainty(model, s.layout, s.theta, s.free, cov, q_deg=ws_q_deg)
    return jac, cov, tcp


def _random_baseline(
    model: RobotModel, s: _Setup, opts: PlanOptions, ws_q_deg: FloatArray
) -> dict[str, float]:
    rng = np.random.default_rng(opts.seed + 1)
    rms, mx = [], []
    for _ in range(max(opts.random_draws, 1)):
        pick = rng.choice(s.cand_q_deg.shape[0], size=opts.n, replace=False)
        tcp = _predict(model, s, pick, opts, ws_q_deg)[2]
        rms.append(tcp.rms_mm)
        mx.append(tcp.max_mm)
    return {"rms": float(np.mean(rms)), "max": float(np.mean(mx))}


def _anchor_gain(
    model: RobotModel,
    s: _Setup,
    opts: PlanOptions,
    fixed: FloatArray,
    weight: FloatArray,
    all_jac: FloatArray,
    all_tcp: TcpUncertainty,
    ws_q_deg: FloatArray,
) -> tuple[dict[str, Any], IndexArray]:
    """Plan at each anchor alone and compare with the plan over all anchors.

    Returns the comparison and the best single-anchor design (candidate indices): the joint
    exchange is a local search and may end below a single-anchor design, which then wins
    (by the plan's criterion: TCP σ for ``"tcp"``, kinematic D-efficiency for ``"d"``).
    Which anchors the final plan uses is added by :func:`_anchors_used`.
    """
    singles: dict[str, Any] = {}
    designs: dict[str, IndexArray] = {}
    for li in s.plan_anchor_index:
        aid = s.layout.anchors[int(li)]
        picked, _ = _select(s, fixed, opts, weight, np.flatnonzero(s.cand_anchor == li))
        designs[aid] = picked
        jac, _, tcp = _predict(model, s, picked, opts, ws_q_deg)
        singles[aid] = {
            "kinematic_log_det": _kinematic_log_det(s, jac),
            "tcp_sigma_mm": tcp.to_dict(),
        }
    all_ld = _kinematic_log_det(s, all_jac)
    if opts.criterion == "tcp":
        best = min(singles, key=lambda a: singles[a]["tcp_sigma_mm"]["rms"])
    else:
        best = max(singles, key=lambda a: singles[a]["kinematic_log_det"])
    gain = float(np.exp(all_ld - singles[best]["kinematic_log_det"]))
    joint_wins = (
        all_tcp.rms_mm <= singles[best]["tcp_sigma_mm"]["rms"]
        if opts.criterion == "tcp"
        else gain >= 1.0
    )
    return {
        "single_anchor": singles,
        "best_single_anchor": best,
        "all_anchors": {"kinematic_log_det": all_ld, "tcp_sigma_mm": all_tcp.to_dict()},
        # Ratio of geometric-mean information per kinematic parameter (D-efficiency) of the
        # selection over all anchors to the best single anchor's.
        "d_efficiency_gain": gain,
        "tcp_rms_ratio": float(singles[best]["tcp_sigma_mm"]["rms"] / all_tcp.rms_mm),
        "joint_selection_wins": bool(joint_wins),
    }, designs[best]


def _anchors_used(s: _Setup, picked: IndexArray, gain: dict[str, Any] | None) -> list[str]:
    """Count the final plan's poses per anchor; record in ``gain`` which anchors it uses
    (``plan_uses``: ``"all"``, or the ids that got poses) and return a note when an anchor
    got none (the optimum may put every pose at one anchor, joint selection or not)."""
    counts = {
        s.layout.anchors[int(li)]: int(np.count_nonzero(s.cand_anchor[picked] == li))
        for li in s.plan_anchor_index
    }
    used = [a for a, c in counts.items() if c > 0]
    if gain is not None:
        gain["poses_per_anchor"] = counts
        gain["plan_uses"] = "all" if len(used) == len(counts) else ", ".join(used)
    unused = [a for a, c in counts.items() if c == 0]
    if not unused:
        return []
    return [
        f"all {len(picked)} poses are at anchor(s) {', '.join(used)}: the best design "
        f"found gives anchor(s) {', '.join(unused)} none (their own P0 and offset cost "
        "more than their cable directions add)"
    ]


def plan(
    model: RobotModel,
    anchors_mm: FloatArray | Sequence[Sequence[float]],
    options: PlanOptions | None = None,
    start: SampleSet | None = None,
    clock: Clock | None = None,
) -> PlanResult:
    """Plan ``options.n`` calibration poses (see the module docstring).

    Parameters
    ----------
    model : RobotModel
        Nominal model; its ``limits_deg`` bound the poses.
    anchors_mm : ndarray, shape (m, 3) or (3,)
        Guessed anchor position(s) in the robot base frame [mm].
    options : PlanOptions
    start : SampleSet, optional
        Poses already measured: their information is part of the criterion (sequential
        design); each start anchor's P0 is multilaterated with the nominal model.
    clock : callable() -> float [s], optional
        Times the plan for ``elapsed_s``, injected by the caller (calib reads no clock);
        None: 0.

    Raises
    ------
    ValueError
        Bad option or anchor (naming it), no feasible pose for an anchor.
    SampleError
        Start samples outside the joint limits.
    """
    # The products here are (thousands × ~22) by (22 × 22): BLAS threads gain nothing and, on
    # a shared 2-core machine, oversubscription made plans several times slower
    # (bench/design_figures.md). One BLAS thread.
    with threadpool_limits(limits=1, user_api="blas"):
        return _plan(model, anchors_mm, options or PlanOptions(), start, clock)


def _plan(
    model: RobotModel,
    anchors_mm: FloatArray | Sequence[Sequence[float]],
    opts: PlanOptions,
    start: SampleSet | None,
    clock: Clock | None,
) -> PlanResult:
    timer = Timer(clock)
    anchors = np.atleast_2d(np.asarray(anchors_mm, dtype=float))
    if anchors.ndim != 2 or anchors.shape[1] != 3 or not np.all(np.isfinite(anchors)):
        raise ValueError(f"anchors_mm: need finite (x, y, z) per anchor, got {anchors_mm!r}")
    opts.validate(anchors.shape[0])
    if start is not None:
        validate_joint_limits(start, model)
    s = _setup(model, anchors, opts, start)
    fixed = _fixed(s, opts.ridge)
    ws = workspace_sample_deg(model, opts.workspace_poses, opts.seed, opts.min_z_mm)
    weight = _tcp_weight(model, s, ws)
    picked, exchanges = _select(s, fixed, opts, weight)
    jac, cov, tcp = _predict(model, s, picked, opts, ws)
    gain = None
    if anchors.shape[0] > 1 and opts.compare_single_anchors:
        gain, single = _anchor_gain(model, s, opts, fixed, weight, jac, tcp, ws)
        if not gain["joint_selection_wins"]:
            picked = single
            jac, cov, tcp = _predict(model, s, picked, opts, ws)
    notes = _anchors_used(s, picked, gain)
    speed = np.asarray(opts.joint_speed_deg_s)
    order: list[int] = []
    travel = campaign = 0.0
    for li in s.plan_anchor_index:
        group = picked[s.cand_anchor[picked] == li]
        path, t_move = order_poses(s.cand_q_deg[group], speed)
        order += [int(group[i]) for i in path]
        travel += t_move
        campaign += campaign_time_s(s.cand_q_deg[group[path]], speed, opts.dwell_s)
    q = s.cand_q_deg[order]
    plan_k = np.array(
        [int(np.flatnonzero(s.plan_anchor_index == li)[0]) for li in s.cand_anchor[order]]
    )
    ext = np.linalg.norm(flange_and_tool_mm(model, q)[1] - anchors[plan_k], axis=1)
    free_idx = np.flatnonzero(s.free)
    if start is not None:
        notes.append(
            f"{len(start)} start samples included; their anchors multilaterated "
            "with the nominal model"
        )
    return PlanResult(
        q_deg=q,
        anchor_index=plan_k,
        anchor_ids=tuple(s.layout.anchors[int(li)] for li in s.plan_anchor_index),
        anchors_mm=anchors,
        extension_mm=ext,
        base=[s.layout.names[i] for i in free_idx],
        param_sigma=np.sqrt(np.clip(np.diag(cov), 0, None)) * s.layout.display_scale[free_idx],
        param_units=[s.layout.units[i] for i in free_idx],
        condition_number=condition_number(jac),
        condition_number_start=condition_number(s.start_jac) if start is not None else None,
        tcp=tcp,
        tcp_random=_random_baseline(model, s, opts, ws),
        travel_s=travel,
        campaign_s=campaign,
        log_det=design.criterion(s.rows, fixed, picked, s.nuisance),
        exchanges=exchanges,
        n_candidates=int(s.cand_q_deg.shape[0]),
        noise_mm=opts.noise_mm,
        anchor_gain=gain,
        elapsed_s=timer.elapsed(),
        notes=notes,
        offsets_mm=opts.offsets_mm,
        reading_window_mm=reading_window_mm(opts.anchor_uncertainty_mm),
    )


def evaluate_poses(
    model: RobotModel,
    anchors_mm: FloatArray,
    q_deg: FloatArray,
    anchor_index: IndexArray | None = None,
    options: PlanOptions | None = None,
    start: SampleSet | None = None,
) -> dict[str, Any]:
    """Predicted quality of given poses (a plan made elsewhere, or made at another anchor).

    Parameters as :func:`plan`; ``q_deg`` (n, 6) [deg], ``anchor_index`` (n,) into
    ``anchors_mm`` (default all 0). The base set and scales are those :func:`plan` would use
    with the same options. Returns ``kinematic_log_det`` (per kinematic parameter, anchors
    eliminated), ``condition_number`` and ``tcp_sigma_mm`` ``{rms, max}``.
    """
    opts = options or PlanOptions()
    anchors = np.atleast_2d(np.asarray(anchors_mm, dtype=float))
    opts.validate(anchors.shape[0])
    q = np.atleast_2d(np.asarray(q_deg, dtype=float))
    idx = np.zeros(q.shape[0], dtype=int) if anchor_index is None else np.asarray(anchor_index)
    with threadpool_limits(limits=1, user_api="blas"):
        s = _setup(model, anchors, opts, start)
        layout_idx = s.plan_anchor_index[idx]
        jac = length_jacobian(model, s.theta, model.table_rad(q), layout_idx)[1][:, s.free]
        full = np.vstack([jac, s.start_jac])
        ws = workspace_sample_deg(model, opts.workspace_poses, opts.seed, opts.min_z_mm)
        tcp = tcp_uncertainty(
            model, s.layout, s.theta, s.free, covariance(full, opts.noise_mm), q_deg=ws
        )
        return {
            "kinematic_log_det": _kinematic_log_det(s, full),
            "condition_number": condition_number(full),
            "tcp_sigma_mm": tcp.to_dict(),
        }
