"""Robot programs: the one home of each controller language.

One package per language (:mod:`calib.programs.rapid`, :mod:`~calib.programs.krl`,
:mod:`~calib.programs.fanuc`, :mod:`~calib.programs.urscript`). Each holds a ``program``
module (joint targets written as a program a controller runs, and a strict parser of what the
writer produces, and of the same language written by hand within the subset named in its
docstring) and a ``filter`` module with its helpers (a plant's own programs read, their
targets found and rewritten in place for ``cablecal filter``; the correction itself is
:mod:`calib.filter`'s). :mod:`calib.programs.sites` is the dialect interface the filter
modules implement, :mod:`calib.programs.dialects` their registry, and
:mod:`calib.programs.rotations` the controllers' rotation conventions.

The program writers:

- :mod:`calib.programs.rapid.program`: ABB RAPID, a ``MODULE`` with ``PROC main()`` and
  ``MoveAbsJ``;
- :mod:`calib.programs.urscript.program`: Universal Robots URScript, ``def … end`` with ``movej``;
- :mod:`calib.programs.krl.program`: KUKA KRL, a ``.src`` with ``DEF … END`` and ``PTP {A1 …}``;
- :mod:`calib.programs.fanuc.program`: Fanuc TP as ASCII ``.LS`` (``/PROG``, ``/MN``, ``/POS``).

:mod:`calib.programs.common` holds the shared type (:class:`JointProgram`), the joint-target
CSV reader and the checks; :mod:`calib.programs.formats` the format names (the one list the
CLI, the REST API and the page read). Pure text in, text out. This package's ``__init__``,
``formats`` and the ``program`` modules use the standard library only (no numpy), so the
command line's ``--help`` can list the formats without loading anything heavy; the ``filter``
modules use numpy and are imported only when a program is filtered.

Everything here is in the robot's joint space [deg], as the joint-target CSVs are.
"""

from __future__ import annotations

from calib.programs.formats import DOWNLOAD_FORMATS, PROGRAM_FORMATS, dwell_s_for_settle

__all__ = ["DOWNLOAD_FORMATS", "PROGRAM_FORMATS", "dwell_s_for_settle"]
