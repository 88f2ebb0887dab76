"""Random scenes through `minirt check` with every oracle: a hunt for crashes and false alarms.

    .venv/bin/python tools/fuzz_scenes.py [--seed N] [--count N] [--size N] [--family NAME] [--keep DIR]

Each scene has 1-4 balls and 0-2 planes placed around the view (some crossing the image plane or
behind the camera), three random materials, a random light, profile, depth and 1 or 4 samples per
pixel. Every backend must PASS; anything else is printed with the scene file, which is kept (in
--keep, default a temporary folder) so it can be rerun with `minirt check FILE`. The same seed
gives the same scenes. The scenes come from minirt.fuzz: family `random` by default, or any of its
hard-case families with --family (start, grazing, contact, far, scaled, f32). Exit status 1 when a
scene did not pass.

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

from minirt import fuzz, harness
from minirt.oracles import names as oracle_names


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--count", type=int, default=12)
    ap.add_argument("--size", type=int, default=24)
    ap.add_argument("--family", choices=list(fuzz.FAMILIES), default="random", help="hard-case family (minirt.fuzz)")
    ap.add_argument("--keep", type=Path, default=None, help="folder for the scene files (default: a temporary one)")
    args = ap.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="minirt-fuzz-"))
    folder.mkdir(parents=True, exist_ok=True)
    rng = random.Random(args.seed)
    bad = 0
    for i in range(args.count):
        path = (
            folder / f"fuzz_{args.family}_{args.seed}_{i}.toml"
            if args.family != "random"
            else folder / f"fuzz_{args.seed}_{i}.toml"
        )
        if args.family == "random":  # one stream over the run, as before: old seeds give the same scenes
            path.write_text(fuzz.FAMILIES["random"].function(rng, args.size, args.size))
        else:
            path.write_text(fuzz.scene_text(args.family, args.seed, i, args.size, args.size))
        sc = harness.check_scene(path, ["reference", *oracle_names()])
        problems = {n: f"{b.verdict.upper()} {b.reason}" for n, b in sc.backends.items() if b.verdict != "pass"}
        print(f"{path}: {problems if problems else 'pass'}", flush=True)
        bad += bool(problems)
    print(f"{bad} of {args.count} scene(s) did not pass")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
