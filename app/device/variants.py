"""Device variants: copies of a shipped device whose simulated hardware differs in one or a few ways.

Tests and ``frhc bench stability`` use them as inputs a passivity layer was not tuned on: a
variant is an ordinary device folder (file, MJCF, calibration) written to a folder of the
caller's, with some ``[plant]`` / ``[motors]`` lines of ``device.toml`` rewritten. The plant and
the device-file schema are not touched: a variant is loaded by :func:`~app.device.spec.load_device`
like any device, so every field keeps its checked range.

What a variant can change (each left at ``None``/1 keeps the shipped value):

- ``encoder_bits``: every joint's encoder resolves ``2**bits`` counts per revolution (10-20 bits
  spans cheap incremental encoders to interpolated optical ones; the shipped devices use 13-14).
- ``damping_scale``: factor on every joint's viscous damping (``plant.damping``).
- ``armature``: reflected rotor inertia added to every joint (kg m^2, ``plant.armature``).
- ``friction``: ``False`` removes the Coulomb friction (``plant.frictionloss`` = 0).
- ``mass_scale``: factor on every link's mass and rotational inertia in the device's MJCF: a
  heavier device its file describes, so the controller's gravity compensation (from the nominal
  model) carries the added weight; the plant's few-percent mismatch (``plant.mass_scale``) stays
  as shipped. Scaling ``plant.mass_scale`` instead would make the device's model wrong by the whole
  factor: the heavy Kraft then sags 23 mm onto the surface under 6 N of uncompensated weight
  before the hand pushes, and every renderer pushes the slave to its limit (measured: issue 26).
- ``gear_scale``: factor on every gear ratio (``motors.gear_ratio``): the same motors through
  another reduction, so the joint torque limit scales with it.
"""

from __future__ import annotations

import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

from app.config import Checked, Range
from app.device.spec import load_device, resolve_device_path


@dataclass(frozen=True)
class DeviceVariant(Checked):
    """How a variant's hardware differs from the device it copies (see the module docstring).

    Attributes:
        label: Short name (a folder name: letters, digits, ``_``, ``.``, ``-``).
        encoder_bits: Encoder resolution of every joint (bits per revolution); None = as shipped.
        damping_scale: Factor on the joints' viscous damping (-).
        armature: Rotor inertia added to every joint (kg m^2; kg for slides).
        friction: Keep the joints' Coulomb friction (``False`` = none).
        mass_scale: Factor on every link's mass and rotational inertia in the MJCF (-).
        gear_scale: Factor on every gear ratio (-).
    """

    label: str
    encoder_bits: Annotated[int, Range(8, 24)] | None = None
    damping_scale: Annotated[float, Range(0.0, 100.0)] = 1.0
    armature: Annotated[float, Range(0.0, 1.0, "kg m^2")] = 0.0
    friction: bool = True
    mass_scale: Annotated[float, Range(0.1, 10.0, lo_open=True)] = 1.0
    gear_scale: Annotated[float, Range(0.1, 10.0, lo_open=True)] = 1.0


#: The variants the bench and the tests run (none of them was used to choose a passivity setting).
VARIANTS = (
    DeviceVariant("enc10", encoder_bits=10),
    DeviceVariant("enc12", encoder_bits=12),
    DeviceVariant("enc16", encoder_bits=16),
    DeviceVariant("enc20", encoder_bits=20),
    DeviceVariant("damp0.5", damping_scale=0.5),
    DeviceVariant("damp2", damping_scale=2.0),
    DeviceVariant("arm0.002", armature=0.002),
    DeviceVariant("nofric", friction=False),
    DeviceVariant("heavy2", mass_scale=2.0),
    DeviceVariant("gear0.5", gear_scale=0.5),
)


def _rewrite(text: str, key: str, values: list[float] | list[int]) -> str:
    """``text`` with the line ``key = [...]`` (its first occurrence) replaced by ``values``."""
    line = f"{key} = [{', '.join(repr(v) for v in values)}]"
    new, count = re.subn(rf"(?m)^{re.escape(key)} = \[[^\]]*\].*$", line, text, count=1)
    if count != 1:
        raise ValueError(f"device file has no '{key} = [...]' line to vary")
    return new


def _scale_inertials(mjcf: str, scale: float) -> str:
    """``mjcf`` (MJCF text) with every ``<inertial>``'s ``mass`` (kg) and ``diaginertia`` (kg m^2)
    multiplied by ``scale``; the centres of mass stay."""

    def values(match: re.Match[str]) -> str:
        return f'{match.group(1)}="{" ".join(repr(float(v) * scale) for v in match.group(2).split())}"'

    def inertial(match: re.Match[str]) -> str:
        return re.sub(r'\b(mass|diaginertia)="([^"]*)"', values, match.group(0))

    new, count = re.subn(r"<inertial\b[^>]*>", inertial, mjcf)
    if count == 0:
        raise ValueError("device MJCF has no <inertial> to scale")
    return new


def write_variant(device: str | Path, variant: DeviceVariant, folder: Path) -> Path:
    """Copy ``device`` (a name or device file) into ``folder`` as ``variant``; returns its ``device.toml``."""
    spec = load_device(device)
    source = resolve_device_path(device).parent
    target = folder / f"{spec.name}_{variant.label}"
    shutil.copytree(source, target)
    path = target / "device.toml"
    n, plant, motors = spec.n_joints, spec.data.plant, spec.data.motors
    text = path.read_text()
    if variant.encoder_bits is not None:
        text = _rewrite(text, "encoder_counts_per_rev", [2**variant.encoder_bits] * n)
    if variant.damping_scale != 1.0:
        damping = plant.per_joint("damping", n) * variant.damping_scale
        text = _rewrite(text, "damping", [float(v) for v in damping])
    if variant.armature:
        armature = plant.per_joint("armature", n) + variant.armature
        text = _rewrite(text, "armature", [float(v) for v in armature])
    if not variant.friction:
        text = _rewrite(text, "frictionloss", [0.0] * n)
    if variant.mass_scale != 1.0:
        mjcf = target / spec.data.mjcf
        mjcf.write_text(_scale_inertials(mjcf.read_text(), variant.mass_scale))
    if variant.gear_scale != 1.0:
        text = _rewrite(text, "gear_ratio", [g * variant.gear_scale for g in motors.gear_ratio])
    path.write_text(text)
    load_device(path)  # the variant is a valid device file
    return path
