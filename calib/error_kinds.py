"""What kind of failure an error is, carried by the error itself: a caller picks its answer
(the daemon's HTTP status, :data:`daemon.api.errors.STATUS_OF_KIND`) from the kind, never
from the message, so rewording a message changes no status. Standard library only."""

from __future__ import annotations

from enum import StrEnum


class ErrorKind(StrEnum):
    """The kinds: the request's own form is bad (``INVALID``), a thing it names is not there
    (``NOT_FOUND``), or the state of what it addresses refuses it (``CONFLICT``: a target
    outside the robot's joint limits, a plan that needs its anchor picked)."""

    INVALID = "invalid"
    NOT_FOUND = "not_found"
    CONFLICT = "conflict"
