"""Analysis of recorded runs: error statistics (thesis 6.6), exponential fits, CTE estimates
(chapter 2) and the run report. Pure numerics plus matplotlib (Agg) figures; imports nothing
of the rest of the daemon.

Only the step series (numpy) load with the package; the statistics, fits, CTE estimates and
report (SciPy, Matplotlib) load on first use (PEP 562), so the daemon and the command line
start without them."""

from importlib import import_module
from typing import TYPE_CHECKING, Any

from daemon.analysis.steps import (
    NUMERIC_COLUMNS,
    RESIDUAL_COLUMN,
    SUMMARY_KEYS,
    RunSteps,
    compensation_of,
    steps_from_rows,
    summarize_run,
)

if TYPE_CHECKING:
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
    from daemon.analysis.report import (
        ReportFiles,
        build_summary,
        write_report,
    )
    from daemon.analysis.statistics import (
        ChiSquaredTest,
        ErrorStatistics,
        chi_squared_against_normal,
        error_statistics,
        interval_count,
    )

#: Name -> the module that defines it, for the names loaded on first use.
_LAZY = {
    "Camera": "daemon.analysis.cte",
    "CteTable": "daemon.analysis.cte",
    "Links": "daemon.analysis.cte",
    "PredictionRow": "daemon.analysis.cte",
    "RunChange": "daemon.analysis.cte",
    "RunCteFit": "daemon.analysis.cte",
    "cte_from_run": "daemon.analysis.cte",
    "cte_table": "daemon.analysis.cte",
    "estimate_cte": "daemon.analysis.cte",
    "run_change": "daemon.analysis.cte",
    "PREDICTIVE_CURVES": "daemon.analysis.fits",
    "TIME2DEF": "daemon.analysis.fits",
    "ExponentialCurve": "daemon.analysis.fits",
    "ExponentialFit": "daemon.analysis.fits",
    "FitError": "daemon.analysis.fits",
    "fit_exponential": "daemon.analysis.fits",
    "predictive_curve": "daemon.analysis.fits",
    "steady_state_time": "daemon.analysis.fits",
    "ReportFiles": "daemon.analysis.report",
    "build_summary": "daemon.analysis.report",
    "write_report": "daemon.analysis.report",
    "ChiSquaredTest": "daemon.analysis.statistics",
    "ErrorStatistics": "daemon.analysis.statistics",
    "chi_squared_against_normal": "daemon.analysis.statistics",
    "error_statistics": "daemon.analysis.statistics",
    "interval_count": "daemon.analysis.statistics",
}

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


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'daemon.analysis' has no attribute {name!r}")
    value = getattr(import_module(module), name)
    globals()[name] = value
    return value
