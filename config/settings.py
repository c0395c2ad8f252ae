"""The settings tree of thermocomp: one pydantic model, loaded once in the entry point.

A settings object is built by :func:`load_settings` from a TOML file and
``THERMOCOMP_<SECTION>__<FIELD>`` environment variables (environment wins), and is then
passed down explicitly. There is deliberately no module-level settings instance.

Every section forbids unknown keys, so a typo in a TOML file is an error that names the
key instead of a silently ignored setting.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from types import UnionType
from typing import Annotated, Any, Literal, Self, Union, get_args, get_origin

from pydantic import BaseModel, ValidationError, model_validator

from config.arm_settings import ArmSettings
from config.bench_settings import BenchSettings, two_link_settings_given
from config.device_settings import CameraSettings, IrRegion, IrSettings, RobotSettings
from config.inputs import InputError
from config.model_settings import (
    CompensationSettings,
    ModelSettings,
    ObserverSettings,
    SchedulerSettings,
)
from config.room_settings import RoomSettings
from config.section import MAX_CONNECTIONS_LIMIT, SUPPORTED_BAUDRATES, Section
from config.service_settings import ApiSettings, StorageSettings
from config.toml_file import MAX_TOML_BYTES, read_toml

# The settings tree's sections live in their own modules (one job each); they are part of this
# module's interface, as the tree they make up.
__all__ = [
    "ENV_NESTING",
    "ENV_PREFIX",
    "MAX_CONNECTIONS_LIMIT",
    "MAX_TOML_BYTES",
    "README_BEGIN",
    "README_END",
    "SUPPORTED_BAUDRATES",
    "ApiSettings",
    "ArmSettings",
    "BenchSettings",
    "CameraSettings",
    "CompensationSettings",
    "ConfigError",
    "IrRegion",
    "IrSettings",
    "ModelSettings",
    "ObserverSettings",
    "RobotSettings",
    "RoomSettings",
    "SchedulerSettings",
    "Settings",
    "StorageSettings",
    "load_settings",
    "read_toml",
    "redact_secrets",
    "settings_reference",
    "settings_reference_markdown",
]

ENV_PREFIX = "THERMOCOMP_"
ENV_NESTING = "__"


class ConfigError(InputError):
    """The configuration could not be loaded; ``str()`` is the message for the user (one line
    per problem: ``<file>: <field.path>: <reason>``)."""


class Settings(Section):
    """Everything thermocomp can be told, one section per part of the product."""

    @model_validator(mode="after")
    def _playable_duty_cycle(self) -> Self:
        # a real arm cannot be accelerated, and the fast path's frames carry no speed
        if self.arm.play_duty_cycle:
            if self.robot.driver == "c500c-server":
                raise ValueError(
                    "arm.play_duty_cycle needs robot.driver c500c: the fast path's moves "
                    "carry no speed (controller/PROTOCOL.md)"
                )
            if self.compensation.time_scale != 1.0:
                raise ValueError(
                    "arm.play_duty_cycle needs compensation.time_scale 1: a played cycle "
                    "moves the arm in real time"
                )
        return self

    @model_validator(mode="after")
    def _arm_bench_truth(self) -> Self:
        # the arm bench's truth is bench.arm_truth: a two-link truth setting would be ignored
        if self.arm.enabled and self.bench.enabled and self.robot.driver == "sim":
            given = two_link_settings_given(self.bench)
            if given:
                raise ValueError(
                    f"bench.{given[0]}"
                    + (f" (and {', '.join(given[1:])})" if given[1:] else "")
                    + " is the two-link bench's truth, not the arm bench's: give the arm's "
                    "in the file of bench.arm_truth (docs/explanation/bench-truth.md)"
                )
        return self

    @model_validator(mode="after")
    def _simulated_room_on_the_arm_bench(self) -> Self:
        arm_bench = self.arm.enabled and self.bench.enabled and self.robot.driver == "sim"
        ur_bench = self.bench.enabled and self.robot.driver == "ur-rtde"  # issue 31
        if self.room.driver == "sim" and not (arm_bench or ur_bench):
            raise ValueError(
                "room.driver 'sim' is the arm bench's or the UR bench's room thermometer: it "
                "needs bench.enabled and robot.driver sim (with arm.enabled) or ur-rtde (on "
                "hardware: room.driver w1)"
            )
        return self

    @model_validator(mode="after")
    def _emulator_in_its_own_process(self) -> Self:
        # Another process shares only the machine's clock (CLOCK_MONOTONIC): a virtual or
        # accelerated clock is this process's own. The joint arm (the arm bench) and the UR
        # emulator are served in-process only.
        if self.bench.emulator != "process":
            return self
        arm_bench = self.arm.enabled and self.robot.driver == "sim"
        if (
            self.bench.clock != "real"
            or not self.bench.enabled
            or self.robot.driver not in ("sim", "c500c-server")
            or arm_bench
        ):
            raise ValueError(
                "bench.emulator 'process' needs bench.clock real, bench.enabled and "
                "robot.driver sim or c500c-server without arm.enabled (got bench.clock "
                f"{self.bench.clock}, bench.enabled {str(self.bench.enabled).lower()}, "
                f"robot.driver {self.robot.driver}, arm.enabled "
                f"{str(self.arm.enabled).lower()})"
            )
        return self

    bench: BenchSettings = BenchSettings()
    camera: CameraSettings = CameraSettings()
    ir: IrSettings = IrSettings()
    robot: RobotSettings = RobotSettings()
    model: ModelSettings = ModelSettings()
    observer: ObserverSettings = ObserverSettings()
    compensation: CompensationSettings = CompensationSettings()
    scheduler: SchedulerSettings = SchedulerSettings()
    storage: StorageSettings = StorageSettings()
    api: ApiSettings = ApiSettings()
    arm: ArmSettings = ArmSettings()
    room: RoomSettings = RoomSettings()


#: Setting names whose value is a secret: never stored (run rows) nor served (GET /config),
#: only whether they are set.
SECRET_SUFFIXES = ("token", "password", "secret")
REDACTED = "<redacted>"


def redact_secrets(value: Any) -> Any:
    """``value`` (a settings dump, or any JSON-like tree) with every secret's value replaced
    by ``"<redacted>"``; an unset secret stays null."""
    if isinstance(value, dict):
        return {
            key: (
                REDACTED
                if isinstance(key, str)
                and key.lower().endswith(SECRET_SUFFIXES)
                and item is not None
                else redact_secrets(item)
            )
            for key, item in value.items()
        }
    if isinstance(value, list | tuple):
        return [redact_secrets(item) for item in value]
    return value


def _env_value(raw: str) -> Any:
    """An environment value: JSON when it parses (numbers, lists, objects), else the string."""
    try:
        return json.loads(raw)
    except ValueError:
        return raw


def _apply_environment(data: dict[str, Any], environ: Mapping[str, str]) -> dict[str, str]:
    """Merge ``THERMOCOMP_SECTION__FIELD`` variables into ``data``; return the ones used."""
    used: dict[str, str] = {}
    for name, raw in sorted(environ.items()):
        if not name.startswith(ENV_PREFIX) or ENV_NESTING not in name:
            continue
        path = name[len(ENV_PREFIX) :].lower().split(ENV_NESTING)
        node = data
        for key in path[:-1]:
            child = node.setdefault(key, {})
            if not isinstance(child, dict):
                raise ConfigError(f"{name}: {'.'.join(path)}: {key} is not a section")
            node = child
        node[path[-1]] = _env_value(raw)
        used[".".join(path)] = name
    return used


def _describe(error: ValidationError, source: str, env_used: dict[str, str]) -> str:
    lines = []
    for item in error.errors():
        path = ".".join(str(part) for part in item["loc"])
        reason = str(item["msg"]).removeprefix("Value error, ")
        if item["type"] == "extra_forbidden":
            reason = "unknown setting"
        origin = f"{env_used[path]} (environment)" if path in env_used else source
        lines.append(f"{origin}: {path}: {reason}" if path else f"{origin}: {reason}")
    return "\n".join(lines)


def load_settings(path: Path | None = None, environ: Mapping[str, str] | None = None) -> Settings:
    """Build the settings from an optional TOML file and the environment.

    Raises :class:`ConfigError` with ``<file>: <field.path>: <reason>`` lines.
    """
    environ = os.environ if environ is None else environ
    data: dict[str, Any] = {}
    source = "defaults"
    if path is not None:
        source = str(path)
        data = read_toml(path, ConfigError)
    env_used = _apply_environment(data, environ)
    try:
        return Settings.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_describe(err, source, env_used)) from err


def _type_name(annotation: Any) -> str:
    """A reader's name for a field type: choices spelled out, Optional as "| none"."""
    origin, args = get_origin(annotation), get_args(annotation)
    if origin is Literal:
        return " \\| ".join(json.dumps(arg) for arg in args)
    if origin in (Union, UnionType):
        return " \\| ".join("none" if arg is type(None) else _type_name(arg) for arg in args)
    if origin is Annotated:
        return _type_name(args[0])
    if origin is not None:
        inner = ", ".join("..." if arg is Ellipsis else _type_name(arg) for arg in args)
        return f"{getattr(origin, '__name__', str(origin))}[{inner}]"
    return getattr(annotation, "__name__", str(annotation))


def settings_reference() -> list[tuple[str, str, str, str]]:
    """(key, type, default, description) of every setting, for the README's reference."""
    rows: list[tuple[str, str, str, str]] = []
    for section_name, section_field in Settings.model_fields.items():
        section_type = section_field.annotation
        assert isinstance(section_type, type) and issubclass(section_type, BaseModel)
        for name, field in section_type.model_fields.items():
            annotation = _type_name(field.annotation)
            default = field.get_default(call_default_factory=True)
            default_text = json.dumps(default, default=str) if default is not None else "none"
            rows.append(
                (f"{section_name}.{name}", annotation, default_text, field.description or "")
            )
    return rows


README_BEGIN = (
    "<!-- settings-reference:begin (generated by `python -m config --readme README.md`) -->"
)
README_END = "<!-- settings-reference:end -->"


def settings_reference_markdown() -> str:
    """The configuration reference as a Markdown table (kept in README.md)."""
    lines = [
        "| key | type | default | meaning |",
        "| --- | --- | --- | --- |",
    ]
    for key, type_name, default, description in settings_reference():
        cells = (key, type_name, default.replace("|", "\\|"), description.replace("|", "\\|"))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
