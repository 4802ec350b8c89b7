"""Write ``tests/data/result_shape*.json``: one ``result.json`` of every shape identify has
written (:data:`calib.result.RESULT_SHAPES`), for the test that each still loads and works.

``PYTHONPATH=. python tests/data/make_result_shapes.py`` (from a checkout's root) identifies a
small emulated cell and rewrites today's document into each older shape as
``calib/identify.py`` / ``calib/report.py`` wrote it then (``git log -p`` of both): the keys a
shape did not have are left out, and its blocks take the form of their day (the first
``prior`` block, the first ``robust_detail``, a ``split`` without ``test_rows``, a ``drift``
block without ``summary``). Long lists are cut (cost history, correlation) so the files stay
small; a correlation matrix cut to its first names is still one.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
KEEP_CORRELATION = 4
KEEP_HISTORY = 6


def _identify(model_name: str, seed: int, n: int = 40, step_mm: float = 0.0) -> dict[str, Any]:
    """``identify``'s defaults on ``n`` poses of an emulated cell; ``step_mm``: the indicator
    re-zeroed by that much from half way on (drift auto looks from 60 training rows on)."""
    from calib.dataset import make_samples
    from calib.identify import identify
    from calib.models import builtin_model
    from calib.options import IdentifyOptions
    from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg

    model = builtin_model(model_name)
    cell = make_true_cell(model)
    rng = np.random.default_rng(seed)
    q = random_poses_deg(cell, n, rng)
    lengths = noisy_lengths(cell, q, rng)
    lengths[n // 2 :] += step_mm
    fit = identify(model, make_samples(q, lengths), IdentifyOptions())
    return fit.to_json()


def _small(doc: dict[str, Any]) -> dict[str, Any]:
    out = dict(doc)
    corr = doc["correlation"]
    k = KEEP_CORRELATION
    out["correlation"] = {
        "names": corr["names"][:k],
        "matrix": [row[:k] for row in corr["matrix"][:k]],
    }
    out["cost_history_rms_mm"] = doc["cost_history_rms_mm"][:KEEP_HISTORY]
    if "cost_history_fit_starts" in doc:
        out["cost_history_fit_starts"] = [
            i for i in doc["cost_history_fit_starts"] if i < KEEP_HISTORY
        ]
    if isinstance(doc.get("drift"), dict) and "per_sample_mm" in doc["drift"]:
        out["drift"] = dict(doc["drift"])
        out["drift"].pop("per_sample_mm")  # a list as long as the samples
    return out


def _without(doc: dict[str, Any], *keys: str) -> dict[str, Any]:
    return {k: v for k, v in doc.items() if k not in keys}


def shapes() -> dict[str, dict[str, Any]]:
    """File name → document."""
    now = _small(_identify("hsr-jr680", 5))
    first_prior = {k: now["prior"][k] for k in ("used", "dh_mm", "dh_deg", "tool_mm", "noise_mm")}
    first_split = _without(now["split"], "test_rows")
    # 2026-11-21 (aabb0f2): the first contract.
    shape1 = _without(
        now, "tcp_uncertainty_mm", "robust_detail", "cost_history_fit_starts", "drift"
    )
    shape1 |= {"prior": first_prior, "split": first_split}
    # 2026-11-23 (3858223): + tcp_uncertainty_mm, after uncertainty.
    shape2 = {}
    for k, v in shape1.items():
        shape2[k] = v
        if k == "uncertainty":
            shape2["tcp_uncertainty_mm"] = now["tcp_uncertainty_mm"]
    # 2026-11-23 (c58351c): + robust_detail (mode, threshold, fits), the prior's weight.
    shape3 = {}
    for k, v in shape2.items():
        shape3[k] = now["prior"] if k == "prior" else v
        if k == "robust":
            detail = now["robust_detail"]
            shape3["robust_detail"] = {k: detail[k] for k in ("mode", "threshold", "fits")}
    # 2026-11-25 (148991a): + cost_history_fit_starts, drift (no summary yet), split.test_rows.
    stepped = _small(_identify("hsr-jr680", 6, n=90, step_mm=0.8))
    shape4 = {**stepped, "drift": _without(stepped["drift"], "summary", "rows_flagged")}
    # 2026-11-28 (caf347f): a robot whose controller counts its joints otherwise carries a
    # `controller` block; the daemon stores flagged_sample_ids, split.test_sample_ids and
    # plan_check beside identify's keys.
    fanuc = _small(_identify("fanuc-m10ia", 7))
    ids = [1000 + i for i in range(fanuc["split"]["n_train"] + fanuc["split"]["n_test"])]
    fanuc["flagged_sample_ids"] = [ids[i] for i in fanuc["flagged_samples"]]
    fanuc["split"] = {
        **fanuc["split"],
        "test_sample_ids": [ids[i] for i in fanuc["split"]["test_rows"]],
    }
    fanuc["plan_check"] = {"plan_id": 3, "on_plan": True, "note": "on the plan"}
    return {
        "result_shape1_2026-11-21.json": shape1,
        "result_shape2_2026-11-23.json": shape2,
        "result_shape3_2026-11-23.json": shape3,
        "result_shape4_2026-11-25.json": shape4,
        "result_shape4_2026-11-28_daemon.json": fanuc,
    }


def main() -> None:
    for name, doc in shapes().items():
        (HERE / name).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        print(name, len(json.dumps(doc)))


if __name__ == "__main__":
    main()
