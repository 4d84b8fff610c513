"""Device variants (app.device.variants): each writes a loadable device file with the asked-for change."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from app.device.spec import load_device
from app.device.variants import VARIANTS, DeviceVariant, write_variant
from app.errors import InvalidField


@pytest.mark.parametrize("device", ["kraft", "freflex"])
def test_every_variant_changes_only_what_it_names(device: str, tmp_path: Path) -> None:
    shipped = load_device(device)
    n, plant = shipped.n_joints, shipped.data.plant
    for variant in VARIANTS:
        v = load_device(write_variant(device, variant, tmp_path))
        vp = v.data.plant
        bits = variant.encoder_bits
        expected_cpr = [2**bits] * n if bits is not None else list(plant.encoder_counts_per_rev)
        assert list(vp.encoder_counts_per_rev) == expected_cpr
        np.testing.assert_allclose(vp.per_joint("damping", n), plant.per_joint("damping", n) * variant.damping_scale)
        np.testing.assert_allclose(vp.per_joint("armature", n), plant.per_joint("armature", n) + variant.armature)
        friction = plant.per_joint("frictionloss", n) if variant.friction else np.zeros(n)
        np.testing.assert_allclose(vp.per_joint("frictionloss", n), friction)
        # Heavier links are in the model the controller knows (its MJCF); the plant's mismatch stays.
        np.testing.assert_allclose(vp.per_joint("mass_scale", n), plant.per_joint("mass_scale", n))
        np.testing.assert_allclose(v.model.body_mass, shipped.model.body_mass * variant.mass_scale)
        np.testing.assert_allclose(v.model.body_inertia, shipped.model.body_inertia * variant.mass_scale)
        np.testing.assert_allclose(v.model.body_ipos, shipped.model.body_ipos)
        np.testing.assert_allclose(
            v.data.motors.gear_ratio, np.array(shipped.data.motors.gear_ratio) * variant.gear_scale
        )
        # Everything else is the shipped device's.
        assert v.data.motors.torque_limit == shipped.data.motors.torque_limit
        assert vp.motor_deadzone == plant.motor_deadzone


def test_a_10_bit_variant_steps_one_1024th_of_a_turn(tmp_path: Path) -> None:
    v = load_device(write_variant("jpl", DeviceVariant("enc10", encoder_bits=10), tmp_path))
    np.testing.assert_allclose(v.encoder_step, 2.0 * math.pi / 1024)


def test_a_variant_outside_its_ranges_is_refused_naming_the_field() -> None:
    with pytest.raises(InvalidField) as exc:
        DeviceVariant("x", encoder_bits=30)
    assert exc.value.field == "encoder_bits"
