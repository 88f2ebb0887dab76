"""Do two checkouts of minirt write the same outputs? Runs each command in both trees and compares what they write.

    .venv/bin/python tools/same_outputs.py --base OTHER_TREE [--tree THIS_TREE] [--set exact|render|all]
        [--command 'render three_balls -b exact --width 48 --height 32 --out {out}'] [--keep DIR]

Each command is a ``minirt`` command line with ``{out}`` for an output folder of its own (files it writes go
there); it runs as ``TREE/.venv/bin/python -m minirt ...``, each tree's own virtual environment (``make
setup`` there, or a copy of this one's with its editable install pointed at the tree): the package maps
``minirt.oracles`` to the top-level ``oracles/`` folder through its install, so a tree put first on
``PYTHONPATH`` alone would still import the installed tree's oracles. Then, per command:

- the exit status must be equal;
- the two output folders must hold the same file names; a ``.json`` file must hold the same document once
  every key naming a time (``TIMING_KEYS``: wall and CPU times, which differ run to run) is dropped at any
  depth; every other file must be the same bytes (PNG, EXR with every buffer, NumPy arrays, CSV, HTML);
- what the command prints is not compared (progress and times).

Prints one line a command (``same`` or what differs, with the SHA-256 of each differing file) and exits 1 if
anything differs, 0 if all is the same. ``--keep DIR`` keeps both trees' outputs (DIR/a, DIR/b).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

# Keys whose values are times (seconds, rates): dropped from JSON documents before comparing.
TIMING_KEYS = frozenset({
    "timings", "timing", "seconds", "elapsed", "wall", "cpu", "duration", "per_ray", "started", "finished",
    "wall_seconds", "cpu_seconds", "time", "times", "date", "created",
})  # fmt: skip

BUNDLED = ("exercise", "three_balls", "rules", "shadows", "matte", "soft", "colored_specular")

# The certified oracle's renders and checks: every bundled scene rendered whole at a small size (every
# buffer, aux included, in the EXR), a supersampled render, a rule override, and the check of each bundled
# scene at its own size (the edge-and-sample pixels on worker processes) as a JSON document.
EXACT_SET = (
    *(f"render {s} -b exact --width 40 --height 32 --out {{out}} --quiet" for s in BUNDLED),
    "render three_balls -b exact --width 24 --height 24 --samples 4 --out {out} --quiet",
    "render rules -b exact --width 32 --height 32 --rule clamp=true --rule two_sided=true --out {out} --quiet",
    "render shadows -b exact --width 32 --height 32 --rule offset=error-bound --out {out} --quiet",
    *(f"check {s} -b exact --quiet --json {{out}}/check.json" for s in BUNDLED),
)
# The reference's renders and the check's documents of the other oracles that run here.
RENDER_SET = (
    *(f"render {s} --out {{out}} --quiet" for s in BUNDLED),
    "render three_balls --width 300 --height 200 --samples 4 --out {out} --quiet",
    "render exercise --precision f32 --out {out} --quiet",
)
SETS = {"exact": EXACT_SET, "render": RENDER_SET, "all": EXACT_SET + RENDER_SET}


def strip_times(doc):
    """The JSON document without any key in TIMING_KEYS, at any depth."""
    if isinstance(doc, dict):
        return {k: strip_times(v) for k, v in doc.items() if k not in TIMING_KEYS}
    if isinstance(doc, list):
        return [strip_times(v) for v in doc]
    return doc


def interpreter(tree: Path) -> Path:
    """The tree's own Python (module docstring), after checking that it imports minirt and its oracles from
    the tree."""
    python = tree / ".venv" / "bin" / "python"
    if not python.exists():
        raise SystemExit(f"{tree}: no .venv/bin/python (make setup there)")
    probe = "import minirt, minirt.oracles; print(minirt.__file__); print(minirt.oracles.__file__)"
    where = subprocess.run([str(python), "-c", probe], cwd=tempfile.gettempdir(), capture_output=True, text=True)
    paths = [Path(p).resolve() for p in where.stdout.split()]
    if where.returncode or len(paths) != 2 or not all(p.is_relative_to(tree.resolve()) for p in paths):
        raise SystemExit(f"{tree}: its .venv imports minirt from elsewhere: {where.stdout.strip() or where.stderr}")
    return python


def run(python: Path, command: str, out: Path) -> int:
    """``python -m minirt COMMAND`` in the output folder; its exit status."""
    out.mkdir(parents=True, exist_ok=True)
    args = [a.replace("{out}", str(out)) for a in shlex.split(command)]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    done = subprocess.run([str(python), "-m", "minirt", *args], env=env, cwd=out, capture_output=True)
    return done.returncode


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def compare(a: Path, b: Path) -> list[str]:
    """What differs between the output folders a and b (empty: the same)."""
    fa = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    fb = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    diffs = [f"only in one tree: {p}" for p in sorted(set(fa) ^ set(fb))]
    for rel in sorted(set(fa) & set(fb)):
        pa, pb = a / rel, b / rel
        if rel.suffix == ".json":
            try:
                same = strip_times(json.loads(pa.read_text())) == strip_times(json.loads(pb.read_text()))
            except ValueError:
                same = pa.read_bytes() == pb.read_bytes()
        else:
            same = pa.read_bytes() == pb.read_bytes()
        if not same:
            diffs.append(f"{rel}: {digest(pa)} != {digest(pb)}")
    return diffs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, type=Path, help="the other checkout (its top folder)")
    ap.add_argument("--tree", type=Path, default=Path(__file__).resolve().parents[1], help="this checkout")
    ap.add_argument("--set", choices=sorted(SETS), default="exact", help="the commands to run (default exact)")
    ap.add_argument("--command", action="append", default=[], help="a command instead of the set (repeatable)")
    ap.add_argument("--keep", type=Path, default=None, help="keep both trees' outputs in DIR/a and DIR/b")
    args = ap.parse_args()
    commands = args.command or list(SETS[args.set])
    pythons = (interpreter(args.tree), interpreter(args.base))
    root = args.keep or Path(tempfile.mkdtemp(prefix="same-outputs-"))
    failed = 0
    for k, command in enumerate(commands):
        out_a, out_b = root / "a" / f"{k:02d}", root / "b" / f"{k:02d}"
        status = (run(pythons[0], command, out_a), run(pythons[1], command, out_b))
        diffs = [] if status[0] == status[1] else [f"exit status {status[0]} != {status[1]}"]
        diffs += compare(out_a, out_b)
        files = sum(1 for p in out_a.rglob("*") if p.is_file())
        print(f"{'same' if not diffs else 'DIFFERS'}  ({files} files, exit {status[0]})  minirt {command}", flush=True)
        for d in diffs:
            print(f"    {d}")
        failed += bool(diffs)
    print(f"{len(commands) - failed} of {len(commands)} commands write the same outputs")
    if args.keep is None:
        import shutil

        shutil.rmtree(root, ignore_errors=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
