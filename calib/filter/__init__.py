"""``cablecal filter``: correct the targets of a plant's own robot programs, in place.

The correction engine: :mod:`~calib.filter.kin` (the filter's kinematics in the controller's
joint angles), :mod:`~calib.filter.branches` (every nominal IK solution) and
:mod:`~calib.filter.select` (the controller's branch among them), :mod:`~calib.filter.nearest`
(UR's nearest-reference rule), :mod:`~calib.filter.ur_ik` (UR's 8-solution IK),
:mod:`~calib.filter.correct` (the correction and the σ at a tool), and :mod:`~calib.filter.run`
(files in, files and summary out; no file I/O). The languages themselves (reading a program,
finding its targets, writing the corrected numbers back) are :mod:`calib.programs`' packages,
one per dialect, behind the interface :mod:`calib.programs.sites`.
"""
