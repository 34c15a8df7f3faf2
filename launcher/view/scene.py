"""The 3D scene of one arm for ``jara-arm view``: its links from its URDF, and what is around them.

:class:`RobotGeometry` reads a robot model's URDF with Pinocchio (its visual
geometry: meshes and primitives, and their placements) and gives the pose of
every visual shape in the arm frame for a wire ``JointPos``; it knows nothing
of the browser. :class:`ArmScene` draws one arm in a viser scene under a node
of its own (the arm's world): the links, the obstacles, the Cartesian
soft-limit box (in the robot frame, the base offset away from the arm frame),
the control point frame, the robot frame and the path of the running motion.

Frames (kinematics/frames.py): the world of the simulation holds the obstacles;
the arm frame (the URDF root) sits at ``basePosition`` in it; the robot frame
is ``baseOffset`` seen from the arm frame; the control point is the flange
times ``controlPointOffset``.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
from collections.abc import Sequence
from pathlib import Path
from typing import cast

import numpy as np
import numpy.typing as npt
import pinocchio as pin
import trimesh
import viser

from jara_arm.kinematics import hg_to_se3
from jara_arm.robots import RobotModel
from jara_arm.schema.messages import ServoWorld, WorldBox
from jara_arm.schema.planner import MotionSettings

Rgb = tuple[int, int, int]

#: Half the side of a soft-limit box edge drawn where a limit is unbounded (or absurdly far) [m].
FAR = 3.0
OBSTACLE_COLOR: Rgb = (200, 60, 60)
LIMIT_COLOR: Rgb = (240, 160, 0)
PATH_COLOR: Rgb = (0, 170, 255)
#: Links drawn in this colour while the arm is gone (its servo's token is down).
GONE_COLOR: Rgb = (120, 120, 120)


class ShapeKind(enum.Enum):
    BOX = "box"
    CYLINDER = "cylinder"
    SPHERE = "sphere"
    MESH = "mesh"


@dataclasses.dataclass(frozen=True)
class Shape:
    """One visual element of a link, as the URDF gives it."""

    name: str  # Pinocchio's geometry name: ``<link>_<i>``
    link: str  # the URDF link it belongs to
    kind: ShapeKind
    size: tuple[float, ...]  # [m] box: full x, y, z; cylinder: radius, length (along z); sphere: radius
    color: Rgb
    mesh: Path | None = None  # MESH: the file
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)  # MESH: per axis [-]


def _rgb(rgba: npt.ArrayLike) -> Rgb:
    r, g, b = (int(round(255 * min(1.0, max(0.0, float(c))))) for c in np.asarray(rgba)[:3])
    return (r, g, b) if (r, g, b) != (255, 255, 255) else (225, 225, 225)  # white: visible on white


def _shape(obj: pin.GeometryObject, link: str) -> Shape:
    geom = obj.geometry
    kind = type(geom).__name__
    color = _rgb(obj.meshColor)
    if kind == "Box":
        return Shape(obj.name, link, ShapeKind.BOX, tuple(2.0 * float(h) for h in geom.halfSide), color)
    if kind in ("Cylinder", "Capsule"):  # a capsule drawn as its cylinder: close enough for a view
        return Shape(obj.name, link, ShapeKind.CYLINDER, (float(geom.radius), 2.0 * float(geom.halfLength)), color)
    if kind == "Sphere":
        return Shape(obj.name, link, ShapeKind.SPHERE, (float(geom.radius),), color)
    if obj.meshPath:
        s = [float(v) for v in obj.meshScale]
        return Shape(obj.name, link, ShapeKind.MESH, (), color, Path(obj.meshPath), (s[0], s[1], s[2]))
    raise ValueError(f"{obj.name}: visual geometry {kind} is not drawn")


@functools.lru_cache(maxsize=64)
def _mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [m], faces) of a mesh file, loaded once per process."""
    mesh = cast(trimesh.Trimesh, trimesh.load(str(path), force="mesh"))  # force="mesh": one Trimesh
    return np.asarray(mesh.vertices, dtype=np.float32), np.asarray(mesh.faces, dtype=np.uint32)


class RobotGeometry:
    """The visual shapes of a robot model and their poses for given joints (Pinocchio, no browser)."""

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        urdf = str(model.urdf)
        self._pin, self._visual = pin.buildModelsFromUrdf(urdf, str(model.urdf.parent),
                                                           geometry_types=pin.GeometryType.VISUAL)
        self._data = self._pin.createData()
        self._gdata = pin.GeometryData(self._visual)
        frames = self._pin.frames
        self.shapes: tuple[Shape, ...] = tuple(_shape(g, frames[g.parentFrame].name)
                                               for g in self._visual.geometryObjects)
        self._flange = self._pin.getFrameId(model.flange_frame)
        # Wire axis k -> the (idx_q, nq) of the Pinocchio joints it drives (the gripper: every finger).
        self._axes: list[list[tuple[int, int]]] = [[self._slot(j)] for j in model.arm_joints]
        if model.has_gripper:
            self._axes.append([self._slot(j) for j in model.gripper_joints])
        self._q = pin.neutral(self._pin)

    def _slot(self, joint: str) -> tuple[int, int]:
        jm = self._pin.joints[self._pin.getJointId(joint)]
        return jm.idx_q, jm.nq

    @property
    def links(self) -> tuple[str, ...]:
        """The links that have a visual element, in the URDF's order."""
        return tuple(dict.fromkeys(s.link for s in self.shapes))

    def _configure(self, joints: Sequence[float]) -> None:
        if len(joints) != len(self._axes):
            raise ValueError(f"{self.model.name}: expected {len(self._axes)} joint values, got {len(joints)}")
        q = self._q
        for value, slots in zip(joints, self._axes):
            for idx, nq in slots:
                if nq == 2:  # a continuous joint: (cos, sin)
                    q[idx:idx + 2] = (np.cos(value), np.sin(value))
                else:
                    q[idx] = value
        pin.forwardKinematics(self._pin, self._data, q)
        pin.updateFramePlacements(self._pin, self._data)
        pin.updateGeometryPlacements(self._pin, self._data, self._visual, self._gdata)

    def poses(self, joints: Sequence[float]) -> tuple[pin.SE3, ...]:
        """Every shape's pose in the arm frame at the wire joints ``joints`` [rad or m]."""
        self._configure(joints)
        return tuple(pin.SE3(m) for m in self._gdata.oMg)

    def flange(self) -> pin.SE3:
        """The flange's pose in the arm frame at the joints of the last :meth:`poses`."""
        return pin.SE3(self._data.oMf[self._flange])


def wxyz(rotation: npt.ArrayLike) -> tuple[float, float, float, float]:
    """The unit quaternion (w, x, y, z) of a rotation matrix, as viser takes it."""
    x, y, z, w = pin.Quaternion(np.asarray(rotation, dtype=float)).coeffs()
    return float(w), float(x), float(y), float(z)


def limit_box(settings: MotionSettings) -> tuple[np.ndarray, np.ndarray]:
    """(centre, full size) [m] of the Cartesian soft-limit box in the robot frame; an unbounded
    side (or one farther than ``FAR``) is drawn at ``FAR``."""
    lower = np.array([max(-FAR, lim.lower) for lim in settings.softLimitCartesian], dtype=float)
    upper = np.array([min(FAR, lim.upper) for lim in settings.softLimitCartesian], dtype=float)
    return (lower + upper) / 2.0, np.maximum(upper - lower, 1e-3)


def box_edges(centre: npt.ArrayLike, size: npt.ArrayLike) -> np.ndarray:
    """(12, 2, 3) [m]: the edges of an axis-aligned box, for line segments."""
    c, h = np.asarray(centre, dtype=float), np.asarray(size, dtype=float) / 2.0
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float) * h + c
    pairs = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
    return np.array([[corners[i], corners[j]] for i, j in pairs])


class ArmScene:
    """One arm drawn under ``root`` (e.g. ``/arm0``) of a viser scene; call from one thread only."""

    def __init__(self, scene: viser.SceneApi, root: str, geometry: RobotGeometry,
                 offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        self.scene = scene
        self.root = root
        self.geometry = geometry
        model = geometry.model
        #: the arm's world, placed ``offset`` [m] from the others' in the page
        self._world = scene.add_frame(root, show_axes=False, position=offset)
        self._arm = scene.add_frame(f"{root}/arm", show_axes=True, axes_length=0.15, axes_radius=0.004,
                                    position=model.base_position)
        self._links: list[viser.SceneNodeHandle] = [
            self._add_shape(f"{root}/arm/links/{i}", s) for i, s in enumerate(geometry.shapes)]
        self._robot_frame = scene.add_frame(f"{root}/arm/robot", show_axes=True, axes_length=0.1,
                                            axes_radius=0.003)
        self._limits: viser.SceneNodeHandle | None = None
        self._limits_drawn: tuple[tuple[float, ...], tuple[float, ...]] | None = None  # (centre, size) [m]
        self._control_point = scene.add_frame(f"{root}/arm/control_point", axes_length=0.08, axes_radius=0.004)
        self._path: viser.SceneNodeHandle | None = None
        self._obstacles: list[viser.SceneNodeHandle] = []
        self._obstacles_drawn: tuple[WorldBox, ...] | None = None
        self._label = scene.add_label(f"{root}/label", root.strip("/"), position=(0.0, 0.0, -0.05),
                                      anchor="top-center")
        self._tool = pin.SE3.Identity()
        self._joints: tuple[float, ...] | None = None
        self._gone = False
        self._links_visible(False)  # until the first feedback says where they are

    def _add_shape(self, name: str, s: Shape) -> viser.SceneNodeHandle:
        if s.kind is ShapeKind.BOX:
            return self.scene.add_box(name, color=s.color, dimensions=(s.size[0], s.size[1], s.size[2]))
        if s.kind is ShapeKind.CYLINDER:
            return self.scene.add_cylinder(name, radius=s.size[0], height=s.size[1], color=s.color)
        if s.kind is ShapeKind.SPHERE:
            return self.scene.add_icosphere(name, radius=s.size[0], color=s.color)
        assert s.mesh is not None
        vertices, faces = _mesh(s.mesh)
        return self.scene.add_mesh_simple(name, vertices * np.asarray(s.scale, dtype=np.float32), faces,
                                          color=s.color)

    def _links_visible(self, visible: bool) -> None:
        for handle in self._links:
            handle.visible = visible
        self._control_point.visible = visible

    @property
    def link_count(self) -> int:
        """Shapes drawn for the links."""
        return len(self._links)

    def show_joints(self, joints: Sequence[float]) -> bool:
        """Place the links at the wire joints [rad or m] (a ``Servo/status`` sample's measured ones); False if they
        are the drawn ones (nothing sent to the page)."""
        joints = tuple(joints)
        if joints == self._joints:
            return False
        poses = self.geometry.poses(joints)
        for handle, pose in zip(self._links, poses):
            handle.position = tuple(pose.translation)
            handle.wxyz = wxyz(pose.rotation)
        cp = self.geometry.flange() * self._tool
        self._control_point.position = tuple(cp.translation)
        self._control_point.wxyz = wxyz(cp.rotation)
        if self._joints is None:
            self._links_visible(True)
        self._joints = joints
        return True

    def show_world(self, world: ServoWorld) -> None:
        """The obstacles of the servo's world, and the arm frame where the servo placed it."""
        self._arm.position = np.asarray(world.basePosition, dtype=float)
        if world.obstacles == self._obstacles_drawn:  # republished as it was: a redraw costs the page frames
            return
        self._obstacles_drawn = world.obstacles
        for handle in self._obstacles:
            handle.remove()
        self._obstacles = [
            self.scene.add_box(f"{self.root}/obstacles/{i}", color=OBSTACLE_COLOR, opacity=0.6,
                               dimensions=2.0 * np.asarray(box.halfExtents, dtype=float),
                               position=np.asarray(box.position, dtype=float))
            for i, box in enumerate(world.obstacles)]

    def show_settings(self, settings: MotionSettings) -> None:
        """The robot frame (base offset), the Cartesian soft-limit box in it, the control point offset."""
        base = hg_to_se3(settings.baseOffset)
        self._robot_frame.position = tuple(base.translation)
        self._robot_frame.wxyz = wxyz(base.rotation)
        centre, size = limit_box(settings)
        box = (tuple(centre.tolist()), tuple(size.tolist()))
        if box != self._limits_drawn:  # the command republishes its settings unchanged: a redraw costs frames
            if self._limits is not None:
                self._limits.remove()
            self._limits = self.scene.add_line_segments(f"{self.root}/arm/robot/soft_limits",
                                                        box_edges(centre, size), LIMIT_COLOR, thickness=2.0,
                                                        thickness_units="screen")
            self._limits_drawn = box
        tool = hg_to_se3(settings.controlPointOffset)
        if not tool.isApprox(self._tool):
            self._tool = tool
            if self._joints is not None:
                joints, self._joints = self._joints, None
                self.show_joints(joints)

    def show_path(self, points: npt.ArrayLike | None) -> None:
        """The running motion's control point polyline [m] in the arm frame; None hides it."""
        if self._path is not None:
            self._path.remove()
            self._path = None
        pts = None if points is None else np.asarray(points, dtype=float).reshape(-1, 3)
        if pts is not None and len(pts) >= 2:
            segments = np.stack([pts[:-1], pts[1:]], axis=1)
            self._path = self.scene.add_line_segments(f"{self.root}/arm/path", segments, PATH_COLOR,
                                                      thickness=4.0, thickness_units="screen")

    @property
    def path_shown(self) -> bool:
        """Whether a motion's path is drawn."""
        return self._path is not None

    def show_label(self, text: str) -> None:
        self._label.text = text

    def show_gone(self, gone: bool) -> None:
        """Grey the links while the arm's servo is away (the pose is its last one)."""
        if gone == self._gone:
            return
        self._gone = gone
        for handle, shape in zip(self._links, self.geometry.shapes):
            handle.color = GONE_COLOR if gone else shape.color  # type: ignore[attr-defined]

    def remove(self) -> None:
        """Take the arm off the page (its node and every node under it)."""
        self._world.remove()
