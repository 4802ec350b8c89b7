"""The live watch's running fit of a campaign and its per-sample test, pure.

The **running fit** predicts a new sample's cable length without having seen it. It is fitted
on the campaign's included samples so far, minus those under suspicion, and refitted as the
campaign grows (after each new sample while small, every :data:`REFIT_FRACTION` later):

- ``identify``: the campaign's own full identification (DH errors, tool, every anchor's P0
  and c; :func:`calib.identify.identify`, no hold-out, no robust pass) once there are
  :data:`MIN_DOF` more samples than it solves parameters (30 with one anchor on the HSR
  JR680); mm-level DH errors then stay out of the residuals;
- ``calibration``: before that, the robot's accepted calibration with this campaign's anchors
  (P0 and c) fitted;
- ``nominal``: else the nominal model with the anchors fitted. Its prediction errors are as
  large as the DH errors (several mm), as large as the bumps to find, so its residuals are
  **not tested**: a campaign of a robot without a calibration is watched from its ~30th
  sample on.

The test's scale starts from the fit's expected prediction error (:attr:`RunningFit.scale_mm`)
and then follows the tested residuals. At the first testable fit of a campaign without a
calibration, a **look back** (:func:`scan_for_step`) asks whether the sensor moved among the
samples no fit could test yet (a split into two anchor sessions that explains them much
better; MAP fits with identify's prior toward the nominal model, :func:`map_fit`, determined
with few samples). A MAP fit is not used as the running fit: on 20-odd samples it predicts
some poses well and others to a mm, and a check on a few held-out samples cannot tell which
(a false alarm at 0.2 mm noise).

An anchor with fewer than :data:`calib.cable.MIN_ANCHOR_SAMPLES` samples cannot be located:
its samples are not tested (the first samples of a campaign and of a new anchor session).

:class:`LiveTester` ties the fit to :class:`calib.monitor.stepwatch.StepDetector`; the daemon
(:mod:`daemon.monitors.watch`) and the benchmark (``bench/drift_watch.py``) drive it the same way.
``calib.identify`` and scipy are imported inside the functions that use them.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from calib.cable import MIN_ANCHOR_SAMPLES, N_KIN
from calib.monitor.stepwatch import StepAlarm, StepDetector, locate_step

if TYPE_CHECKING:
    from calib.cable import ParamLayout
    from calib.dataset import SampleSet
    from calib.kinematics import FloatArray
    from calib.models import RobotModel

FitKind = Literal["identify", "calibration", "nominal"]
#: Rows beyond the parameters a fit needs before its predictions are used (identify).
MIN_DOF = 5
#: Prior 1σ of the tool point in the look back's MAP fits [mm] (the DH priors are identify's).
MAP_TOOL_PRIOR_MM = 5.0
#: The look back at the first testable fit: a split of the samples into two anchor sessions
#: must cut the residual RMS by this factor to be called a move that happened before.
SCAN_RATIO = 5.0
#: Refit when the clean samples grew by this fraction since the last fit (at least one).
REFIT_FRACTION = 0.1
#: Tested samples an alarm looks back over for the step (:meth:`LiveTester.locate`): as
#: many as the detector keeps clean residuals for (``StepSettings.history``'s default).
LOCATE_WINDOW = 30


@dataclass
class RunningFit:
    """A fitted model of one campaign: predicts a sample's cable length [mm]."""

    kind: FitKind
    model: RobotModel
    layout: ParamLayout
    theta: FloatArray
    rmse_mm: float
    n_rows: int
    n_params: int

    @property
    def testable(self) -> bool:
        """Whether its predictions are good enough to test samples with: not the nominal
        model (its errors are as large as a bump)."""
        return self.kind != "nominal"

    @property
    def scale_mm(self) -> float:
        """Expected 1σ prediction error of a new sample [mm]: the residual RMSE corrected
        for the parameters fitted (``sqrt(n / (n − p))``) and for their uncertainty at a new
        pose (``sqrt(1 + p / n)``, the mean leverage)."""
        n, p = self.n_rows, self.n_params
        return self.rmse_mm * math.sqrt(n / max(n - p, 1)) * math.sqrt(1.0 + p / n)

    def step_design(self, joints_deg: FloatArray, anchor: str) -> FloatArray | None:
        """How a change of ``anchor``'s sensor changes the length at poses ``joints_deg``
        (n, 6) [deg]: ``(−u, 1)`` per pose (n, 4) [mm/mm], ``u`` the unit cable direction
        from P0 to the hook point (a P0 shift ``δ`` and an offset change ``Δc`` change the
        length by ``−u·δ + Δc``); None for an anchor not fitted."""
        from calib.cable import kinematic_parts
        from calib.kinematics import forward_position

        if anchor not in self.layout.anchors:
            return None
        q = self.model.table_rad(np.asarray(joints_deg, dtype=float).reshape(-1, 6))
        dh, tool = kinematic_parts(self.model, self.theta)
        hook = forward_position(dh, q, tool, self.model.convention)
        start = N_KIN + 4 * self.layout.anchors.index(anchor)
        diff = hook - self.theta[start : start + 3]
        unit = diff / np.linalg.norm(diff, axis=1)[:, None]
        out: FloatArray = np.hstack([-unit, np.ones((q.shape[0], 1))])
        return out

    def predict_mm(self, joints_deg: Sequence[float] | FloatArray, anchor: str) -> float | None:
        """The predicted length [mm] of one pose (6,) [deg]; None for an anchor not fitted."""
        from calib.cable import predict_lengths

        if anchor not in self.layout.anchors:
            return None
        q = self.model.table_rad(np.asarray(joints_deg, dtype=float).reshape(1, 6))
        index = np.array([self.layout.anchors.index(anchor)])
        return float(predict_lengths(self.model, self.theta, q, index)[0])


def fit_campaign(
    samples: SampleSet, nominal: RobotModel, calibration: Mapping[str, Any] | None
) -> RunningFit | None:
    """The running fit of ``samples`` (see the module docstring); None when no anchor has
    :data:`calib.cable.MIN_ANCHOR_SAMPLES` samples. Pure computation (the daemon runs it in a
    worker thread)."""
    from calib.anchors import fit_anchors
    from calib.cable import ParamLayout, predict_lengths
    from calib.dataset import SampleError
    from calib.export import model_from_result
    from calib.identify import IdentifyOptions, identify

    counts = {a: samples.anchor.count(a) for a in samples.anchor_ids}
    keep = np.array([counts[a] >= MIN_ANCHOR_SAMPLES for a in samples.anchor])
    if not keep.any():
        return None
    sub = samples.subset(np.flatnonzero(keep)) if not keep.all() else samples
    q, length = sub.joints_deg, sub.length_mm
    names = {f.name for f in dataclasses.fields(IdentifyOptions)}
    extra: dict[str, Any] = {"drift": "none"} if "drift" in names else {}
    kind: FitKind | None = None
    try:
        res = identify(nominal, sub, IdentifyOptions(test_fraction=0.0, robust="none", **extra))
        n_params = len(res.free_names)
        if len(sub) - n_params >= MIN_DOF:
            model, layout, theta, kind = res.model, res.layout, res.theta, "identify"
    except (SampleError, ValueError, np.linalg.LinAlgError):
        pass
    if kind is None:
        layout = ParamLayout(sub.anchor_ids)
        model = nominal if calibration is None else model_from_result(calibration)
        kind = "nominal" if calibration is None else "calibration"
        n_params = 4 * len(layout.anchors)
        theta = fit_anchors(
            model, layout, np.zeros(layout.size), model.table_rad(q), sub.anchor_index(), length
        )
    fitted = predict_lengths(model, theta, model.table_rad(q), sub.anchor_index())
    rmse = float(np.sqrt(np.mean((length - fitted) ** 2)))
    return RunningFit(kind, model, layout, theta, rmse, len(sub), n_params)


def map_fit(model: RobotModel, samples: SampleSet) -> tuple[ParamLayout, FloatArray]:
    """A maximum a-posteriori fit of every DH error, the tool point and every anchor's P0
    and c, with identify's Gaussian prior toward the nominal model
    (:func:`calib.prior.with_prior`: ``prior_mm``, ``prior_deg``, and
    :data:`MAP_TOOL_PRIOR_MM` as ``prior_tool_mm``): determined with fewer samples than
    parameters. Returns the layout and the full parameter vector."""
    from scipy.optimize import least_squares

    from calib.anchors import fit_anchors
    from calib.cable import ParamLayout
    from calib.options import IdentifyOptions, PriorOptions, part
    from calib.prior import with_prior
    from calib.problem import Problem

    opts = dataclasses.replace(
        part(IdentifyOptions(), PriorOptions), prior_tool_mm=MAP_TOOL_PRIOR_MM
    )
    layout = ParamLayout(samples.anchor_ids)
    q, idx, length = model.table_rad(samples.joints_deg), samples.anchor_index(), samples.length_mm
    start = fit_anchors(model, layout, np.zeros(layout.size), q, idx, length)
    problem = Problem(model, layout, q, length, idx, np.ones(layout.size, dtype=bool), start)
    problem = with_prior(problem, opts)
    # The problem's rows are in mm (prior rows weighed by noise_mm); divided by the noise
    # they are the normalised residuals whose sum of squares is the negative log posterior.
    noise = problem.noise_mm

    def fun(theta: FloatArray) -> FloatArray:
        return problem.residuals(theta) / noise

    def jac(theta: FloatArray) -> FloatArray:
        return problem.residuals_and_jacobian(theta)[1] / noise

    res = least_squares(fun, start, jac=jac, method="trf", x_scale="jac", max_nfev=200)
    theta: FloatArray = np.asarray(res.x, dtype=float)
    return layout, theta


def scan_for_step(
    model: RobotModel, samples: SampleSet, min_step_mm: float
) -> tuple[int, float, float] | None:
    """Look back over samples no fit could test yet: did the sensor move among them?

    For each split row ``k`` (at least :data:`calib.cable.MIN_ANCHOR_SAMPLES` on each side),
    a MAP fit (:func:`map_fit`) with the rows from ``k`` on as a second anchor session,
    against one session. A move is a split that cuts the residual RMS by :data:`SCAN_RATIO`
    and changes the cable lengths by at least half of ``min_step_mm`` (median over the moved
    rows).

    Returns ``(k, step_mm, size_mm)`` (step: median signed length change [mm]) or None.
    Samples of several anchors are not scanned.
    """
    from calib.cable import predict_lengths

    n = len(samples)
    if len(samples.anchor_ids) != 1 or n < 2 * MIN_ANCHOR_SAMPLES:
        return None
    q = model.table_rad(samples.joints_deg)

    def rms(layout: Any, theta: FloatArray, anchors: tuple[str, ...]) -> float:
        index = np.array([layout.anchors.index(a) for a in anchors])
        r = samples.length_mm - predict_lengths(model, theta, q, index)
        return float(np.sqrt(np.mean(r**2)))

    layout, theta = map_fit(model, samples)
    single = rms(layout, theta, samples.anchor)
    if single < min_step_mm / 4.0:
        return None
    old = samples.anchor[0]
    best: tuple[float, int, Any, FloatArray] | None = None
    for k in range(MIN_ANCHOR_SAMPLES, n - MIN_ANCHOR_SAMPLES + 1):
        anchors = (old,) * k + (old + "~moved",) * (n - k)
        split = dataclasses.replace(samples, anchor=anchors, group=None)
        lay2, th2 = map_fit(model, split)
        value = rms(lay2, th2, anchors)
        if best is None or value < best[0]:
            best = (value, k, lay2, th2)
    if best is None or best[0] * SCAN_RATIO > single:
        return None
    _, k, lay2, th2 = best
    moved = q[k:]
    before = predict_lengths(model, th2, moved, np.full(n - k, lay2.anchors.index(old)))
    after = predict_lengths(model, th2, moved, np.full(n - k, lay2.anchors.index(old + "~moved")))
    change = after - before
    size = float(np.median(np.abs(change)))
    if size < min_step_mm / 2.0:
        return None
    return k, float(np.median(change)), size


@dataclass
class LiveTester:
    """The per-sample test of one campaign, without I/O: the running fit and the detector.

    The daemon (:class:`daemon.monitors.watch.SensorWatch`) and the benchmark
    (``bench/drift_watch.py``) drive it the same way: :meth:`clean_rows` →
    (:meth:`needs_refit` → :meth:`refit`) → :meth:`test`; :meth:`refit_rows` does the
    middle step from the campaign's samples and their ids.
    """

    nominal: RobotModel
    calibration: Mapping[str, Any] | None
    detector: StepDetector
    fit: RunningFit | None = None
    fit_clean: int = 0  # clean samples the fit saw
    scanned: bool = False  # the look back (scan_for_step) ran in this anchor session
    found: StepAlarm | None = None  # a move the look back found, reported by the next test
    #: The samples tested in this anchor session, newest last, at most
    #: :data:`LOCATE_WINDOW`: ``(key, joints (6,) [deg], length [mm], anchor)``. An alarm
    #: looks for the step among them (:meth:`locate`); older ones the watch trusts.
    tested: list[tuple[int, FloatArray, float, str]] = dataclasses.field(default_factory=list)

    def clean_rows(self, ids: list[int], sample_id: int) -> list[int]:
        """Rows of ``ids`` (sample ids, in order) the fit may use for ``sample_id``: the
        samples before it, minus those of the detector's open run."""
        suspects = set(self.detector.suspects)
        return [i for i, sid in enumerate(ids) if sid < sample_id and sid not in suspects]

    def needs_refit(self, n_clean: int) -> bool:
        """Refit when the clean samples grew by :data:`REFIT_FRACTION` (at least one)."""
        grown = n_clean - self.fit_clean
        return self.fit is None or grown >= max(1.0, REFIT_FRACTION * self.fit_clean)

    def refit(self, samples: SampleSet, n_clean: int, ids: list[int] | None = None) -> None:
        """Fit ``samples`` (the clean rows, sample ids ``ids``; CPU-bound: the daemon runs it
        in a thread). At the first testable fit of an anchor session, look back over the
        samples no fit could test (:func:`scan_for_step`)."""
        if len(samples) < MIN_ANCHOR_SAMPLES:
            return
        fit = fit_campaign(samples, self.nominal, self.calibration)
        if fit is None:
            return
        if fit.testable and not self.scanned and fit.kind != "calibration":
            self.scanned = True
            step = scan_for_step(self.nominal, samples, self.detector.settings.min_step_mm)
            if step is not None and ids is not None:
                k, step_mm, size_mm = step
                keys = tuple(ids[k:])
                self.found = StepAlarm(keys[0], keys, step_mm, size_mm, len(keys))
                return
        if self.fit is not None and self.fit.kind != fit.kind:
            self.detector.reset()  # another model: the old residual scale no longer holds
        self.detector.prior_scale_mm = fit.scale_mm
        self.fit, self.fit_clean = fit, n_clean

    def refit_rows(self, samples: SampleSet, ids: list[int], clean: list[int]) -> None:
        """:meth:`refit` on the rows ``clean`` of ``samples`` (a campaign's samples, sample
        ids ``ids``)."""
        subset = samples.subset(np.array(clean, dtype=int))
        self.refit(subset, len(clean), [ids[i] for i in clean])

    def test(
        self,
        sample_id: int,
        joints_deg: Sequence[float] | FloatArray,
        length_mm: float,
        anchor: str,
    ) -> tuple[float | None, StepAlarm | None]:
        """``(residual_mm, alarm)`` of one sample (joints (6,) [deg], length [mm]); residual
        None when the fit cannot predict it (no fit yet, or its anchor has too few samples).
        The nominal model's residuals are not tested (alarm None)."""
        if self.found is not None:
            found, self.found = self.found, None
            keys = (*found.keys, sample_id)
            return None, dataclasses.replace(found, keys=keys, delay=len(keys))
        if self.fit is None:
            return None, None
        predicted = self.fit.predict_mm(joints_deg, anchor)
        if predicted is None:
            return None, None
        residual = float(length_mm) - predicted
        if not self.fit.testable:
            return residual, None
        self.tested.append(
            (sample_id, np.asarray(joints_deg, dtype=float), float(length_mm), anchor)
        )
        del self.tested[:-LOCATE_WINDOW]
        alarm = self.detector.update(sample_id, residual)
        return residual, None if alarm is None else self.locate(alarm)

    def locate(self, alarm: StepAlarm) -> StepAlarm:
        """``alarm`` with its first sample moved to where the sensor moved: the step located
        (:func:`calib.monitor.stepwatch.locate_step`) among the samples of the alarm's anchor
        tested since the last one the watch trusts (:attr:`tested`), by their residuals
        against the running fit. The run's first exceedance is only the latest possible
        step: samples before it whose change was inside the band (a pose whose cable is
        nearly square to the bump) or whose run died out were taken after the move too.
        ``keys`` become every sample of the window from the step on, and the alarm's own."""
        fit = self.fit
        first = next((t for t in self.tested if t[0] == alarm.first_key), None)
        if fit is None or first is None:
            return alarm
        window = [t for t in self.tested if t[3] == first[3]]
        keys = [t[0] for t in window]
        q = np.array([t[1] for t in window], dtype=float).reshape(-1, 6)
        design = fit.step_design(q, first[3])
        if design is None:
            return alarm
        predicted = [fit.predict_mm(t[1], t[3]) for t in window]
        residual = np.array(
            [t[2] - (p if p is not None else t[2]) for t, p in zip(window, predicted, strict=True)]
        )
        settings = self.detector.settings
        sigma = max(self.detector.scale_mm, settings.sigma_floor_mm)
        size = max(alarm.size_mm, settings.min_step_mm)
        k = locate_step(residual, design, sigma, size, keys.index(alarm.first_key))
        moved = tuple(sorted({*keys[k:], *alarm.keys}))
        return dataclasses.replace(alarm, first_key=moved[0], keys=moved, delay=len(moved))

    def moved(self) -> None:
        """After a move: the new anchor session needs a new fit."""
        self.tested.clear()
        self.fit = None
        self.fit_clean = 0
        self.scanned = True  # a session after a move has a fitted model of the robot
