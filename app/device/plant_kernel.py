"""One plant period, compiled: motor stage, MuJoCo physics and encoders in a single call.

:meth:`~app.device.plant.DevicePlant.step` used to spend more time crossing between Python,
numpy and the MuJoCo bindings than in the physics; here the whole period is one numba call
that runs MuJoCo's ``mj_step2``/``mj_step1`` through :mod:`app.mjcall`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from app.mjcall import call_model_data
from app.spatial import Array, IntArray


@njit(cache=True)
def plant_period(
    mj: IntArray,
    substeps: int,
    counts: IntArray,
    counts_max: int,
    table: Array,
    row_offset: IntArray,
    tau_joint: Array,
    encoders: Array,
    q_true: Array,
    q: Array,
    unstable: IntArray,
) -> bool:
    """Advance the device one servo period and read its encoders; False if the physics went unstable.

    Args:
        mj: ``[mj_step1 address, mj_step2 address, mjModel*, mjData*]`` (:mod:`app.mjcall`), (4,).
        substeps: Physics steps in the period (the model's timestep is period / substeps).
        counts: Motor commands (counts), (n,), or an empty array: no new counts, the joint
            torques in ``tau_joint`` are held (the amplifier's last output, or zero after its
            watchdog switched the motors off).
        counts_max: Full-scale count; commands clip to ``+-counts_max`` as the amplifier's do.
        table: The true motor curve times gear ratio, clipped to the joint limits (N m), one row
            of ``2 counts_max + 1`` entries per joint, flattened.
        row_offset: Index in ``table`` of each joint's zero count, (n,).
        tau_joint: Output, the joint torques held over the period (N m), (n,): MuJoCo's
            ``qfrc_applied`` for the joints.
        encoders: ``[scale (n,); inverse (n,)]`` counts per rad (or per m) and its inverse; all
            zero scales mean no quantisation, (2 n,).
        q_true: The joints' ``qpos`` (rad; m for slides), (n,).
        q: Output, encoder angles ``round(q_true * scale) / scale``, (n,); left as it was when
            the period went unstable.
        unstable: MuJoCo's counts of bad joint positions, velocities and accelerations (a view
            of ``mjData.warning``), (3,). On one, MuJoCo resets the device to the model's zero
            angles and steps on: the encoders would read a jump that no joint made, so they are
            not read, and the torques are zeroed.
    """
    n = q.shape[0]
    for j in range(counts.shape[0]):
        c = min(max(counts[j], -counts_max), counts_max)
        tau_joint[j] = table[row_offset[j] + c]
    # step2 then step1: the kinematics left in data always belong to the new state.
    for _ in range(substeps):
        call_model_data(mj[1], mj[2], mj[3])
        call_model_data(mj[0], mj[2], mj[3])
    if unstable[0] + unstable[1] + unstable[2] > 0:
        for j in range(tau_joint.shape[0]):
            tau_joint[j] = 0.0
        return False
    for j in range(n):
        scale = encoders[j]
        q[j] = np.rint(q_true[j] * scale) * encoders[n + j] if scale > 0.0 else q_true[j]
    return True
