"""Step 6b of an identification: every identified parameter against a physical bound, and the
advice of an implausible result (which parameters the data leave loose, and what to measure).

The bounds are display units (degrees, millimetres); the filter's robot check reads the DH
ones too (:func:`calib.filter.run.robot_check`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calib.cable import N_DH, N_KIN, ParamLayout
from calib.kinematics import FloatArray
from calib.options import IdentifyOptions

#: Plausible magnitudes, in display units, used by the plausibility report.
PLAUSIBLE_DH_MM = 10.0
PLAUSIBLE_DH_DEG = 1.0
PLAUSIBLE_TOOL_MM = 500.0
PLAUSIBLE_ANCHOR_MM = 5000.0
PLAUSIBLE_OFFSET_MM = 2000.0
CABLE_EXTENSION_MAX_MM = 2050.0


def plausible_bounds(layout: ParamLayout) -> FloatArray:
    """Plausible magnitude of every parameter, shape (p,), in display units (deg, mm): of the
    error for DH parameters, of the absolute value for the others."""
    out = np.full(layout.size, PLAUSIBLE_ANCHOR_MM)
    for i, name in enumerate(layout.names):
        if i < N_DH:
            out[i] = PLAUSIBLE_DH_DEG if layout.is_angle[i] else PLAUSIBLE_DH_MM
        elif i < N_KIN:
            out[i] = PLAUSIBLE_TOOL_MM
        elif name.startswith("offset"):
            out[i] = PLAUSIBLE_OFFSET_MM
    return out


def plausibility(
    layout: ParamLayout, theta: FloatArray, nominal_tool: FloatArray, extension_mm: FloatArray
) -> dict[str, Any]:
    """Every parameter against its plausible bound, and the cable extension (mm) against the
    sensor's range: ``plausible``, ``outside_bounds``, ``cable_extension_mm``, ``parameters``.

    ``theta`` shape (p,) internal units; ``nominal_tool`` (3,) [mm]; ``extension_mm`` (n,).
    """
    scale = layout.display_scale
    names = layout.names
    bounds = plausible_bounds(layout)
    items = []
    for i, name in enumerate(names):
        value = float(theta[i] * scale[i])
        bound, kind = float(bounds[i]), "error" if i < N_DH else "absolute"
        if N_DH <= i < N_KIN:
            value = float(nominal_tool[i - N_DH] + theta[i])
        items.append(
            {
                "name": name,
                "value": value,
                "unit": layout.units[i],
                "kind": kind,
                "bound": bound,
                "ok": bool(abs(value) <= bound),
            }
        )
    ext_ok = bool(
        extension_mm.size == 0
        or (extension_mm.min() > 0 and extension_mm.max() <= CABLE_EXTENSION_MAX_MM)
    )
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


#: How many parameters the advice names, and how many terms of the weakest direction.
ADVICE_NAMES = 4


def weakest_direction(
    layout: ParamLayout, free_names: list[str], cov: FloatArray
) -> list[tuple[str, float]]:
    """The least constrained combination of the solved parameters, relative to their plausible
    sizes: the top eigenvector of ``D⁻¹ C D⁻¹`` (``C`` the (k, k) covariance in internal units,
    ``D`` the plausible bounds in internal units), as ``(name, coefficient)`` pairs, largest
    first (at most :data:`ADVICE_NAMES`), the sign fixed so the first is positive."""
    idx = [layout.index(n) for n in free_names]
    if not idx:
        return []
    bound = plausible_bounds(layout)[idx] / layout.display_scale[idx]
    scaled = cov / np.outer(bound, bound)
    _, vecs = np.linalg.eigh(scaled)
    v = vecs[:, -1]
    order = np.argsort(-np.abs(v))[:ADVICE_NAMES]
    sign = 1.0 if v[order[0]] >= 0 else -1.0
    return [(free_names[i], round(float(sign * v[i]), 2)) for i in order if abs(v[i]) >= 0.1]


def implausibility_advice(
    layout: ParamLayout,
    free_names: list[str],
    sigma: FloatArray,
    cov: FloatArray,
    plaus: dict[str, Any],
    options: IdentifyOptions,
) -> str:
    """The note of an implausible result: what is out of bounds, which parameters the data
    leave least constrained (largest 1σ against the plausible bound, and the weakest
    direction), and what to do: plan poses that excite them (``cablecal plan --start``), and
    ``--prior`` only when it is off. ``sigma`` (p,) 1σ in internal units; ``cov`` (k, k)."""
    scale, bounds = layout.display_scale, plausible_bounds(layout)
    idx = [layout.index(n) for n in free_names]
    ratio = sigma[idx] * scale[idx] / bounds[idx]
    loose = [idx[i] for i in np.argsort(-ratio)[:ADVICE_NAMES]]
    loose_text = ", ".join(
        f"{layout.names[i]} ±{sigma[i] * scale[i]:.3g} {layout.units[i]}" for i in loose
    )
    direction = " ".join(f"{c:+.2f}·{n}" for n, c in weakest_direction(layout, free_names, cov))
    outside = ", ".join(plaus["outside_bounds"][:6]) or "no parameter"
    if not plaus["cable_extension_mm"]["ok"]:
        outside += ", cable extension"
    text = (
        f"identified parameters are physically implausible ({outside}): the data do not "
        f"hold them within bounds. Least constrained (1σ): {loose_text}; "
        f"weakest direction: {direction}. "
        "Measure poses that excite these: `cablecal plan --start DATA.csv` plans the next "
        "poses given those already measured"
    )
    if options.prior:
        return text + (
            f" (the prior, {options.prior_mm} mm / {options.prior_deg} deg, is on and does not "
            "hold them at this weight)"
        )
    return text + "; or constrain them toward the nominal model with --prior"
