"""Whole commands, as a user waits for them (issue 37): start-up and a large render against POV-Ray.

    .venv/bin/python benchmarks/bench_commands.py [--runs 7] [--balls 200] [--size 1024] [--out FILE.json]

Each pair of commands runs in turn, A B A B ..., in child processes (start-up, imports and the files
written included), and the ratio A/B is taken pair by pair, so a machine whose speed drifts (a shared
VM) moves both sides of a ratio alike. Figures: min / median / max of the wall times and of the ratios.

- ``help``: ``minirt --help`` against ``python -c "import numpy"`` (target: ratio <= 3).
- ``render``: ``minirt render SCENE --out DIR -q`` of a scene of random balls over a mirror floor
  (benchmarks/balls_scene.py: 200 balls, 1024x1024, seed 1) against POV-Ray's whole command on the
  same scene as ``minirt export --to povray`` writes it (its render.sh: ``povray ... +Iscene.pov``;
  target: ratio <= 1). The reference's kernels are compiled once before the runs (Dr.Jit's disk cache).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from minirt.campaign.generate import balls_scene

MINIRT = [sys.executable, "-m", "minirt"]
TARGETS = {"help": 3.0, "render": 1.0}  # A/B medians at most this (issue 37)


def timed(cmd: list[str], cwd: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def pair(a: list[str], b: list[str], runs: int, cwd: Path) -> dict[str, Any]:
    """A and B in turn, ``runs`` times each after one warm-up of each: wall seconds and A/B per pair."""
    timed(a, cwd), timed(b, cwd)
    ta, tb = [], []
    for _ in range(runs):
        ta.append(timed(a, cwd))
        tb.append(timed(b, cwd))

    def stats(xs: list[float]) -> dict[str, float]:
        return {"min": min(xs), "median": statistics.median(xs), "max": max(xs)}

    ratios = [x / y for x, y in zip(ta, tb, strict=True)]
    return {"a": a, "b": b, "a_s": stats(ta), "b_s": stats(tb), "ratio": stats(ratios)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--balls", type=int, default=200)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, help="write the figures as JSON here")
    args = ap.parse_args(argv)
    res: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="minirt-bench-") as tmp:
        work = Path(tmp)
        res["help"] = pair([*MINIRT, "--help"], [sys.executable, "-c", "import numpy"], args.runs, work)
        scene = work / "balls.toml"
        scene.write_text(balls_scene(args.balls, seed=args.seed, width=args.size, height=args.size, max_depth=3))
        if shutil.which("povray") is None:
            res["render"] = {"skipped": "povray is not on PATH"}
        else:
            export = [*MINIRT, "export", str(scene), "--to", "povray", "--out", "pov"]
            subprocess.run(export, cwd=work, check=True, stdout=subprocess.DEVNULL)
            render = [*MINIRT, "render", str(scene), "--out", "out", "-q"]
            res["render"] = pair(render, ["sh", str(work / "pov" / "render.sh")], args.runs, work)
            res["render"]["scene"] = {"balls": args.balls, "size": args.size, "seed": args.seed}
    for name, r in res.items():
        if "ratio" not in r:
            print(f"{name}: {r}")
            continue
        ok = r["ratio"]["median"] <= TARGETS[name]
        r["target"], r["verdict"] = TARGETS[name], "PASS" if ok else "MISS"
        print(
            f"{name}: A {r['a_s']['median']:.3f} s (min {r['a_s']['min']:.3f}, max {r['a_s']['max']:.3f}), "
            f"B {r['b_s']['median']:.3f} s (min {r['b_s']['min']:.3f}, max {r['b_s']['max']:.3f}), "
            f"A/B median {r['ratio']['median']:.2f} (min {r['ratio']['min']:.2f}, max {r['ratio']['max']:.2f}); "
            f"target <= {TARGETS[name]}: {r['verdict']}"
        )
    if args.out:
        args.out.write_text(json.dumps(res, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
