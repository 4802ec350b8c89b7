"""``cablecal filter``: correct the targets of a plant's own robot programs, in place.

Modules: :mod:`~calib.filter.sites` (the dialect interface: sources, targets, uses, edits),
:mod:`~calib.filter.rotations` (the controllers' rotation conventions, 4x4 frames),
:mod:`~calib.filter.branches` (every nominal IK solution and the controller's branch),
:mod:`~calib.filter.correct` (the correction and the σ at a tool),
:mod:`~calib.filter.dialects` (the registry), one module per dialect
(:mod:`~calib.filter.rapid`, :mod:`~calib.filter.urscript`, …), and
:mod:`~calib.filter.run` (files in, files and summary out; no file I/O).
"""
