"""File access for calibration inputs: sample CSVs, robot model files, the bundled dataset.

``calib/`` is pure computation; this is where files are read.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from calib.dataset import SampleError, SampleSet, parse_samples_csv
from calib.models import ModelError, RobotModel, builtin_model, parse_model_text

BUNDLED_DATASET = "hsr-robotcali.csv"


def bundled_dataset_text() -> str:
    """The real HSR-RobotCali dataset (the paper's D1) shipped in ``calib/data``."""
    return resources.files("calib.data").joinpath(BUNDLED_DATASET).read_text(encoding="utf-8")


def read_samples(path: Path | None) -> SampleSet:
    """Samples from a CSV file, or the bundled dataset when ``path`` is None."""
    if path is None:
        return parse_samples_csv(bundled_dataset_text())
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise SampleError(f"cannot read {path}: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise SampleError(f"{path} is not UTF-8 text: {exc.reason}") from exc
    return parse_samples_csv(text)


def load_robot(spec: str) -> RobotModel:
    """A built-in model name (``hsr-jr680``) or a path to a ``.toml`` / ``.json`` model file."""
    path = Path(spec)
    if path.suffix.lower() in (".toml", ".json"):
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ModelError("robot", f"cannot read {path}: {exc.strerror}") from exc
        return parse_model_text(text, path.suffix.lower().lstrip("."))
    return builtin_model(spec)
