"""Accuracy figures of cable-length residuals ``Z − Z'`` (measured minus model), in mm.

The paper's eq. (28) defines "STD" as ``(1/m) Σ |Z_i − Z'_i|``: that is the mean absolute error,
not a standard deviation. We report both under their proper names: ``mae_mm`` is the paper's
"STD" column, ``std_mm`` is the standard deviation of the residuals about their mean.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calib.kinematics import FloatArray


def length_metrics(
    measured_mm: FloatArray | Sequence[float], model_mm: FloatArray | Sequence[float]
) -> dict[str, float]:
    """RMSE, MAE, STD and MAX of ``measured − model`` [mm], plus the sample count ``n``.

    Parameters
    ----------
    measured_mm, model_mm : ndarray, shape (n,)
    """
    e = np.asarray(measured_mm, dtype=float) - np.asarray(model_mm, dtype=float)
    if e.size == 0:
        return {
            "n": 0,
            "rmse_mm": float("nan"),
            "mae_mm": float("nan"),
            "std_mm": float("nan"),
            "max_mm": float("nan"),
        }
    return {
        "n": int(e.size),
        "rmse_mm": float(np.sqrt(np.mean(e * e))),
        "mae_mm": float(np.mean(np.abs(e))),
        "std_mm": float(np.std(e)),
        "max_mm": float(np.max(np.abs(e))),
    }
