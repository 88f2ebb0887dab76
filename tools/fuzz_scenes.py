"""Random scenes through `minirt check` with every oracle: a hunt for crashes and false alarms.

    .venv/bin/python tools/fuzz_scenes.py [--seed N] [--count N] [--size N] [--keep DIR]

Each scene has 1-4 balls and 0-2 planes placed around the view (some crossing the image plane or
behind the camera), three random materials, a random light, profile, depth and 1 or 4 samples per
pixel. Every backend must PASS; anything else is printed with the scene file, which is kept (in
--keep, default a temporary folder) so it can be rerun with `minirt check FILE`. The same seed
gives the same scenes. Exit status 1 when a scene did not pass.

Every false alarm it found became a test: tests/test_regression.py (edge scenes) and
tests/scenes/fuzz_reflected_edges.toml.
"""

from __future__ import annotations

import argparse
import random
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from minirt import harness
from minirt.oracles import names as oracle_names


def _vec(rng: random.Random, lo: float, hi: float) -> list[float]:
    return [round(rng.uniform(lo, hi), 3) for _ in range(3)]


def scene_text(rng: random.Random, size: int) -> str:
    lines = [f"[camera]\ndistance = {round(rng.uniform(0.8, 4), 3)}\nwidth = {size}\nheight = {size}"]
    lines.append(f"[light]\nposition = {_vec(rng, -8, 8)}")
    profile = rng.choice(["exercise", "conventional"])
    lines.append(f'[render]\nbackground = {_vec(rng, 0, 0.3)}\nmax_depth = {rng.randint(0, 4)}\n'
                 f'profile = "{profile}"\nsamples = {rng.choice([1, 1, 4])}')  # fmt: skip
    for k in range(3):
        spec = _vec(rng, 0, 0.8) if rng.random() < 0.6 else [0.0, 0.0, 0.0]
        refl = _vec(rng, 0, 0.5) if rng.random() < 0.5 else [0.0, 0.0, 0.0]
        lines.append(f"[materials.m{k}]\nambient = {_vec(rng, 0, 0.2)}\ndiffuse = {_vec(rng, 0, 1)}\n"
                     f"specular = {spec}\nreflection = {refl}")  # fmt: skip
    for _ in range(rng.randint(1, 4)):
        c = [round(rng.uniform(-2, 2), 3), round(rng.uniform(-1.5, 1.5), 3), round(rng.uniform(-1, 8), 3)]
        lines.append(f'[[shapes]]\ntype = "ball"\ncenter = {c}\nradius = {round(rng.uniform(0.1, 1.5), 3)}\n'
                     f'material = "m{rng.randint(0, 2)}"')  # fmt: skip
    for _ in range(rng.randint(0, 2)):
        n = _vec(rng, -1, 1)
        if not any(n):
            n = [0.0, 1.0, 0.0]
        lines.append(f'[[shapes]]\ntype = "plane"\nnormal = {n}\ndistance = {round(rng.uniform(-3, 3), 3)}\n'
                     f'material = "m{rng.randint(0, 2)}"')  # fmt: skip
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--count", type=int, default=12)
    ap.add_argument("--size", type=int, default=24)
    ap.add_argument("--keep", type=Path, default=None, help="folder for the scene files (default: a temporary one)")
    args = ap.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="minirt-fuzz-"))
    folder.mkdir(parents=True, exist_ok=True)
    rng = random.Random(args.seed)
    bad = 0
    for i in range(args.count):
        path = folder / f"fuzz_{args.seed}_{i}.toml"
        path.write_text(scene_text(rng, args.size))
        sc = harness.check_scene(path, ["reference", *oracle_names()])
        problems = {n: f"{b.verdict.upper()} {b.reason}" for n, b in sc.backends.items() if b.verdict != "pass"}
        print(f"{path}: {problems if problems else 'pass'}", flush=True)
        bad += bool(problems)
    print(f"{bad} of {args.count} scene(s) did not pass")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
