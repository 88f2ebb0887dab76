"""Write the bundled sample "student" images.

- scenes/samples/rules.student.png: scenes/rules.toml as a tracer with two classic mistakes draws it
  (rays through pixel centres, the 2014 edition's (r·s)^16), saved the way a student's bitmap writer
  would (min(255, floor(256·c))), with float32-like rounding noise on the colours.
- scenes/samples/three_balls.student.png: scenes/three_balls.toml with bugs seen in a real solution of
  the exercise: a closest-hit search that starts at a finite "infinity" (t_max = 9.5), a ball's normal
  p - c used in the diffuse term without dividing by the radius (raw_normals_ball = "shading"), bytes written
  as min(255, floor(256·c)); and one the rule table does not have -- the blue ball's diffuse colour
  typed as (0.1, 0.1, 0.9) instead of the scene's -- which the grade reports as a group of unexplained
  pixels on that ball where it faces the light.

    .venv/bin/python tools/make_sample_student.py   # rewrites both

`make demo` grades them: `minirt grade scenes/rules.toml scenes/samples/rules.student.png`, and the same
for three_balls.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from minirt.io.images import write_image
from minirt.model import bitmap
from minirt.model.rules import resolve
from minirt.model.scene import load_scene
from minirt.reference.tracer import render

OUT = Path(__file__).resolve().parent.parent / "scenes" / "samples" / "rules.student.png"
REAL = OUT.parent / "three_balls.student.png"


def main() -> None:
    scene = load_scene(OUT.parent.parent / "rules.toml")
    rules = replace(resolve(scene), pixel_sample="center", specular_exponent=16, encoding="floor256")
    color = render(scene, rules.traced(), precision="f32").color  # a float32 tracer, like most students'
    write_image(OUT, bitmap.bitmap(color, rules))
    _said(OUT)

    scene = load_scene(OUT.parent.parent / "three_balls.toml")
    rules = replace(resolve(scene), t_max=9.5, raw_normals_ball="shading", encoding="floor256")
    shapes = list(scene.shapes)
    blue = next(k for k, s in enumerate(shapes) if s.material.name == "blue")
    m = shapes[blue].material
    shapes[blue] = replace(shapes[blue], material=replace(m, diffuse=(0.1, 0.1, 0.9)))
    color = render(replace(scene, shapes=tuple(shapes)), rules.traced(), precision="f32").color
    write_image(REAL, bitmap.bitmap(color, rules))
    _said(REAL)


def _said(path: Path) -> None:
    print(f"wrote {path.relative_to(Path.cwd()) if path.is_relative_to(Path.cwd()) else path}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
