"""Batches: a folder of brackets in one command (``hdrcore batch``).

scan (what each file says) -> group (which files are one bracket) -> plan (named brackets,
editable) -> task (one bracket merged by ``hdrcore merge``, a sidecar with its content key)
-> runner (skip what is done; this process, worker processes or Dask) -> index (one row per
bracket, worst first for ``hdrview --batch``). Any of the folders and files may be an fsspec
URL (``s3://``, ``gcs://``, ``file://``, ``memory://``): :mod:`hdrcore.batch.remote`.
"""

from . import remote
from .group import GROUPING_METHODS, HDRMERGE_GAP, Group, bracket_order, group_shots
from .index import read_index, worst_first, write_index
from .plan import Plan, PlannedBracket, make_plan, plan_table, read_plan
from .runner import BatchRun, run_batch, tasks_from_plan, up_to_date
from .scan import Shot, find_images, read_shot, read_shots, scan_shots, thumbnail_similarity
from .task import BracketRecord, BracketTask, bracket_key, quality_from_report, run_task

__all__ = [
    "GROUPING_METHODS",
    "HDRMERGE_GAP",
    "BatchRun",
    "BracketRecord",
    "BracketTask",
    "Group",
    "Plan",
    "PlannedBracket",
    "Shot",
    "bracket_key",
    "bracket_order",
    "find_images",
    "group_shots",
    "make_plan",
    "plan_table",
    "quality_from_report",
    "read_index",
    "read_plan",
    "read_shot",
    "read_shots",
    "remote",
    "run_batch",
    "run_task",
    "scan_shots",
    "tasks_from_plan",
    "thumbnail_similarity",
    "up_to_date",
    "worst_first",
    "write_index",
]
