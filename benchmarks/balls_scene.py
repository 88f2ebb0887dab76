"""Write a scene of random balls over a mirror floor, deterministic by seed: the workload of the whole-command
render benchmark (benchmarks/README.md, issue 37: 200 balls at 1024x1024 against POV-Ray's whole command).

    .venv/bin/python benchmarks/balls_scene.py OUT.toml [--balls 200] [--size 1024] [--seed 1]

The layout is minirt.campaign.generate.balls_scene's (the scale benchmark's too): n balls in a slab that
grows as n^(1/3), four materials, a mirror floor, max_depth 3. The same arguments write the same bytes.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from minirt.campaign.generate import balls_scene


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", type=Path, help="the scene file to write (TOML)")
    ap.add_argument("--balls", type=int, default=200)
    ap.add_argument("--size", type=int, default=1024, help="width and height in pixels")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    a.out.write_text(balls_scene(a.balls, seed=a.seed, width=a.size, height=a.size, max_depth=3))
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
