"""contact_wrench at its boundary: arbitrary shapes, dtypes and values give a valid finite result,
an invalid (flagged, zero) one, or the project's ContactInputError, never anything else."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from app.errors import ContactInputError
from app.spatial import make_pose, zyx_to_matrix
from app.world import ContactModel
from app.world.scene import load_scene

DTYPES = st.sampled_from([np.float64, np.float32, np.int64, np.int8, np.bool_, np.complex128])
SHAPES = st.sampled_from([(4, 4), (3, 3), (4,), (16,), (4, 4, 1), (6,), ()])


@pytest.fixture(scope="module")
def model() -> ContactModel:
    return ContactModel(load_scene("probe"))


@st.composite
def poses(draw: st.DrawFn) -> object:
    kind = draw(st.sampled_from(["rigid", "any"]))
    if kind == "rigid":
        angles = draw(st.tuples(*(st.floats(-3.2, 3.2),) * 3))
        position = draw(hnp.arrays(np.float64, 3, elements=st.floats(-0.2, 0.2)))
        return make_pose(zyx_to_matrix(*angles), position)
    dtype = draw(DTYPES)
    elements = (
        st.booleans() if dtype == np.bool_ else hnp.from_dtype(np.dtype(dtype), allow_nan=True, allow_infinity=True)
    )
    return draw(hnp.arrays(dtype, draw(SHAPES), elements=elements))


@settings(max_examples=120, deadline=None)
@given(pose=poses(), twist=st.one_of(st.none(), hnp.arrays(np.float64, st.sampled_from([(6,), (3,)]))))
def test_any_pose_is_answered_or_refused_with_the_projects_error(model: ContactModel, pose, twist) -> None:
    try:
        result = model.wrench(pose, twist)
    except ContactInputError:
        return
    finite = np.all(np.isfinite(result.wrench_S)) and np.all(np.isfinite(result.wrench_MRF))
    assert finite  # an invalid result carries a zero wrench, never NaN
    if not result.valid:
        np.testing.assert_array_equal(result.wrench_S, 0.0)
    model.reset()


def test_complex_and_boolean_poses_are_refused(model: ContactModel) -> None:
    for pose in (np.eye(4, dtype=complex), np.eye(4, dtype=bool)):
        with pytest.raises(ContactInputError, match="real numbers"):
            model.wrench(pose)


def test_a_mirrored_pose_is_refused(model: ContactModel) -> None:
    mirrored = make_pose(np.diag([1.0, 1.0, -1.0]), np.array([0.0, 0.0, 0.004]))
    with pytest.raises(ContactInputError):
        model.wrench(mirrored)
