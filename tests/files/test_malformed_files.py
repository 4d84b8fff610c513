"""Malformed scene, device, calibration and session files: one line naming the file and the dotted field.

Every case is checked with ``frhc check``'s :func:`app.check.check_file`, which builds everything
``frhc run`` builds, so a refusal here is a refusal before anything runs, and a file that passes
``check`` starts. Each case asserts the file, the field, a one-line message and that no warning
was issued before the error. A few cases also go through the command line (exit 2, one line on
stderr, no traceback, nothing written).
"""

from __future__ import annotations

import codecs
import dataclasses
import shutil
import subprocess
import sys
import tomllib
import typing
import warnings
from dataclasses import dataclass
from pathlib import Path

import pytest
import trimesh

from app.check import check_file
from app.config import MAX_FILE_BYTES, load_toml
from app.device.spec import DEVICES_DIR
from app.errors import ConfigError
from app.session.spec import MAX_SCRIPT_ENTRIES, SESSIONS_DIR, SwitchEvent, Waypoint, load_session
from app.world.scene import SCENES_DIR

BASE_SCENE = """\
name = "t"
description = "base scene of the malformed-file table"
gravity = [0.0, 0.0, -9.81]
margin = 0.0

[[objects]]
name = "surface"
box = [0.2, 0.2, 0.02]
stiffness = 1000.0
damping = 1.0
pose = { position = [0.0, 0.0, -0.01] }

[tool]
mass = 0.5
inertia = [1e-3, 1e-3, 1e-3, 0.0, 0.0, 0.0]
com = [0.0, 0.0, 0.0]
home = { position = [0.0, 0.0, 0.1], quat_wxyz = [1.0, 0.0, 0.0, 0.0] }

[[tool.spheres]]
center = [0.0, 0.0, 0.0]
radius = 0.01

[[tool.capsules]]
start = [0.0, 0.0, 0.0]
end = [0.0, 0.0, 0.05]
radius = 0.005
spacing = 0.0025

[[tool.boxes]]
extents = [0.02, 0.02, 0.02]
sphere_radius = 0.002
spacing = 0.004

[slave]
kp_lin = 3000.0

[task]
goal = { position = [0.0, 0.0, 0.05] }
position_tolerance = 0.002
"""


@dataclass(frozen=True)
class Case:
    """One malformed file: ``old`` replaced once by ``new`` in the base file of ``kind``.

    ``old = None`` appends ``new``; ``old = ""`` prepends it. ``{tmp}`` in ``new`` is the test's
    scratch folder, holding the meshes of :func:`write_meshes`. ``kind`` is ``scene``, ``session``,
    ``device`` or ``calibration`` (the device's calibration file; the device file is checked).
    """

    kind: str
    old: str | None
    new: str | bytes
    field: str
    reason: str = ""


def S(old: str | None, new: str | bytes, field: str, reason: str = "") -> Case:
    return Case("scene", old, new, field, reason)


def D(old: str | None, new: str | bytes, field: str, reason: str = "") -> Case:
    return Case("device", old, new, field, reason)


def C(old: str | None, new: str | bytes, field: str, reason: str = "") -> Case:
    return Case("calibration", old, new, field, reason)


def P(old: str | None, new: str | bytes, field: str, reason: str = "") -> Case:
    return Case("session", old, new, field, reason)


KRAFT_CALIBRATION = (DEVICES_DIR / "kraft" / "calibration.toml").read_text().splitlines()
#: The text of the first rows of the shipped Kraft curves: ``[c0, c1, ...]`` without the comma.
KRAFT_ROW0 = KRAFT_CALIBRATION[KRAFT_CALIBRATION.index("positive = [") + 1].strip().rstrip(",")
KRAFT_NEG0 = KRAFT_CALIBRATION[KRAFT_CALIBRATION.index("negative = [") + 1].strip().rstrip(",")
C1 = KRAFT_ROW0.split(", ")[1]
MANY_OBJECTS = "".join(f'[[objects]]\nname = "o{i}"\nsphere = 0.01\nstiffness = 1.0\n' for i in range(1001))
MANY_SPHERES = "".join("[[tool.spheres]]\ncenter = [0.0, 0.0, 0.0]\nradius = 0.01\n" for _ in range(1001))
CAPSULE = "[[tool.capsules]]\nstart = [0.0, 0.0, 0.0]\nend = [0.0, 0.0, 1.0]\nradius = 1e-5\n"

CASES: dict[str, dict[str, Case]] = {
    "encoding": {
        "session BOM, then a latin-1 byte": P(
            "", b"\xef\xbb\xbf# caf\xe9\n", "<file>", "not UTF-8 text (byte 0xe9 on line 1)"
        ),
        "scene latin-1 byte": S('"base scene', b'"base sc\xe9ne', "<file>", "not UTF-8"),
        "session UTF-16": P("", "\ufeff".encode("utf-16-le"), "<file>", "not UTF-8"),
        "device NUL and 0xff": D('name = "kraft"', b'name = "kr\x00\xffaft"', "<file>", "not UTF-8"),
        "calibration non-UTF-8": C("positive = [", b"# \xc3\x28\npositive = [", "<file>", "not UTF-8"),
        "TOML syntax": S("margin = 0.0", "margin = = 0.0", "<file>", "not valid TOML"),
        "nesting 100000 deep": S("", "deep = " + "[" * 100_000 + "]" * 100_000 + "\n", "<file>", "nested"),
        "duplicate key": P("seed = 0", "seed = 0\nseed = 1", "<file>", "not valid TOML"),
    },
    "resource exhaustion": {
        "file over 4 MiB": S(None, "#" + "x" * (5 * 2**20) + "\n", "<file>", "larger than"),
        "capsule spacing 1e-12": S(
            "spacing = 0.0025", "spacing = 1e-12", "tool.capsules[0].spacing", "in [1e-6, 10] m"
        ),
        "capsule spacing too fine": S("spacing = 0.0025", "spacing = 1e-6", "tool.capsules[0].spacing", "spheres"),
        "capsule default spacing too fine": S(None, CAPSULE, "tool.capsules[1].radius", "over 10000 spheres"),
        "box grid too fine": S("spacing = 0.004", "spacing = 1e-6", "tool.boxes[0].spacing", "spheres"),
        "dotted key of 100000 parts": S("", "a" + ".a" * 100_000 + " = 1\n", "<file>", "more than 32 parts (line 1)"),
        "quoted dotted key of 33 parts": P(None, '"k".' * 32 + '"k" = 1', "<file>", "more than 32 parts"),
        "table header of 100 parts": D(None, "[" + ".".join(["t"] * 100) + "]", "<file>", "more than 32 parts"),
        "inline tables 1000 deep": S("", "x = " + "{a=" * 1000 + "1" + "}" * 1000 + "\n", "<file>", "32 deep"),
        "5000-digit integer": P("seed = 0", "seed = 1" + "0" * 5000, "<file>", "more than 1000 digits"),
        "1001 objects": S(None, MANY_OBJECTS, "objects", "0..1000 entries"),
        "1001 tool spheres": S(None, MANY_SPHERES, "tool.spheres", "0..1000 entries"),
        "duration 1e12": P("duration = 5.0", "duration = 1e12", "duration", "(0, 86400] s"),
        "ticks over the limit": P("duration = 5.0", "duration = 86400.0", "duration", "ticks"),
        "ticks at 20 kHz": P(
            "duration = 5.0\nservo_rate = 1000.0", "duration = 200.0\nservo_rate = 20000.0", "duration", "4000000 ticks"
        ),
        "counts_max 2**70": D("counts_max = 2047", f"counts_max = {2**70}", "motors.counts_max", "[1, 65535]"),
        "counts_max 2**20": D("counts_max = 2047", f"counts_max = {2**20}", "motors.counts_max"),
        "integer beyond float": P("duration = 5.0", f"duration = {10**400}", "duration", "too large"),
        "seed 2**70": P("seed = 0", f"seed = {2**70}", "seed"),
    },
    "inf, NaN, huge or tiny": {
        "stiffness 1e300": S("stiffness = 1000.0", "stiffness = 1e300", "objects[0].stiffness", "(0, 1e7] N/m"),
        "stiffness inf": S("stiffness = 1000.0", "stiffness = inf", "objects[0].stiffness", "finite"),
        "stiffness nan": S("stiffness = 1000.0", "stiffness = nan", "objects[0].stiffness", "NaN"),
        "damping 1e300": S("damping = 1.0", "damping = 1e300", "objects[0].damping"),
        "sphere 1e200": S("box = [0.2, 0.2, 0.02]", "sphere = 1e200", "objects[0].sphere", "[1e-6, 100] m"),
        "box 1e-300": S("box = [0.2, 0.2, 0.02]", "box = [0.2, 1e-300, 0.02]", "objects[0].box[1]"),
        "tool mass 1e-300": S("mass = 0.5", "mass = 1e-300", "tool.mass", "[1e-6, 1000] kg"),
        "tool inertia 1e-300": S("[1e-3, 1e-3, 1e-3,", "[1e-300, 1e-300, 1e-300,", "tool.inertia", "principal moments"),
        "com 1e6 m": S("com = [0.0, 0.0, 0.0]", "com = [1e6, 0.0, 0.0]", "tool.com[0]", "[-10, 10] m"),
        "gravity 1e300": S("-9.81]", "-1e300]", "gravity[2]"),
        "margin inf": S("margin = 0.0", "margin = inf", "margin"),
        "home position 1e308": S("[0.0, 0.0, 0.1]", "[0.0, 0.0, 1e308]", "tool.home.position[2]"),
        "zero quaternion": S("[1.0, 0.0, 0.0, 0.0]", "[1e-300, 0.0, 0.0, 0.0]", "tool.home.quat_wxyz", "non-zero"),
        "slave kp_lin 1e300": S("kp_lin = 3000.0", "kp_lin = 1e300", "slave.kp_lin"),
        "slave kind unknown": S("kp_lin = 3000.0", 'kp_lin = 3000.0\nkind = "puma"', "slave.kind", "unknown slave"),
        "slave kind path": S("kp_lin = 3000.0", 'kp_lin = 3000.0\nkind = "../devices"', "slave.kind", "unknown slave"),
        "task tolerance 0": S("position_tolerance = 0.002", "position_tolerance = 0.0", "task.position_tolerance"),
        "device home inf": D("home = [0.0,", "home = [inf,", "home[0]", "finite"),
        "device home 1e9 rad": D("home = [0.0,", "home = [1e9,", "home[0]"),
        "home outside the joint range": D("home = [0.0,", "home = [3.0,", "home[0]", "outside joint 'j1'"),
        "torque_limit inf": D(
            "torque_limit = [0.40,", "torque_limit = [inf,", "motors.torque_limit", "torque_limit[0]"
        ),
        "k_t inf": D("k_t = [1.0,", "k_t = [inf,", "gains.k_t", "finite"),
        "k_t 1e30": D("k_t = [1.0,", "k_t = [1e30,", "gains.k_t"),
        "rtc_a 1e308": D("rtc_a = [1.0e4,", "rtc_a = [1e308,", "gains.rtc_a"),
        "plant mass_scale 1e300": D("mass_scale = [1.0,", "mass_scale = [1e300,", "plant.mass_scale[0]"),
        "plant damping -1": D("damping = [0.04, 0.04, 0.03,", "damping = [-1.0, 0.04, 0.03,", "plant.damping[0]"),
        "calibration coefficient inf": C(KRAFT_ROW0, KRAFT_ROW0.replace(C1, "inf"), "positive[0][1]"),
        "calibration not monotonic": C(
            KRAFT_ROW0, "[0.0, 4000.0, 0.0, 0.0, 0.0, -1e6]", "positive[0]", "not monotonic"
        ),
        "calibration reverses sign": C(KRAFT_ROW0, "[-500.0, 4000.0, 0.0, 0.0, 0.0, 0.0]", "positive[0]", "reverses"),
        "calibration negative side": C(KRAFT_NEG0, KRAFT_NEG0.replace("[-", "[", 1), "negative[0]", "reverses"),
        "tremor inf": P("seed = 0", "seed = 0\ntremor = inf", "tremor", "finite"),
        "seed -1": P("seed = 0", "seed = -1", "seed", "[0, 4294967295]"),
        "time_scale inf": P("seed = 0", "seed = 0\ntime_scale = inf", "time_scale"),
        "time_scale 1e-300": P("seed = 0", "seed = 0\ntime_scale = 1e-300", "time_scale"),
        "waypoint t inf": P("t = 0.3", "t = inf", "waypoints[0].t"),
        "waypoint position 1e308": P(
            "[0.0, 0.0, -0.03]\n\n[[waypoints]]\nt = 3.5",
            "[0.0, 0.0, 1e308]\n\n[[waypoints]]\nt = 3.5",
            "waypoints[1].position[2]",
        ),
        "event t nan": P("t = 0.0\ndeadman", "t = nan\ndeadman", "events[0].t", "NaN"),
        "servo_rate 1e9": P("servo_rate = 1000.0", "servo_rate = 1e9", "servo_rate"),
        "hand stiffness 1e12": P(
            "accommodation = true", "accommodation = true\n[hand]\nstiffness_trans = 1e12", "hand.stiffness_trans"
        ),
        "hand damping 1e300": P(
            "accommodation = true", "accommodation = true\n[hand]\ndamping_trans = 1e300", "hand.damping_trans"
        ),
        "hand force_limit 0": P(
            "accommodation = true", "accommodation = true\n[hand]\nforce_limit = 0.0", "hand.force_limit"
        ),
        "hand torque_limit nan": P(
            "accommodation = true", "accommodation = true\n[hand]\ntorque_limit = nan", "hand.torque_limit", "NaN"
        ),
        "passivity damping inf": P(
            "accommodation = true",
            "accommodation = true\n[passivity]\nfriction_credit = inf",
            "passivity.friction_credit",
        ),
        "passivity step_counts 0": P(
            "accommodation = true",
            "accommodation = true\n[passivity]\nstep_counts = 0",
            "passivity.step_counts",
        ),
        "passivity step_counts 2.5": P(
            "accommodation = true",
            "accommodation = true\n[passivity]\nstep_counts = 2.5",
            "passivity.step_counts",
        ),
        "passivity law_onset not a form": P(
            "accommodation = true",
            'accommodation = true\n[passivity]\nlaw_onset = "stepped"',
            "passivity.law_onset",
        ),
        "passivity swing_charge a string": P(
            "accommodation = true",
            'accommodation = true\n[passivity]\nswing_charge = "yes"',
            "passivity.swing_charge",
        ),
        "passivity reserve 2 J": P(
            "accommodation = true",
            "accommodation = true\n[passivity]\nenergy_reserve = 2.0",
            "passivity.energy_reserve",
        ),
        "channel delay -5": P(
            "accommodation = true", "accommodation = true\n[channel]\ndelay_ms = -5.0", "channel.delay_ms"
        ),
        "channel wave cutoff -1": P(
            "accommodation = true", "accommodation = true\n[channel]\nwave_cutoff_hz = -1.0", "channel.wave_cutoff_hz"
        ),
        "channel coupling": P(
            "accommodation = true", 'accommodation = true\n[channel]\ncoupling = "scattering"', "channel.coupling"
        ),
        "max_period 1e-9": P(
            "accommodation = true", "accommodation = true\n[gains]\nmax_period = 1e-9", "gains.max_period"
        ),
        "max_period below the period": P(
            "servo_rate = 1000.0\nseed = 0\naccommodation = true",
            "servo_rate = 100.0\nseed = 0\naccommodation = true\n[gains]\nmax_period = 0.005",
            "gains.max_period",
            "overrun",
        ),
    },
    "wrong shape or type": {
        "event grip a string": P(
            "t = 0.0\ndeadman", 't = 0.0\ngrip = "on"\ndeadman', "events[0].grip", "true or false"
        ),
        "home 5 values": D("home = [0.0, 0.2,", "home = [0.2,", "home", "expected 6 values"),
        "plant damping 3 values": D(
            "damping = [0.04, 0.04, 0.03, 0.004, 0.004, 0.004]",
            "damping = [0.04, 0.04, 0.03]",
            "plant.damping",
            "expected 6",
        ),
        "gains k_v 3 values": D(
            "k_v = [2.0, 2.0, 2.0, 1.5, 1.5, 1.5]", "k_v = [2.0, 2.0, 2.0]", "gains.k_v", "expected 6 values"
        ),
        "inertia 5 values": S("[1e-3, 1e-3, 1e-3, 0.0, 0.0, 0.0]", "[1e-3, 1e-3, 1e-3, 0.0, 0.0]", "tool.inertia"),
        "calibration row of 5": C(
            KRAFT_ROW0, "[75.5, 4544.9, -16708.7, 146973.6, -509670.6]", "positive[0]", "6 coefficients"
        ),
        "calibration 5 rows": C(KRAFT_ROW0 + ",\n", "", "positive", "expected 6 rows"),
        "position a number": S("{ position = [0.0, 0.0, 0.1],", "{ position = 0.1,", "tool.home.position", "array"),
        "objects a table": S("[[objects]]", "[objects]", "objects", "expected an array"),
        "stiffness a string": S("stiffness = 1000.0", 'stiffness = "stiff"', "objects[0].stiffness", "number"),
        "no joints": D('joints = ["j1", "j2", "j3", "j4", "j5", "j6"]', "joints = []", "joints", "1..32"),
        "duplicate joints": D('joints = ["j1", "j2",', 'joints = ["j1", "j1",', "joints[1]", "duplicate"),
        "duplicate objects": S(
            None, '[[objects]]\nname = "surface"\nsphere = 0.1\nstiffness = 1.0\n', "objects[1].name", "duplicate"
        ),
        "missing [tool]": S(
            BASE_SCENE[BASE_SCENE.index("[tool]") : BASE_SCENE.index("[slave]")], "", "tool", "required"
        ),
        "missing joints": D('joints = ["j1", "j2", "j3", "j4", "j5", "j6"]\n', "", "joints", "required"),
        "missing duration": P("duration = 5.0\n", "", "duration", "required"),
        "two orientations": S(
            "quat_wxyz = [1.0, 0.0, 0.0, 0.0]",
            "quat_wxyz = [1.0, 0.0, 0.0, 0.0], zyx_deg = [0.0, 0.0, 0.0]",
            "tool.home.quat_wxyz",
            "not both",
        ),
        "two shapes": S(
            "box = [0.2, 0.2, 0.02]", "box = [0.2, 0.2, 0.02]\nsphere = 0.1", "objects[0].mesh", "exactly one"
        ),
        "encoder on some joints": D(
            "encoder_counts_per_rev = [16384,",
            "encoder_counts_per_rev = [0,",
            "plant.encoder_counts_per_rev",
            "every joint",
        ),
        "no tool geometry": S(
            BASE_SCENE[BASE_SCENE.index("[[tool.spheres]]") : BASE_SCENE.index("[slave]")],
            "",
            "tool.spheres",
            "contact geometry",
        ),
        "torque_curve unknown": D('torque_curve = "calibrated"', 'torque_curve = "cubic"', "torque_curve", "one of"),
        "waypoints not increasing": P("t = 1.0\n", "t = 0.2\n", "waypoints[1].t", "increase"),
    },
    "unknown key": {
        "scene root": S("", "colour = 'red'\n", "colour", "unknown field"),
        "tool table misspelt": S("[tool]\nmass = 0.5", "[toolx]\nmass = 0.5", "toolx", "unknown field"),
        "plant": D("substeps = 1", "substeps = 1\nbacklash = 0.01", "plant.backlash", "unknown field"),
        "plant substeps 0": D("substeps = 1", "substeps = 0", "plant.substeps", "[1, 100]"),
        "plant mass_scale negative": D("mass_scale = [1.0,", "mass_scale = [-1.0,", "plant.mass_scale[0]"),
        "session root": P("seed = 0", "seed = 0\nspeed = 3", "speed", "unknown field"),
        "session slave unknown": P("seed = 0", 'seed = 0\nslave = "kuka"', "slave", "unknown slave"),
        "device gains": D("assist_fraction = 0.3", "assist_fraction = 0.3\nk_vv = 1.0", "gains.k_vv", "unknown field"),
        "session gains": P(
            "accommodation = true", "accommodation = true\n[gains]\nk_vv = 1.0", "gains.k_vv", "unknown field"
        ),
        "session hand": P(
            "accommodation = true", "accommodation = true\n[hand]\nstiffnes = 1.0", "hand.stiffnes", "unknown field"
        ),
        "calibration": C("negative = [", "extra = 1\nnegative = [", "extra", "unknown field"),
        "tool sphere": S("radius = 0.01\n", "radius = 0.01\nradus = 1\n", "tool.spheres[0].radus", "unknown field"),
        "device root": D(
            'torque_curve = "calibrated"', 'torque_curve = "calibrated"\ncolour = 1', "colour", "unknown field"
        ),
        "unknown scene name": P('scene = "probe"', 'scene = "moon"', "scene", "no such scene"),
        "unknown device name": P('device = "kraft"', 'device = "phantom"', "device", "no such device"),
        "unknown joint": D('"j5", "j6"]', '"j5", "j9"]', "joints[5]", "unknown joint"),
        "unknown site": D('grip_site = "grip"', 'grip_site = "handle_tip"', "grip_site", "unknown site"),
    },
    "bad mesh or model": {
        "mesh missing": S("box = [0.2, 0.2, 0.02]", 'mesh = "no_such_mesh.stl"', "objects[0].mesh", "not found"),
        "mesh junk bytes": S("box = [0.2, 0.2, 0.02]", 'mesh = "{tmp}/junk.stl"', "objects[0].mesh"),
        "mesh empty file": S("box = [0.2, 0.2, 0.02]", 'mesh = "{tmp}/empty.stl"', "objects[0].mesh"),
        "mesh flat": S("box = [0.2, 0.2, 0.02]", 'mesh = "{tmp}/flat.ply"', "objects[0].mesh", "not closed"),
        "mesh non-finite vertex": S("box = [0.2, 0.2, 0.02]", 'mesh = "{tmp}/nan.obj"', "objects[0].mesh"),
        # Refused from the header: trimesh would spend gigabytes on these before counting.
        "binary STL of 5M triangles": S(
            "box = [0.2, 0.2, 0.02]", 'mesh = "{tmp}/huge.stl"', "objects[0].mesh", "5000000 faces (at most 2000000)"
        ),
        "PLY header of 3M faces": S(
            "box = [0.2, 0.2, 0.02]", 'mesh = "{tmp}/huge.ply"', "objects[0].mesh", "3000000 faces (at most 2000000)"
        ),
        "mesh path longer than the file system allows": S(
            "box = [0.2, 0.2, 0.02]", 'mesh = "{tmp}/' + "m" * 300 + '.stl"', "objects[0].mesh", "File name too long"
        ),
        "mesh is a folder": S("box = [0.2, 0.2, 0.02]", 'mesh = "{tmp}"', "objects[0].mesh", "is a folder, not a file"),
        "open mesh refused before a later error": S(
            None,
            '[[objects]]\nname = "open"\nmesh = "{tmp}/open.ply"\nstiffness = 1.0\n'
            '[[objects]]\nname = "b"\nmesh = "{tmp}/missing.stl"\nstiffness = 1.0\n',
            "objects[1].mesh",
            "not closed",
        ),
        "MJCF missing": D('mjcf = "kraft.xml"', 'mjcf = "nowhere.xml"', "mjcf", "not found"),
        "MJCF not XML": D('mjcf = "kraft.xml"', 'mjcf = "calibration.toml"', "mjcf", "MuJoCo cannot load"),
        # Before, MuJoCo printed its warning on stdout and wrote MUJOCO_LOG.TXT in the working folder.
        "MJCF with a NaN": D(
            'mjcf = "kraft.xml"', 'mjcf = "{tmp}/nan.xml"', "mjcf", "MuJoCo warns: XML contains a 'NaN'"
        ),
        "calibration file missing": D(
            'calibration = "calibration.toml"', 'calibration = "none.toml"', "calibration", "not found"
        ),
    },
}

ALL = [(cls, name, case) for cls, cases in CASES.items() for name, case in cases.items()]


def write_meshes(folder: Path) -> None:
    """The bad meshes and model the table refers to as ``{tmp}/...``."""
    (folder / "junk.stl").write_bytes(b"\x00\x01 not a mesh")
    (folder / "empty.stl").write_bytes(b"")
    with (folder / "huge.stl").open("wb") as fh:  # sparse: 250 MB long, no disk used
        fh.write(b"\0" * 80 + (5_000_000).to_bytes(4, "little"))
        fh.truncate(84 + 50 * 5_000_000)
    (folder / "huge.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        b"property float z\nelement face 3000000\nproperty list uchar int vertex_indices\nend_header\n"
    )
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]], process=False)
    flat.export(folder / "flat.ply")
    (folder / "nan.xml").write_text(
        '<mujoco><worldbody><body pos="0 0 NaN"><geom size="0.1"/></body></worldbody></mujoco>'
    )
    (folder / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 nan 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n")
    box = trimesh.creation.box(extents=(0.2, 0.2, 0.02))
    trimesh.Trimesh(box.vertices, box.faces[box.face_normals[:, 2] > -0.9]).export(folder / "open.ply")


def make_file(tmp_path: Path, case: Case) -> tuple[Path, Path]:
    """Write the malformed file; return (the file to check, the file the error must name)."""
    if case.kind == "scene":
        target = checked = tmp_path / "scene.toml"
        target.write_text(BASE_SCENE)
    elif case.kind == "session":
        target = checked = tmp_path / "session.toml"
        shutil.copy(SESSIONS_DIR / "probe_rate.toml", target)
    else:
        shutil.copytree(DEVICES_DIR / "kraft", tmp_path / "kraft")
        checked = tmp_path / "kraft" / "device.toml"
        target = checked if case.kind == "device" else tmp_path / "kraft" / "calibration.toml"
    data = target.read_bytes()
    new = case.new if isinstance(case.new, bytes) else case.new.replace("{tmp}", str(tmp_path)).encode()
    if case.old is None:
        data += b"\n" + new
    elif case.old == "":
        data = new + data
    else:
        old = case.old.encode()
        assert data.count(old) == 1, f"{case.old!r} occurs {data.count(old)} times in the base {case.kind} file"
        data = data.replace(old, new)
    target.write_bytes(data)
    if "{tmp}" in str(case.new):
        write_meshes(tmp_path)
    return checked, target


def test_the_table_covers_every_class_of_the_issue() -> None:
    sizes = {cls: len(cases) for cls, cases in CASES.items()}
    assert all(n >= 7 for n in sizes.values()), sizes
    assert len(ALL) >= 100


@pytest.mark.parametrize(("cls", "name", "case"), ALL, ids=[f"{c}: {n}" for c, n, _ in ALL])
def test_malformed_file_is_refused_in_one_line_naming_file_and_field(
    tmp_path: Path, cls: str, name: str, case: Case
) -> None:
    checked, source = make_file(tmp_path, case)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(ConfigError) as info:
            check_file(str(checked))
    err = info.value
    assert [str(w.message) for w in caught] == []
    assert (err.source, err.field) == (str(source), case.field), str(err)
    assert case.reason in err.reason, str(err)
    assert "\n" not in str(err)
    assert str(err).startswith(f"{source}: field '{case.field}': ")


def test_the_base_files_pass(tmp_path: Path) -> None:
    """The table's base files are valid, so each case fails for its own change only."""
    for kind in ("scene", "session", "device"):
        folder = tmp_path / kind
        folder.mkdir()
        checked, _ = make_file(folder, Case(kind, "", "", ""))
        assert check_file(str(checked)).startswith(kind)


@pytest.mark.parametrize("kind", ["scene", "session", "device", "calibration"])
def test_a_file_saved_with_a_utf8_byte_order_mark_reads_as_without_it(tmp_path: Path, kind: str) -> None:
    """Windows editors (Notepad) may save UTF-8 with a byte-order mark. It was refused as 'not valid
    TOML: Invalid statement (at line 1, column 1)', a character nobody sees; now skipped (a UTF-16
    file is still refused as not UTF-8: the table)."""
    checked, target = make_file(tmp_path, Case(kind, "", "\ufeff", ""))
    assert target.read_bytes().startswith(codecs.BOM_UTF8)
    assert load_toml(target) == tomllib.loads(target.read_bytes()[len(codecs.BOM_UTF8) :].decode())
    assert check_file(str(checked)).startswith("device" if kind == "calibration" else kind)


def test_an_open_mesh_is_refused_naming_its_field(tmp_path: Path) -> None:
    """Contact needs an inside (issue 12): an open mesh is refused at load, not warned about."""
    checked, _ = make_file(tmp_path, S("box = [0.2, 0.2, 0.02]", 'mesh = "{tmp}/open.ply"', ""))
    with pytest.raises(ConfigError, match=r"objects\[0\]\.mesh.*not closed"):
        check_file(str(checked))


CLI_CASES = [
    ("encoding", "scene latin-1 byte"),
    ("resource exhaustion", "capsule spacing 1e-12"),
    ("resource exhaustion", "dotted key of 100000 parts"),
    ("resource exhaustion", "5000-digit integer"),
    ("inf, NaN, huge or tiny", "tool mass 1e-300"),
    ("inf, NaN, huge or tiny", "stiffness 1e300"),
    ("unknown key", "plant"),
    ("bad mesh or model", "open mesh refused before a later error"),
    ("bad mesh or model", "MJCF with a NaN"),
]


@pytest.mark.parametrize(("cls", "name"), CLI_CASES)
def test_command_line_prints_one_line_and_exits_2(tmp_path: Path, cls: str, name: str) -> None:
    case = CASES[cls][name]
    checked, source = make_file(tmp_path, case)
    commands = [["check", str(checked)]]
    if case.kind == "session":
        commands.append(["run", str(checked), "--out", str(tmp_path / "out")])
    for args in commands:
        res = subprocess.run(
            [sys.executable, "-m", "app.cli", *args], capture_output=True, text=True, timeout=300, check=False
        )
        assert res.returncode == 2, res.stderr
        assert res.stdout == ""
        assert res.stderr.count("\n") == 1, res.stderr
        assert res.stderr.startswith(f"error: {source}: field '{case.field}': ")
    assert not (tmp_path / "out").exists()
    assert not (Path.cwd() / "MUJOCO_LOG.TXT").exists()


def verbose_entry(cls: type, table: str, t: float) -> str:
    """One entry of a session script in the most verbose form a program writes: its own
    ``[[table]]``, every field on its own CRLF line, numbers at 17 significant digits, every switch
    given."""
    hints = typing.get_type_hints(cls, include_extras=True)
    number = "-1.2345678901234567e-300"  # in every range, and as long as a float64 gets
    lines = [f"[[{table}]]", f"t = {t:.16e}"]
    for f in dataclasses.fields(cls):
        tp = (
            typing.get_args(hints[f.name])[0] if typing.get_origin(hints[f.name]) is typing.Annotated else hints[f.name]
        )
        if f.name == "t":
            continue
        if typing.get_origin(tp) is tuple:
            lines.append(f"{f.name} = [{', '.join([number] * len(typing.get_args(tp)))}]")
        else:
            assert tp == bool | None, tp  # a new kind of field: give it its longest form here
            lines.append(f"{f.name} = false")
    return "".join(line + "\r\n" for line in lines)


def test_a_session_script_at_its_entry_limits_fits_the_file_limit_in_the_most_verbose_form(tmp_path: Path) -> None:
    """The documented most waypoints and events load in any form (before, 100,000 of each fitted
    only inline with short numbers: the 4 MiB limit refused about 19,000 verbose waypoints), and
    one waypoint more is refused in one line naming the field."""
    n = MAX_SCRIPT_ENTRIES
    head = 'scene = "probe"\r\ndevice = "touch3"\r\nduration = 1.0\r\n'
    waypoints = [verbose_entry(Waypoint, "waypoints", (i + 1) * 1e-290) for i in range(n)]
    events = [verbose_entry(SwitchEvent, "events", 0.0) for _ in range(n)]
    path = tmp_path / "long.toml"
    path.write_text(head + "".join(waypoints) + "".join(events), newline="")
    assert path.stat().st_size <= MAX_FILE_BYTES
    session = load_session(path)
    assert (len(session.data.waypoints), len(session.data.events)) == (n, n)
    path.write_text(head + "".join(waypoints) + verbose_entry(Waypoint, "waypoints", 1.0), newline="")
    with pytest.raises(ConfigError, match=rf"field 'waypoints': .*{n}") as err:
        load_session(path)
    assert "\n" not in str(err.value)


def test_check_of_a_folder_that_is_not_a_devices_says_so(tmp_path: Path) -> None:
    """``frhc check some/folder`` (no device.toml in it) said 'no such file, device, scene, session
    or sweep' of a folder that is there; a missing name still says that."""
    (tmp_path / "scenes").mkdir()
    with pytest.raises(ConfigError, match=r"scenes: field '<file>': a folder with no device.toml$"):
        check_file(str(tmp_path / "scenes"))
    with pytest.raises(ConfigError, match=r"field '<file>': no such file, device, scene, session or sweep$"):
        check_file(str(tmp_path / "nothing"))


def test_a_referenced_file_that_is_a_device_node_is_named_so_not_missing(tmp_path: Path) -> None:
    """A scene's mesh that is not a regular file (``/dev/null``; a folder: the table's 'mesh is a
    folder') was 'mesh file not found': it is there. The same check (``require_file``) serves an
    MJCF, a calibration and a named file."""
    scene = (SCENES_DIR / "probe.toml").read_text()
    scene = scene.replace("plane = [0.3, 0.3]", 'mesh = "/dev/null" #').replace("plane_thickness = 0.02\n", "")
    path = tmp_path / "scene.toml"
    path.write_text(scene)
    with pytest.raises(ConfigError) as err:
        check_file(str(path))
    assert str(err.value) == f"{path}: field 'objects[0].mesh': /dev/null is not a regular file"
