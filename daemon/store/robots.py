"""Robots: the nominal models campaigns are captured against."""

from __future__ import annotations

import json
import sqlite3
from typing import Literal, cast

from calib.models import RobotModel, builtin_model, model_from_mapping
from daemon.store.db import Row, StoreDB, decode_row, last_id, now, or_none, to_json
from daemon.store.errors import StoreError, StoreInvalid
from daemon.store.rows import RobotRow


class RobotStore(StoreDB):
    """Robot models (part of :class:`daemon.store.Store`)."""

    def _robot_row(self, model: RobotModel, source: str) -> Row:
        return {
            "name": model.name,
            "convention": model.convention,
            "model_json": to_json(model.to_dict(), "model"),
            "source": source,
            "created_at": now(),
        }

    def ensure_builtin_robot(self, name: str) -> RobotRow:
        """The built-in model ``name`` (:func:`calib.models.builtin_model`), created on first use.

        An existing row is returned unchanged, so campaigns keep the nominal model they were
        captured against even if the built-in definition changes in a later release.

        Raises
        ------
        calib.models.ModelError
            Unknown built-in name.
        """
        model = builtin_model(name)
        with self._write():
            rows = list(
                self._table("robots").rows_where(
                    "name = ? AND source = 'builtin'", [model.name], limit=1
                )
            )
            if rows:
                return cast(RobotRow, decode_row(rows[0]))
            table = self._table("robots").insert(self._robot_row(model, "builtin"))
            return self.robot(last_id(table))

    def add_robot(
        self, model: RobotModel, source: Literal["builtin", "uploaded"] = "uploaded"
    ) -> RobotRow:
        """Store a robot model; returns its row (``model`` is :meth:`RobotModel.to_dict`)."""
        if source not in ("builtin", "uploaded"):
            raise StoreInvalid(f"source: must be 'builtin' or 'uploaded', got {source!r}")
        with self._write():
            try:
                table = self._table("robots").insert(self._robot_row(model, source))
            except sqlite3.IntegrityError as exc:
                raise StoreError(f"robot {model.name!r} ({source}): {exc}") from exc
            return self.robot(last_id(table))

    def robot(self, robot_id: int) -> RobotRow:
        """A robot row.

        Raises
        ------
        StoreNotFound
        """
        return cast(RobotRow, decode_row(self._require("robots", "robot", robot_id)))

    def get_robot(self, robot_id: int) -> RobotRow | None:
        """A robot row, or None."""
        return or_none(self.robot, robot_id)

    def list_robots(self) -> list[RobotRow]:
        """Every robot, by id."""
        rows = self._query("SELECT * FROM robots ORDER BY id")
        return [cast(RobotRow, decode_row(r)) for r in rows]

    def robot_model(self, robot_id: int) -> RobotModel:
        """The stored nominal model as a :class:`RobotModel`.

        Raises
        ------
        StoreNotFound
        """
        row = self._require("robots", "robot", robot_id)
        return model_from_mapping(json.loads(row["model_json"]))
