"""The world: a scene that includes the car model and a ground plane with the track on it."""

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
          contype="0" conaffinity="1" condim="3" friction="1.0 0.005 0.0001"/>
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
) -> mujoco.MjModel:
    """Compile the scene. With ``texture_rgb`` the ground carries the track image (for MuJoCo's renderer);
    without it the ground is a plain plane, which keeps the physics-only model small."""
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
    )
    return mujoco.MjModel.from_xml_string(xml, assets)
