"""Random scenes of many balls, as scene-file text: for tests, benchmarks and anyone who wants a big scene.

``balls_scene(n, seed)`` scatters n balls in a slab in front of the camera, over a mirror floor, with
four materials (one mirror-like, one matte, two shiny), under the exercise's light. The slab widens as
n^(1/3) and the radii shrink with it, so the image stays about equally full whatever n. Deterministic
for (n, seed): the same text on every machine.
"""

from __future__ import annotations

import numpy as np

from minirt.campaign.families import dump_toml

_MATERIALS = {
    "red": {
        "ambient": [0.08, 0.0, 0.0],
        "diffuse": [0.8, 0.1, 0.1],
        "specular": [0.6, 0.6, 0.6],
        "reflection": [0.2, 0.2, 0.2],
    },
    "green": {"ambient": [0.0, 0.08, 0.0], "diffuse": [0.1, 0.7, 0.2], "specular": [0.4, 0.4, 0.4]},
    "blue": {
        "ambient": [0.0, 0.0, 0.08],
        "diffuse": [0.1, 0.2, 0.8],
        "specular": [0.8, 0.8, 0.8],
        "reflection": [0.5, 0.5, 0.5],
    },
    "grey": {"ambient": [0.02, 0.02, 0.02], "diffuse": [0.5, 0.5, 0.5]},
    "floor": {"ambient": [0.02, 0.02, 0.02], "diffuse": [0.3, 0.3, 0.3], "reflection": [0.5, 0.5, 0.5]},
}


def balls_scene(
    n: int, seed: int = 0, width: int = 256, height: int = 256, max_depth: int = 3, floor: bool = True
) -> str:
    """TOML text of a scene with n random balls (and a mirror floor unless ``floor`` is False)."""
    rng = np.random.default_rng(seed)
    k = max(1.0, n ** (1 / 3))
    half = 1.2 * k  # half-width of the slab in x and y
    depth = 2.0 * k
    center = np.column_stack(
        [rng.uniform(-half, half, n), rng.uniform(-half * 0.6, half, n), rng.uniform(4.0, 4.0 + depth, n)]
    )
    radius = rng.uniform(0.25, 0.6, n)
    names = ("red", "green", "blue", "grey")
    mats = rng.integers(0, len(names), n)
    # one table a paragraph, written as the fuzzer writes its scenes (floats with repr: they read back bit for bit)
    tables = [
        {"scene": {"name": f"balls_{n}_{seed}", "description": f"{n} random balls (seed {seed}) over a mirror floor"}},
        {"camera": {"distance": 1.0 / k + 1.0, "width": width, "height": height}},
        {"light": {"position": [-3.0 * k, 6.0 * k, -2.0 * k]}},
        {"render": {"background": [0.05, 0.05, 0.15], "max_depth": max_depth}},
        *({"materials": {name: m}} for name, m in _MATERIALS.items()),
    ]
    for c, r, m in zip(center, radius, mats, strict=True):
        ball = {"type": "ball", "center": [float(x) for x in c], "radius": float(r), "material": names[m]}
        tables.append({"shapes": [ball]})
    if floor:
        plane = {"type": "plane", "normal": [0.0, 1.0, 0.0], "distance": -half * 0.6 - 0.6, "material": "floor"}
        tables.append({"shapes": [plane]})
    return "\n".join(dump_toml(t) for t in tables)
