"""Write the bundled sample "student" image: scenes/rules.toml as a tracer with two classic mistakes
draws it (rays through pixel centres, the 2014 edition's (r·s)^16), saved the way a student's bitmap
writer would (min(255, floor(256·c))), with float32-like rounding noise on the colours.

    .venv/bin/python tools/make_sample_student.py   # rewrites scenes/samples/rules.student.png

`make demo` grades it: `minirt grade scenes/rules.toml scenes/samples/rules.student.png`.
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


def main() -> None:
    scene = load_scene(OUT.parent.parent / "rules.toml")
    rules = replace(resolve(scene), pixel_sample="center", specular_exponent=16, encoding="floor256")
    color = render(scene, rules.traced(), precision="f32").color  # a float32 tracer, like most students'
    write_image(OUT, bitmap.bitmap(color, rules))
    print(f"wrote {OUT.relative_to(Path.cwd()) if OUT.is_relative_to(Path.cwd()) else OUT}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
