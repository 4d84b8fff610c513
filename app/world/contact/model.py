"""The Python face of the contact model: :class:`ContactModel`, :class:`ContactResult`,
:func:`contact_wrench`. The model itself is described in :mod:`app.world.contact`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypeVar

import numpy as np

from app.compiled import F8, entry_point
from app.errors import ContactInputError
from app.spatial import Array, IntArray, invert_pose
from app.world.contact import layout
from app.world.contact.bundle import bundle
from app.world.contact.step import contact_step_bundled
from app.world.scene import Scene

ArrayT = TypeVar("ArrayT", Array, IntArray)

# Candidate triangles cached per pair at most; more within a sphere's reach is an error
# (ERR_OVERFLOW): the mesh is far finer than the sphere.
CACHE_MAX = 4096
_INVALID = {
    layout.ERR_POSE: "non-finite tool pose",
    layout.ERR_TWIST: "non-finite tool twist",
    layout.ERR_WRENCH: "non-finite contact wrench",
    layout.ERR_OVERFLOW: f"more than {CACHE_MAX} candidate triangles within a sphere's reach (mesh far finer than the tool)",
}
_SHAPE_T = (4, 4)
_SHAPE_V = (6,)
# Contact counts below which a result's rows are copied from views made once.
_FIRST_VIEWS = 32


def _frozen(a: ArrayT) -> ArrayT:
    a.flags.writeable = False
    return a


# The empty per-contact arrays of a result without contacts, shared (read-only): building them
# anew was a good part of the cost of a free-space evaluation.
_NO_CONTACTS = _frozen(np.zeros((0, 9)))


@dataclass(slots=True)
class ContactResult:
    """The contact state of the tool at one pose (treat as read-only).

    Not frozen, and the arrays are views made on access of two blocks copied once (``w``,
    ``contacts``): it is built every servo substep, where a frozen dataclass's ``__init__`` or
    a copy per array cost microseconds.

    Attributes:
        valid: False when the pose, twist or result was non-finite (or the mesh too fine for the
            cache); the wrenches are then 0.
        w: ``wrench_S``, ``wrench_MRF`` and ``force_w`` (see those properties), (15,).
        contacts: Per contact: point on the object surface (m, {w}), outward object normal
            (unit, {w}: the direction of the normal force on the tool), effective depth (m: the
            elastic force is stiffness * depth), tool sphere and object (index into
            ``scene.objects``), (k, 9); read them as the properties ``points_w``,
            ``normals_w``, ``depths``, ``sphere_ids``, ``object_ids``.
        queries: Number of (sphere, object) pair evaluations (culling diagnostics).
        gathers: How many of them refilled the pair's candidate cache from the grid.
        error: Why the result is invalid, or ``None``.
    """

    valid: bool
    w: Array
    contacts: Array = field(default_factory=lambda: _NO_CONTACTS)
    queries: int = 0
    gathers: int = 0
    error: str | None = None

    @property
    def wrench_S(self) -> Array:
        """Contact wrench ``[f; m]`` (N, N m) on the tool at the {S} origin in {S}, (6,)."""
        return self.w[0:6]

    @property
    def wrench_MRF(self) -> Array:
        """The same wrench at the {MRF} origin in {MRF} (Eq 6), (6,)."""
        return self.w[6:12]

    @property
    def force_w(self) -> Array:
        """Total contact force on the tool in {w} (N), (3,)."""
        return self.w[12:15]

    @property
    def count(self) -> int:
        """Number of contacts (a sphere may touch an object at several places)."""
        return len(self.contacts)

    @property
    def points_w(self) -> Array:
        """Contact points on the object surfaces in {w} (m), (k, 3)."""
        return self.contacts[:, 0:3]

    @property
    def normals_w(self) -> Array:
        """Outward object normals at the contact points in {w} (unit), (k, 3)."""
        return self.contacts[:, 3:6]

    @property
    def depths(self) -> Array:
        """Effective penetration depths (m), (k,): the elastic force is stiffness * depth."""
        return self.contacts[:, 6]

    @property
    def sphere_ids(self) -> IntArray:
        """Index of the tool sphere of each contact, (k,)."""
        return self.contacts[:, 7].astype(np.int64)

    @property
    def object_ids(self) -> IntArray:
        """Index (into ``scene.objects``) of the object of each contact, (k,)."""
        return self.contacts[:, 8].astype(np.int64)


class ContactModel:
    """Contact wrench of the scene's tool against its objects, with per-pair memory.

    Stateful (remembered surfaces, culling state, candidate caches): use one instance per
    simulated tool and call :meth:`reset` when the tool jumps. :func:`contact_wrench` is the
    stateless convenience.

    Args:
        scene: The loaded scene.
        margin: Extra distance (m) kept in the culling tests (0 is exact; the default is the
            scene's ``margin``).
    """

    def __init__(self, scene: Scene, margin: float | None = None) -> None:
        self.scene = scene
        tool = scene.tool
        geo = scene.packed
        n, m = len(tool.radii), len(scene.objects)
        margin = scene.spec.margin if margin is None else margin
        # Bounding sphere of the tool: centre c0 in {T}, radius of the centres and of the spheres.
        c0_T = tool.centers_T.mean(axis=0)
        spread = np.linalg.norm(tool.centers_T - c0_T, axis=1)
        T_MRF_S = tool.T_MRF_S
        self._tool = t = np.zeros(1, dtype=layout.TOOL)
        t["c0"], t["rho"], t["reach"], t["margin"] = c0_T, spread.max(), np.max(spread + tool.radii) + margin, margin
        t["r_min"] = tool.radii.min()
        t["T_MRF_T"] = invert_pose(tool.T_T_MRF)
        t["p_MRF_S"], t["R_MRF_S"] = T_MRF_S[0:3, 3], T_MRF_S[0:3, 0:3]
        self._objs = objs = geo.objs.copy()
        for j, o in enumerate(scene.objects):
            objs[j]["k"], objs[j]["b"], objs[j]["mu"] = o.stiffness, o.damping, o.friction
        self._pairs = np.zeros(m * n, dtype=layout.PAIR)
        self._pairs["c_T"] = np.tile(tool.centers_T, (m, 1))  # pair k = object k // n, sphere k % n
        self._pairs["r"] = np.tile(tool.radii, m)
        # Untouched rows of np.empty cost no memory: only pairs that gather ever touch theirs.
        self._pool = np.empty((m * n, CACHE_MAX), dtype=layout.CANDIDATE)
        self._out = out = np.zeros(max(1, m * n * layout.MAX_PER_PAIR), dtype=layout.CONTACT)
        # Views of the outputs, made once: reading fields of record arrays costs microseconds.
        self._out_w = t["out"][0]
        self._counts = t["counts"][0]
        # The contact records as rows of 9 floats (p, n, depth, sphere, object): one contiguous
        # copy per result instead of one strided copy per field.
        assert layout.CONTACT.itemsize == 72
        self._out_f = out_f = out.view(np.float64).reshape(len(out), 9)
        # Its first k rows for the usual counts, as views made once: slicing costs more than
        # copying a few rows.
        self._first = [out_f[:k] for k in range(min(len(out_f), _FIRST_VIEWS) + 1)]
        self._no_twist = np.zeros(6)
        # Gather scratch: which triangles the current gather has seen, then its vertex-cone
        # tests (F + V,).
        stamp = np.zeros(len(geo.tris) + len(geo.verts), dtype=np.int64)
        # The kernel's arguments after the pose and twist, bound once (a compiled caller that
        # evaluates several models in one call, :mod:`app.world.dynamics`, passes them itself).
        self.arrays = bundle(
            self._tool, objs, self._pairs, self._pool, out, geo.verts, geo.tris, geo.edges, geo.cells, geo.lists, stamp
        )
        # ``wrench`` checks the pose and twist (C-contiguous float64 of their shapes) and passes
        # the model's own arrays, bundled as one argument, for the rest, so the compiled step is
        # called without numba's typing of its arguments (~1.5 us a call) and unboxes one object
        # instead of eleven arrays (~0.45 us).
        self._step = entry_point(contact_step_bundled, np.eye(4), np.zeros(6), False, self.arrays)
        self.reset()

    def reset(self) -> None:
        """Forget the remembered surfaces, culling state and caches (e.g. after the tool was teleported)."""
        self._pairs["mem"] = 0
        self._pairs["fresh"] = 1
        self.forget_caches()

    def forget_caches(self) -> None:
        """Forget culling state and candidate caches but keep the remembered surfaces: the next
        evaluation is computed from scratch with the same history (a check of the culling's
        exactness)."""
        p = self._pairs
        p["last"] = np.inf
        p["slack"] = -1.0
        p["hot"] = 0
        p["cache_n"] = -1
        p["near_t"] = -1
        self._objs["slack"] = -1.0
        self._objs["near"] = 0
        self._tool["near_slack"] = -1.0

    @property
    def remembered(self) -> int:
        """Number of (sphere, object) pairs holding a remembered surface (:mod:`.track`)."""
        return int(self._pairs["mem"].sum())

    def wrench(self, T_w_MRF: Array, V_w_MRF: Array | None = None) -> ContactResult:
        """Contact wrench of the tool with {MRF} at ``T_w_MRF``.

        Args:
            T_w_MRF: Pose of {MRF} in {w}, (4, 4): a rigid transform (rotation orthonormal
                within 1e-6, determinant +1, last row ``[0, 0, 0, 1]``).
            V_w_MRF: Optional twist ``[v; w]`` (m/s, rad/s) of {MRF} in {w} coordinates (v of the
                {MRF} origin), shape (6,). Needed for contact damping and friction; without it
                the wrench is the elastic part only.

        Returns:
            A :class:`ContactResult`; ``valid`` is False (zero wrench) for a non-finite pose or
            twist, which a servo loop may meet and must survive.

        Raises:
            ContactInputError: The pose or twist has the wrong shape or type, or the pose is not
                a rigid transform (a reflection, a scaled or sheared rotation): misuse, not data.
        """
        if not (
            T_w_MRF.__class__ is np.ndarray
            and T_w_MRF.dtype is F8
            and T_w_MRF.flags.c_contiguous
            and T_w_MRF.shape == _SHAPE_T
            and (
                V_w_MRF is None
                or (
                    V_w_MRF.__class__ is np.ndarray
                    and V_w_MRF.dtype is F8
                    and V_w_MRF.flags.c_contiguous
                    and V_w_MRF.shape == _SHAPE_V
                )
            )
        ):
            T_w_MRF, V_w_MRF = contact_inputs(T_w_MRF, V_w_MRF)
        if V_w_MRF is None:
            code = self._step(T_w_MRF, self._no_twist, False, self.arrays)
        else:
            code = self._step(T_w_MRF, V_w_MRF, True, self.arrays)
        if code < 0:
            self.reset()
            return failed(code)
        w = self._out_w.copy()
        queries, gathers = self._counts.tolist()
        if code == 0:
            # Every field positional: the default factories cost microseconds on this path.
            return ContactResult(True, w, _NO_CONTACTS, queries, gathers, None)
        rows = self._first[code] if code < _FIRST_VIEWS else self._out_f[:code]
        return ContactResult(True, w, rows.copy(), queries, gathers, None)


def _as_array(x: object, name: str) -> Array:
    """``x`` as a C-contiguous float64 array, or a :class:`ContactInputError` naming the argument."""
    try:
        a = np.asarray(x)
    except (TypeError, ValueError) as exc:
        raise ContactInputError(f"{name} must be an array of numbers: {exc}") from None
    if a.dtype.kind not in "iuf":  # complex, bool, object, strings: not a pose
        raise ContactInputError(f"{name} must be an array of real numbers, got dtype {a.dtype}")
    return np.ascontiguousarray(a, dtype=float)


def contact_inputs(T_w_MRF: object, V_w_MRF: object | None) -> tuple[Array, Array | None]:
    """The pose (4, 4) and optional twist (6,) of :meth:`ContactModel.wrench` as C-contiguous
    float64 arrays (what the compiled step may be handed), or a :class:`ContactInputError`."""
    T = _as_array(T_w_MRF, "T_w_MRF")
    if T.shape != _SHAPE_T:
        raise ContactInputError(f"T_w_MRF must have shape (4, 4), got {T.shape}")
    if V_w_MRF is None:
        return T, None
    V = _as_array(V_w_MRF, "V_w_MRF")
    if V.shape != _SHAPE_V:
        raise ContactInputError(f"V_w_MRF must have shape (6,), got {V.shape}")
    return T, V


def failed(code: int) -> ContactResult:
    """The invalid result of the compiled step's error ``code`` (< 0); raises
    :class:`ContactInputError` for a pose that is not a rigid transform (misuse, not data). The
    caller resets the model that failed."""
    if code == layout.ERR_ROTATION:
        raise ContactInputError(
            "T_w_MRF is not a rigid transform (rotation not orthonormal within 1e-6, a reflection, "
            "or last row not [0, 0, 0, 1])"
        )
    return ContactResult(False, np.zeros(15), error=_INVALID[code])


def contact_wrench(scene: Scene, T_w_MRF: Array, V_w_MRF: Array | None = None) -> ContactResult:
    """Stateless contact wrench of ``scene``'s tool at ``T_w_MRF`` (4, 4); see :meth:`ContactModel.wrench`.

    Builds a fresh :class:`ContactModel` on each call, so nothing is remembered: a centre more
    than r inside a solid is pushed out of its nearest surface, which past the middle of a thin
    part is the far one. For a sequence of poses (a push, a stroke) keep one model.
    """
    return ContactModel(scene).wrench(T_w_MRF, V_w_MRF)
