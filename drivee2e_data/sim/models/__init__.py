"""Procedural models of the agents: a pure function from (class, blueprint, box, instance) to a
mesh that fills the box, and the posing that animates it; no GL, no pybullet."""

from __future__ import annotations

import functools

import numpy as np

from drivee2e_data.scenario import AgentClass
from drivee2e_data.sim.models import palette
from drivee2e_data.sim.models.figures import tricycle, two_wheeler, walking_figure
from drivee2e_data.sim.models.mesh import Animation, Light, Material, ModelMesh, pose
from drivee2e_data.sim.models.vehicles import vehicle_model

__all__ = ["LOOK_VERSION", "Animation", "Light", "Material", "ModelMesh", "agent_model", "pose"]

# Names the look of the images (models, materials, shaders); a log's collection record carries
# it, so a reader knows which images came from which look. 1: pybullet's boxes; 2: the GL
# renderer's shading of the same boxes; 3: procedural models, materials, shadows, sky; 4: the
# ego casts its shadow into its own cameras' view (`SceneLights.casters`); 5: windows as quads
# of their own in whole bays centred on each wall, walls without the window grid's tone, crowns
# drawn coarser beyond 40 m where the CPU draws (`twin.CROWN_SPHERES`); 6: the sun's shadow map
# centred on the ego's position rounded to 8 m (`gl_renderer.SHADOW_FOCUS_STEP_M`: shadow
# edges sampled at another phase, the map's faded border elsewhere), no grass under the road;
# 7: asphalt, marking and grass grain as smooth value noise instead of a hash per cell (no
# texel blocks near the camera), faded where its cells shrink below a pixel; 8: static
# obstacles as models (cones, barrels, bollards, barriers, signs: `sim/obstacles.py`), the
# other kinds grey boxes instead of orange ones; 9: generated buildings farther out (up to
# 180 m from the junction) where a map's roads leave no room for them nearer
# (`scenery.BUILDING_REACHES_M`: nuScenes maps); 10: each camera's auto-exposure
# (`conditions.exposure`: a drawn image's mean grey held within 80-100 of 255 by day), its gain
# logged per frame on `/CAM_*/exposure`.
LOOK_VERSION = 10
STATURE_RANGE_M = (1.52, 1.70)  # pedestrians' heights, inside the 1.72 m blueprint box
BUILD_RANGE = (0.85, 1.15)


@functools.lru_cache(maxsize=512)
def agent_model(
    agent_class: AgentClass, blueprint: str, size_m: tuple[float, float, float], instance: str
) -> ModelMesh:
    """The model of one agent: its class and blueprint's shape filling `size_m` (length, width,
    height; centred on the box), its colours, stature and build drawn from `instance` (the
    track id). Cached: a clip asks for each of its agents once per world."""
    size = np.asarray(size_m, dtype=np.float64)
    rng = palette.instance_rng(instance)
    if agent_class == AgentClass.PEDESTRIAN:
        stature = float(rng.uniform(*STATURE_RANGE_M)) * min(1.0, size[2] / 1.72)
        figure = walking_figure(stature, float(rng.uniform(*BUILD_RANGE)), rng)
        # stand the figure on the box's floor
        from dataclasses import replace

        lift = np.float32(-0.5 * size[2] + 0.5 * stature)
        positions = figure.positions + np.array([0.0, 0.0, lift], np.float32)
        joints = tuple(
            replace(j, pivot_m=(j.pivot_m[0], j.pivot_m[1], j.pivot_m[2] + float(lift)))
            for j in figure.joint_table
        )
        return replace(figure, positions=positions, joint_table=joints)
    if agent_class in (AgentClass.CYCLIST, AgentClass.MOTORCYCLIST):
        return two_wheeler(size, agent_class == AgentClass.MOTORCYCLIST, rng)
    if agent_class == AgentClass.TRICYCLIST:
        return tricycle(size, rng)
    return vehicle_model(blueprint, size_m, instance)
