"""The race's objects as bodies: what DeepRacer's obstacles and bot cars are, their sizes and where they stand.

The simapp's ``ObstacleDimensions`` covers both kinds, and so does this module: boxes, parked bot cars and moving bot
cars, each a :class:`WorldObject` with a kind from :data:`FOOTPRINTS`. Where they are placed is
``sim/placement.py`` (static obstacles) and ``sim/bots.py`` (bot cars); what they mean for the race is
``sim/race_rules.py`` and ``sim/object_params.py``. ``docs/object-avoidance.md`` has the notes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import KW_ONLY, dataclass

import numpy as np

BOX_KINDS = ("box_obstacle", "deepracer_box_obstacle", "amazon_box_obstacle")
"""simapp ``markov/agent_ctrl/constants.py: OBSTACLE_TYPE_LIST``."""
BOT_CAR_OBSTACLE = "bot_car_obstacle"
"""A parked bot car used as a static obstacle (simapp IS_OBSTACLE_BOT_CAR: named ``obstacle_<i>`` there)."""
BOT_CAR = "bot_car"
"""A moving bot car (simapp ``BotCarsCtrl``: named ``bot_car_<i>``)."""


@dataclass(frozen=True)
class Footprint:
    """The size of one kind of object.

    ``length``/``width``/``height`` are the model's real size (what a camera or LiDAR sees);
    ``crash_length``/``crash_width`` the rectangle the simapp's crash rule and camera test use
    (``track_geom/constants.py: ObstacleDimensions``, read by ``track_data.py: get_object_bounding_rect`` as
    (width along y, length along x) -- the enum's comment says the opposite, the code wins); ``z`` the height of the
    pose the simapp keeps for the object (``agent_ctrl/constants.py: OBSTACLE_Z``, ``BOT_CAR_Z``), which its camera
    test uses."""

    length: float
    width: float
    height: float
    crash_length: float
    crash_width: float
    z: float
    source: str


_BOX_CRASH = (0.5, 0.4)  # ObstacleDimensions.BOX_OBSTACLE_DIMENSION = (0.4, 0.5): width 0.3 + 0.1, length 0.4 + 0.1
_BOT_CAR_CRASH = (0.32352, 0.1961)  # ObstacleDimensions.BOT_CAR_DIMENSION = (0.1961, 0.32352)
_BOT_CAR_HEIGHT_M = 0.2108
"""Top of the bot car: ``bundle/meshes/deepracer/car_body_link_v3.STL`` reaches z = 0.19504 m and
``bundle/models/bot_car/model.sdf`` places it at z + 0.01577 m (the visual's pose)."""

FOOTPRINTS: dict[str, Footprint] = {
    "box_obstacle": Footprint(
        0.4, 0.3, 0.25, *_BOX_CRASH, 0.1, "bundle/models/box_obstacle/model.sdf: <box><size>0.4 0.3 0.25"
    ),
    "deepracer_box_obstacle": Footprint(
        0.36,
        0.265,
        0.24,
        *_BOX_CRASH,
        0.1,
        "bundle/models/deepracer_box_obstacle/model.sdf: a 1 m cube mesh scaled 0.36 0.265 0.24",
    ),
    "amazon_box_obstacle": Footprint(
        0.4,
        0.3,
        0.25,
        *_BOX_CRASH,
        0.1,
        "bundle/models/amazon_box_obstacle/model.sdf: a 1 m cube mesh scaled 0.4 0.3 0.25",
    ),
    BOT_CAR_OBSTACLE: Footprint(
        *_BOT_CAR_CRASH, _BOT_CAR_HEIGHT_M, *_BOT_CAR_CRASH, 0.0, "ObstacleDimensions.BOT_CAR_DIMENSION + bot_car mesh"
    ),
    BOT_CAR: Footprint(
        *_BOT_CAR_CRASH, _BOT_CAR_HEIGHT_M, *_BOT_CAR_CRASH, 0.0, "ObstacleDimensions.BOT_CAR_DIMENSION + bot_car mesh"
    ),
}
"""Every kind of object. The bot car's length and width are the simapp's BOT_CAR_DIMENSION, which matches its mesh
(body 0.324 m long; 0.197 m wide over the wheels)."""

CAR_CRASH_LENGTH_M, CAR_CRASH_WIDTH_M = _BOT_CAR_CRASH
"""The racing car's crash rectangle, centred on its base_link: the simapp registers the agent with
BOT_CAR_DIMENSION too (``rollout_agent_ctrl.py: RolloutCtrl.__init__``)."""


@dataclass(frozen=True)
class WorldObject:
    """An obstacle or bot car: pose (metres, radians CCW from +x) and size (metres) in world coordinates."""

    x: float
    y: float
    yaw: float
    _: KW_ONLY
    length: float
    width: float
    height: float
    speed: float
    """m/s along the centre line; 0 for static obstacles."""
    kind: str
    """A key of :data:`FOOTPRINTS`."""

    @classmethod
    def of(cls, kind: str, x: float, y: float, yaw: float, speed: float = 0.0) -> WorldObject:
        """An object of a known kind, sized from :data:`FOOTPRINTS`."""
        fp = FOOTPRINTS[kind]
        return cls(
            float(x),
            float(y),
            float(yaw),
            length=fp.length,
            width=fp.width,
            height=fp.height,
            speed=float(speed),
            kind=kind,
        )

    @property
    def footprint(self) -> Footprint:
        return FOOTPRINTS[self.kind]

    @property
    def is_obstacle(self) -> bool:
        """A static obstacle (the simapp's ``obstacle_<i>``), as opposed to a moving bot car."""
        return self.kind != BOT_CAR


def as_boxes(objects: Sequence[WorldObject]) -> np.ndarray:
    """(K, 6) float64 ``[x, y, yaw, length, width, height]`` of the objects in world coordinates (for the
    renderer and the LiDAR; height is the object's real height, standing on the ground)."""
    rows = [(o.x, o.y, o.yaw, o.length, o.width, o.height) for o in objects]
    return np.array(rows, dtype=np.float64).reshape(len(rows), 6)


def rect_corners(x: float, y: float, yaw: float, length: float, width: float) -> list[tuple[float, float]]:
    """simapp ``TrackData.get_object_bounding_rect``: the 4 floor corners of a rectangle centred on a pose."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = 0.5 * length, 0.5 * width
    return [(x + c * a - s * b, y + s * a + c * b) for a, b in ((hl, hw), (hl, -hw), (-hl, -hw), (-hl, hw))]
