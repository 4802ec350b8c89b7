"""The correction of program targets with a calibrated model (the issue's formulas).

The controller turns a Cartesian target into joints with its nominal model. For a target
``T`` in work object ``W`` with tool ``Tool`` (all 4x4, mm):

* the nominal solution ``q_nom`` of the flange pose ``W·T·Tool⁻¹`` on the branch the
  controller takes (:mod:`calib.filter.branches`);
* ``q* = IK_calibrated(W·T·Tool⁻¹)``, the damped-least-squares pose IK of
  :func:`calib.ik.solve_ik` seeded from ``q_nom`` (so it stays on that branch; all targets
  in one batch);
* ``T′ = W⁻¹ · FK_nominal(q*) · Tool``: the target that makes the nominal controller
  command ``q*``, where the calibrated model says the tool really is at ``T``.

A joint target ``q`` becomes ``q′ = IK_calibrated(FK_nominal(q))`` (seeded from ``q``;
the tool does not matter: position and orientation of the flange are matched exactly).

Left unchanged and reported: no nominal solution within the joint limits or on the program's
configuration (``unreachable`` / ``skipped``), no calibrated solution near the nominal one
(the IK did not converge: ``unreachable``), ``q*`` outside the joint limits
(``unreachable``), ``q*`` on another branch than ``q_nom`` (the engine's one definition,
:func:`calib.filter.select.left_branch`: shoulder, elbow or wrist sign changed, or a joint
moved by more than :data:`~calib.filter.select.BRANCH_JUMP_DEG`: ``skipped``, it would need another
configuration), and every target whose tool or work object is unknown or differs
between its uses (``skipped``, with the reason).

**σ at the tool.** The result's covariance of the free parameters (``uncertainty`` and
``correlation`` of ``result.json``) propagated to the target's own tool point at ``q*``
through the calibrated model's position Jacobian, after removing the rigid motions that
cable lengths cannot see (as :mod:`calib.tcp` does for the hook point, over the targets and
the workspace sample together): ``σ = sqrt(trace Σ)`` [mm]. The hook point's σ understates a
long tool's error: an orientation error of the flange moves a point 200 mm out by its lever.
Terms the calibration cannot observe (rotation about and shift along base z, the joint-6
terms absorbed in the hook point) are not in the covariance; a tool's orientation error
from them is not in σ either.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calib.export import model_from_result
from calib.filter.branches import nominal_solutions
from calib.filter.kin import counted_as, flange_frames, solve_flange_ik, to_table_deg
from calib.filter.nearest import IK_OPTIONS, keeps_nearest, nearest_solutions
from calib.filter.select import BRANCH_JUMP_DEG, choose, left_branch
from calib.kinematics import DH_FIELDS, N_JOINTS, FloatArray, position_jacobian
from calib.models import RobotModel
from calib.programs.rotations import invert, rotation_angle_deg
from calib.programs.sites import (
    OPEN_RANGES_DEG,
    WRIST_SINGULARITY_DEG,
    WRIST_SINGULARITY_REASON,
    Configuration,
    Correction,
    Target,
)
from calib.result import CalibrationResult, ResultLike
from calib.tcp import joint_limits_deg, remove_rigid, workspace_sample_deg

#: A correction smaller than this (TCP position [mm] and orientation [deg]; joints [deg]) is
#: below anything a controller resolves: the target keeps its numbers exactly (so a
#: calibration equal to the nominal model changes no byte, whatever the IK's last digits).
NEGLIGIBLE_MM = 1e-4
NEGLIGIBLE_DEG = 1e-5
#: Workspace poses stacked with the targets for the rigid-motion removal of σ.
SIGMA_WORKSPACE_POSES = 200


@dataclass(frozen=True)
class Calibration:
    """The two models and the covariance the filter needs.

    Attributes
    ----------
    nominal, calibrated : RobotModel
        The controller's model and the identified one (limits: the nominal's).
    covariance : ndarray, shape (k, k), or None
        Covariance of the free kinematic parameters (internal units: mm, rad).
    columns : ndarray of int, shape (k,)
        Column of each free parameter in :func:`calib.kinematics.position_jacobian`'s DH
        columns (0..23), or -1 for parameters that do not move a program's tool (the cable
        hook point, anchors).
    """

    nominal: RobotModel
    calibrated: RobotModel
    covariance: FloatArray | None
    columns: np.ndarray


def calibration_from_result(result: ResultLike, nominal: RobotModel) -> Calibration:
    """The calibrated model and covariance of a ``result.json`` mapping.

    Raises
    ------
    ValueError
        The result's DH table is missing or invalid, or its convention differs from the
        nominal model's.
    """
    res = CalibrationResult.of(result)
    calibrated = model_from_result(res, nominal)
    if calibrated.convention != nominal.convention:
        raise ValueError(
            f"convention: the result is {calibrated.convention!r}, the nominal "
            f"model {nominal.convention!r}"
        )
    names = list(res.correlation.names) if res.correlation else []
    dh_names = [f"{f}{j + 1}" for j in range(N_JOINTS) for f in DH_FIELDS]
    if res.correlation is None or not names:
        return Calibration(nominal, calibrated, None, np.zeros(0, dtype=int))
    try:
        c = np.asarray(res.correlation.matrix, dtype=float)
        sd = np.array([res.uncertainty.get(n, 0.0) for n in names])
    except ValueError:  # a ragged matrix
        return Calibration(nominal, calibrated, None, np.zeros(0, dtype=int))
    if c.shape != (len(names), len(names)) or not np.all(np.isfinite(c)):
        return Calibration(nominal, calibrated, None, np.zeros(0, dtype=int))
    scale = np.array([math.pi / 180.0 if n.startswith(("alpha", "theta")) else 1.0 for n in names])
    sd = sd * scale
    cov = c * np.outer(sd, sd)
    columns = np.array([dh_names.index(n) if n in dh_names else -1 for n in names])
    return Calibration(nominal, calibrated, cov, columns)


def _uses_frames(t: Target) -> tuple[FloatArray | None, FloatArray | None, str]:
    """The one tool and work object of a Cartesian target, or the reason there is none."""
    if not t.uses:
        return (
            None,
            None,
            ("not used by any move in the given files: its tool and work object are unknown"),
        )
    for u in t.uses:
        if u.problem:
            return None, None, f"line {u.line}: {u.problem}"
    first = t.uses[0]
    assert first.tool is not None and first.work is not None
    for u in t.uses[1:]:
        assert u.tool is not None and u.work is not None
        if u.tool is first.tool and u.work is first.work:  # the same resolved frames
            continue
        if not (
            np.allclose(u.tool, first.tool, atol=1e-9)
            and np.allclose(u.work, first.work, atol=1e-9)
        ):
            return (
                None,
                None,
                (
                    f"used with two tools/work objects ({first.tool_name}/{first.work_name} at "
                    f"line {first.line}, {u.tool_name}/{u.work_name} at line {u.line}); one "
                    "declaration cannot be corrected for both: give each use its own target"
                ),
            )
    return first.tool, first.work, ""


def sigma_at_tools(
    cal: Calibration, joints_deg: FloatArray, tool_points_mm: FloatArray
) -> FloatArray:
    """Predicted 1σ position error [mm] at each target's tool point (n,), see the module
    docstring; NaN without a covariance. ``joints_deg`` (n, 6), ``tool_points_mm`` (n, 3) in
    the flange frame."""
    n = joints_deg.shape[0]
    if cal.covariance is None or n == 0:
        return np.full(n, np.nan)
    model = cal.calibrated
    dh = model.dh_internal()
    sample = workspace_sample_deg(cal.nominal, SIGMA_WORKSPACE_POSES, seed=0)
    qs = to_table_deg(cal.nominal, np.vstack([joints_deg, sample]))
    m = qs.shape[0]
    tools = np.vstack([tool_points_mm, np.tile(model.tool_mm, (sample.shape[0], 1))])
    k = cal.columns.size
    a = np.zeros((m, 3, k))
    pos = np.zeros((m, 3))
    keys, inverse = np.unique(np.round(tools, 9), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    for u in range(keys.shape[0]):
        rows = np.flatnonzero(inverse == u)
        p, jac = position_jacobian(dh, np.deg2rad(qs[rows]), keys[u], model.convention)
        pos[rows] = p
        has = cal.columns >= 0
        a[np.ix_(rows, np.arange(3), np.flatnonzero(has))] = jac[:, :, cal.columns[has]]
    b = remove_rigid(pos, a.reshape(3 * m, k)).reshape(m, 3, k)[:n]
    var = np.einsum("nij,jk,nik->n", b, cal.covariance, b)
    out: FloatArray = np.sqrt(np.clip(var, 0.0, None))
    return out


def _leaves_ranges(c: Configuration | None, q_deg: FloatArray) -> str | None:
    """Why a Cartesian target whose written configuration the controller honours must be
    left: its corrected joints ``q_deg`` (6,) [deg] leave a joint range that configuration
    fixes (an ABB quadrant, a KUKA T sign, a Fanuc turn number), so writing it would change
    that field (or make the controller refuse it); None when they stay inside."""
    if c is None or c.ranges_rewritten or not c.honoured:
        return None
    if c.after is not None or c.nearest_deg is not None:
        return None
    lo, hi = c.joint_ranges_deg[:, 0], c.joint_ranges_deg[:, 1]
    out = (q_deg < lo) | (q_deg >= hi)
    if not np.any(out):
        return None
    j = int(np.argmax(out))
    return (
        f"the correction would change the configuration {c.text or ''}: J{j + 1} would be "
        f"{q_deg[j]:.3f} deg, outside [{lo[j]:g}, {hi[j]:g}) that it fixes"
    ).replace("configuration :", "configuration:")


def _at_wrist_singularity(q_nom_deg: FloatArray, q_deg: FloatArray) -> str | None:
    """Why a target whose corrected joints ``q_deg`` (6,) [deg] left the branch of its nominal
    joints ``q_nom_deg`` (6,) is left, when that branch has joint 5 within
    :data:`~calib.programs.sites.WRIST_SINGULARITY_DEG` of 0; None elsewhere.

    There axes 4 and 6 line up, so the nominal pose fixes only J4 + J6; the calibrated arm's
    wrist is not singular at the same place, so its solution tilts J5 off 0 in one direction,
    which turns J4 and J6 by tens of degrees in opposite senses. Keeping the nominal J4 and J6
    and correcting the other joints does not reach the pose (bench/filter_corpus.md gives the
    measured residuals), so the target is left, named."""
    if abs(float(q_nom_deg[4])) >= WRIST_SINGULARITY_DEG:
        return None
    d4, d6 = float(q_deg[3] - q_nom_deg[3]), float(q_deg[5] - q_nom_deg[5])
    if max(abs(d4), abs(d6)) > BRANCH_JUMP_DEG:
        what = f"turns J4 by {d4:.2f} deg and J6 by {d6:.2f} deg"
    elif (q_deg[4] >= 0) != (q_nom_deg[4] >= 0):
        what = f"puts J5 at {float(q_deg[4]):.3f} deg, the other wrist"
    else:
        what = "leaves the branch"
    return (
        f"{WRIST_SINGULARITY_REASON} (J5 = {float(q_nom_deg[4]):.3f} deg, within "
        f"{WRIST_SINGULARITY_DEG:g} deg of 0): only J4 + J6 is fixed there, and the calibrated "
        f"solution {what}; teach it with J5 off 0"
    )


def _may_leave_ranges(configs: Sequence[Configuration | None], q_deg: FloatArray) -> list[bool]:
    """Per row, whether :func:`_leaves_ranges` may refuse it: its corrected joints ``q_deg``
    (n, 6) [deg] leave the joint ranges of a configuration it honours (all rows at once; the
    reason is then written for those rows alone)."""
    ranges = np.array([c.joint_ranges_deg if c is not None else OPEN_RANGES_DEG for c in configs])
    if not ranges.size:
        return []
    with np.errstate(invalid="ignore"):
        out = np.any((q_deg < ranges[..., 0]) | (q_deg >= ranges[..., 1]), axis=1)
    return out.tolist()  # type: ignore[no-any-return]


def correct_targets(
    cal: Calibration,
    targets: Sequence[Target],
    *,
    keep_joint_targets: bool = False,
    only: Sequence[str] | None = None,
) -> list[Correction]:
    """One :class:`Correction` per target (same order); see the module docstring."""
    n = len(targets)
    out: list[Correction | None] = [None] * n
    wanted = None if only is None else {s.lower() for s in only}
    cart: list[int] = []
    joint: list[int] = []
    tools: dict[int, FloatArray] = {}
    works: dict[int, FloatArray] = {}
    for i, t in enumerate(targets):
        if t.follows is not None:
            continue
        if wanted is not None and t.name.lower() not in wanted:
            out[i] = Correction("skipped", "not selected (--only)")
        elif t.problem:
            out[i] = Correction("skipped", t.problem)
        elif t.kind == "joint":
            if keep_joint_targets:
                out[i] = Correction("skipped", "joint target kept (--keep-joint-targets)")
            else:
                joint.append(i)
        else:
            tool, work, why = _uses_frames(t)
            if why:
                out[i] = Correction("skipped", why)
            else:
                assert tool is not None and work is not None
                tools[i], works[i] = tool, work
                cart.append(i)
    nominal = cal.nominal
    calibrated = counted_as(cal.calibrated, nominal)
    # Nominal solutions: Cartesian targets on the controller's branch.
    seeds: dict[int, FloatArray] = {}
    flanges: dict[int, FloatArray] = {}
    fl_of: dict[int, FloatArray] = {}
    if cart:
        stacked = (
            np.array([works[i] for i in cart])
            @ np.array([targets[i].pose for i in cart])
            @ invert(np.array([tools[i] for i in cart]))
        )
        fl_of = dict(zip(cart, stacked, strict=True))
    analytic = [
        i
        for i in cart
        if (c := targets[i].configuration) is None or (c.nearest_deg is None and c.after is None)
    ]
    if analytic:
        fl = np.stack([fl_of[i] for i in analytic])
        configs: list[Configuration | None] = [targets[i].configuration for i in analytic]
        try:
            sol = nominal_solutions(nominal, fl)
        except ValueError as exc:  # no closed form for this arm
            for i in analytic:
                out[i] = Correction("skipped", f"{exc}, and the target has no joint reference")
        else:
            idx, reasons = choose(sol, configs)
            for r, i in enumerate(analytic):
                if idx[r] < 0:
                    if reasons[r].startswith("unreachable"):
                        out[i] = Correction("unreachable", reasons[r].removeprefix("unreachable: "))
                    else:
                        out[i] = Correction("skipped", reasons[r])
                else:
                    seeds[i] = sol.joints_deg[r, idx[r]]
                    flanges[i] = fl[r]
    # Targets whose branch is "nearest a joint reference" (UR): the nominal IK from it.
    for i in joint:
        seeds[i] = np.asarray(targets[i].joints_deg, dtype=float)
    by_name = {(t.file, t.name): k for k, t in enumerate(targets)}
    ref_of: dict[int, FloatArray] = {}  # the joint reference of a UR-rule target
    analytic_set = set(analytic)
    todo = [i for i in cart if i not in analytic_set]
    while todo:
        ready, refs = [], []
        for i in todo:
            c = targets[i].configuration
            assert c is not None
            if c.nearest_deg is not None:
                ready.append(i)
                refs.append(c.nearest_deg)
                continue
            k = by_name.get((targets[i].file, c.after or ""))
            if k is not None and (k in seeds or targets[k].kind == "joint"):
                ready.append(i)
                refs.append(
                    seeds[k] if k in seeds else np.asarray(targets[k].joints_deg, dtype=float)
                )
            elif k is None or out[k] is not None or k not in todo:
                out[i] = Correction(
                    "skipped",
                    f"the previous move's target {c.after} has no nominal joints to start from",
                )
        ready_set = set(ready)
        todo = [i for i in todo if i not in ready_set and out[i] is None]
        if not ready:
            for i in todo:
                out[i] = Correction("skipped", "no joint reference for the branch")
            break
        fl = np.stack([fl_of[i] for i in ready])
        for r, (i, q, why) in enumerate(
            zip(ready, *nearest_solutions(nominal, fl, np.array(refs)), strict=True)
        ):
            if why:
                out[i] = Correction("unreachable", why)
            else:
                seeds[i], flanges[i], ref_of[i] = q, fl[r], refs[r]
    rows = list(seeds)
    if rows:
        q_nom = np.array([seeds[i] for i in rows])
        fk_nom = flange_frames(nominal, q_nom)
        target_fl = np.array([flanges.get(i, fk_nom[r]) for r, i in enumerate(rows)])
        sol_c = solve_flange_ik(calibrated, q_nom, target_fl, IK_OPTIONS)
        q_star = sol_c.joints_deg
        limits = joint_limits_deg(nominal)
        fk_star = flange_frames(nominal, q_star)
        kept = keeps_nearest(nominal, rows, ref_of, fk_star, q_star)
        tool_pts = np.array([tools[i][:3, 3] if i in tools else np.zeros(3) for i in rows])
        sigma = sigma_at_tools(cal, q_star, tool_pts)
        # Shifts, all at once: the TCP for Cartesian targets, the flange for joint targets.
        eye = np.eye(4)
        w_inv = invert(np.array([works.get(i, eye) for i in rows]))
        tl = np.array([tools.get(i, eye) for i in rows])
        new_all = w_inv @ fk_star @ tl
        old_all = np.array(
            [
                targets[i].pose if targets[i].kind == "cartesian" else fk_nom[r]
                for r, i in enumerate(rows)
            ]
        )
        shift_mm_all = np.linalg.norm(new_all[:, :3, 3] - old_all[:, :3, 3], axis=1)
        shift_deg_all = rotation_angle_deg(old_all[:, :3, :3], new_all[:, :3, :3])
        jump_all = np.max(np.abs(q_star - q_nom), axis=1)
        outside = np.any((q_star < limits[:, 0]) | (q_star > limits[:, 1]), axis=1)
        left = left_branch(nominal, q_nom, q_star) | ~kept
        converged = sol_c.converged.tolist()
        outside_l, left_l = outside.tolist(), left.tolist()
        shifts_mm, shifts_deg = shift_mm_all.tolist(), shift_deg_all.tolist()
        jumps, sigmas = jump_all.tolist(), sigma.tolist()
        leaves = _may_leave_ranges([targets[i].configuration for i in rows], q_star)
        for r, i in enumerate(rows):
            t = targets[i]
            qs = q_star[r]
            if not converged[r]:
                out[i] = Correction(
                    "unreachable",
                    "no calibrated solution near the nominal one "
                    f"(residual {sol_c.position_error_mm[r]:.3g} mm)",
                )
                continue
            if outside_l[r]:
                low, high = qs < limits[:, 0], qs > limits[:, 1]
                j = int(np.argmax(low | high))
                lim = limits[j, 0] if low[j] else limits[j, 1]
                out[i] = Correction(
                    "unreachable", f"outside the joint limits: J{j + 1}={qs[j]:.3f} (limit {lim:g})"
                )
                continue
            jump = jumps[r]
            if left_l[r]:
                why = (
                    "would need another configuration (the "
                    f"calibrated solution leaves the branch; {jump:.2f} deg)"
                )
                if not kept[r]:
                    why = (
                        "the controller would solve the corrected pose from its joint "
                        "reference to another solution (nearest q)"
                    )
                elif (singular := _at_wrist_singularity(q_nom[r], qs)) is not None:
                    why = singular
                out[i] = Correction("skipped", why)
                continue
            if leaves[r] and (changed := _leaves_ranges(t.configuration, qs)) is not None:
                out[i] = Correction("skipped", changed)
                continue
            shift_mm, shift_deg = shifts_mm[r], shifts_deg[r]
            if t.kind == "joint":
                if jump < NEGLIGIBLE_DEG:
                    qs = q_nom[r]
                # The shift of a joint target: at the flange (its tool is irrelevant).
                out[i] = Correction(
                    "corrected",
                    joints_deg=qs,
                    nominal_joints_deg=q_nom[r],
                    shift_mm=shift_mm,
                    shift_deg=shift_deg,
                    configuration_kept=True,
                    sigma_mm=sigmas[r],
                )
                continue
            new, old = new_all[r], t.pose
            assert old is not None
            if shift_mm < NEGLIGIBLE_MM and shift_deg < NEGLIGIBLE_DEG:
                new = old
            out[i] = Correction(
                "corrected",
                pose=new,
                joints_deg=qs,
                nominal_joints_deg=q_nom[r],
                shift_mm=shift_mm,
                shift_deg=shift_deg,
                configuration_kept=True,
                sigma_mm=sigmas[r],
            )
    # Joint targets that follow a Cartesian one (a PolyScope Waypoint_n_q).
    for i, t in enumerate(targets):
        if t.follows is None:
            continue
        k = by_name.get((t.file, t.follows))
        lead = out[k] if k is not None else None
        if wanted is not None and t.name.lower() not in wanted and t.follows.lower() not in wanted:
            out[i] = Correction("skipped", "not selected (--only)")
        elif lead is None or lead.status != "corrected" or lead.joints_deg is None:
            out[i] = Correction("skipped", f"follows {t.follows}, which was not corrected")
        else:
            q_old = np.asarray(t.joints_deg, dtype=float)
            # The written q and pose agree only to their written precision: move q by the
            # correction of its pose's joints (a pose that did not move leaves q as it was).
            assert lead.nominal_joints_deg is not None
            delta = lead.joints_deg - lead.nominal_joints_deg
            q_new = q_old if float(np.max(np.abs(delta))) < NEGLIGIBLE_DEG else q_old + delta
            out[i] = Correction(
                "corrected",
                joints_deg=q_new,
                nominal_joints_deg=q_old,
                shift_mm=lead.shift_mm,
                shift_deg=lead.shift_deg,
                configuration_kept=lead.configuration_kept,
                sigma_mm=lead.sigma_mm,
            )
    return [c if c is not None else Correction("skipped", "internal: not processed") for c in out]


__all__ = ["Calibration", "calibration_from_result", "correct_targets", "sigma_at_tools"]
