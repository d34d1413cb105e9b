"""Batch fitting of many scans (``jsrte fit-many``): a local process pool or a Ray cluster.

:func:`fit_many` lists the scans (:mod:`jsrte.batch.inputs`), skips those already done, and
sends the others as jobs (:mod:`jsrte.batch.worker`) to a backend (:mod:`jsrte.batch.local`,
:mod:`jsrte.batch.ray_backend`); results and ``summary.csv`` are written by the driver alone.
"""

from jsrte.batch.inputs import find_truth, list_scans, result_names
from jsrte.batch.run import COLUMNS, SUMMARY_NAME, BatchReport, fit_many

__all__ = ["COLUMNS", "SUMMARY_NAME", "BatchReport", "find_truth", "fit_many", "list_scans",
           "result_names"]
