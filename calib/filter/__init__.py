"""``cablecal filter``: correct the targets of a plant's own robot programs, in place.

Modules: :mod:`~calib.filter.sites` (the dialect interface: sources, targets, uses, edits,
corrections), :mod:`~calib.filter.rotations` (the controllers' rotation conventions, 4x4
frames), :mod:`~calib.filter.branches` (every nominal IK solution) and
:mod:`~calib.filter.select` (the controller's branch among them),
:mod:`~calib.filter.correct` (the correction and the σ at a tool),
:mod:`~calib.filter.dialects` (the registry), one module per dialect
(:mod:`~calib.filter.rapid` with :mod:`~calib.filter.rapid_syntax`,
:mod:`~calib.filter.urscript`, …), and :mod:`~calib.filter.run` (files in, files and summary
out; no file I/O).
"""
