"""meshes: labelled triangle meshes of sensors, the tank and objects (pure geometry, no physics)."""
from electrosense.meshes.labelled_mesh import LabelledMesh, concatenate
from electrosense.meshes.objects import Box, Cylinder, Sphere, parse_material
from electrosense.meshes.pose import Pose, poses_array, rotation_z
from electrosense.meshes.scene import Scene
from electrosense.meshes.sensor import Electrode, SensorDescription, load_sensor, preset, save_sensor
from electrosense.meshes.tank import TANK_REGIONS, Tank

# meshing, files and pictures load scipy/pyvista: imported on first use
_LAZY = {
    "mesh_sensor": "sensor_mesh",
    "mesh_tank": "tank_mesh",
    "mesh_object": "object_mesh",
    "mesh_scene": "scene_mesh",
    "check_scene": "scene_mesh",
    "SceneMesh": "scene_mesh",
    "SceneError": "scene_mesh",
    "load_scene": "scene_file",
    "save_scene": "scene_file",
    "mesh_quality": "quality",
    "check_mesh": "quality",
    "MeshError": "quality",
    "read_mesh": "io",
    "write_mesh": "io",
    "render_mesh": "render",
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
