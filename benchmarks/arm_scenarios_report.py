"""What benchmarks/bench_arm_scenarios.py judges and prints: issue 29's targets, the rows of a
run each controller is judged over, a scenario's table and the worst case per target."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from benchmarks.common import print_table

#: controller -> (least share removed, largest RMS over the meter's 1-sigma or None).
TARGETS: dict[str, tuple[float, float | None]] = {
    "identified+room": (0.95, 2.0),
    "identified+room+adapt": (0.95, 2.0),
    "other-cycle+room": (0.93, None),
    "other-cycle+room+adapt": (0.93, None),
    "adapt": (0.90, None),
    "preset+room+ir": (0.80, None),
}
WHOLE = "whole"
LAST_THIRD = "last-third"
#: The rows each controller is judged over (issue 29's targets): the whole run, but for the
#: adaptation from the preset ("adapt": >= 90 % removed "by the last third", it has no
#: calibration to start from). The adaptation from the other task's model is judged over the
#: whole run, as the transfer target it answers ("calibrated on one cycle, run on another"),
#: and its last third is printed beside it (what it reaches once it has learnt).
JUDGED_OVER: dict[str, str] = {"adapt": LAST_THIRD}
#: Controllers whose last third is printed beside the judged figure.
SHOW_LAST_THIRD = ("identified+room+adapt", "other-cycle+room+adapt")


def judged_over(controller: str) -> str:
    return JUDGED_OVER.get(controller, WHOLE)


def window_rows(window: str, count: int) -> slice:
    """The rows of a run of ``count`` measurements a window covers."""
    return slice(2 * count // 3, None) if window == LAST_THIRD else slice(None)


def target_met(controller: str, figures: dict[str, Any]) -> bool | None:
    if controller not in TARGETS:
        return None
    removed, ratio = TARGETS[controller]
    return figures["removed"] >= removed and (ratio is None or figures["rms_over_sigma"] <= ratio)


def cell(figures: dict[str, Any] | None, controller: str) -> str:
    if figures is None:
        return "-"
    if controller == "none":
        return f"{figures['rms_3d_um']:.1f} um"
    met = target_met(controller, figures)
    mark = "" if met is None else (" ok" if met else " MISS")
    text = (
        f"{figures['rms_3d_um']:.1f} um {100 * figures['removed']:.1f} % "
        f"{figures['rms_over_sigma']:.1f}s{mark} (truth {100 * figures['true_removed']:.1f} %)"
    )
    if judged_over(controller) != WHOLE:
        text += f" [{judged_over(controller)}]"
    third = figures.get(LAST_THIRD)
    if controller in SHOW_LAST_THIRD and third is not None:
        text += f"; last third {100 * third['removed']:.1f} % {third['rms_over_sigma']:.1f}s"
    return text


def print_scenario(name: str, found: dict[str, Any], controllers: Sequence[str]) -> None:
    load = found["load_average"]
    print(
        f"\n{name} ({'plausible' if found['plausible'] else 'BEYOND plausible'}; meter sigma "
        f"{found['meter_sigma_um']:.2f} um; {found['wall_s']:.0f} s wall, load "
        f"{load[0]:.1f} {load[1]:.1f} {load[2]:.1f})"
    )
    tasks = list(found["tasks"])
    print_table(
        ["controller", *(f"task {t}: RMS, removed, RMS/sigma (on the truth)" for t in tasks)],
        [[c, *(cell(found["tasks"][t].get(c), c) for t in tasks)] for c in controllers],
    )
    for label, calibration in found["calibrations"].items():
        print(
            f"  calibration on {label}: {calibration['identification_wall_s']:.1f} s wall, "
            f"{calibration['identification_cpu_s']:.1f} s CPU (load "
            f"{calibration['load_average'][0]:.1f}); not identified: "
            f"{', '.join(calibration['not_identified']) or 'none'}"
        )
    for task in tasks:
        for controller, figures in found["tasks"][task].items():
            if "estimates" in figures:
                ended = ", ".join(
                    f"{k} {v[0]:.3g}+-{v[1]:.2g}"
                    for k, v in figures["estimates"].items()
                    if not k.startswith("offset:")
                )
                print(f"  {controller} on {task}, the adapted factors at the end: {ended}")


def worst_cases(results: dict[str, Any]) -> list[dict[str, Any]]:
    """Per target: the worst plausible scenario x task, and how many met it."""
    out = []
    for controller in TARGETS:
        cases = [
            (name, task, figures[controller])
            for name, found in results.items()
            if found["plausible"]
            for task, figures in found["tasks"].items()
            if controller in figures
        ]
        if not cases:
            continue
        name, task, figures = min(cases, key=lambda c: (c[2]["removed"], -c[2]["rms_over_sigma"]))
        highest = max(cases, key=lambda c: c[2]["rms_over_sigma"])
        worst_true = min(cases, key=lambda c: c[2]["true_removed"])
        met = sum(bool(target_met(controller, c[2])) for c in cases)
        out.append(
            {
                "controller": controller,
                "judged_over": judged_over(controller),
                "scenario": name,
                "task": task,
                "removed": figures["removed"],
                "rms_3d_um": figures["rms_3d_um"],
                "rms_over_sigma": figures["rms_over_sigma"],
                "true_removed": figures["true_removed"],
                "worst_true_removed": [worst_true[0], worst_true[1], worst_true[2]["true_removed"]],
                "highest_rms_over_sigma": [highest[0], highest[1], highest[2]["rms_over_sigma"]],
                "met": met,
                "cases": len(cases),
            }
        )
    return out


def print_worst(worst: list[dict[str, Any]]) -> None:
    print("\nworst plausible case per target:")
    print_table(
        [
            "target", "judged over", "scenario", "task", "RMS um", "removed", "RMS/sigma", "met",
            "worst RMS/sigma", "its truth removed", "worst truth removed",
        ],
        [
            [
                w["controller"], w["judged_over"], w["scenario"], w["task"], w["rms_3d_um"],
                f"{100 * w['removed']:.1f} %", w["rms_over_sigma"], f"{w['met']}/{w['cases']}",
                f"{w['highest_rms_over_sigma'][2]:.2f} ({w['highest_rms_over_sigma'][0]} "
                f"{w['highest_rms_over_sigma'][1]})",
                f"{100 * w['true_removed']:.1f} %",
                f"{100 * w['worst_true_removed'][2]:.1f} % ({w['worst_true_removed'][0]} "
                f"{w['worst_true_removed'][1]})",
            ]
            for w in worst
        ],
    )  # fmt: skip
