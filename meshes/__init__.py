"""meshes: labelled triangle meshes of sensors, the tank and objects (pure geometry, no physics)."""
from .objects import Box, Cylinder, Sphere, parse_material
from .pose import Pose, poses_array, rotation_z
from .scene import Scene
from .sensor import Electrode, SensorDescription, load_sensor, preset, save_sensor
from .tank import TANK_REGIONS, Tank
