"""The world: a scene that includes the car model, a ground plane with the track on it and, optionally,
slots for objects (obstacles, bot cars) that the cameras and the lidar see."""

from __future__ import annotations

from importlib import resources

import cv2
import mujoco
import numpy as np

from sim.texture import TextureFrame

PHYSICS_SUBSTEPS = 8
"""Physics steps per 15 Hz control step (timestep 1/120 s: stable for the wheel servos and contacts)."""
CONTROL_HZ = 15.0
"""Camera and action rate, Hz, as on DeepRacer."""

OBJECT_GEOM_GROUP = 1
"""Geom group of the object slots in use: drawn by MuJoCo's renderer (its default option shows groups 0-2; the
car is group 2, its collision spheres group 3, the ground group 0) and the only group the lidar's rays test."""
HIDDEN_GEOM_GROUP = 5
"""Geom group of unused object slots: neither drawn nor seen by the lidar."""
PARKED_Z_M = -50.0
"""Height of an unused slot's box: under the ground, far from any ray or view, in case a group filter is off."""

_SCENE = """
<mujoco model="racer_world">
  <compiler angle="degree"/>
  <!-- Elliptic friction cones: pyramidal ones are anisotropic and make a car driving straight veer
       depending on its heading. -->
  <option timestep="{timestep}" integrator="implicitfast" cone="elliptic">
    <flag energy="disable"/>
  </option>
  <visual>
    <!-- Ambient-only light: the ground shows the texture's own colours, so MuJoCo's render and the
         fast ground-projection camera can be compared pixel for pixel. -->
    <headlight ambient="{ambient} {ambient} {ambient}" diffuse="0 0 0" specular="0 0 0"/>
    <global offwidth="640" offheight="480"/>
    <quality shadowsize="0"/>
    <map znear="0.01" zfar="60"/>
  </visual>
  <asset>
    <texture name="sky" type="skybox" builtin="flat" rgb1="{sky}" rgb2="{sky}" width="8" height="8"/>
    {ground_assets}
  </asset>
  <include file="car.xml"/>
  <worldbody>
    <geom name="ground" type="plane" pos="{cx} {cy} 0" size="{hx} {hy} 0.1" {ground_material}
          contype="0" conaffinity="1" condim="3" friction="1.0 0.005 0.0001"/>{objects}
  </worldbody>
</mujoco>
"""


def car_xml() -> str:
    """The car model's MJCF text."""
    return (resources.files("sim") / "assets" / "car.xml").read_text()


def build_model(
    frame: TextureFrame,
    texture_rgb: np.ndarray | None = None,
    sky_rgb: tuple[int, int, int] = (150, 170, 200),
    ambient: float = 1.0,
    object_slots: int = 0,
) -> mujoco.MjModel:
    """Compile the scene. With ``texture_rgb`` the ground carries the track image (for MuJoCo's renderer);
    without it the ground is a plain plane, which keeps the physics-only model small.

    ``object_slots`` adds that many mocap bodies ``object_<k>``, each with one box geom ``object_<k>`` that
    :func:`set_objects` places, sizes and colours (or hides). The boxes have no contacts (``contype`` and
    ``conaffinity`` 0): DeepRacer detects crashes geometrically (the task's job), not through the physics, and the
    car's physics stays bit for bit that of a scene without them. ``object_slots=0`` compiles today's scene."""
    if object_slots < 0:
        raise ValueError(f"object_slots must be >= 0, not {object_slots}")
    assets = {"car.xml": car_xml().encode()}
    cx, cy = frame.center_m
    hx, hy = (v / 2 for v in frame.size_m)
    if texture_rgb is not None:
        ok, png = cv2.imencode(".png", cv2.cvtColor(texture_rgb, cv2.COLOR_RGB2BGR))
        assert ok, "PNG encoding of the track texture failed"
        assets["track.png"] = png.tobytes()
        ground_assets = (
            '<texture name="track" type="2d" file="track.png"/>'
            '<material name="track" texture="track" texrepeat="1 1" texuniform="false"/>'
        )
        ground_material = 'material="track"'
    else:
        ground_assets, ground_material = "", 'rgba="0.25 0.3 0.25 1"'
    xml = _SCENE.format(
        timestep=1.0 / (CONTROL_HZ * PHYSICS_SUBSTEPS),
        ambient=ambient,
        sky=" ".join(f"{c / 255:.3f}" for c in sky_rgb),
        ground_assets=ground_assets,
        ground_material=ground_material,
        cx=cx,
        cy=cy,
        hx=hx,
        hy=hy,
        objects="".join(_SLOT.format(k=k, group=HIDDEN_GEOM_GROUP) for k in range(object_slots)),
    )
    return mujoco.MjModel.from_xml_string(xml, assets)


# Compiled small at the origin, inside the car's bounds: MuJoCo's model statistics (extent, centre), which scale
# the renderer's clip planes, stay those of the scene without slots. set_objects parks unused slots at runtime.
# The colour is that of DeepRacer's default obstacle (sim.box_raster.DEFAULT_BOX_RGB).
_SLOT = """
    <body name="object_{k}" mocap="true" pos="0 0 0.01">
      <geom name="object_{k}" type="box" size="0.01 0.01 0.01" group="{group}" contype="0" conaffinity="0"
            rgba="0.482 0.38 0.309 1"/>
    </body>"""


def object_slot_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Geom ids of the model's object slots, slot order (empty for a model built without slots)."""
    ids = []
    while (gid := mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"object_{len(ids)}")) >= 0:
        ids.append(gid)
    geoms = np.array(ids, np.int64)
    assert not len(geoms) or np.array_equal(geoms, geoms[0] + np.arange(len(geoms))), "object slots not consecutive"
    return geoms


def set_objects(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    boxes: np.ndarray,
    rgba: np.ndarray | None = None,
    slots: np.ndarray | None = None,
) -> None:
    """Put the first ``len(boxes)`` object slots at ``boxes`` and hide the others.

    ``boxes`` is (K, 6) ``[x, y, yaw, length, width, height]`` in world coordinates (metres, radians): boxes
    standing on the ground, z from 0 to ``height``, ``length`` along the box's yaw. ``rgba`` (K, 4) in 0..1
    recolours them for MuJoCo's renderer (None keeps their colours). ``slots`` (from :func:`object_slot_geoms`)
    saves the name look-up when called every step. The slots' derived positions are refreshed
    (``mj_kinematics``: recomputes positions from the state, changes no state), so rays and renders see them at
    once. Raises ValueError if there are more boxes than slots."""
    geoms = object_slot_geoms(model) if slots is None else slots
    boxes = np.asarray(boxes, np.float64).reshape(-1, 6)
    k, n = len(boxes), len(geoms)
    if k > n:
        raise ValueError(f"{k} objects but the model has {n} object slots (build_model(object_slots=...))")
    if n == 0:
        return
    # Slots are compiled in order at the end of the scene: consecutive geoms, bodies and mocap indices.
    mocap = int(model.body_mocapid[model.geom_bodyid[geoms[0]]])
    g, mc = slice(int(geoms[0]), int(geoms[0]) + n), slice(mocap, mocap + n)
    half = np.full((n, 3), 0.1)
    half[:k] = boxes[:, 3:6] / 2
    pos = np.zeros((n, 3))
    pos[:, 2] = PARKED_Z_M
    pos[:k, :2] = boxes[:, :2]
    pos[:k, 2] = half[:k, 2]
    quat = np.zeros((n, 4))
    quat[:, 0] = 1.0
    quat[:k, 0] = np.cos(boxes[:, 2] / 2)
    quat[:k, 3] = np.sin(boxes[:, 2] / 2)
    aabb = np.zeros((n, 6))
    aabb[:, 3:] = half
    group = np.full(n, HIDDEN_GEOM_GROUP, np.int32)
    group[:k] = OBJECT_GEOM_GROUP
    data.mocap_pos[mc] = pos
    data.mocap_quat[mc] = quat
    model.geom_size[g] = half
    model.geom_rbound[g] = np.sqrt((half * half).sum(axis=1))
    model.geom_aabb[g] = aabb
    model.geom_group[g] = group
    if rgba is not None and k:
        model.geom_rgba[g.start : g.start + k] = np.asarray(rgba, np.float32).reshape(k, 4)
    mujoco.mj_kinematics(model, data)
