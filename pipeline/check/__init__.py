"""Checking a dataset folder: ``validate`` (and ``--repair``), ``info``, ``preview``.

Readers of a dataset, never writers, except ``validate --repair``, which re-renders through
``pipeline.run``. May import ``pipeline.store``, ``pipeline.dataset``, ``pipeline.render``
(tone map, stats), ``pipeline.run`` (repair) and ``pipeline.errors``.
"""
