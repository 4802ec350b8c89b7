"""What every layer says about one sample, standard library only (the CLI, the daemon's
sampler and the API read it without loading numpy).

- :data:`Joints`: a pose's six joint angles [deg], in the controller's order ``q1..q6``.
- :data:`DEFAULT_ANCHOR`: the anchor (sensor position) id of a sample that names none; a
  campaign's later sensor positions are named after it (``A2``, or ``B``, ``C`` … in a plan
  with several anchors).
"""

from __future__ import annotations

from typing import Final

#: A pose's six joint angles [deg] (``q1..q6``).
Joints = tuple[float, float, float, float, float, float]

#: The anchor id of a sample, a capture or an import that names none.
DEFAULT_ANCHOR: Final = "A"
