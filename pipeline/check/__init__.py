"""Checking a dataset folder: ``validate`` (and ``--repair``), ``info``, ``preview``.

``validate`` is split by concern: ``report`` (problem kinds, report types, output),
``inspect`` (EXR and file checks), ``crosscheck`` (records against files and the plan),
``repair``; ``validate`` keeps the entry points.

Readers of a dataset, never writers, except ``validate --repair``, which re-renders through
``pipeline.run``. May import ``pipeline.store``, ``pipeline.dataset``, ``pipeline.render``
(tone map, stats), ``pipeline.run`` (repair) and ``pipeline.errors``.
"""
