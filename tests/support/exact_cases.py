"""Scenes built so that a decision of the exercise's model is exactly 0 in rational arithmetic on their
binary64 numbers (tests/oracles/test_oracle_exact.py, tests/campaign/test_judge.py): a 4x4 image, the camera
1 behind the image plane, the light straight above the floor point of pixel (2, 3)."""

from __future__ import annotations

from minirt.model.scene import Scene, parse_scene

HEADER = """
[camera]
distance = 1.0
width = 4
height = 4
[light]
position = [0.0, 9.0, 3.0]
[materials.m]
ambient = [0.1, 0.1, 0.1]
diffuse = [0.5, 0.5, 0.5]
"""
FLOOR = '[[shapes]]\ntype = "plane"\nnormal = [0.0, 1.0, 0.0]\ndistance = -1.0\nmaterial = "m"'
# touches the shadow ray of pixel (2, 3) -- from (0, -1, 3) straight up -- at (0, 4, 3)
TANGENT_BALL = '[[shapes]]\ntype = "ball"\ncenter = [1.0, 4.0, 3.0]\nradius = 1.0\nmaterial = "m"'


def exact_case(shapes: str, model: str = 'ray_origin = "camera"') -> Scene:
    return parse_scene(f"{HEADER}\n[model]\n{model}\n{shapes}", "test.toml")
