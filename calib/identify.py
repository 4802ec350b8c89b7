"""Identification of a robot's DH errors, tool point, anchors and zero offsets from cable lengths.

The public entry point is :func:`identify`. It

1. splits the samples into training and test rows (random, grouped, or given);
2. fits the *before* model: nominal kinematics with only ``P0`` and ``c`` per anchor, started
   by linear multilateration (:func:`calib.cable.multilaterate`) and refined by LM;
3. starts the full identification from the nominal DH table with the tool point, ``P0`` and
   ``c`` fitted (so that every method starts from the same, data-driven point, and no manual
   guess is needed);
4. analyses identifiability at that point (:mod:`calib.identifiability`) and solves for the
   base parameter set, plus parameters freed by name, minus parameters fixed by name;
5. runs the chosen method, optionally robustly (IRLS with Huber or soft-L1 weights, or
   iterative 3.5σ rejection, the scale being the MAD of the residuals), optionally with a
   Gaussian prior toward the nominal model (MAP);
6. computes the covariance ``(JᵀJ/σ̂² + Σ_prior⁻¹)⁻¹`` with ``σ̂² = Σ w r² / (n − k)``, the
   metrics before and after on train and test, and the plausibility of every parameter.

Units: inputs in degrees and millimetres; internal computation in radians and millimetres;
every reported figure in degrees and millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import scipy.cluster.hierarchy as sch

from calib import metrics
from calib.cable import (
    N_DH,
    N_KIN,
    ParamLayout,
    kinematic_parts,
    length_jacobian,
    multilaterate,
    predict_lengths,
)
from calib.dataset import SampleError, SampleSet, validate_joint_limits
from calib.identifiability import Identifiability, analyse
from calib.kinematics import N_JOINTS, FloatArray, forward_position
from calib.models import RobotModel
from calib.problem import Problem
from calib.solvers import de, ekf, lm, ukf, ukf_vslm, vslm
from calib.solvers.common import ProgressFn, SolverResult, Timer, report

METHODS = ("ukf-vslm", "lm", "vslm", "ukf", "ekf", "de")
Method = Literal["ukf-vslm", "lm", "vslm", "ukf", "ekf", "de"]
Robust = Literal["none", "huber", "soft_l1", "reject"]
Holdout = Literal["random", "grouped"]


@dataclass(frozen=True)
class IdentifyOptions:
    """Options of :func:`identify`.

    Attributes
    ----------
    method : one of :data:`METHODS`
    test_fraction : float
        Share of samples held out for testing, 0 ≤ f < 1.
    seed : int
        Seed of the split (and of DE).
    holdout : {"random", "grouped"}
        ``grouped`` holds out whole pose groups (a ``group`` column, or clusters of the joint
        angles) instead of random rows: accuracy at poses unlike the training poses.
    n_groups : int
        Number of clusters for ``grouped`` when the data have no ``group`` column.
    robust : {"none", "huber", "soft_l1", "reject"}
    robust_k : float
        Huber / soft-L1 threshold in robust standard deviations.
    flag_threshold : float
        Samples whose residual exceeds this many robust standard deviations are flagged (and,
        for ``reject``, excluded).
    prior : bool
        Add a Gaussian prior toward the nominal model (MAP). Off: maximum likelihood.
    prior_mm, prior_deg : float
        Prior 1σ of DH length and angle errors [mm, deg].
    prior_tool_mm : float or None
        Prior 1σ of the tool point error [mm]; None = no prior on the tool.
    noise_mm : float
        Assumed 1σ length noise [mm]: weighs the prior and sets the filters' ``R``.
    fix, free : tuple of str
        Parameter names to hold at their start value / to solve for even if unidentifiable.
    identify_tool : bool
        Solve for the tool point (default). If False it stays at the nominal value.
    tool_mm : tuple of 3 floats or None
        Nominal tool point overriding the model's [mm].
    rtol : float
        Identifiability threshold (see :func:`calib.identifiability.analyse`).
    ukf_epochs : int
        Sweeps of the UKF and EKF over the samples (the paper's ``T3``).
    ukf_batch_size : int or None
        Samples per filter update; None: 1 for ``ukf`` and ``ekf`` (per-sample updates), and
        for the UKF stage of ``ukf-vslm`` batches growing 1, 2, 4, … to 32 in each epoch (see
        :mod:`calib.solvers.ukf_vslm`).
    """

    method: Method = "ukf-vslm"
    test_fraction: float = 0.2
    seed: int = 0
    holdout: Holdout = "random"
    n_groups: int = 10
    robust: Robust = "none"
    robust_k: float = 1.345
    flag_threshold: float = 3.5
    prior: bool = False
    prior_mm: float = 2.0
    prior_deg: float = 0.2
    prior_tool_mm: float | None = None
    noise_mm: float = 0.1
    fix: tuple[str, ...] = ()
    free: tuple[str, ...] = ()
    identify_tool: bool = True
    tool_mm: tuple[float, float, float] | None = None
    rtol: float = 1e-8
    filter_sigma_mm: float = 5.0
    filter_sigma_deg: float = 0.5
    ukf_epochs: int = 2
    ukf_batch_size: int | None = None
    vslm_delta0: float = 0.8
    vslm_mu: float = 0.95
    de_max_generations: int = 300

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if not 0.0 <= self.test_fraction < 1.0:
            raise ValueError(f"test_fraction must be in [0, 1), got {self.test_fraction}")
        if self.robust not in ("none", "huber", "soft_l1", "reject"):
            raise ValueError(f"robust must be none, huber, soft_l1 or reject, got {self.robust!r}")
        if self.holdout not in ("random", "grouped"):
            raise ValueError(f"holdout must be random or grouped, got {self.holdout!r}")
        for name in ("prior_mm", "prior_deg", "noise_mm", "robust_k", "flag_threshold"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")


#: Plausible magnitudes, in display units, used by the plausibility report.
PLAUSIBLE_DH_MM = 10.0
PLAUSIBLE_DH_DEG = 1.0
PLAUSIBLE_TOOL_MM = 500.0
PLAUSIBLE_ANCHOR_MM = 5000.0
PLAUSIBLE_OFFSET_MM = 2000.0
CABLE_EXTENSION_MAX_MM = 2050.0


# ------------------------------------------------------------------------------- splitting
def pose_groups(samples: SampleSet, n_groups: int) -> np.ndarray:
    """Group label per sample, shape (n,): the ``group`` column, or Ward clusters of joints."""
    if samples.group is not None:
        ids = {g: i for i, g in enumerate(dict.fromkeys(samples.group))}
        return np.array([ids[g] for g in samples.group], dtype=int)
    n = len(samples)
    if n <= n_groups:
        return np.arange(n)
    tree = sch.linkage(samples.joints_deg, method="ward")
    return np.asarray(sch.fcluster(tree, t=n_groups, criterion="maxclust"), dtype=int) - 1


def split_rows(
    samples: SampleSet, test_fraction: float, seed: int, holdout: Holdout, n_groups: int = 10
) -> tuple[np.ndarray, np.ndarray]:
    """Training and test row indices (sorted)."""
    n = len(samples)
    rng = np.random.default_rng(seed)
    if test_fraction <= 0:
        return np.arange(n), np.zeros(0, dtype=int)
    target = round(test_fraction * n)
    if holdout == "random":
        perm = rng.permutation(n)
        return np.sort(perm[target:]), np.sort(perm[:target])
    labels = pose_groups(samples, n_groups)
    test: list[int] = []
    for g in rng.permutation(np.unique(labels)):
        if len(test) >= target:
            break
        test.extend(np.flatnonzero(labels == g).tolist())
    test_rows = np.sort(np.array(test, dtype=int))
    train_rows = np.setdiff1d(np.arange(n), test_rows)
    return train_rows, test_rows


# ------------------------------------------------------------------------- result types
@dataclass
class IdentifyResult:
    """Everything :func:`identify` found. :meth:`to_json` gives the documented contract."""

    model: RobotModel
    layout: ParamLayout
    method: str
    theta: FloatArray  # (p,) identified full vector, internal units
    theta_before: FloatArray  # (p,) nominal kinematics, fitted anchors
    free_names: list[str]
    sigma: FloatArray  # (p,) 1σ in internal units, 0 for fixed parameters
    correlation: FloatArray  # (k, k) over free_names
    identifiability: Identifiability
    solver: SolverResult
    metrics: dict[str, dict[str, dict[str, float]]]
    flagged_rows: list[int]
    train_rows: np.ndarray
    test_rows: np.ndarray
    options: IdentifyOptions
    plausibility: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    #: (p,) where every method started: nominal DH, tool point and anchors fitted.
    theta_start: FloatArray | None = None

    def dh_table_deg_mm(self, errors_only: bool = False) -> FloatArray:
        """Calibrated (or error) DH table, shape (6, 4): alpha_deg, a_mm, d_mm, theta_deg."""
        err = self.theta[:N_DH].reshape(N_JOINTS, 4).copy()
        err[:, [0, 3]] = np.rad2deg(err[:, [0, 3]])
        return err if errors_only else self.model.dh_table + err

    def tool_mm(self) -> FloatArray:
        return np.asarray(self._nominal_tool() + self.theta[N_DH:N_KIN], dtype=float)

    def _nominal_tool(self) -> FloatArray:
        return (
            np.asarray(self.options.tool_mm, dtype=float)
            if self.options.tool_mm is not None
            else self.model.tool_mm
        )

    def calibrated_model(self) -> RobotModel:
        """The calibrated robot as a model (same convention, joint limits kept)."""
        return RobotModel(
            name=f"{self.model.name}-calibrated",
            convention=self.model.convention,
            dh_table=self.dh_table_deg_mm(),
            joint_limits_deg=self.model.joint_limits_deg,
            tool_mm=self.tool_mm(),
        )

    def to_json(self) -> dict[str, Any]:
        """The stable ``result.json`` contract (see README)."""

        def rows(table: FloatArray) -> list[dict[str, float | int]]:
            return [
                {"joint": j + 1, "alpha_deg": float(table[j, 0]), "a_mm": float(table[j, 1]),
                 "d_mm": float(table[j, 2]), "theta_deg": float(table[j, 3])}
                for j in range(N_JOINTS)
            ]  # fmt: skip

        scale = self.layout.display_scale
        anchors: dict[str, dict[str, Any]] = {}
        for k, aid in enumerate(self.layout.anchors):
            vals = self.theta[self.layout.anchor_slice(k)]
            anchors[aid] = {
                "anchor_mm": [float(v) for v in vals[:3]],
                "length_offset_mm": float(vals[3]),
            }
        first = anchors[self.layout.anchors[0]]
        names = self.layout.names
        uncertainty = {
            names[i]: float(self.sigma[i] * scale[i]) for i in range(len(names)) if self.sigma[i]
        }
        return {
            "robot": self.model.name,
            "method": self.method,
            "convention": self.model.convention,
            "dh": rows(self.dh_table_deg_mm()),
            "dh_error": rows(self.dh_table_deg_mm(errors_only=True)),
            "tool_mm": [float(v) for v in self.tool_mm()],
            "anchor_mm": first["anchor_mm"],
            "length_offset_mm": first["length_offset_mm"],
            "anchor_id": self.layout.anchors[0],
            "anchors": {a: v for a, v in anchors.items() if a != self.layout.anchors[0]},
            "uncertainty": uncertainty,
            "correlation": {
                "names": list(self.free_names),
                "matrix": [[round(float(v), 6) for v in row] for row in self.correlation],
            },
            "identifiability": self.identifiability.to_dict(),
            "metrics": self.metrics,
            "flagged_samples": list(self.flagged_rows),
            "iterations": int(self.solver.iterations),
            "elapsed_s": float(self.elapsed_s),
            "status": int(self.solver.status),
            "success": bool(self.solver.success),
            "message": self.solver.message,
            "cost_history_rms_mm": [float(v) for v in self.solver.cost_history_rms_mm],
            "prior": {
                "used": self.options.prior,
                "dh_mm": self.options.prior_mm,
                "dh_deg": self.options.prior_deg,
                "tool_mm": self.options.prior_tool_mm,
                "noise_mm": self.options.noise_mm,
            },
            "robust": self.options.robust,
            "split": {
                "holdout": self.options.holdout,
                "test_fraction": self.options.test_fraction,
                "seed": self.options.seed,
                "n_train": int(self.train_rows.size),
                "n_test": int(self.test_rows.size),
            },
            "plausibility": self.plausibility,
            "notes": list(self.notes),
        }


# ------------------------------------------------------------------------------ helpers
def _internal_sigma(layout: ParamLayout, mm: float, deg: float, other_mm: float) -> FloatArray:
    """Scale per parameter (p,): DH lengths ``mm``, DH angles ``deg`` (rad), rest ``other_mm``."""
    out = np.full(layout.size, float(other_mm))
    out[:N_DH] = mm
    out[layout.is_angle] = np.deg2rad(deg)
    return out


def _fit(problem: Problem, x0: FloatArray | None = None) -> FloatArray:
    res = lm.solve(problem, x0, lm.LMOptions(max_iterations=100))
    return problem.full(res.x)


def fit_anchors(
    model: RobotModel, layout: ParamLayout, theta: FloatArray, q_rad: FloatArray,
    anchor_index: np.ndarray, length_mm: FloatArray,
) -> FloatArray:  # fmt: skip
    """``theta`` with every anchor's P0 and c fitted (multilateration start, LM refinement)."""
    theta = theta.copy()
    dh, tool = kinematic_parts(model, theta)
    pts = forward_position(dh, q_rad, tool, model.convention)
    for k in range(len(layout.anchors)):
        rows = anchor_index == k
        if np.count_nonzero(rows) < 5:
            raise SampleError(
                f"anchor {layout.anchors[k]!r} has {np.count_nonzero(rows)} samples; at least 5 "
                "are needed to locate it",
                column="anchor",
            )
        p0, c = multilaterate(pts[rows], length_mm[rows])
        if not (np.all(np.isfinite(p0)) and np.isfinite(c)):
            p0, c = pts[rows].mean(axis=0) + 500.0, 0.0
        theta[layout.anchor_slice(k)] = [*p0, c]
    free = np.zeros(layout.size, dtype=bool)
    free[N_KIN:] = True
    prob = Problem(model, layout, q_rad, length_mm, anchor_index, free, theta)
    return _fit(prob)


def _robust_weights(res: FloatArray, opts: IdentifyOptions) -> tuple[FloatArray, FloatArray]:
    """IRLS weights and standardised residuals ``|r|/s`` (``s`` = 1.4826 MAD)."""
    med = np.median(res)
    scale = 1.4826 * np.median(np.abs(res - med))
    scale = max(scale, 1e-6)
    u = np.abs(res) / scale
    if opts.robust == "huber":
        w = np.where(u <= opts.robust_k, 1.0, opts.robust_k / np.maximum(u, 1e-300))
    elif opts.robust == "soft_l1":
        w = 1.0 / np.sqrt(1.0 + (u / opts.robust_k) ** 2)
    elif opts.robust == "reject":
        w = (u <= opts.flag_threshold).astype(float)
    else:
        w = np.ones_like(res)
    return w, u


def _run_method(
    problem: Problem, x0: FloatArray, opts: IdentifyOptions, progress: ProgressFn | None
) -> SolverResult:
    layout = problem.layout
    free = problem.free
    if problem.has_prior:
        assert problem.prior_sigma is not None
        spread = np.where(
            np.isfinite(problem.prior_sigma),
            problem.prior_sigma,
            _internal_sigma(layout, 20.0, 1.0, 20.0),
        )[free]
    else:
        spread = _internal_sigma(
            layout, opts.filter_sigma_mm, opts.filter_sigma_deg, 4 * opts.filter_sigma_mm
        )[free]
    p0 = np.diag(spread**2)
    m = opts.method
    default = ukf_vslm.UKFVSLMOptions().ukf if m == "ukf-vslm" else ukf.UKFOptions()
    batch = default.batch_size if opts.ukf_batch_size is None else opts.ukf_batch_size
    ukf_opts = ukf.UKFOptions(epochs=opts.ukf_epochs, batch_size=batch, ramp=default.ramp)
    vslm_opts = vslm.VSLMOptions(delta0=opts.vslm_delta0, mu=opts.vslm_mu)
    if m == "lm":
        return lm.solve(problem, x0, progress=progress)
    if m == "vslm":
        return vslm.solve(problem, x0, vslm_opts, progress)
    if m == "ukf":
        return ukf.solve(problem, x0, p0, ukf_opts, progress)
    if m == "ekf":
        ekf_opts = ekf.EKFOptions(epochs=opts.ukf_epochs, batch_size=batch)
        return ekf.solve(problem, x0, p0, ekf_opts, progress)
    if m == "ukf-vslm":
        return ukf_vslm.solve(
            problem, x0, p0, ukf_vslm.UKFVSLMOptions(ukf=ukf_opts, vslm=vslm_opts), progress
        )
    bounds = _internal_sigma(layout, 5.0, 0.5, 50.0)[free]
    de_opts = de.DEOptions(max_generations=opts.de_max_generations, seed=opts.seed)
    return de.solve(problem, bounds, x0, de_opts, progress)


def _covariance(problem: Problem, x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Free-parameter covariance (k, k) in internal units and σ̂ [mm]."""
    pred, jac_full = length_jacobian(problem.model, problem.full(x), problem.q_rad,
                                     problem.anchor_index)  # fmt: skip
    sw = np.sqrt(problem.weights)
    res = sw * (pred - problem.length_mm)
    jac = sw[:, None] * jac_full[:, problem.free]
    k = jac.shape[1]
    dof = max(int(np.count_nonzero(problem.weights > 0)) - k, 1)
    sigma2 = max(float(res @ res) / dof, 1e-18)
    d = np.linalg.norm(jac, axis=0)
    d = np.where(d > 0, d, 1.0)
    info = (jac / d).T @ (jac / d) / sigma2
    if problem.has_prior:
        assert problem.prior_sigma is not None
        ps = problem.prior_sigma[problem.free]
        info = info + np.diag(np.where(np.isfinite(ps), 1.0 / (ps * ps), 0.0) / (d * d))
    evals, evecs = np.linalg.eigh(info)
    cutoff = evals.max() * 1e-15
    inv = np.where(evals > cutoff, 1.0 / np.where(evals > cutoff, evals, 1.0), 0.0)
    cov_scaled = (evecs * inv) @ evecs.T
    return cov_scaled / np.outer(d, d), np.array(np.sqrt(sigma2))


def _plausibility(
    layout: ParamLayout, theta: FloatArray, nominal_tool: FloatArray, extension_mm: FloatArray
) -> dict[str, Any]:
    scale = layout.display_scale
    names = layout.names
    items = []
    for i, name in enumerate(names):
        value = float(theta[i] * scale[i])
        if i < N_DH:
            bound = PLAUSIBLE_DH_DEG if layout.is_angle[i] else PLAUSIBLE_DH_MM
            kind = "error"
        elif i < N_KIN:
            value = float(nominal_tool[i - N_DH] + theta[i])
            bound, kind = PLAUSIBLE_TOOL_MM, "absolute"
        elif name.startswith("offset"):
            bound, kind = PLAUSIBLE_OFFSET_MM, "absolute"
        else:
            bound, kind = PLAUSIBLE_ANCHOR_MM, "absolute"
        items.append({"name": name, "value": value, "unit": layout.units[i], "kind": kind,
                      "bound": bound, "ok": bool(abs(value) <= bound)})  # fmt: skip
    ext_ok = bool(extension_mm.size == 0 or (
        extension_mm.min() > 0 and extension_mm.max() <= CABLE_EXTENSION_MAX_MM))  # fmt: skip
    outside = [it["name"] for it in items if not it["ok"]]
    return {
        "plausible": not outside and ext_ok,
        "outside_bounds": outside,
        "cable_extension_mm": {
            "min": float(extension_mm.min()) if extension_mm.size else None,
            "max": float(extension_mm.max()) if extension_mm.size else None,
            "ok": ext_ok,
        },
        "parameters": items,
    }


# ------------------------------------------------------------------------------- entry
def identify(
    model: RobotModel,
    samples: SampleSet,
    options: IdentifyOptions | None = None,
    *,
    train_rows: np.ndarray | None = None,
    test_rows: np.ndarray | None = None,
    progress: ProgressFn | None = None,
) -> IdentifyResult:
    """Identify the calibrated model from samples.

    Parameters
    ----------
    model : RobotModel
        Nominal model.
    samples : SampleSet
        ``n`` samples: joints (n, 6) [deg], lengths (n,) [mm], anchor ids.
    options : IdentifyOptions
    train_rows, test_rows : ndarray of int, optional
        Explicit split; overrides ``options.test_fraction``.
    progress : callable(fraction, message), optional
        May raise :class:`calib.solvers.common.Cancelled` to stop.

    Raises
    ------
    SampleError
        Joint angles outside the model's limits, too few samples, an anchor with too few
        samples. Nothing is partially returned.
    ValueError
        Unknown parameter names in ``fix``/``free``.
    """
    opts = options or IdentifyOptions()
    timer = Timer()
    validate_joint_limits(samples, model)
    if train_rows is None or test_rows is None:
        train_rows, test_rows = split_rows(
            samples, opts.test_fraction, opts.seed, opts.holdout, opts.n_groups
        )
    train = samples.subset(train_rows)
    layout = ParamLayout(samples.anchor_ids)
    unknown = [n for n in (*opts.fix, *opts.free) if n not in layout.names]
    if unknown:
        raise ValueError(f"fix/free: unknown parameter name(s) {unknown}; known: {layout.names}")
    if opts.tool_mm is not None:
        model = RobotModel(model.name, model.convention, model.dh_table, model.joint_limits_deg,
                           np.asarray(opts.tool_mm, dtype=float))  # fmt: skip
    aidx_all = samples.anchor_index()
    q_all = np.deg2rad(samples.joints_deg)
    q, aidx, length = q_all[train_rows], aidx_all[train_rows], train.length_mm
    for k, aid in enumerate(layout.anchors):
        if not np.any(aidx == k):
            raise SampleError(f"anchor {aid!r} has no training samples", column="anchor")

    report(progress, 0.0, "fitting the anchor with the nominal model")
    theta_before = fit_anchors(model, layout, np.zeros(layout.size), q, aidx, length)

    candidates = np.ones(layout.size, dtype=bool)
    if not opts.identify_tool:
        candidates[N_DH:N_KIN] = False
    for name in opts.fix:
        candidates[layout.index(name)] = False
    theta_start = theta_before
    if candidates[N_DH:N_KIN].any():
        free0 = np.zeros(layout.size, dtype=bool)
        free0[N_DH:] = candidates[N_DH:]
        theta_start = _fit(Problem(model, layout, q, length, aidx, free0, theta_before))
    report(progress, 0.05, "identifiability analysis")

    _, jac = length_jacobian(model, theta_start, q, aidx)
    generic = _generic_jacobian(model, layout, theta_start)
    ident = analyse(jac, layout.names, candidates, rtol=opts.rtol, structural_jacobian=generic)
    free = np.array([n in ident.base for n in layout.names]) & candidates
    for name in opts.free:
        free[layout.index(name)] = True
    n_free = int(np.count_nonzero(free))
    if train_rows.size < n_free + 1:
        raise SampleError(
            f"{train_rows.size} training samples for {n_free} parameters; need at least "
            f"{n_free + 1} (more rows, or fix parameters)"
        )

    prior_sigma = None
    notes: list[str] = []
    if opts.prior:
        prior_sigma = _internal_sigma(layout, opts.prior_mm, opts.prior_deg, np.inf)
        prior_sigma[N_DH:N_KIN] = np.inf if opts.prior_tool_mm is None else opts.prior_tool_mm
        notes.append(
            f"MAP prior toward the nominal model: {opts.prior_mm} mm / {opts.prior_deg} deg "
            f"per DH error, noise {opts.noise_mm} mm"
        )
    prior_mean = theta_start.copy()
    prior_mean[:N_DH] = 0.0
    if opts.prior_tool_mm is not None:
        prior_mean[N_DH:N_KIN] = 0.0
    problem = Problem(model, layout, q, length, aidx, free, theta_start,
                      prior_sigma=prior_sigma, prior_mean=prior_mean,
                      noise_mm=opts.noise_mm)  # fmt: skip

    def solve_progress(lo: float, hi: float) -> ProgressFn | None:
        if progress is None:
            return None
        outer = progress
        return lambda f, msg: outer(lo + (hi - lo) * f, msg)

    x = problem.x0()
    weights = np.ones(train_rows.size)
    u = np.zeros(train_rows.size)
    rounds = 1 if opts.robust == "none" else 8
    result: SolverResult | None = None
    total_iter = 0
    for r in range(rounds):
        prob_r = problem.with_weights(weights)
        lo = 0.05 + 0.9 * r / rounds
        result = _run_method(prob_r, x, opts, solve_progress(lo, lo + 0.9 / rounds))
        total_iter += result.iterations
        x = result.x
        if opts.robust == "none":
            break
        new_w, u = _robust_weights(prob_r.predict(x) - length, opts)
        if np.max(np.abs(new_w - weights)) < 1e-3:
            weights = new_w
            break
        weights = new_w
    assert result is not None
    result.iterations = total_iter
    final = problem.with_weights(weights)
    if opts.robust != "none":
        notes.append(f"robust mode {opts.robust}: {int(np.sum(u > opts.flag_threshold))} flagged")
    report(progress, 0.96, "covariance and metrics")

    theta = final.full(x)
    cov, _ = _covariance(final, x)
    sig_free = np.sqrt(np.clip(np.diag(cov), 0, None))
    sigma = np.zeros(layout.size)
    sigma[free] = sig_free
    denom = np.outer(sig_free, sig_free)
    corr = np.divide(cov, denom, out=np.zeros_like(cov), where=denom > 0)

    def lengths(th: FloatArray, rows: np.ndarray) -> FloatArray:
        if rows.size == 0:
            return np.zeros(0)
        return predict_lengths(model, th, q_all[rows], aidx_all[rows])

    figures: dict[str, dict[str, dict[str, float]]] = {}
    for label, th in (("before", theta_before), ("after", theta)):
        figures[label] = {
            part: metrics.length_metrics(samples.length_mm[rows], lengths(th, rows))
            for part, rows in (("train", train_rows), ("test", test_rows))
        }
    extension = lengths(theta, np.arange(len(samples))) - theta[N_KIN:].reshape(-1, 4)[aidx_all, 3]
    plaus = _plausibility(layout, theta, model.tool_mm, extension)
    if not plaus["plausible"]:
        notes.append(
            "identified parameters are physically implausible ("
            + ", ".join(plaus["outside_bounds"][:6])
            + ("" if plaus["cable_extension_mm"]["ok"] else ", cable extension")
            + "): the data do not constrain them; use --prior or more varied poses"
        )
    flagged = (
        [int(train_rows[i]) for i in np.flatnonzero(u > opts.flag_threshold)]
        if opts.robust != "none"
        else []
    )
    report(progress, 1.0, "done")
    return IdentifyResult(
        model=model,
        layout=layout,
        method=opts.method,
        theta=theta,
        theta_before=theta_before,
        free_names=[n for n, f in zip(layout.names, free, strict=True) if f],
        sigma=sigma,
        correlation=corr,
        identifiability=ident,
        solver=result,
        metrics=figures,
        flagged_rows=flagged,
        train_rows=train_rows,
        test_rows=test_rows,
        options=opts,
        plausibility=plaus,
        notes=notes,
        elapsed_s=timer.elapsed(),
        theta_start=theta_start,
    )


def _generic_jacobian(model: RobotModel, layout: ParamLayout, theta: FloatArray) -> FloatArray:
    """Jacobian at 200 fixed well-spread poses, to tell structural from data-limited rank."""
    rng = np.random.default_rng(20230410)
    limits = model.joint_limits_deg
    lo = np.full(N_JOINTS, -170.0) if limits is None else np.maximum(limits[:, 0], -170.0)
    hi = np.full(N_JOINTS, 170.0) if limits is None else np.minimum(limits[:, 1], 170.0)
    hi = np.where(hi > lo, hi, lo + 1.0)
    q = np.deg2rad(rng.uniform(lo, hi, size=(200, N_JOINTS)))
    aidx = np.arange(200) % len(layout.anchors)
    _, jac = length_jacobian(model, theta, q, aidx)
    return jac
