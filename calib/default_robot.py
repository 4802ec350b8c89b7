"""The robot model used when none is named: one home for the CLI, the API, the simulator.

``hsr-jr680``, the Huashu JR680 of the paper's cell and of the bundled dataset
(:mod:`calib.data`), is the one built-in model (:data:`calib.models.BUILTIN_MODELS`), so it
is the only default that needs no file. Standard library only, so ``cablecal --help`` shows
it without loading numpy.
"""

from __future__ import annotations

from typing import Final

#: The built-in model used when no robot model is named (``--robot``, ``robot_model``,
#: the emulated cell's ``[robot] model``).
DEFAULT_ROBOT_MODEL: Final = "hsr-jr680"
