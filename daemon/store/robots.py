"""Robots: each physical robot, its own name and the nominal model it is captured against."""

from __future__ import annotations

import json
import sqlite3
from typing import Literal, cast

from calib.models import RobotModel, builtin_model, model_from_mapping
from daemon.store.db import Row, StoreDB, decode_row, last_id, now, or_none, to_json
from daemon.store.errors import StoreConflict, StoreInvalid
from daemon.store.rows import RobotRow


def check_robot_name(name: object) -> str:
    """A robot's own name, stripped; :class:`StoreInvalid` naming the field if blank (the API
    bounds its length, as every name's)."""
    if not isinstance(name, str) or not name.strip():
        raise StoreInvalid(f"robot name: must be a non-empty string, got {name!r}")
    return name.strip()


def _same_model(row: Row, model: RobotModel, source: str) -> bool:
    """Whether a stored robot was made with ``model``: a built-in one by the model's name (the
    stored copy is kept even if a later release changes the built-in definition), an uploaded
    one by the whole model (every DH row, limit and tool number)."""
    if row["source"] == "builtin" and source == "builtin":
        return bool(row["model_name"] == model.name)
    stored = json.loads(row["model_json"])
    return bool(stored == json.loads(to_json(model.to_dict(), "model")))


class RobotStore(StoreDB):
    """Robots: each a physical robot with its own name and its nominal model (part of
    :class:`daemon.store.Store`). Calibrations, checks and hold-check history hang on the robot's
    id, so two robots of one model are two robots, and the same name is the same robot."""

    def _robot_row(self, model: RobotModel, source: str, name: str) -> Row:
        return {
            "name": name,
            "model_name": model.name,
            "convention": model.convention,
            "model_json": to_json(model.to_dict(), "model"),
            "source": source,
            "created_at": now(),
        }

    def robot_named(self, name: str) -> RobotRow | None:
        """The robot called ``name`` (exact, after stripping), or None."""
        row = self._one("SELECT * FROM robots WHERE name = ?", [name.strip()])
        return None if row is None else cast(RobotRow, decode_row(row))

    def ensure_robot(
        self,
        name: str | None,
        model: RobotModel,
        source: Literal["builtin", "uploaded"] = "uploaded",
    ) -> tuple[RobotRow, bool]:
        """The robot called ``name`` (None: the model's name), created with ``model`` on first
        use; returns it and whether it was created now. The same name with the same model is
        the same robot again (its calibration and hold-check history go on).

        Raises
        ------
        StoreConflict
            A robot of that name exists with another model (nothing written).
        StoreInvalid
            Blank name, or an unknown ``source``.
        """
        if source not in ("builtin", "uploaded"):
            raise StoreInvalid(f"source: must be 'builtin' or 'uploaded', got {source!r}")
        own = check_robot_name(model.name if name is None else name)
        with self._write():
            row = self._one("SELECT * FROM robots WHERE name = ?", [own])
            if row is not None:
                if not _same_model(row, model, source):
                    raise StoreConflict(
                        f"robot {own!r} (robot {row['id']}) exists with the model "
                        f"{row['model_name']!r} ({row['source']}), not this {model.name!r} "
                        f"({source}); give this robot its own name (cell, serial number)"
                    )
                return cast(RobotRow, decode_row(row)), False
            table = self._table("robots").insert(self._robot_row(model, source, own))
            return self.robot(last_id(table)), True

    def ensure_builtin_robot(self, name: str) -> RobotRow:
        """The robot named after the built-in model ``name`` (:func:`calib.models
        .builtin_model`), created on first use (what a campaign without a robot name gets).

        Raises
        ------
        calib.models.ModelError
            Unknown built-in name.
        StoreConflict
            A robot of that name exists with another model.
        """
        return self.ensure_robot(None, builtin_model(name), "builtin")[0]

    def add_robot(
        self,
        model: RobotModel,
        source: Literal["builtin", "uploaded"] = "uploaded",
        name: str | None = None,
    ) -> RobotRow:
        """Store a new robot called ``name`` (None: the model's name); returns its row.

        Raises
        ------
        StoreConflict
            The name is taken.
        """
        if source not in ("builtin", "uploaded"):
            raise StoreInvalid(f"source: must be 'builtin' or 'uploaded', got {source!r}")
        own = check_robot_name(model.name if name is None else name)
        with self._write():
            try:
                table = self._table("robots").insert(self._robot_row(model, source, own))
            except sqlite3.IntegrityError as exc:
                raise StoreConflict(f"robot {own!r}: the name is taken ({exc})") from exc
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
