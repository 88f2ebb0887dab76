"""Grading a program, not one picture: a student's program rendered over a suite of scenes, each image
diagnosed, and one verdict for the program.

``grade_program`` renders every scene of the suite through the program (minirt.oracles.program: a command
line or a C++ source, in a sandbox), grades each image with the single-image machinery
(minirt.diagnose.diagnose, as minirt.grading.grade does) and combines the scenes in ``diagnose_suite``,
the one place that turns the scenes' images into the program's diagnosis. A scene the program fails
(compile error, crash, time-out, no image, a wrong-sized one) is that scene's ``error``; the run goes on.

Each scene's time limit is ``timeout_for``: ``TIMEOUT_FACTOR`` times the reference tracer's own time for
the scene, at least ``TIMEOUT_FLOOR`` seconds -- so a program that hangs costs a few of these, not the
suite's. The JSON carries no timings: the same program and suite write the same bytes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from minirt import diagnose as dg
from minirt.grading import suite as suite_mod
from minirt.grading.grade import DIFFERS, ERROR, EXIT, MATCH, Grade, sentence
from minirt.model import rules as rules_mod
from minirt.model.rules import PROFILES, Rules
from minirt.model.scene import Scene
from minirt.oracles.program import ProgramOracle, ProgramSpec, Run

# A scene's time limit: the reference's time (vectorised float64, ~10-50 ms at 96^2) times this, at least
# the floor. A C++ or NumPy program is within 10x of the reference; a pure-Python one (one Python call per
# ray and shape, ~1000x) still fits 96^2 in the floor; a program beyond both is reported as timed out.
TIMEOUT_FACTOR = 200.0
TIMEOUT_FLOOR = 20.0


def timeout_for(reference_seconds: float) -> float:
    return max(TIMEOUT_FLOOR, TIMEOUT_FACTOR * reference_seconds)


def given_rules(rules: Rules, spec: ProgramSpec, profile_given: bool) -> Rules:
    """The model a program is graded against: the scene's rules, or the 2014 edition's for a 2014 source
    (unless --profile said otherwise)."""
    if spec.kind == "cpp" and spec.edition == "2014" and not profile_given:
        return PROFILES["eth2014"]
    return rules


@dataclass
class SceneGrade(Grade):
    """One scene of the suite through the program: a ``Grade`` of the image it drew (``image`` the file's
    name as the program wrote it; ``reason``, why it drew none), with the rules it was graded against and
    the program's wall clock on it."""

    rules: Rules | None = None
    seconds: float = 0.0  # the program's wall clock on it (not in the JSON)
    timeout: float = 0.0
    # one of the 2014 course's test scenes: what the course's 10x10-grid comparison would have said ("pass",
    # "fail"; None when the program drew no float image, which the course's in-memory colours were)
    course_grid: str | None = None
    course: bool = False

    @property
    def error(self) -> str:
        """Why the program drew no image of this scene ("" when it did)."""
        return self.reason

    def as_dict(self) -> dict[str, Any]:
        d = self.diagnosis
        out: dict[str, Any] = {
            "scene": self.scene.name,
            "scene_file": self.scene_file,
            "size": [self.scene.camera.width, self.scene.camera.height],
            "verdict": self.verdict,
            "mismatch_pixels": d.mismatch_pixels if d else None,
            "as_given_pixels": d.as_given_pixels if d else None,
            "rules": d.changed if d else {},
            "undetermined": sorted(d.undetermined) if d else [],  # rules this image alone cannot decide
            "error": self.error,
        }
        if self.target is not None:
            out["image_format"] = "float" if self.target.is_float else "8-bit"
        if self.course:
            out["course_grid"] = self.course_grid
        return out


def diagnose_suite(graded: list[SceneGrade], cache: dg.VariantCache | None = None) -> dg.JointDiagnosis:
    """The program's one diagnosis: the images it drew, weighed together (minirt.diagnose.joint), so that a
    setting that fits one scene by accident and breaks another is never chosen. Scenes that failed take
    no part."""
    drawn = [g for g in graded if g.target is not None]
    # each scene's own search was run for its grade: its answer is what the scene proposes
    answers = [g.diagnosis.searched for g in drawn]
    return dg.diagnose_joint([(g.scene, g.rules, g.target) for g in drawn], cache, answers)


@dataclass
class ProgramGrade:
    spec: ProgramSpec
    scenes: list[SceneGrade]
    diagnosis: dg.JointDiagnosis
    compile: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def verdict(self) -> str:
        if all(g.verdict == ERROR for g in self.scenes):
            return ERROR
        return MATCH if all(g.verdict == MATCH for g in self.scenes) else DIFFERS

    @property
    def exit_code(self) -> int:
        return EXIT[self.verdict]

    def summary(self) -> str:
        n = len(self.scenes)
        counts = {v: sum(g.verdict == v for g in self.scenes) for v in (MATCH, DIFFERS, ERROR)}
        head = f"{counts[MATCH]} of {n} scenes match, {counts[DIFFERS]} differ, {counts[ERROR]} failed"
        if self.compile is not None and not self.compile["ok"]:
            return "the program does not compile"
        d = self.diagnosis
        if d.rules:
            head += "; explained by " + ", ".join(f"{k}={v}" for k, v in d.rules.items())
        if d.mismatch_pixels:
            head += f"; {d.mismatch_pixels} pixels unexplained"
        return head

    def _sentence(self, rule: str) -> str:
        """The sentence for the student on one rule of the program's diagnosis (against the suite's rules)."""
        given = self.scenes[0].rules
        return sentence(rule, self.diagnosis.changes[rule], getattr(given, rule))

    def as_dict(self) -> dict[str, Any]:
        d = self.diagnosis
        return {
            "verdict": self.verdict,
            "summary": self.summary(),
            "program": {**self.spec.describe(), "compile": self.compile},
            "scenes": [g.as_dict() for g in self.scenes],
            "diagnosis": {
                # decided by the images together; ``undetermined``: what they cannot decide
                "rules": d.rules,
                "undetermined": d.undetermined,
                "undetermined_sentence": d.undetermined_sentence,
                "mismatch_pixels": d.mismatch_pixels,
                "broken_pixels": d.broken_pixels,
                "explained": [dict(e, sentence=self._sentence(e["rule"])) for e in d.explained],
                "rejected": [r.as_dict() for r in d.rejected],
                "unexplained": d.unexplained,
            },
            "indistinguishable": d.indistinguishable,
            "notes": self.notes,
        }


def run_program(
    oracle: ProgramOracle, scene: Scene, rules: Rules, timeout: float | None, nonfinite: bool = False
) -> tuple[Scene, Run, float]:
    """``scene`` through the program, one sample a pixel, as the program receives it (``scene_as_rendered``),
    within ``timeout`` seconds (None: ``timeout_for`` the reference's time on it under ``rules``):
    (that scene, the run, the timeout). ``nonfinite``: see ``ProgramOracle.run_scene``."""
    from minirt.harness import backends

    scene = oracle.scene_as_rendered(scene.with_overrides(samples=1))
    if timeout is None:
        t0 = time.perf_counter()
        backends.render(backends.REFERENCE, scene, rules)
        timeout = timeout_for(time.perf_counter() - t0)
    return scene, oracle.run_scene(scene, timeout, nonfinite=nonfinite), timeout


def grade_scene(
    oracle: ProgramOracle, scene: Scene, scene_file: str, rules: Rules, cache: dg.VariantCache, timeout: float | None
) -> SceneGrade:
    """One scene through the program, its image diagnosed (or its error)."""
    scene, run, timeout = run_program(oracle, scene, rules, timeout)
    course = scene.name in suite_mod.COURSE_2014
    times = {"rules": rules, "seconds": run.seconds, "timeout": timeout, "course": course}
    if run.error:
        return SceneGrade(scene, scene_file, "", ERROR, reason=run.error, **times)
    target = dg.Target(run.pixels, run.is_float, run.image_name)
    d = dg.diagnose(scene, rules, target, cache, swaps=False)  # the suite's answer's: diagnose_suite
    verdict = MATCH if d.as_given_pixels == 0 else DIFFERS
    grid = suite_mod.course_grid(target.in_layout(rules), d.given_color) if course and target.is_float else None
    return SceneGrade(scene, scene_file, run.image_name, verdict, diagnosis=d, target=target, course_grid=grid, **times)


def grade_program(
    spec: ProgramSpec,
    suite: list[tuple[str, Scene, Rules]],
    timeout: float | None = None,
    on_scene=None,
    cache: dg.VariantCache | None = None,
) -> ProgramGrade:
    """Render every (scene file, scene, rules) of ``suite`` through the program and grade it: one
    ``SceneGrade`` per scene and the program's diagnosis (``diagnose_suite``). ``timeout``: seconds per
    scene (None: ``timeout_for`` the reference's time). ``on_scene(SceneGrade)`` is called as each is done.
    ``cache``: the reference's renders, which programs graded over the same suite may share.
    Raises MinirtError for bad input (no sandbox, no compiler)."""
    oracle = ProgramOracle(spec)
    oracle.require_sandbox()
    build = oracle.build()
    cache = cache or dg.VariantCache(share=False)
    graded = []
    for scene_file, scene, rules in suite:
        g = grade_scene(oracle, scene, scene_file, rules, cache, timeout or spec.timeout)
        graded.append(g)
        if on_scene is not None:
            on_scene(g)
    compiled = build.as_dict() if build is not None else None
    return ProgramGrade(spec, graded, diagnose_suite(graded, cache), compile=compiled)


def format_rules(rules: Rules) -> dict[str, str]:
    return {n: rules_mod.format_rule_value(n, v) for n, v in rules.as_dict().items()}
