"""Before/after proof that an identity joint convention changes no number (docs/robots.md).

``python -m bench.convention_identity OUT.json`` (run from a checkout's root) writes every
figure of: ``cablecal identify`` with its defaults on the bundled real data
(calib/data/hsr-robotcali.csv), and a synthetic JR680 cell (identify, workspace sample, true
tool points, IK, a 12-pose plan). Run it in two checkouts and compare the files with
``python -m bench.convention_identity --compare A.json B.json`` (exit 1 when they differ; the
identification's elapsed time is left out).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def _real_identify() -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "result.json"
        data = "calib/data/hsr-robotcali.csv"
        subprocess.run(
            [sys.executable, "-m", "daemon.cli", "identify", data, "--out", str(out)],
            cwd=ROOT,
            check=True,
            capture_output=True,
        )
        result: dict[str, Any] = json.loads(out.read_text())
    result.pop("elapsed_s", None)
    return result


def _synthetic() -> dict[str, Any]:
    from calib.dataset import make_samples
    from calib.identify import identify
    from calib.ik import IKOptions, solve_ik, tool_pose
    from calib.models import builtin_model
    from calib.options import IdentifyOptions
    from calib.planning import PlanOptions, plan
    from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg
    from calib.tcp import workspace_sample_deg

    model = builtin_model("hsr-jr680")
    cell = make_true_cell(model)
    rng = np.random.default_rng(7)
    q = random_poses_deg(cell, 60, rng)
    fit = identify(
        model, make_samples(q, noisy_lengths(cell, q, rng)), IdentifyOptions(method="lm")
    )
    result = fit.to_json()
    result.pop("elapsed_s", None)
    ws = workspace_sample_deg(model, 50, seed=3, min_z_mm=0.0)
    hook = np.array([0.0, 0.0, 100.0])
    pos, rot = tool_pose(model, ws, hook)
    ik = solve_ik(model, ws + 2.0, pos, rot, hook, IKOptions())
    planned = plan(model, np.array([[1400.0, 300.0, 200.0]]), PlanOptions(n=12, candidates=300))
    return {
        "identify": result,
        "workspace_deg": ws.tolist(),
        "true_tool_mm": cell.tool_positions_mm(ws).tolist(),
        "ik_deg": ik.joints_deg.tolist(),
        "plan_deg": np.asarray(planned.q_deg).tolist(),
    }


def main(argv: list[str]) -> int:
    if argv[:1] == ["--compare"] and len(argv) == 3:
        a, b = (json.loads(Path(p).read_text()) for p in argv[1:])
        differ = sorted(k for k in a if a[k] != b.get(k)) + sorted(set(b) - set(a))
        print("identical" if not differ else f"differ: {differ}")
        return 1 if differ else 0
    if len(argv) != 1:
        print(__doc__)
        return 2
    data = {"real_identify": _real_identify(), "synthetic": _synthetic()}
    Path(argv[0]).write_text(json.dumps(data, sort_keys=True))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
