"""Live sensor watch: after each new sample, did the drawstring sensor move?

The flow (the decisions are pure, in :mod:`daemon.stepwatch`):

1. The sampler's sink is wrapped (:meth:`SensorWatch.wrap`): every stored capture is queued
   for its campaign, and one task per campaign takes them in order, off the event loop.
2. The **running fit** predicts the new sample's cable length without having seen it. It is
   fitted on the campaign's included samples so far, minus those under suspicion, and
   refitted as the campaign grows (after each new sample while small, every ~10 % later):

   - ``identify``: the campaign's own full identification (DH errors, tool, every anchor's P0
     and c; :func:`calib.identify.identify`, no hold-out, no robust pass) once there are
     :data:`MIN_DOF` more samples than it solves parameters (30 with one anchor on the
     HSR JR680); mm-level DH errors then stay out of the residuals;
   - ``calibration``: before that, the robot's accepted calibration with this campaign's
     anchors (P0 and c) fitted;
   - ``nominal``: else the nominal model with the anchors fitted. Its prediction errors are
     as large as the DH errors (several mm), as large as the bumps to find, so its residuals
     are **not tested**: a campaign of a robot without a calibration is watched from its
     ~30th sample on.

   The test's scale starts from the fit's expected prediction error
   (:attr:`RunningFit.scale_mm`) and then follows the tested residuals. At the first
   testable fit of a campaign without a calibration, a **look back** (:func:`scan_for_step`)
   asks whether the sensor moved among the samples no fit could test yet (a split into two
   anchor sessions that explains them much better; MAP fits with identify's prior toward
   the nominal model, :func:`map_fit`, determined with few samples). A MAP fit is not used
   as the running fit: on 20-odd samples it predicts some poses well and others to a mm, and
   a check on a few held-out samples cannot tell which (a false alarm at 0.2 mm noise).

   An anchor with fewer than 5 samples cannot be located: its samples are not tested (the
   first samples of a campaign and of a new anchor session).
3. :class:`daemon.stepwatch.StepDetector` tests the residual. On an alarm the samples from the
   run's first on go to a new anchor session (:func:`daemon.stepwatch.next_anchor`), auto
   capture goes on with it, and the event ``sensor_moved`` (size, first sample id and row),
   the counter ``cablecal_sensor_moved_total`` and the ``watch`` block of ``GET /status``
   (the page's banner) tell the operator, who can undo it
   (``POST /campaigns/{id}/sensor-moved/undo``: :meth:`SensorWatch.undo`).

numpy and ``calib`` are imported inside the functions that use them.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from daemon import metrics
from daemon.stepwatch import StepAlarm, StepDetector, StepSettings, next_anchor

if TYPE_CHECKING:
    from calib.cable import ParamLayout
    from calib.dataset import SampleSet
    from calib.kinematics import FloatArray
    from calib.models import RobotModel
    from daemon.capture import Capture, CaptureSink
    from daemon.store import Store

log = logging.getLogger("cablecal.watch")

FitKind = Literal["identify", "calibration", "nominal"]
#: Samples an anchor needs before it can be located (:func:`calib.identify.fit_anchors`).
MIN_ANCHOR_SAMPLES = 5
#: Rows beyond the parameters a fit needs before its predictions are used (identify).
MIN_DOF = 5
#: Prior 1σ of the tool point in the look back's MAP fits [mm] (the DH priors are identify's).
MAP_TOOL_PRIOR_MM = 5.0
#: The look back at the first testable fit: a split of the samples into two anchor sessions
#: must cut the residual RMS by this factor to be called a move that happened before.
SCAN_RATIO = 5.0
#: Refit when the clean samples grew by this fraction since the last fit (at least one).
REFIT_FRACTION = 0.1

SENSOR_MOVED = "sensor_moved"
SENSOR_MOVED_UNDONE = "sensor_moved_undone"


class NothingToUndo(LookupError):
    """The campaign has no automatic anchor split left to undo."""


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

    def predict_mm(self, joints_deg: FloatArray, anchor: str) -> float | None:
        """The predicted length [mm] of one pose (6,) [deg]; None for an anchor not fitted."""
        import numpy as np

        from calib.cable import predict_lengths

        if anchor not in self.layout.anchors:
            return None
        q = np.deg2rad(np.asarray(joints_deg, dtype=float).reshape(1, 6))
        index = np.array([self.layout.anchors.index(anchor)])
        return float(predict_lengths(self.model, self.theta, q, index)[0])


def fit_campaign(
    samples: SampleSet, nominal: RobotModel, calibration: Mapping[str, Any] | None
) -> RunningFit | None:
    """The running fit of ``samples`` (see the module docstring); None when no anchor has
    :data:`MIN_ANCHOR_SAMPLES` samples. Pure computation (runs in a worker thread)."""
    import numpy as np

    from calib.cable import ParamLayout, predict_lengths
    from calib.dataset import SampleError
    from calib.export import model_from_result
    from calib.identify import IdentifyOptions, fit_anchors, identify

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
        theta = fit_anchors(model, layout, np.zeros(layout.size), np.deg2rad(q),
                            sub.anchor_index(), length)  # fmt: skip
    fitted = predict_lengths(model, theta, np.deg2rad(q), sub.anchor_index())
    rmse = float(np.sqrt(np.mean((length - fitted) ** 2)))
    return RunningFit(kind, model, layout, theta, rmse, len(sub), n_params)


def map_fit(model: RobotModel, samples: SampleSet) -> tuple[ParamLayout, FloatArray]:
    """A maximum a-posteriori fit of every DH error, the tool point and every anchor's P0
    and c, with identify's Gaussian prior toward the nominal model (``prior_mm``,
    ``prior_deg``) and :data:`MAP_TOOL_PRIOR_MM` on the tool: determined with fewer samples
    than parameters. Returns the layout and the full parameter vector."""
    import numpy as np
    from scipy.optimize import least_squares

    from calib.cable import N_DH, N_KIN, ParamLayout, length_jacobian, predict_lengths
    from calib.identify import IdentifyOptions, fit_anchors

    opts = IdentifyOptions()
    layout = ParamLayout(samples.anchor_ids)
    q, idx, length = np.deg2rad(samples.joints_deg), samples.anchor_index(), samples.length_mm
    start = fit_anchors(model, layout, np.zeros(layout.size), q, idx, length)
    joint = [math.radians(opts.prior_deg), opts.prior_mm, opts.prior_mm,
             math.radians(opts.prior_deg)]  # fmt: skip
    weight = np.zeros(layout.size)
    weight[:N_DH] = 1.0 / np.tile(joint, 6)
    weight[N_DH:N_KIN] = 1.0 / MAP_TOOL_PRIOR_MM
    noise = opts.noise_mm

    def fun(theta: FloatArray) -> FloatArray:
        r = (length - predict_lengths(model, theta, q, idx)) / noise
        return np.concatenate([r, weight * theta])

    def jac(theta: FloatArray) -> FloatArray:
        _, j = length_jacobian(model, theta, q, idx)
        return np.vstack([-j / noise, np.diag(weight)])

    res = least_squares(fun, start, jac=jac, method="trf", x_scale="jac", max_nfev=200)
    theta: FloatArray = np.asarray(res.x, dtype=float)
    return layout, theta


def scan_for_step(
    model: RobotModel, samples: SampleSet, min_step_mm: float
) -> tuple[int, float, float] | None:
    """Look back over samples no fit could test yet: did the sensor move among them?

    For each split row ``k`` (at least :data:`MIN_ANCHOR_SAMPLES` on each side), a MAP fit
    (:func:`map_fit`) with the rows from ``k`` on as a second anchor session, against one
    session. A move is a split that cuts the residual RMS by :data:`SCAN_RATIO` and changes
    the cable lengths by at least half of ``min_step_mm`` (median over the moved rows).

    Returns ``(k, step_mm, size_mm)`` (step: median signed length change [mm]) or None.
    Samples of several anchors are not scanned.
    """
    import numpy as np

    from calib.cable import predict_lengths

    n = len(samples)
    if len(samples.anchor_ids) != 1 or n < 2 * MIN_ANCHOR_SAMPLES:
        return None
    q = np.deg2rad(samples.joints_deg)

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

    The daemon (:class:`SensorWatch`) and the benchmark (``bench/drift_watch.py``) drive it
    the same way: :meth:`clean_rows` → (:meth:`needs_refit` → :meth:`refit`) → :meth:`test`.
    """

    nominal: RobotModel
    calibration: Mapping[str, Any] | None
    detector: StepDetector
    fit: RunningFit | None = None
    fit_clean: int = 0  # clean samples the fit saw
    scanned: bool = False  # the look back (scan_for_step) ran in this anchor session
    found: StepAlarm | None = None  # a move the look back found, reported by the next test

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

    def test(
        self, sample_id: int, joints_deg: FloatArray, length_mm: float, anchor: str
    ) -> tuple[float | None, StepAlarm | None]:
        """``(residual_mm, alarm)`` of one sample; residual None when the fit cannot predict
        it (no fit yet, or its anchor has too few samples). The nominal model's residuals
        are not tested (alarm None)."""
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
        return residual, self.detector.update(sample_id, residual)

    def moved(self) -> None:
        """After a move: the new anchor session needs a new fit."""
        self.fit = None
        self.fit_clean = 0
        self.scanned = True  # a session after a move has a fitted model of the robot


@dataclass
class CampaignWatch:
    """The watch's state of one campaign."""

    campaign_id: int
    robot_id: int
    tester: LiveTester
    queue: list[dict[str, Any]] = field(default_factory=list)
    task: asyncio.Task[None] | None = None
    tested: int = 0
    last_residual_mm: float | None = None


class WatchedSink:
    """A :class:`daemon.capture.CaptureSink` that tells the watch about each stored capture
    (everything else goes to the wrapped sink)."""

    def __init__(self, inner: CaptureSink, watch: SensorWatch) -> None:
        self._inner = inner
        self._watch = watch

    def store_capture(self, campaign_id: int, capture: Capture) -> Mapping[str, Any]:
        row = self._inner.store_capture(campaign_id, capture)
        self._watch.saw_sample(campaign_id, dict(row))
        return row

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)


class SensorWatch:
    """Watches every campaign's new samples for a moved sensor (see the module docstring).

    Parameters
    ----------
    store : Store
    settings : StepSettings
    auto : daemon.autocapture.AutoCapture or None
        Auto capture's owner: a move takes auto capture to the new anchor.
    enabled : bool
    """

    def __init__(
        self, store: Store, settings: StepSettings, auto: Any = None, enabled: bool = True
    ) -> None:
        self.store = store
        self.settings = settings
        self.auto = auto
        self.enabled = enabled
        self._campaigns: dict[int, CampaignWatch] = {}
        #: Newest unacknowledged move per campaign (the page's banner): the event detail.
        self._moves: dict[int, dict[str, Any]] = {}

    def wrap(self, sink: CaptureSink) -> WatchedSink:
        """``sink`` with this watch listening to its stored captures."""
        return WatchedSink(sink, self)

    async def stop(self) -> None:
        """Cancel the campaigns' tasks."""
        for cw in self._campaigns.values():
            if cw.task is not None:
                cw.task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await cw.task

    async def idle(self) -> None:
        """Wait until every queued sample was tested (tests and benchmarks)."""
        while any(cw.task is not None and not cw.task.done() for cw in self._campaigns.values()):
            await asyncio.sleep(0.01)

    # ------------------------------------------------------------------ per sample
    def saw_sample(self, campaign_id: int, row: dict[str, Any]) -> None:
        """A sample was stored (called on the event loop, from the sink): queue it."""
        if not self.enabled:
            return
        cw = self._campaigns.get(campaign_id)
        if cw is None:
            try:
                robot_id = int(self.store.campaign(campaign_id)["robot_id"])
            except Exception:
                log.exception("watch: campaign %d unreadable", campaign_id)
                return
            nominal = self.store.robot_model(robot_id)
            calibration: Mapping[str, Any] | None = None
            with contextlib.suppress(Exception):  # none accepted yet
                calibration = self.store.accepted_result(robot_id)["result"]
            tester = LiveTester(nominal, calibration, StepDetector(self.settings))
            cw = CampaignWatch(campaign_id, robot_id, tester)
            self._campaigns[campaign_id] = cw
            metrics.SENSOR_MOVED.labels(str(robot_id))  # the series exists at 0 (alerts)
        cw.queue.append(row)
        if cw.task is None or cw.task.done():
            cw.task = asyncio.get_running_loop().create_task(
                self._drain(cw), name=f"watch-{campaign_id}"
            )

    async def _drain(self, cw: CampaignWatch) -> None:
        while cw.queue:
            row = cw.queue.pop(0)
            try:
                await self._test(cw, row)
            except asyncio.CancelledError:
                raise
            except Exception:
                log.exception("watch: testing sample %s failed", row.get("id"))

    async def _test(self, cw: CampaignWatch, row: dict[str, Any]) -> None:
        import numpy as np

        sample_id = int(row["id"])
        current = self.store.get_sample(sample_id)
        if current is None or current["excluded"]:
            return
        samples, ids = self.store.sample_set(cw.campaign_id)
        tester = cw.tester
        clean = tester.clean_rows(ids, sample_id)
        if tester.needs_refit(len(clean)):
            subset = samples.subset(np.array(clean, dtype=int))
            clean_ids = [ids[i] for i in clean]
            await asyncio.to_thread(tester.refit, subset, len(clean), clean_ids)
        row_q = (current["q1"], current["q2"], current["q3"], current["q4"], current["q5"],
                 current["q6"])  # fmt: skip
        q: FloatArray = np.asarray(row_q, dtype=np.float64)
        residual, alarm = tester.test(sample_id, q, current["length_mm"], str(current["anchor"]))
        if residual is not None:
            cw.tested += 1
            cw.last_residual_mm = residual
        if alarm is not None:
            self._moved(cw, alarm, ids)

    # ------------------------------------------------------------------ a move
    def _moved(self, cw: CampaignWatch, alarm: StepAlarm, ids: list[int]) -> None:
        cid = cw.campaign_id
        first = self.store.sample(int(alarm.first_key))
        previous = str(first["anchor"])
        campaign = self.store.campaign(cid)
        new = next_anchor(previous, campaign["anchors"])
        moved = [int(k) for k in alarm.keys]
        self.store.move_samples_to_anchor(cid, moved, new)
        auto = self.auto is not None and self.auto.move_anchor(cid, new)
        row = ids.index(moved[0]) + 1 if moved[0] in ids else None
        fit = cw.tester.fit
        detail = {
            "campaign_id": cid, "robot_id": cw.robot_id, "sample_id": moved[0], "row": row,
            "detected_at_sample_id": moved[-1], "delay_samples": alarm.delay,
            "step_mm": round(alarm.step_mm, 4), "size_mm": round(alarm.size_mm, 4),
            "previous_anchor": previous, "new_anchor": new, "moved_sample_ids": moved,
            "auto_capture_switched": auto, "fit": fit.kind if fit else None,
            "fit_rmse_mm": round(fit.rmse_mm, 4) if fit else None,
        }  # fmt: skip
        message = (
            f"sensor moved at sample {moved[0]} (row {row}) of campaign {cid}: length change "
            f"{alarm.step_mm:+.2f} mm (median |change| {alarm.size_mm:.2f} mm); "
            f"{len(moved)} sample(s) and the next captures go to new anchor {new!r}"
        )
        self.store.record_event(SENSOR_MOVED, None, message, detail, campaign_id=cid)
        metrics.SENSOR_MOVED.labels(str(cw.robot_id)).inc()
        self._moves[cid] = detail
        cw.tester.moved()  # the new anchor has too few samples; refit from the next one
        log.warning(message, extra={"campaign_id": cid, "sample_id": moved[0]})

    def undo(self, campaign_id: int) -> dict[str, Any]:
        """Undo the newest automatic anchor split of a campaign: its new anchor's samples go
        back to the previous anchor, and so does auto capture when it uses the new one.

        Raises
        ------
        daemon.store.StoreNotFound
            No such campaign.
        NothingToUndo
            No ``sensor_moved`` event for the campaign, or it was undone already.
        """
        self.store.campaign(campaign_id)
        events = self.store.list_events(kind=SENSOR_MOVED, campaign_id=campaign_id, limit=1)
        if not events:
            raise NothingToUndo(f"campaign {campaign_id} has no sensor_moved event")
        event = events[-1]
        undone = self.store.list_events(kind=SENSOR_MOVED_UNDONE, campaign_id=campaign_id,
                                        limit=1)  # fmt: skip
        if undone and (undone[-1]["detail"] or {}).get("event_id") == event["id"]:
            raise NothingToUndo(f"sensor_moved event {event['id']} was undone already")
        detail = event["detail"] or {}
        new, previous = str(detail["new_anchor"]), str(detail["previous_anchor"])
        ids = [int(r["id"]) for r in self.store.list_samples(campaign_id) if r["anchor"] == new]
        self.store.move_samples_to_anchor(campaign_id, ids, previous)
        if self.auto is not None:
            self.auto.move_anchor(campaign_id, previous, from_anchor=new)
        out = {"event_id": event["id"], "anchor": previous, "from_anchor": new,
               "sample_ids": ids}  # fmt: skip
        self.store.record_event(
            SENSOR_MOVED_UNDONE, None,
            f"sensor move of campaign {campaign_id} undone by the operator: {len(ids)} "
            f"sample(s) back from anchor {new!r} to {previous!r}", out, campaign_id=campaign_id,
        )  # fmt: skip
        self._moves.pop(campaign_id, None)
        cw = self._campaigns.get(campaign_id)
        if cw is not None:
            cw.tester.detector.reset()
            cw.tester.moved()
        return out

    def status(self) -> dict[str, Any]:
        """The ``watch`` block of ``GET /status``: ``enabled``, ``moves`` (per campaign with
        an automatic split not undone since this start: the ``sensor_moved`` detail without
        the sample id list), ``campaigns`` (per watched campaign: ``fit``, ``fit_rmse_mm``,
        ``tested``, ``last_residual_mm``, ``band_mm``)."""
        moves = [{k: v for k, v in d.items() if k != "moved_sample_ids"}
                 for d in self._moves.values()]  # fmt: skip
        campaigns = []
        for cw in self._campaigns.values():
            fit = cw.tester.fit
            campaigns.append({
                "campaign_id": cw.campaign_id, "fit": fit.kind if fit else None,
                "fit_rmse_mm": None if fit is None else _round(fit.rmse_mm),
                "tested": cw.tested, "last_residual_mm": _round(cw.last_residual_mm),
                "band_mm": _round(cw.tester.detector.band_mm),
            })  # fmt: skip
        return {"enabled": self.enabled, "moves": moves, "campaigns": campaigns}


def _round(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else round(v, 4)
