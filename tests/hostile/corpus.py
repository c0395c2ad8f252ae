"""The hostile files (issue 26 "Bad files"): each a :class:`Case` that writes its files into a
fresh folder and runs one real ``thermocomp`` command on them. Every case expects ONE line on
stderr naming the problem (``says``, a regular expression), its exit status, no traceback,
and the command done within the runner's time and memory bounds (tests/hostile/runner.py).

Placeholders in ``argv`` and in file text: ``{t}`` the case's folder, ``{repo}`` the checkout.
A file whose content is :data:`FIFO` is made a named pipe (reading one blocks forever).
"""

from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from tests.helpers import REPO_ROOT

FIFO = b"<fifo>"
CONFIG = REPO_ROOT / "config"
A465 = (CONFIG / "arms" / "crs-a465.toml").read_text("utf-8")
UR5E_URDF = (CONFIG / "arms" / "ur5e.urdf").read_text("utf-8")
DUTY = (CONFIG / "duty" / "a465-pick-and-place.toml").read_text("utf-8")
# the arm bench's settings with its data directory in the case's folder ({t})
ARM_SIM = re.sub(
    r'^data_dir = ".*"$',
    'data_dir = "{t}/data"',
    (CONFIG / "arm-sim.toml").read_text("utf-8"),
    flags=re.M,
)
assert 'data_dir = "{t}/data"' in ARM_SIM


@dataclass(frozen=True)
class Case:
    id: str
    kind: str
    argv: tuple[str, ...]
    says: str  # a regular expression the one line matches (case-insensitive)
    files: dict[str, bytes | str] = field(default_factory=dict)
    status: int = 2
    env: dict[str, str] = field(default_factory=dict)

    def write(self, folder: Path) -> None:
        for name, content in self.files.items():
            path = folder / name
            path.parent.mkdir(parents=True, exist_ok=True)
            if content == FIFO:
                import os

                os.mkfifo(path)
                continue
            data = content.encode("utf-8") if isinstance(content, str) else content
            data = data.replace(b"{t}", str(folder).encode()).replace(
                b"{repo}", str(REPO_ROOT).encode()
            )
            path.write_bytes(data)

    def command(self, folder: Path) -> list[str]:
        return [
            word.replace("{t}", str(folder)).replace("{repo}", str(REPO_ROOT)) for word in self.argv
        ]


# -- settings files ------------------------------------------------------------------------------

RUN = ("run", "--config", "{t}/c.toml", "--data-dir", "{t}/data")


def config(id: str, text: str | bytes, says: str, **kw: object) -> Case:
    return Case(f"config/{id}", "config", RUN, says, {"c.toml": text}, **kw)  # type: ignore[arg-type]


CONFIG_CASES = [
    config("nested-arrays", "a = " + "[" * 5000 + "]" * 5000, r"nested over 16"),
    config("nested-tables", "a = " + "{b=" * 3000 + "1" + "}" * 3000, r"nested over 16"),
    config("nested-20", "x = " + "[" * 20 + "1" + "]" * 20, r"nested over 16"),
    config("dotted-keys-deep", ".".join(["k"] * 400) + " = 1", r"nested over 16"),
    config("bool-yes", '[bench]\nenabled = "yes"\n', r"bench\.enabled: .*valid boolean"),
    config("bool-one", "[storage]\nreport_at_end = 1\n", r"report_at_end: .*valid boolean"),
    config("bool-string-false", '[arm]\nbending = "false"\n', r"arm\.bending"),
    config("not-utf8", b"[bench]\nseed = 1 # \xff\xfe\n", r"not UTF-8"),
    config("binary", bytes(range(256)) * 8, r"binary file"),
    config("huge", "# " + "x" * (5 * 1024 * 1024), r"over 4 MiB"),
    config("fifo", FIFO, r"not a regular file"),
    config("bad-syntax", "[bench\nenabled = true\n", r"not valid TOML"),
    config("duplicate-key", "[bench]\nseed = 1\nseed = 2\n", r"not valid TOML"),
    config("unknown-key", "[bench]\nenabeld = true\n", r"bench\.enabeld: unknown setting"),
    config("unknown-section", "[benc]\nenabled = true\n", r"benc: unknown setting"),
    config("inf-step", "[scheduler]\nstep_s = inf\n", r"scheduler\.step_s"),
    config("nan-step", "[scheduler]\nstep_s = nan\n", r"scheduler\.step_s"),
    config("overflow-float", "[scheduler]\nduration_s = 1e400\n", r"scheduler\.duration_s"),
    config("huge-int-port", "[api]\nport = 123456789012345678901234567890\n", r"api\.port"),
    config("negative-duration", "[scheduler]\nduration_s = -5.0\n", r"duration_s"),
    config("string-for-number", '[scheduler]\nstep_s = "fast"\n', r"step_s"),
    config(
        "network-typo",
        '[model]\nnetwork = "thesis-two-lnk"\n',
        r"no network preset or saved network 'thesis-two-lnk' \(did you mean 'thesis-two-link'",
    ),
    config(
        "duty-typo",
        ARM_SIM.replace('"a465-pick-and-place"', '"pick-and-plce"'),
        r"no duty cycle 'pick-and-plce' \(did you mean .*'a465-pick-and-place'",
    ),
    config(
        "arm-file-typo",
        ARM_SIM.replace('arm_file = "crs-a465"', 'arm_file = "crs-a456"'),
        r"no arm 'crs-a456' \(did you mean 'crs-a465'",
    ),
    config(
        "cameras-file-missing",
        ARM_SIM.replace("[arm]\n", '[arm]\ncameras_file = "{t}/no-such-cameras.toml"\n'),
        r"no-such-cameras\.toml: no such file",
    ),
]
CONFIG_CASES += [
    Case(
        "config/folder",
        "config",
        ("run", "--config", "{t}", "--data-dir", "{t}/data"),
        r"is a folder",
    ),
    Case("config/missing", "config", ("run", "--config", "{t}/nope.toml"), r"no such file"),
    Case(
        "config/env-bool-yes",
        "config",
        ("run", "--data-dir", "{t}/data"),
        r"THERMOCOMP_BENCH__ENABLED.*valid boolean",
        env={"THERMOCOMP_BENCH__ENABLED": "yes"},
    ),
    Case(
        "config/env-not-a-section",
        "config",
        ("run", "--data-dir", "{t}/data"),
        r"seed is not a section",
        env={"THERMOCOMP_BENCH__SEED": "1", "THERMOCOMP_BENCH__SEED__X": "1"},
    ),
]


# -- network files (``model info FILE``, ``run --network FILE``) ----------------------------------

NODE = """
[[nodes]]
name = "{name}"
position_mm = {x}
capacitance_j_per_c = {c}
r_ambient_c_per_w = 50.0
"""


def nodes(count: int, c: str = "10.0") -> str:
    text = "alpha_per_c = 2.3e-5\n" + "".join(
        NODE.format(name=f"n{i}", x=float(i), c=c) for i in range(count)
    )
    links = "".join(
        f'[[resistances]]\nbetween = ["n{i}", "n{i + 1}"]\nr_c_per_w = 1.0\n'
        for i in range(count - 1)
    )
    return text + links


def segment(spacing: str, length: str = "500.0", extra: str = "") -> str:
    return f"""
[[segments]]
length_mm = {length}
width_mm = 30.0
thickness_mm = 10.0
material = "6061-T6"
node_spacing_mm = {spacing}
h_w_per_m2k = 10.0
{extra}"""


def network(id: str, text: str | bytes, says: str, *, via_run: bool = False) -> Case:
    argv = (
        ("run", "--network", "{t}/n.toml", "--data-dir", "{t}/data", "--duration", "1")
        if via_run
        else ("model", "info", "{t}/n.toml")
    )
    return Case(f"network/{id}", "network", argv, says, {"n.toml": text})


NETWORK_CASES = [
    network("spacing-1e-4", segment("0.0001"), r"node_spacing_mm .*nodes"),
    network("spacing-1e-4-run", segment("0.0001"), r"node_spacing_mm .*nodes", via_run=True),
    network("spacing-1e-300", segment("1e-300"), r"node_spacing_mm .*nodes"),
    network("length-1e308", segment("5.0", length="1e308"), r"nodes|length_mm"),
    network("spacing-nan", segment("nan"), r"node_spacing_mm"),
    network("spacing-inf", segment("inf"), r"node_spacing_mm"),
    network("spacing-negative", segment("-5.0"), r"node_spacing_mm"),
    network("12000-nodes", nodes(12_000), r"12000 nodes"),
    network("capacitance-nan", nodes(3, c="nan"), r"capacitance"),
    network("capacitance-inf", nodes(3, c="inf"), r"capacitance"),
    network("capacitance-negative", nodes(3, c="-1.0"), r"capacitance"),
    network("no-nodes", 'name = "empty"\n', r"needs \[\[nodes\]\]"),
    network(
        "unknown-end",
        nodes(2) + '[[resistances]]\nbetween = ["n0", "zz"]\nr_c_per_w = 1.0\n',
        r"unknown node 'zz'",
    ),
    network(
        "self-loop",
        nodes(2) + '[[resistances]]\nbetween = ["n0", "n0"]\nr_c_per_w = 1.0\n',
        r"joined to itself",
    ),
    network("duplicate-node", nodes(2) + NODE.format(name="n0", x=9.0, c=1.0), r"defined twice"),
    network(
        "unknown-material",
        segment("5.0").replace("6061-T6", "unobtainium"),
        r"unobtainium",
    ),
    network("nested", "x = " + "[" * 3000 + "]" * 3000, r"nested over 16"),
    network(
        "position-string",
        nodes(2).replace("position_mm = 0.0", 'position_mm = "zero"'),
        r"position_mm",
    ),
    network("heater-unknown", 'heater_nodes = ["hot"]\n' + nodes(2), r"'hot'"),
    network("fifo", FIFO, r"not a regular file"),
    network("not-utf8", b'name = "\xff"\n', r"not UTF-8"),
    Case(
        "network/name-typo",
        "network",
        ("run", "--network", "thesis-two-lnk", "--data-dir", "{t}/data"),
        r"no network preset or saved network 'thesis-two-lnk' \(did you mean 'thesis-two-link'",
    ),
    Case(
        "network/name-typo-model-info",
        "network",
        ("model", "info", "thesis-singel-link"),
        r"did you mean 'thesis-single-link'",
    ),
]


# -- arm files: DH tables and URDFs (``run`` with arm.arm_file) ----------------------------------

ARM_CONFIG = ARM_SIM.replace('arm_file = "crs-a465"', 'arm_file = "{t}/arm.toml"')
URDF_CONFIG = ARM_CONFIG.replace("{t}/arm.toml", "{t}/arm.urdf")
ARM_RUN = ("run", "--config", "{t}/c.toml")


def arm(id: str, text: str | bytes, says: str) -> Case:
    return Case(f"arm/{id}", "arm", ARM_RUN, says, {"c.toml": ARM_CONFIG, "arm.toml": text})


def a465(old: str, new: str, count: int = 1) -> str:
    assert old in A465, old
    return A465.replace(old, new, count)


def dh_rows(count: int) -> str:
    head = 'name = "snake"\nconvention = "standard"\n'
    return head + "".join(f'[[joints]]\nname = "j{i}"\na_mm = 10.0\n' for i in range(count))


ARM_CASES = [
    arm("a-nan", a465("d_mm = 330.2", "d_mm = nan"), r"joint 'waist': d_mm"),
    arm("d-inf", a465("d_mm = 330.2", "d_mm = inf"), r"joint 'waist': d_mm"),
    arm("alpha-1e308", a465("alpha_deg = -90.0", "alpha_deg = 1e308"), r"alpha_deg"),
    arm("a-1e300", a465("a_mm = 0.0", "a_mm = 1e300"), r"a_mm"),
    arm("one-joint", dh_rows(1), r"1 joints; the arm bench.s emulated C500C moves 6"),
    arm("zero-joints", 'name = "none"\nconvention = "standard"\n', r"joints"),
    arm("3000-joints", dh_rows(3000), r"3000 joints"),
    arm(
        "limits-reversed",
        a465("lower_deg = -175.0", "lower_deg = 179.0"),
        r"lower limit above upper",
    ),
    arm("limit-nan", a465("upper_deg = 175.0", "upper_deg = nan"), r"upper_deg"),
    arm("gear-negative", a465("gear_ratio = 100.0", "gear_ratio = -100.0"), r"gear_ratio"),
    arm("unknown-key", a465("a_mm = 0.0", "a_mm = 0.0\nlength = 3"), r"length: .*not permitted"),
    arm("grows-with-unknown", a465('grows_with = "turret"', 'grows_with = "tower"'), r"'tower'"),
    arm("no-convention", a465('convention = "modified"', ""), r"convention"),
    arm("base-nan", a465("xyz_mm = [0.0, 0.0, 0.0]", "xyz_mm = [nan, 0.0, 0.0]"), r"base"),
    arm("fifo", FIFO, r"not a regular file"),
    arm("nested", "x = " + "{a=" * 2000 + "1" + "}" * 2000, r"nested over 16"),
    arm("urdf-missing", 'name = "u"\nurdf = "nope.urdf"\n', r"nope\.urdf: no such file"),
]


def link(name: str) -> str:
    return f'  <link name="{name}"/>\n'


def joint(name: str, parent: str, child: str, kind: str = "revolute", xyz: str = "0 0 0.1") -> str:
    return (
        f'  <joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}" rpy="0 0 0"/><axis xyz="0 0 1"/>'
        '<limit lower="-3" upper="3" effort="1" velocity="1"/></joint>\n'
    )


def robot(body: str) -> str:
    return f'<?xml version="1.0"?>\n<robot name="r">\n{body}</robot>\n'


def urdf(id: str, text: str | bytes, says: str) -> Case:
    return Case(f"urdf/{id}", "urdf", ARM_RUN, says, {"c.toml": URDF_CONFIG, "arm.urdf": text})


CHAIN = [f"l{i}" for i in range(4)]
CYCLE = robot(
    "".join(link(n) for n in ["base", *CHAIN])
    + joint("j0", "base", "l0")
    + "".join(joint(f"j{i + 1}", CHAIN[i], CHAIN[i + 1]) for i in range(3))
    + joint("back", "l3", "l1")
)
LONG = robot(
    "".join(link(f"l{i}") for i in range(3001))
    + "".join(joint(f"j{i}", f"l{i}", f"l{i + 1}") for i in range(3000))
)
LAUGHS = (
    '<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a "aaaaaaaaaa">'
    + "".join(f'<!ENTITY {chr(98 + i)} "{("&" + chr(97 + i) + ";") * 10}">' for i in range(9))
    + ']>\n<robot name="&j;"><link name="base"/></robot>\n'
)

URDF_CASES = [
    urdf("cycle", CYCLE, r"cycle|more than one parent|one root"),
    urdf(
        "two-parents",
        robot(link("a") + link("b") + link("c") + joint("x", "a", "c") + joint("y", "b", "c")),
        r"more than one parent|one root",
    ),
    urdf(
        "self-joint",
        robot(link("a") + link("b") + joint("x", "a", "b") + joint("y", "b", "b")),
        r"itself|cycle|more than one parent",
    ),
    urdf(
        "all-cycle",
        robot(link("a") + link("b") + joint("x", "a", "b") + joint("y", "b", "a")),
        r"one root|cycle",
    ),
    urdf("3000-joints", LONG, r"3000 (moving )?joints|over \d+ joints"),
    urdf("not-xml", "this is not XML at all", r"not a readable URDF"),
    urdf("billion-laughs", LAUGHS, r"not a readable URDF|entit"),
    urdf(
        "origin-nan",
        robot(
            link("a")
            + link("b")
            + link("c")
            + joint("x", "a", "b", xyz="nan 0 0")
            + joint("y", "b", "c")
        ),
        r"finite|nan",
    ),
    urdf(
        "prismatic",
        robot(link("a") + link("b") + joint("x", "a", "b", kind="prismatic")),
        r"prismatic",
    ),
    urdf("huge", robot(link("a") + "<!--" + "x" * (5 * 1024 * 1024) + "-->"), r"over \d+ MiB"),
    urdf("fifo", FIFO, r"not a regular file"),
    urdf("unknown-parent", robot(link("a") + link("b") + joint("x", "zz", "b")), r"'zz'|root"),
    urdf("empty-robot", robot(""), r"root|link"),
]


# -- duty cycles (``run --duty-cycle FILE`` on the arm bench) ------------------------------------

DUTY_RUN = ("run", "--config", "{t}/c.toml", "--duty-cycle", "{t}/d.toml")
DUTY_CONFIG = ARM_SIM


def duty(id: str, text: str | bytes, says: str) -> Case:
    return Case(f"duty/{id}", "duty", DUTY_RUN, says, {"c.toml": DUTY_CONFIG, "d.toml": text})


def a465_duty(old: str, new: str, count: int = 1) -> str:
    assert old in DUTY, old
    return DUTY.replace(old, new, count)


def poses(count: int) -> str:
    head = DUTY[: DUTY.index("[[poses]]")]
    return head + "".join(
        f'[[poses]]\nname = "p{i}"\njoints_deg = [{i % 10}.0, 35.0, 55.0, 0.0, 0.0, 0.0]\n'
        "measure = true\n"
        for i in range(count)
    )


DUTY_CASES = [
    duty("dwell-1e308", a465_duty("dwell_s = 1.0", "dwell_s = 1e308"), r"dwell_s"),
    duty("dwell-inf", a465_duty("dwell_s = 1.0", "dwell_s = inf"), r"dwell_s"),
    duty("dwell-nan", a465_duty("dwell_s = 1.0", "dwell_s = nan"), r"dwell_s"),
    duty("speed-zero", a465_duty("speed = 0.8", "speed = 0.0"), r"speed"),
    duty("speed-two", a465_duty("speed = 0.8", "speed = 2.0"), r"speed"),
    duty("one-pose", poses(1), r"two poses"),
    duty("no-poses", DUTY[: DUTY.index("[[poses]]")] + "poses = []\n", r"two poses"),
    duty("10001-poses", poses(10_001), r"10001 poses"),
    duty("joint-nan", a465_duty("[0.0, 35.0, 55.0", "[nan, 35.0, 55.0"), r"joints_deg"),
    duty("joint-1e308", a465_duty("[0.0, 35.0, 55.0", "[1e308, 35.0, 55.0"), r"joints_deg|limit"),
    duty(
        "five-joints",
        a465_duty("[0.0, 35.0, 55.0, 0.0, 0.0, 0.0]", "[0.0, 35.0, 55.0, 0.0, 0.0]"),
        r"joint",
    ),
    duty("other-arm", a465_duty('arm = "crs-a465"', 'arm = "ur5e"'), r"'ur5e'.*crs-a465|taught on"),
    duty(
        "max-speed-zero",
        a465_duty("max_speed_deg_s = [180.0", "max_speed_deg_s = [0.0"),
        r"max_speed_deg_s|limits must be",
    ),
    duty(
        "max-accel-inf",
        a465_duty("max_accel_deg_s2 = [360.0", "max_accel_deg_s2 = [inf"),
        r"max_accel_deg_s2|limits must be",
    ),
    duty("payload-1e308", a465_duty("payload_kg = 1.0", "payload_kg = 1e308"), r"payload_kg"),
    duty("measure-yes", a465_duty("measure = true", 'measure = "yes"'), r"measure: .*boolean"),
    duty(
        "tool-unreachable",
        a465_duty("joints_deg = [0.0, 35.0, 55.0, 0.0, 0.0, 0.0]", "tool_mm = [9000.0, 0.0, 0.0]"),
        r"pose 'camera'",
    ),
    duty("fifo", FIFO, r"not a regular file"),
    duty("nested", "x = " + "[" * 4000 + "]" * 4000, r"nested over 16"),
    Case(
        "duty/name-typo",
        "duty",
        ("run", "--config", "{t}/c.toml", "--duty-cycle", "pick-and-plce"),
        r"no duty cycle 'pick-and-plce' \(did you mean .*'a465-pick-and-place'",
        {"c.toml": DUTY_CONFIG},
    ),
    Case(
        "duty/missing-file",
        "duty",
        ("run", "--config", "{t}/c.toml", "--duty-cycle", "{t}/nope.toml"),
        r"nope\.toml: no such file",
        {"c.toml": DUTY_CONFIG},
    ),
]


# -- camera files (arm.cameras_file) --------------------------------------------------------------

CAMERA = """
[[cameras]]
name = "{name}"
width_px = {width}
height_px = 1944
focal_px = [{focal}, 5000.0]
principal_px = [1296.0, 972.0]
distortion = {distortion}
position_mm = [600.0, 0.0, 700.0]
look_at_mm = {look_at}
"""


def camera_text(
    name: str = "front",
    width: str = "2592",
    focal: str = "5000.0",
    distortion: str = "[0.0, 0.0, 0.0, 0.0, 0.0]",
    look_at: str = "[400.0, 0.0, 500.0]",
) -> str:
    return CAMERA.format(
        name=name, width=width, focal=focal, distortion=distortion, look_at=look_at
    )


CAMERA_CONFIG = DUTY_CONFIG.replace(
    "[arm]\n", '[arm]\ncameras = 1\ncameras_file = "{t}/cams.toml"\n'
)


def cameras(id: str, text: str | bytes, says: str) -> Case:
    return Case(
        f"camera/{id}",
        "camera",
        ("run", "--config", "{t}/c.toml"),
        says,
        {"c.toml": CAMERA_CONFIG, "cams.toml": text},
    )


CAMERA_CASES = [
    cameras("focal-negative", camera_text(focal="-5000.0"), r"focal"),
    cameras("focal-nan", camera_text(focal="nan"), r"focal"),
    cameras("distortion-three", camera_text(distortion="[0.1, 0.0, 0.0]"), r"distortion"),
    cameras("distortion-inf", camera_text(distortion="[inf, 0.0, 0.0, 0.0]"), r"distortion"),
    cameras("width-zero", camera_text(width="0"), r"width_px"),
    cameras("width-huge", camera_text(width="1000000000000"), r"width_px"),
    cameras("no-cameras", "cameras = []\n", r"cameras"),
    cameras("1000-cameras", "".join(camera_text(name=f"c{i}") for i in range(1000)), r"cameras"),
    cameras("same-name", camera_text() + camera_text(), r"used by two cameras"),
    cameras("look-at-itself", camera_text(look_at="[600.0, 0.0, 700.0]"), r"front"),
    cameras("fifo", FIFO, r"not a regular file"),
    cameras("count-mismatch", camera_text() + camera_text(name="back"), r"2 camera\(s\) but 1"),
]


# -- arm models (``run --arm-model NAME``: data/arm-models/NAME.toml) -----------------------------

MODEL = """format = 1
name = "cal"
arm = "CRS A465"
duty_cycle = "a465-pick-and-place"
source_runs = ["run 1"]
identified_at = "2026-11-24T01:00:00+00:00"
heat_scales = [1.0, 1.2, 0.8, 1.0, 1.0, 1.0]
convection_scale = 1.0
alpha_scale = 1.0

[ir_offsets_c]

[ir_offset_sigma_c]
"""


def model(id: str, text: str | bytes, says: str, name: str = "cal") -> Case:
    return Case(
        f"arm-model/{id}",
        "arm-model",
        ("run", "--config", "{t}/c.toml", "--arm-model", name),
        says,
        {"c.toml": DUTY_CONFIG, "data/arm-models/cal.toml": text},
    )


def model_with(old: str, new: str) -> str:
    assert old in MODEL, old
    return MODEL.replace(old, new)


MODEL_CASES = [
    model("not-utf8", b'format = 1\nname = "\xff"\n', r"not UTF-8"),
    model("nested", "x = " + "[" * 3000 + "]" * 3000, r"nested over 16"),
    model("format-2", model_with("format = 1", "format = 2"), r"format 2"),
    model("heat-nan", model_with("[1.0, 1.2", "[nan, 1.2"), r"heat_scales"),
    model("heat-string", model_with("[1.0, 1.2", '["hot", 1.2'), r"heat_scales"),
    model("heat-1e308", model_with("[1.0, 1.2", "[1e308, 1.2"), r"heat_scales"),
    model(
        "three-joints",
        model_with("[1.0, 1.2, 0.8, 1.0, 1.0, 1.0]", "[1.0, 1.2, 0.8]"),
        r"3 heat_scales|joints",
    ),
    model("other-arm", model_with('arm = "CRS A465"', 'arm = "UR5e"'), r"identified on arm 'UR5e'"),
    model("no-name", model_with('name = "cal"\n', ""), r"name"),
    model(
        "convection-inf",
        model_with("convection_scale = 1.0", "convection_scale = inf"),
        r"convection_scale",
    ),
    model(
        "offset-text",
        model_with("[ir_offsets_c]\n", '[ir_offsets_c]\nwaist = "warm"\n'),
        r"ir_offsets_c",
    ),
    model("fifo", FIFO, r"not a regular file"),
    model("huge", "# " + "x" * (5 * 1024 * 1024), r"over 4 MiB"),
    model("name-typo", MODEL, r"no saved arm model 'cla' \(did you mean 'cal'", name="cla"),
    model("name-path", MODEL, r"not a name", name="../cal"),
]


# -- images (``centroid FILE``) -------------------------------------------------------------------


def png(width: int, height: int, body: bytes = b"", bit_depth: int = 8) -> bytes:
    """A PNG header claiming ``width`` x ``height`` pixels, with ``body`` as its image data."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    header = struct.pack(">IIBBBBB", width, height, bit_depth, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", body) + chunk(b"IEND", b"")
    )


def tiny_png() -> bytes:
    rows = b"".join(b"\x00" + bytes([10, 200, 10]) for _ in range(3))
    return png(3, 3, zlib.compress(rows))


def image(id: str, content: bytes | str, says: str, status: int = 1, name: str = "f.png") -> Case:
    return Case(
        f"image/{id}", "image", ("centroid", f"{{t}}/{name}"), says, {name: content}, status=status
    )


IMAGE_CASES = [
    image("fifo", FIFO, r"not a regular file", status=2),
    image("text-as-png", "this is no image", r"1 of 1 frames failed"),
    image("empty", b"", r"1 of 1 frames failed"),
    image("truncated", tiny_png()[:40], r"1 of 1 frames failed"),
    image(
        "bomb-header", png(100_000, 100_000, zlib.compress(b"\x00" * 1000)), r"1 of 1 frames failed"
    ),
    image(
        "deflate-bomb",
        png(20_000, 20_000, zlib.compress(b"\x00" * (20_001 * 20_000), 9)),
        r"1 of 1 frames failed",
    ),
    image("one-pixel", png(1, 1, zlib.compress(b"\x00\x80")), r"1 of 1 frames failed"),
    image("tiny", tiny_png(), r"1 of 1 frames failed"),
    Case(
        "image/no-images-folder",
        "image",
        ("centroid", "{t}/frames"),
        r"no image files",
        {"frames/readme.txt": "nothing"},
    ),
    Case("image/glob-nothing", "image", ("centroid", "{t}/*.png"), r"no file matches"),
    Case("image/missing", "image", ("centroid", "{t}/nope.png"), r"no such file"),
    Case(
        "image/times-nan",
        "image",
        ("centroid", "{t}/f.png", "--times", "{t}/times.txt"),
        r"finite times",
        {"f.png": tiny_png(), "times.txt": "nan\n"},
    ),
]


FILE_CASES: list[Case] = [
    *CONFIG_CASES,
    *NETWORK_CASES,
    *ARM_CASES,
    *URDF_CASES,
    *DUTY_CASES,
    *CAMERA_CASES,
    *MODEL_CASES,
    *IMAGE_CASES,
]


def matches(case: Case, line: str) -> bool:
    return re.search(case.says, line, re.IGNORECASE) is not None


__all__ = ["FIFO", "FILE_CASES", "Case", "matches"]
