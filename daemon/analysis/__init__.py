"""Analysis of recorded runs: error statistics (thesis 6.6), exponential fits, CTE estimates
(chapter 2) and the run report. Pure numerics plus matplotlib (Agg) figures; imports nothing
of the rest of the daemon."""

from daemon.analysis.cte import (
    Camera,
    CteTable,
    Links,
    PredictionRow,
    RunChange,
    RunCteFit,
    cte_from_run,
    cte_table,
    estimate_cte,
    run_change,
)
from daemon.analysis.fits import (
    PREDICTIVE_CURVES,
    TIME2DEF,
    ExponentialCurve,
    ExponentialFit,
    FitError,
    fit_exponential,
    predictive_curve,
    steady_state_time,
)
from daemon.analysis.report import ReportFiles, build_summary, write_report
from daemon.analysis.statistics import (
    ChiSquaredTest,
    ErrorStatistics,
    chi_squared_against_normal,
    error_statistics,
    interval_count,
)
from daemon.analysis.steps import (
    NUMERIC_COLUMNS,
    RESIDUAL_COLUMN,
    SUMMARY_KEYS,
    RunSteps,
    compensation_of,
    steps_from_rows,
    summarize_run,
)

__all__ = [
    "NUMERIC_COLUMNS",
    "PREDICTIVE_CURVES",
    "RESIDUAL_COLUMN",
    "SUMMARY_KEYS",
    "TIME2DEF",
    "Camera",
    "ChiSquaredTest",
    "CteTable",
    "ErrorStatistics",
    "ExponentialCurve",
    "ExponentialFit",
    "FitError",
    "Links",
    "PredictionRow",
    "ReportFiles",
    "RunChange",
    "RunCteFit",
    "RunSteps",
    "build_summary",
    "chi_squared_against_normal",
    "compensation_of",
    "cte_from_run",
    "cte_table",
    "error_statistics",
    "estimate_cte",
    "fit_exponential",
    "interval_count",
    "predictive_curve",
    "run_change",
    "steady_state_time",
    "steps_from_rows",
    "summarize_run",
    "write_report",
]
