"""Robot embodiments: what stands between a commanded end-effector velocity and the physics.

The policy acts on end-effector displacements, so every embodiment tracks a Cartesian velocity behind
the same observation and action spaces. They are picked by name from one registry, ``EMBODIMENTS``:

* ``panda`` (default, ``scene/panda.py``): the 7-DoF Franka Panda from gymnasium-robotics' model, driven by
  damped-least-squares differential IK within the Panda's joint limits.
* ``hand`` (``scene/hand.py``): an idealised ablation, the Panda hand as a gravity-compensated body on three
  world-aligned slide joints. The env applies the same Cartesian speed and acceleration limits to both.

Each names its controller (``controller``), which lives a layer up in ``control/cartesian.py``: the env takes it
from there. A new robot is one module with a class that has the ``Embodiment`` members, and one line in
``EMBODIMENTS``, plus a controller if none of the existing ones drives its servos (docs/extending.md).

Both grasp the same way (``scene/grasp.py``): spring-loaded fingertip pads press on the bottom box's lip
and drag it by friction; the box itself is a free body that the scene builder adds.
"""

from __future__ import annotations

from typing import Protocol

import mujoco
import numpy as np

from safemanip.scene.config import TaskGeometry
from safemanip.scene.hand import CartesianHand
from safemanip.scene.panda import PandaArm


class Embodiment(Protocol):
    """What the scene builder and the env need of a robot.

    ``attach`` builds the robot into the scene's spec, its pads resting on the lip of the held box (a free body
    named ``box_bottom`` that the builder adds); ``bind`` resolves ids once per compiled model; ``reset`` puts it
    at its home configuration, the pads pressed in by ``PAD_PRESS``;
    ``controller`` names the one of ``control.cartesian.CONTROLLERS`` that makes the end-effector track a world-frame
    velocity over the next control step (its ``command_velocity`` returns the step as phases ``((substeps, ctrl),
    ...)``, each ``ctrl`` written to the binding's ``actuator_ids`` for that many substeps, the substeps adding up to
    the control step's, so that no Python runs inside a phase).
    Everything in the subtree of ``root_body_name`` is "manipulated": it counts in g_hard and g_soft.
    """

    name: str
    controller: str
    root_body_name: str
    ee_site_name: str
    distance_geom_names: tuple[str, ...]
    """Geoms whose exact distance to the clutter shapes g while nothing is in contact (the held box and the
    hand); contacts of every other robot geom are caught by the per-substep contact check."""
    cache_key: tuple

    def attach(self, spec: mujoco.MjSpec, geo: TaskGeometry) -> None: ...
    def bind(self, model: mujoco.MjModel): ...
    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, binding) -> None: ...
    def holding_reach(self, geo: TaskGeometry) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Where on the table the robot can hold the box: (xs, ys, mask) on a grid of box centres, or None for
        anywhere. The planner keeps the box within it."""


EMBODIMENTS = {"panda": PandaArm, "hand": CartesianHand}
"""Embodiments by name: the closed set a config, a flag or a policy's metadata may name."""


def make_embodiment(name: str, visual: bool = True, gap: float = 0.0) -> Embodiment:
    if name not in EMBODIMENTS:
        raise ValueError(f"unknown embodiment {name!r}: use one of {sorted(EMBODIMENTS)}")
    return EMBODIMENTS[name](visual=visual, gap=gap)
