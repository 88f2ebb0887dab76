"""``minirt grade --program SPEC --fuzz N``: the hard scenes drawn from the fuzz campaign's families
(minirt.campaign) and put through the program (minirt.grading.hard_cases); this module draws and loads
them, keeps their progress and prints a line per scene that fails."""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

from minirt.cli.console import MAX_MESSAGE, err, out
from minirt.cli.options import output_file, parse_size
from minirt.io.untrusted import terminal_text

# The campaign's families that are hard cases for a tracer's arithmetic ("random" is not one), taken in
# turn: scene i is family i mod 6's number i // 6, so --fuzz 6 has one of each.
FAMILIES = ("start", "grazing", "contact", "far", "scaled", "f32")
# The seed of the scenes: fixed, so that --fuzz N is the same N scenes for every program and every run
# (a class's programs meet the same hard cases) and --fuzz N+1 adds one.
SEED = 1


def fuzz_folder(fuzz_dir: Path | None, json_out: str | None) -> Path:
    """Where failing scenes are written: --fuzz-dir, else beside --json FILE, else ./fuzz; checked now
    (bad input before any work), made only when a scene is written."""
    folder = fuzz_dir or (Path(json_out).parent if json_out not in (None, "-") else Path("fuzz"))
    output_file(folder / "scene.toml", "--fuzz-dir")
    return folder


def hard_scenes(n: int, size: str | None, rules) -> list[tuple]:
    """The N scenes as (name, family, text, scene, rules), at the suite's size, each written with ``rules``
    as its own (minirt.grading.hard_cases.scene_with_rules): the scene a user reproduces is the one compared."""
    import tomllib

    from minirt.campaign import campaign
    from minirt.errors import MinirtError
    from minirt.grading import hard_cases
    from minirt.grading.suite import SUITE_SIZE
    from minirt.model.bundled import scene_and_rules
    from minirt.model.scene import parse_scene

    wh = parse_size(size) or SUITE_SIZE
    out = []
    for name, family, drawn in campaign.scenes(n, SEED, FAMILIES, wh):
        text = hard_cases.scene_with_rules(tomllib.loads(drawn), rules)
        scene, own = scene_and_rules(parse_scene(text, name), None, None, 1)
        if own != rules:  # the file must say what was compared; a rule TOML cannot hold would be a bug here
            raise MinirtError(f"fuzz scene {name}: its [model] table does not reproduce the rules {own.differs(rules)}")
        out.append((name, family, text, scene, own))
    return out


def run_fuzz(spec, g, n: int, folder: Path, size, bar=None) -> dict[str, Any]:
    """The N hard scenes through the program graded as ``g``: compared under the rules of its suite with
    the suite's diagnosis applied (minirt.grading.hard_cases.hard_rules); the JSON's ``fuzz`` part."""
    from minirt.grading import hard_cases
    from minirt.model import rules as rules_mod

    rules = hard_cases.hard_rules(g.scenes[0].rules, g.diagnosis.changes)
    doc = {"seed": SEED, "families": list(FAMILIES), "rules": {k: rules_mod.format_rule_value(k, getattr(rules, k))
           for k in sorted(rules.as_dict())}, "failed": 0, "scenes": [], "not_run": ""}  # fmt: skip
    if g.verdict == "error":  # no rules found, and nothing the hard scenes could add to "it draws nothing"
        return doc | {"not_run": "the program drew no image of the suite"}
    cases = hard_scenes(n, size, rules)
    task = bar.add_task("hard cases", total=len(cases)) if bar else None

    def done(case) -> None:
        if bar:
            bar.advance(task)

    graded = hard_cases.grade_hard_cases(spec, cases, folder, spec.timeout, on_case=done)
    failed = [c for c in graded if c.verdict != hard_cases.OK]
    return doc | {"failed": len(failed), "scenes": [c.as_dict() for c in graded]}


def print_fuzz(doc: dict[str, Any], program: str) -> None:
    """A line per hard scene that fails (its sentence and how to reproduce it), and the count."""
    for c in doc["scenes"]:
        if c["verdict"] == "ok":
            continue
        where = f" at pixel {c['example'][0]},{c['example'][1]}" if c["example"] else ""
        err.print(terminal_text(f"  fuzz {c['scene']} ({c['family']}) {c['verdict']}: {c['sentence']}{where}",
                                MAX_MESSAGE))  # fmt: skip
        err.print(
            terminal_text(
                f"    reproduce: minirt grade --program {shlex.quote(program)} {shlex.quote(c['scene_file'])}",
                MAX_MESSAGE,
            )
        )
    if doc["not_run"]:
        out.print(f"fuzz: not run: {doc['not_run']}")
        return
    out.print(f"fuzz: {len(doc['scenes'])} hard scenes, {doc['failed']} with numerical failures or errors")
