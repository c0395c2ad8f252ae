"""A run's step records as numeric series, and the run summary of thesis Table 6.1.

The rows are step records (the columns of daemon/storage/recorder.py's StepRecord): mappings keyed
by column name, as the recorder's SQLite rows or an exported CSV give them (missing values
empty or None). Nothing here reads files; callers hand rows in.
"""

from __future__ import annotations

import json
import logging
import math
import re
from array import array
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

logger = logging.getLogger(__name__)

UM_PER_MM = 1000.0

#: The numeric columns of an exported run (StepRecord), units in the names.
NUMERIC_COLUMNS: tuple[str, ...] = (
    "step",
    "scheduled_s",
    "actual_s",
    "lateness_s",
    "model_time_s",
    "predicted_x_um",
    "predicted_y_um",
    "predicted_z_um",
    "offset_x_mm",
    "offset_y_mm",
    "offset_z_mm",
    "pose_x_mm",
    "pose_y_mm",
    "pose_z_mm",
    "centroid_x_px",
    "centroid_y_px",
    "centroid_x_um",
    "centroid_y_um",
    "drift_x_um",
    "drift_y_um",
    "residual_um",
    "deformation_scale",
    "deformation_sigma_um",
    *(
        f"{kind}_{axis}_{unit}"
        for kind, unit in (("predicted", "um"), ("correction", "mm"), ("measured", "um"))
        for axis in ("tx", "ty", "tz")
    ),
    *(
        f"{kind}_{axis}_urad"
        for kind in ("predicted", "correction", "measured")
        for axis in ("rx", "ry", "rz")
    ),
    "drift_3d_um",
    "rotation_error_urad",
    "measured_sigma_um",
    "measured_rotation_sigma_urad",
    "room_c",
)
#: The 6-DOF columns of an arm run (issue 20); a two-link run leaves them empty.
ARM_COLUMNS: tuple[str, ...] = NUMERIC_COLUMNS[NUMERIC_COLUMNS.index("deformation_sigma_um") + 1 :]

#: The measured compensation error along the link axis: what Table 6.1 summarises.
RESIDUAL_COLUMN = "residual_um"

#: Numeric keys of the run summary, in Table 6.1's order (then the reduction's reference).
SUMMARY_KEYS: tuple[str, ...] = (
    "n",
    "residual_max_um",
    "residual_mean_um",
    "residual_std_um",
    "residual_std_mean_um",
    "measured_drift_max_um",
    "uncompensated_max_um",
    "reduction_percent",
    "reduction_vs_prediction_percent",
    "reference_max_um",
    "reference_span_s",
)

#: What ``reduction_percent`` is measured against (the summary's ``reduction_basis``).
#: reference: a measured uncompensated run; prediction: no reference run, only
#: ``reduction_vs_prediction_percent`` (against the model's own prediction); drift: the run
#: was not compensated (its residual is the measured drift, there is no reduction).
ReductionBasis = Literal["reference", "prediction", "drift"]

FloatArray = NDArray[np.float64]


def number_or_nan(value: object) -> float:
    """A cell as a float; empty, None and text that is not a number are NaN (missing)."""
    if value is None:
        return math.nan
    if isinstance(value, int | float):
        return float(value)
    text = str(value).strip()
    if not text:
        return math.nan
    try:
        return float(text)
    except ValueError:
        return math.nan


def _json_object(value: object) -> dict[str, object]:
    if value is None or value == "":
        return {}
    if isinstance(value, Mapping):
        return dict(value)
    try:
        parsed = json.loads(str(value))
    except json.JSONDecodeError:
        logger.warning("ignoring a step's unreadable JSON cell: %.60s", value)
        return {}
    return parsed if isinstance(parsed, dict) else {}


@dataclass(frozen=True)
class RunSteps:
    """Every column of a run as an array over its steps (NaN where a value is missing)."""

    run_id: str | None
    numeric: dict[str, FloatArray]
    ir_mean_c: dict[str, FloatArray] = field(default_factory=dict)  # region -> series
    ir_max_c: dict[str, FloatArray] = field(default_factory=dict)
    model_temperatures_c: dict[str, FloatArray] = field(default_factory=dict)  # node -> series
    flags: tuple[tuple[str, ...], ...] = ()
    errors: tuple[str, ...] = ()
    #: an arm run's measured pose of each step (arm_pose); empty when no row names one
    poses: tuple[str | None, ...] = ()

    @property
    def n_steps(self) -> int:
        return len(self.flags)

    def column(self, name: str) -> FloatArray:
        try:
            return self.numeric[name]
        except KeyError:
            known = ", ".join(sorted(self.numeric))
            raise KeyError(f"no numeric column {name!r}; columns: {known}") from None

    @property
    def time_s(self) -> FloatArray:
        """Run time of each step: the scheduled time, else the actual time, else step index."""
        for name in ("scheduled_s", "actual_s"):
            values = self.numeric.get(name)
            if values is not None and np.isfinite(values).any():
                return values
        return np.arange(self.n_steps, dtype=float)

    def _vector(self, prefix: str, unit: str) -> FloatArray:
        """x/y/z columns as rows of vectors; a step missing all three is NaN, a component
        missing beside recorded ones is 0 (a 1-D run may record only x)."""
        columns = [self.numeric.get(f"{prefix}_{a}_{unit}") for a in "xyz"]
        vectors: FloatArray = np.full((self.n_steps, 3), np.nan)
        for axis, column in enumerate(columns):
            if column is not None:
                vectors[:, axis] = column
        missing = ~np.isfinite(vectors).any(axis=1)
        vectors = np.nan_to_num(vectors, nan=0.0)
        vectors[missing] = np.nan
        return vectors

    def _axis(self) -> FloatArray:
        """Unit vector of the largest predicted deformation: the link axis (model.direction)."""
        predicted = np.nan_to_num(self.predicted_vector_um, nan=0.0)
        norms = np.linalg.norm(predicted, axis=1)
        if norms.size == 0 or norms.max() == 0:
            return np.array([1.0, 0.0, 0.0])
        unit: FloatArray = predicted[int(np.argmax(norms))] / norms.max()
        return unit

    @property
    def predicted_vector_um(self) -> FloatArray:
        return self._vector("predicted", "um")

    @property
    def deformation_input_um(self) -> FloatArray:
        """Predicted deformation along the link axis (thesis 6.5: plotted positive)."""
        projected: FloatArray = self.predicted_vector_um @ self._axis()
        return projected

    @property
    def compensation_um(self) -> FloatArray:
        """Commanded compensation offset along the same axis, in um (negative: it opposes)."""
        projected: FloatArray = (self._vector("offset", "mm") @ self._axis()) * UM_PER_MM
        return projected

    @property
    def deformation_scale(self) -> FloatArray:
        """The deformation scale of each step (thesis 6.3); 1 where none was recorded."""
        scale = self.numeric.get("deformation_scale")
        if scale is None:
            return np.ones(self.n_steps)
        return np.where(np.isfinite(scale), scale, 1.0)

    @property
    def residual_um(self) -> FloatArray:
        return self.numeric.get(RESIDUAL_COLUMN, np.full(self.n_steps, np.nan))

    def flag_count(self, flag: str) -> int:
        return sum(flag in step_flags for step_flags in self.flags)


#: A cell a row does not have at all (a CSV without the column), unlike an empty one.
_ABSENT = object()


def steps_from_rows(rows: Iterable[Mapping[str, object]]) -> RunSteps:
    """Build the series of a run from its step rows (exported CSV or recorder rows).

    The rows are consumed one at a time into compact float columns, never held as a list:
    an hour at a 20 ms step is 180,000 rows, and holding them as dicts cost ~0.6 GiB per
    70,000 steps (benchmarks/bench_run_end.py)."""
    numeric: dict[str, array[float]] = {}
    ir_mean: dict[str, array[float]] = {}
    ir_max: dict[str, array[float]] = {}
    model_temperatures: dict[str, array[float]] = {}
    flag_tuples: dict[str, tuple[str, ...]] = {}  # one shared tuple per distinct flags cell
    flags: list[tuple[str, ...]] = []
    errors: list[str] = []
    poses: list[str | None] = []
    pose_names: dict[str, str] = {}  # one shared string per pose name
    run_ids: set[str] = set()
    n = 0
    for row in rows:
        for name in NUMERIC_COLUMNS:
            value = row.get(name, _ABSENT)
            if value is _ABSENT and name not in numeric:
                continue
            _series(numeric, name, n).append(number_or_nan(None if value is _ABSENT else value))
        ir_cell = _json_object(row.get("ir_json"))
        for region in ir_cell:
            _series(ir_mean, region, n)
            _series(ir_max, region, n)
        for region, means in ir_mean.items():
            reading = ir_cell.get(region)
            if isinstance(reading, Mapping):
                means.append(number_or_nan(reading.get("mean_c")))
                ir_max[region].append(number_or_nan(reading.get("max_c")))
            else:
                means.append(math.nan)
                ir_max[region].append(math.nan)
        model_cell = _json_object(row.get("model_temperatures_json"))
        for node in model_cell:
            _series(model_temperatures, node, n)
        for node, series in model_temperatures.items():
            series.append(number_or_nan(model_cell.get(node)))
        flags_text = str(row.get("flags") or "")
        step_flags = flag_tuples.get(flags_text)
        if step_flags is None:
            step_flags = tuple(f.strip() for f in flags_text.split(",") if f.strip())
            flag_tuples[flags_text] = step_flags
        flags.append(step_flags)
        errors.append(str(row.get("error") or ""))
        pose = row.get("arm_pose")
        poses.append(pose_names.setdefault(str(pose), str(pose)) if pose else None)
        run_id = row.get("run_id")
        if run_id not in (None, ""):
            run_ids.add(str(run_id))
        n += 1
    if len(run_ids) > 1:
        raise ValueError(f"the rows mix several runs: {sorted(run_ids)}")
    logger.debug("read %d steps, columns %s", n, sorted(numeric))
    return RunSteps(
        run_id=run_ids.pop() if run_ids else None,
        numeric={name: _floats(numeric[name]) for name in NUMERIC_COLUMNS if name in numeric},
        ir_mean_c={region: _floats(ir_mean[region]) for region in sorted(ir_mean, key=natural_key)},
        ir_max_c={region: _floats(ir_max[region]) for region in sorted(ir_max, key=natural_key)},
        model_temperatures_c={
            node: _floats(model_temperatures[node])
            for node in sorted(model_temperatures, key=natural_key)
        },
        flags=tuple(flags),
        errors=tuple(errors),
        poses=tuple(poses) if any(poses) else (),
    )


def _series(columns: dict[str, array[float]], name: str, rows_so_far: int) -> array[float]:
    """The column ``name``, created NaN-filled for the rows before its first value."""
    series = columns.get(name)
    if series is None:
        series = columns[name] = array("d", [math.nan]) * rows_so_far
    return series


def _floats(series: array[float]) -> FloatArray:
    # a view, not a copy: the array keeps the buffer alive and is never appended to again
    return np.frombuffer(series, dtype=np.float64)


_DIGITS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple[tuple[int, int, str], ...]:
    """Natural order: the numbers inside names compare as numbers, so node "2" comes before
    "10" and IR region "node-2" before "node-16" (a reader counts along the link, not
    alphabetically). Plain names compare as text, case-insensitively."""
    return tuple(
        (0, int(part), "") if part.isdigit() else (1, 0, part.casefold())
        for part in _DIGITS.split(name)
        if part
    )


def compensation_of(steps: RunSteps) -> str | None:
    """``"off"`` when every recorded compensating offset is exactly zero (what an
    uncompensated run records), else None: unknown. For exported runs, which do not carry
    their parameters."""
    offsets = [steps.numeric.get(f"offset_{axis}_mm") for axis in "xyz"]
    if any(column is None for column in offsets):
        return None
    values = np.concatenate([column for column in offsets if column is not None])
    values = values[np.isfinite(values)]
    return "off" if values.size and not values.any() else None


def summarize_run(
    rows: Iterable[Mapping[str, object]] | RunSteps,
    *,
    compensation: str | None = None,
    reference: RunSteps | None = None,
    reference_run: int | str | None = None,
) -> dict[str, float | int | str | None]:
    """The run summary of Table 6.1 (keys SUMMARY_KEYS, ``reduction_basis``,
    ``reference_run``).

    n counts the steps with a measured residual; residual_max_um is the largest |residual|
    (thesis 6.5 "maximum error"); the deviation is the sample one (N - 1) and its mean's
    deviation S_x / sqrt(N) (Eq. 6.1). uncompensated_max_um is the largest predicted
    deformation times the step's deformation scale (thesis 6.3): what the model says the spot
    would have moved on the chip without compensation, in the residual's own units.

    The reduction (thesis 6.7: 100 (1 - max error / max uncompensated), 98 % there) is only
    called a reduction when the uncompensated drift was *measured*: ``reference``, the steps
    of an uncompensated run of the same bench (``reference_run`` names it), whose largest
    |residual| is its drift. Both maxima are then taken over the time both runs cover
    (``reference_span_s``), since the drift grows with time. Without a reference,
    ``reduction_percent`` is None and ``reduction_vs_prediction_percent`` gives the same
    formula against the model's prediction: that says how well the moves followed the
    model, not how much drift they removed (a wrong model predicts a large deformation and
    "reduces" it by far more than the measured drift fell). A run with ``compensation``
    "off" (inferred from all-zero offsets when not given) reports its measured drift
    (``measured_drift_max_um``) and no reduction of either kind. Values that cannot be
    computed are None.
    """
    steps = rows if isinstance(rows, RunSteps) else steps_from_rows(rows)
    if compensation is None:
        compensation = compensation_of(steps)
    finite = np.isfinite(steps.residual_um)
    residual = steps.residual_um[finite]
    n = int(residual.size)
    summary: dict[str, float | int | str | None] = dict.fromkeys(SUMMARY_KEYS)
    summary["n"] = n
    if n >= 1:
        summary["residual_max_um"] = float(np.abs(residual).max())
        summary["residual_mean_um"] = float(residual.mean())
    if n >= 2:
        std = float(residual.std(ddof=1))
        summary["residual_std_um"] = std
        summary["residual_std_mean_um"] = std / math.sqrt(n)
    # a step whose prediction was absurd (e.g. 1e308 um: refused by the safety check but still
    # recorded) overflows to inf here and is dropped like a missing one, without a warning
    with np.errstate(over="ignore", invalid="ignore"):
        predicted = np.linalg.norm(steps.predicted_vector_um, axis=1) * steps.deformation_scale
    predicted = predicted[np.isfinite(predicted)]
    uncompensated = float(predicted.max()) if predicted.size else None
    summary["uncompensated_max_um"] = uncompensated
    residual_max = summary["residual_max_um"]
    summary["reference_run"] = None
    if compensation == "off":
        summary["reduction_basis"] = "drift"
        summary["measured_drift_max_um"] = residual_max
        return summary
    if uncompensated is not None and uncompensated > 0 and residual_max is not None:
        summary["reduction_vs_prediction_percent"] = 100.0 * (
            1.0 - float(residual_max) / uncompensated
        )
    summary["reduction_basis"] = "prediction"
    if reference is not None:
        summary["reduction_basis"] = "reference"
        summary["reference_run"] = reference_run if reference_run is not None else reference.run_id
        _reduction_against(summary, steps, reference)
    return summary


def _reduction_against(
    summary: dict[str, float | int | str | None], steps: RunSteps, reference: RunSteps
) -> None:
    """``reduction_percent`` from the largest |residual| of this run and of the uncompensated
    ``reference`` over the time both cover."""
    times, reference_times = steps.time_s, reference.time_s
    if not (np.isfinite(times).any() and np.isfinite(reference_times).any()):
        return
    span = float(min(np.nanmax(times), np.nanmax(reference_times)))
    summary["reference_span_s"] = span
    ours = steps.residual_um[(times <= span) & np.isfinite(steps.residual_um)]
    theirs = reference.residual_um[(reference_times <= span) & np.isfinite(reference.residual_um)]
    if not (ours.size and theirs.size):
        return
    reference_max = float(np.abs(theirs).max())
    summary["reference_max_um"] = reference_max
    if reference_max > 0:
        summary["reduction_percent"] = 100.0 * (1.0 - float(np.abs(ours).max()) / reference_max)
