"""Step 1 of an identification: the checked split's samples as arrays, the tool override
applied (:func:`prepare`), and what every later step asks of them (:class:`Prepared`).

Units: joint angles in radians, lengths in millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib import drift
from calib.cable import N_KIN, ParamLayout, kinematic_parts, predict_lengths
from calib.dataset import SampleError, SampleSet
from calib.identifiability import with_tool
from calib.kinematics import FloatArray, forward_position
from calib.models import RobotModel
from calib.split import Checked


@dataclass
class Prepared:
    """The samples of one identification, split: all rows and the training rows."""

    model: RobotModel  # with the tool override applied
    layout: ParamLayout
    samples: SampleSet
    q_all: FloatArray  # (n, 6) [rad]
    aidx_all: np.ndarray  # (n,) anchor index per sample
    train_rows: np.ndarray  # (n_train,)
    test_rows: np.ndarray  # (n_test,)
    drift_model: drift.DriftModel | None = None  # chosen by fit.select_drift, None: no drift
    drift_basis: FloatArray | None = None  # (n_train, m) its basis at the training rows

    @property
    def times(self) -> tuple[FloatArray, str]:
        """Capture time of every sample (n,) [s, from ``t_s``; else the row index] and unit."""
        if self.samples.t_s is not None:
            return np.asarray(self.samples.t_s, dtype=float), "s"
        return np.arange(len(self.samples), dtype=float), "row"

    def units(self, theta: FloatArray, rows: np.ndarray) -> FloatArray:
        """Unit vectors (r, 3) from each row's ``P0`` to the tool under ``theta``."""
        dh, tool = kinematic_parts(self.model, theta)
        pos = forward_position(dh, self.q_all[rows], tool, self.model.convention)
        diff = pos - theta[N_KIN:].reshape(-1, 4)[self.aidx_all[rows], :3]
        out: FloatArray = diff / np.maximum(np.linalg.norm(diff, axis=1), 1e-9)[:, None]
        return out

    @property
    def q(self) -> FloatArray:
        """Training joint angles, shape (n_train, 6) [rad]."""
        return np.asarray(self.q_all[self.train_rows], dtype=float)

    @property
    def aidx(self) -> np.ndarray:
        """Training anchor index per sample, shape (n_train,)."""
        return np.asarray(self.aidx_all[self.train_rows])

    @property
    def length_mm(self) -> FloatArray:
        """Training cable lengths, shape (n_train,) [mm]."""
        return np.asarray(self.samples.length_mm[self.train_rows], dtype=float)

    def lengths(self, theta: FloatArray, rows: np.ndarray) -> FloatArray:
        """Predicted lengths [mm] of ``rows`` (shape (r,)) under ``theta``."""
        if rows.size == 0:
            return np.zeros(0)
        return predict_lengths(self.model, theta, self.q_all[rows], self.aidx_all[rows])


def prepare(model: RobotModel, samples: SampleSet, checked: Checked) -> Prepared:
    """Step 1: the checked split (:func:`calib.split.check`), the tool override applied."""
    opts, train_rows, test_rows = checked.options, checked.train_rows, checked.test_rows
    layout = ParamLayout(samples.anchor_ids)
    model = with_tool(model, opts.tool_mm)
    data = Prepared(
        model,
        layout,
        samples,
        model.table_rad(samples.joints_deg),
        samples.anchor_index(),
        train_rows,
        test_rows,
    )
    for k, aid in enumerate(layout.anchors):
        if not np.any(data.aidx == k):
            raise SampleError(f"anchor {aid!r} has no training samples", column="anchor")
    return data
