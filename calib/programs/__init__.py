"""Robot programs: joint targets as a program a controller runs, and read back.

One module per controller language, each with a writer and a strict parser of what the
writer produces (and of the same language written by hand, within the subset named in its
docstring):

- :mod:`calib.programs.rapid`: ABB RAPID, a ``MODULE`` with ``PROC main()`` and ``MoveAbsJ``;
- :mod:`calib.programs.urscript`: Universal Robots URScript, ``def … end`` with ``movej``;
- :mod:`calib.programs.krl`: KUKA KRL, a ``.src`` with ``DEF … END`` and ``PTP {A1 …}``;
- :mod:`calib.programs.fanuc_ls`: Fanuc TP as ASCII ``.LS`` (``/PROG``, ``/MN``, ``/POS``).

:mod:`calib.programs.common` holds the shared type (:class:`JointProgram`), the joint-target
CSV reader and the checks; :mod:`calib.programs.formats` the format names (the one list the
CLI, the REST API and the page read). Pure text in, text out: standard library only (no
numpy), so the command line's ``--help`` can list the formats without loading anything heavy.

Everything here is in the robot's joint space [deg], as the joint-target CSVs are.
"""

from __future__ import annotations

from calib.programs.formats import DOWNLOAD_FORMATS, PROGRAM_FORMATS, dwell_s_for_settle

__all__ = ["DOWNLOAD_FORMATS", "PROGRAM_FORMATS", "dwell_s_for_settle"]
