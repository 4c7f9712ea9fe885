"""The twin's scene, composed with ``mujoco.MjSpec`` from small pieces.

Pieces: the room (floor, walls with a door, lights; built here because its size follows
the cell grid), furniture and the robot (MJCF files in ``twin/assets/``, attached with a
prefix each), the ceiling camera and the person (mocap bodies, sized from the person's
height). See twin/README.md for why MjSpec rather than dm_control's ``mjcf``.

World frame = map frame of ``stack.cells`` (x east, y north, z up, metres).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from stack.cells import ConfigError
from twin.config import PersonConfig, TwinConfig
from twin.person import BodyDims

ASSETS = Path(__file__).resolve().parent / "assets"

ROBOT_PREFIX = "mbot/"
ROBOT_BODY = ROBOT_PREFIX + "base"
LIDAR_SITE = ROBOT_PREFIX + "lidar"
CAMERA_NAME = "ceiling"
PERSON_PREFIX = "person/"  # the first walker's; the others' are person_prefix(i)
# the person's mocap bodies: (name, kind); kinds are laid out in twin.twin
PERSON_SEGMENTS = (
    "torso",
    "thigh_l",
    "thigh_r",
    "shin_l",
    "shin_r",
    "foot_l",
    "foot_r",
    "arm_l",
    "arm_r",
)


def person_prefix(index: int) -> str:
    """Name prefix of the ``index``-th walker's bodies, geoms and materials (0-based).

    The first is ``person/`` (as before several walkers existed, so a one-person
    scene is unchanged), then ``person2/``, ``person3/``, ...
    """
    return PERSON_PREFIX if index == 0 else f"person{index + 1}/"


@dataclass(frozen=True)
class SceneLayout:
    """Where things are, in the world (= map) frame [m].

    Attributes:
        region: (x_min, y_min, x_max, y_max) of the cell region.
        room: (x_min, y_min, x_max, y_max) of the room's inside (wall faces).
        door_x_m: (x_min, x_max) of the doorway in the north wall.
        camera_pos_m: position of the ceiling camera.
        camera_xmat: 3x3 rotation, world from MuJoCo camera frame (x right, y up, z back).
    """

    region: tuple[float, float, float, float]
    room: tuple[float, float, float, float]
    door_x_m: tuple[float, float]
    camera_pos_m: tuple[float, float, float]
    camera_xmat: np.ndarray

    @property
    def door_center_m(self) -> tuple[float, float]:
        return ((self.door_x_m[0] + self.door_x_m[1]) / 2.0, self.room[3])

    def in_room(self, x: float, y: float) -> bool:
        x0, y0, x1, y1 = self.room
        return x0 <= x <= x1 and y0 <= y <= y1


def layout_of(config: TwinConfig) -> SceneLayout:
    """Compute the room and camera placement from the cell grid and the room config.

    Args:
        config: the twin configuration.

    Returns:
        The layout.

    Raises:
        ConfigError: the door does not fit in the north wall.
    """
    g, r, c = config.grid, config.room, config.camera
    w, h = g.size_m
    x0, y0 = g.origin_m
    region = (x0, y0, x0 + w, y0 + h)
    room = (
        x0 - r.margin_west_m,
        y0 - r.margin_south_m,
        x0 + w + r.margin_east_m,
        y0 + h + r.margin_north_m,
    )
    door_c = x0 + w + r.door_offset_east_m
    door = (door_c - r.door_width_m / 2, door_c + r.door_width_m / 2)
    if door[0] < room[0] + 0.1 or door[1] > room[2] - 0.1:
        raise ConfigError(
            "room.door_offset_east_m", r.door_offset_east_m, "the door must fit in the north wall"
        )
    cam = (x0 - c.distance_behind_m, y0 + h / 2 + c.lateral_offset_m, c.height_m)
    tilt = math.radians(c.tilt_deg)
    # looking east (+x), tilted down: MuJoCo cameras look along -z with y up
    right = np.array([0.0, -1.0, 0.0])
    up = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    back = np.cross(right, up)
    xmat = np.column_stack([right, up, back])
    return SceneLayout(region, room, door, cam, xmat)


def _quat_of(xmat: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(xmat).ravel())
    return q


def _yaw_quat(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


def build_spec(config: TwinConfig) -> tuple[mujoco.MjSpec, SceneLayout]:
    """Compose the whole scene.

    Args:
        config: the twin configuration.

    Returns:
        (spec, layout): the uncompiled MjSpec and where its parts are.

    Raises:
        ConfigError: the configuration does not fit a buildable room.
    """
    layout = layout_of(config)
    spec = mujoco.MjSpec()
    spec.modelname = "vigil_twin"
    spec.option.timestep = config.timestep_s
    # implicit-in-velocity integration keeps the stiff velocity actuators stable
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    cam = config.camera
    spec.visual.global_.offwidth = max(cam.width_px, 640)
    spec.visual.global_.offheight = max(cam.height_px, 480)
    spec.visual.quality.offsamples = cam.antialias_samples
    spec.visual.quality.shadowsize = 2048
    spec.visual.headlight.ambient = [0.25, 0.25, 0.25]
    spec.visual.headlight.diffuse = [0.25, 0.25, 0.25]
    spec.visual.headlight.specular = [0.05, 0.05, 0.05]
    spec.stat.extent = 10.0
    _add_room(spec, config, layout)
    if config.room.furniture:
        _add_furniture(spec, layout)
    for i, ob in enumerate(config.obstacles):
        spec.worldbody.add_geom(
            name=f"obstacle_{i}",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=[ob.x_m, ob.y_m, ob.height_m / 2],
            size=[ob.half_size_m, ob.half_size_m, ob.height_m / 2],
            material="trim",
        )
    _add_robot(spec)
    _add_camera(spec, config, layout)
    for i, walker in enumerate(config.walkers):
        _add_person(spec, walker, person_prefix(i))
    return spec, layout


def _box(body: mujoco.MjsBody, name: str, center, half, material: str, **kw) -> None:
    body.add_geom(
        name=name,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        pos=list(center),
        size=list(half),
        material=material,
        **kw,
    )


def _add_room(spec: mujoco.MjSpec, config: TwinConfig, layout: SceneLayout) -> None:
    r = config.room
    tex = spec.add_texture(
        name="floor_tiles",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.62, 0.60, 0.56],
        rgb2=[0.56, 0.55, 0.52],
        mark=mujoco.mjtMark.mjMARK_RANDOM,
        markrgb=[0.40, 0.39, 0.36],
        random=0.03,  # speckles, as on vinyl lab tiles
        width=512,
        height=512,
    )
    floor = spec.add_material(name="floor", texuniform=True)
    floor.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex.name
    # one texture holds 2 x 2 tiles; with texuniform the repeat is per metre
    rep = 1.0 / r.floor_tile_m
    floor.texrepeat = [rep, rep]
    spec.add_material(name="wall", rgba=[0.86, 0.85, 0.80, 1.0])
    spec.add_material(name="trim", rgba=[0.35, 0.30, 0.26, 1.0])
    spec.add_material(name="board", rgba=[0.97, 0.97, 0.97, 1.0], specular=0.6)
    spec.add_material(name="cabinet", rgba=[0.55, 0.58, 0.62, 1.0])

    wb = spec.worldbody
    x0, y0, x1, y1 = layout.room
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    wb.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        pos=[cx, cy, 0.0],
        size=[(x1 - x0) / 2 + 4.0, (y1 - y0) / 2 + 4.0, 0.1],
        material="floor",
    )
    t, hgt = r.wall_thickness_m, r.wall_height_m
    hz = hgt / 2
    _box(wb, "wall_south", (cx, y0 - t / 2, hz), ((x1 - x0) / 2 + t, t / 2, hz), "wall")
    _box(wb, "wall_west", (x0 - t / 2, cy, hz), (t / 2, (y1 - y0) / 2, hz), "wall")
    _box(wb, "wall_east", (x1 + t / 2, cy, hz), (t / 2, (y1 - y0) / 2, hz), "wall")
    # north wall in three parts around the doorway
    d0, d1 = layout.door_x_m
    yn = y1 + t / 2
    _box(wb, "wall_north_w", ((x0 - t + d0) / 2, yn, hz), ((d0 - x0 + t) / 2, t / 2, hz), "wall")
    _box(wb, "wall_north_e", ((d1 + x1 + t) / 2, yn, hz), ((x1 + t - d1) / 2, t / 2, hz), "wall")
    lintel_h = hgt - r.door_height_m
    _box(
        wb,
        "wall_north_lintel",
        ((d0 + d1) / 2, yn, r.door_height_m + lintel_h / 2),
        ((d1 - d0) / 2, t / 2, lintel_h / 2),
        "wall",
    )
    # door frame and an open door leaf swung outwards against the corridor wall
    for name, xf in (("door_jamb_w", d0), ("door_jamb_e", d1)):
        _box(
            wb,
            name,
            (xf, yn, r.door_height_m / 2),
            (0.03, t / 2 + 0.02, r.door_height_m / 2),
            "trim",
        )
    leaf = d1 - d0 - 0.04
    _box(
        wb,
        "door_leaf",
        (d1 + 0.03, yn + t / 2 + leaf / 2, r.door_height_m / 2 - 0.01),
        (0.02, leaf / 2, r.door_height_m / 2 - 0.02),
        "trim",
    )
    # a whiteboard on the east wall and a cabinet: background behind a walking person
    _box(wb, "whiteboard", (x1 - 0.015, cy, 1.5), (0.01, 1.0, 0.55), "board")
    _box(wb, "cabinet", (x1 - 0.25, y0 + 0.6, 0.9), (0.22, 0.45, 0.9), "cabinet")
    # ceiling lights: one casts shadows if asked (FEASIBILITY: shadows dominate render time,
    # and a single light alone gave many HOG false positives)
    spots = [(0.25, 0.3), (0.75, 0.3), (0.25, 0.7), (0.75, 0.7)]
    for i, (fx, fy) in enumerate(spots):
        wb.add_light(
            name=f"ceiling_light_{i}",
            pos=[x0 + fx * (x1 - x0), y0 + fy * (y1 - y0), hgt - 0.1],
            dir=[0.0, 0.0, -1.0],
            type=mujoco.mjtLightType.mjLIGHT_SPOT,
            cutoff=70.0,
            exponent=2.0,
            diffuse=[0.42, 0.42, 0.40],
            specular=[0.1, 0.1, 0.1],
            ambient=[0.04, 0.04, 0.04],
            castshadow=bool(config.camera.shadows and i == 1),
        )


def _attach(spec: mujoco.MjSpec, file: str, prefix: str, pos, yaw: float = 0.0) -> None:
    child = mujoco.MjSpec.from_file(str(ASSETS / file))
    frame = spec.worldbody.add_frame(pos=list(pos), quat=_yaw_quat(yaw))
    frame.attach_body(child.worldbody.first_body(), prefix, "")


def _add_furniture(spec: mujoco.MjSpec, layout: SceneLayout) -> None:
    """Desks along the north and south walls, chairs in front of them, a pole.

    Chair and table legs are within lidar range of the region: the leg detector's
    classic false positives.
    """
    rx0, ry0, rx1, ry1 = layout.region
    x0, y0, x1, y1 = layout.room
    d0, _ = layout.door_x_m
    north = [rx0 + 0.3 + 0.8, rx0 + 2.2 + 0.8]
    north = [x for x in north if x + 0.8 < d0 - 0.2]
    south = [rx0 + 1.0 + 0.8, rx0 + 3.4 + 0.8]
    for i, x in enumerate(north):
        _attach(spec, "desk.xml", f"desk_n{i}/", (x, y1 - 0.42, 0.0), yaw=math.pi)
        _attach(
            spec, "chair.xml", f"chair_n{i}/", (x + 0.3 * (-1) ** i, y1 - 1.1, 0.0), math.pi / 2
        )
    for i, x in enumerate(south):
        _attach(spec, "desk.xml", f"desk_s{i}/", (x, y0 + 0.42, 0.0))
        _attach(spec, "chair.xml", f"chair_s{i}/", (x - 0.2, y0 + 1.05, 0.0), -math.pi / 2 + 0.3)
    # a loose chair and a pole west of the region, between the camera and the cells
    _attach(spec, "chair.xml", "chair_w/", (rx0 - 1.3, ry1 + 0.9, 0.0), 0.8)
    spec.worldbody.add_geom(
        name="pole",
        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
        pos=[rx0 - 1.0, ry0 - 1.2, 1.5],
        size=[0.06, 1.5, 0.0],
        material="trim",
    )


def _add_robot(spec: mujoco.MjSpec) -> None:
    # at the world origin, unrotated: the slides then read world x and y directly,
    # and Twin sets the start pose through qpos
    child = mujoco.MjSpec.from_file(str(ASSETS / "mbot.xml"))
    spec.attach(child, prefix=ROBOT_PREFIX, frame=spec.worldbody.add_frame())


def _add_camera(spec: mujoco.MjSpec, config: TwinConfig, layout: SceneLayout) -> None:
    c = config.camera
    spec.worldbody.add_camera(
        name=CAMERA_NAME,
        pos=list(layout.camera_pos_m),
        quat=list(_quat_of(layout.camera_xmat)),
        fovy=c.fovy_deg,
    )
    # the camera's housing on its wall bracket (not in the camera's own view)
    px, py, pz = layout.camera_pos_m
    _box(spec.worldbody, "camera_housing", (px - 0.08, py, pz + 0.02), (0.07, 0.05, 0.04), "trim")
    wall_x = layout.room[0]
    _box(
        spec.worldbody,
        "camera_bracket",
        ((wall_x + px - 0.15) / 2, py, pz + 0.05),
        (max((px - 0.15 - wall_x) / 2, 0.01), 0.015, 0.015),
        "trim",
    )


def _add_person(spec: mujoco.MjSpec, p: PersonConfig, prefix: str) -> None:
    """One person as mocap bodies moved by twin.person; geoms never collide.

    Segment bodies carry a capsule along their local z, centred on the body origin; the
    twin sets each body's position to the segment midpoint and turns z along it.
    Every name starts with ``prefix`` (:func:`person_prefix`).
    """
    d = BodyDims(p.height_m)
    for name, rgb in (
        ("shirt", p.shirt_rgb),
        ("trousers", p.trousers_rgb),
        ("skin", p.skin_rgb),
        ("hair", p.hair_rgb),
        ("shoes", p.shoes_rgb),
    ):
        spec.add_material(name=prefix + name, rgba=[*rgb, 1.0], specular=0.1)
    ghost = {"contype": 0, "conaffinity": 0}
    cap = mujoco.mjtGeom.mjGEOM_CAPSULE
    h = p.height_m
    torso = spec.worldbody.add_body(name=prefix + "torso", mocap=True)
    # torso frame: on the floor under the pelvis, x = heading, z up
    hip, sh = d.hip_height_m, d.shoulder_height_m
    torso.add_geom(
        name=prefix + "pelvis",
        type=cap,
        fromto=[0, -d.hip_half_width_m, hip + 0.02, 0, d.hip_half_width_m, hip + 0.02],
        size=[0.085 * h / 1.75, 0, 0],
        material=prefix + "trousers",
        **ghost,
    )
    torso.add_geom(
        name=prefix + "chest",
        type=mujoco.mjtGeom.mjGEOM_ELLIPSOID,
        pos=[0, 0, (hip + sh) / 2 + 0.02],
        size=[0.12 * h / 1.75, 0.19 * h / 1.75, (sh - hip) / 2 + 0.06],
        material=prefix + "shirt",
        **ghost,
    )
    torso.add_geom(
        name=prefix + "shoulders",
        type=cap,
        fromto=[0, -d.shoulder_half_width_m, sh, 0, d.shoulder_half_width_m, sh],
        size=[0.055 * h / 1.75, 0, 0],
        material=prefix + "shirt",
        **ghost,
    )
    torso.add_geom(
        name=prefix + "neck",
        type=cap,
        fromto=[0, 0, sh, 0, 0, 0.88 * h],
        size=[0.045 * h / 1.75, 0, 0],
        material=prefix + "skin",
        **ghost,
    )
    head_r = 0.065 * h
    head_z = h - head_r
    torso.add_geom(
        name=prefix + "head",
        type=mujoco.mjtGeom.mjGEOM_ELLIPSOID,
        pos=[0, 0, head_z],
        size=[head_r * 0.95, head_r * 0.85, head_r],
        material=prefix + "skin",
        **ghost,
    )
    torso.add_geom(
        name=prefix + "hair",
        type=mujoco.mjtGeom.mjGEOM_ELLIPSOID,
        pos=[-0.015 * h / 1.75, 0, head_z + 0.025 * h / 1.75],
        size=[head_r * 0.97, head_r * 0.88, head_r * 0.9],
        material=prefix + "hair",
        **ghost,
    )
    # legs are about 0.15 m wide at lidar height (FEASIBILITY), arms a little thinner
    segments = {
        "thigh": (d.thigh_m, 0.075 * h / 1.75, "trousers"),
        "shin": (d.shin_m, 0.065 * h / 1.75, "trousers"),
        "arm": (d.arm_m, 0.045 * h / 1.75, "shirt"),
    }
    for side in ("l", "r"):
        for kind, (length, radius, mat) in segments.items():
            body = spec.worldbody.add_body(name=f"{prefix}{kind}_{side}", mocap=True)
            body.add_geom(
                name=f"{prefix}{kind}_{side}_geom",
                type=cap,
                fromto=[0, 0, -length / 2, 0, 0, length / 2],
                size=[radius, 0, 0],
                material=prefix + mat,
                **ghost,
            )
            if kind == "arm":
                body.add_geom(
                    name=f"{prefix}hand_{side}",
                    type=mujoco.mjtGeom.mjGEOM_SPHERE,
                    pos=[0, 0, -length / 2],
                    size=[0.045 * h / 1.75, 0, 0],
                    material=prefix + "skin",
                    **ghost,
                )
        foot = spec.worldbody.add_body(name=f"{prefix}foot_{side}", mocap=True)
        # foot frame: at the ankle, x = heading; the shoe reaches forward of the ankle
        foot.add_geom(
            name=f"{prefix}foot_{side}_geom",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=[0.05 * h / 1.75, 0, -d.ankle_height_m / 2],
            size=[0.13 * h / 1.75, 0.05 * h / 1.75, d.ankle_height_m / 2],
            material=prefix + "shoes",
            **ghost,
        )
