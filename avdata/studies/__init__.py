"""Trade studies from configuration tables: cases x trials of generate -> perceive -> track -> predict -> evaluate.

A study file (YAML) names the generator scenario, the number of trials (scene seeds), the frames per
trial, the evaluation settings and a table of cases, each a set of values over named axes (communication
range, detection rate, detection noise, ...). ``avdata study run STUDY.yaml OUT`` runs every (case, trial) as
one task, resumable, and writes ``OUT/results.parquet`` (one row per case and trial);
``avdata study report OUT`` aggregates it (mean +/- std over trials) into Markdown, CSV and plots.
"""

from avdata.studies.config import CaseConfig, StudyConfig, load_study
from avdata.studies.report import aggregate, write_report
from avdata.studies.runner import run_case, run_study

__all__ = ["CaseConfig", "StudyConfig", "aggregate", "load_study", "run_case", "run_study", "write_report"]
