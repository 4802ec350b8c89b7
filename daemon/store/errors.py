"""The store's exceptions: one base, one for a missing row, one for a refused argument."""

from __future__ import annotations


class StoreError(Exception):
    """The store cannot do what was asked (database unusable, newer schema, conflict)."""


class StoreNotFound(StoreError, KeyError):
    """A campaign, sample, job, result or robot does not exist.

    The service answers every one with 404 (one handler in :mod:`daemon.api.main`).

    Parameters
    ----------
    kind : str
        ``"campaign"``, ``"sample"``, ``"job"``, ``"result"`` or ``"robot"``.
    id : int or str
    reason : str, optional
        What is missing when it is not the row itself (e.g. ``"no accepted calibration
        yet"`` for a robot that exists); the message is then ``"robot 3: no accepted …"``
        instead of ``"robot 3 not found"``.
    """

    def __init__(self, kind: str, id: int | str, reason: str | None = None) -> None:
        super().__init__(f"{kind} {id} not found" if reason is None else f"{kind} {id}: {reason}")
        self.kind = kind
        self.id = id
        self.reason = "not found" if reason is None else reason

    def __str__(self) -> str:  # KeyError would show the repr
        return str(self.args[0])


class StoreInvalid(StoreError, ValueError):
    """An argument is invalid (names it); nothing was written."""


class StoreConflict(StoreError):
    """The request contradicts what is stored (e.g. a robot name already taken by a robot of
    another model); nothing was written. The service answers 409."""
