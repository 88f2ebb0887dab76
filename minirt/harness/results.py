"""What a check finds, as data: per comparison a Check (verdict, figures, thresholds, the evidence images),
per backend a BackendCheck (its checks, rule effects and RuleDiagnosis), per scene a SceneCheck, per run a
CheckResult (check.json's content, ``as_dict``, and the CLI's exit code).

Verdicts: PASS, WARN, FAIL, ERROR (the backend broke), SKIP (does not apply, with the reason); of several,
the ``worst`` (ORDER) is the one that counts, SKIP only when nothing else was said.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from minirt.harness.tolerances import THRESHOLDS
from minirt.model.result import RenderResult

ORDER = ["skip", "pass", "warn", "fail", "error"]

# The reason of a check that could not fail on most of what it judges starts with this (WARN, not PASS).
INCONCLUSIVE = "inconclusive: "


def worst(verdicts: list[str]) -> str:
    vs = [v for v in verdicts if v]
    if not vs:
        return "skip"
    real = [v for v in vs if v != "skip"]
    return max(real, key=ORDER.index) if real else "skip"


@dataclass
class Check:
    verdict: str
    figures: dict[str, Any] = field(default_factory=dict)
    reason: str = ""
    thresholds: dict[str, str] = field(default_factory=dict)
    images: dict[str, np.ndarray] = field(default_factory=dict)  # evidence for the report

    @property
    def inconclusive(self) -> bool:
        """WARN because the check could not have failed on most of what it judges."""
        return self.verdict == "warn" and self.reason.startswith(INCONCLUSIVE)

    def as_dict(self) -> dict[str, Any]:
        d = {"verdict": self.verdict, **self.figures}
        if self.reason:
            d["reason"] = self.reason
        if self.thresholds:
            d["thresholds"] = self.thresholds
        return d


@dataclass
class RuleDiagnosis:
    """Which rule settings explain an oracle's colour image (minirt.diagnose, searched from the scene's
    rules). Counts are pixels beyond one 8-bit level, ill-conditioned pixels left out."""

    ran: bool = False
    reason: str = ""  # why it did not run, or why no search was needed
    # The diagnosis's changed rules that explain pixels (taken back singly, at least one pixel is lost) ...
    rules_explaining: dict[str, str] = field(default_factory=dict)
    explained: dict[str, int] = field(default_factory=dict)  # ... and per rule, the pixels it explains
    # ... and those the best setting changed too (a whole profile is one step) that explain none: this image
    # cannot tell them from the scene's (a background rule over a black background, say).
    cannot_tell: dict[str, str] = field(default_factory=dict)
    mismatch_pixels: int = 0  # still unexplained under rules_explaining
    as_given_pixels: int = 0  # differing from the reference under the scene's rules
    ill_conditioned_pixels: int = 0
    pixels: int = 0
    declared: dict[str, str] = field(default_factory=dict)  # rules the oracle says it follows, where they differ
    renders: float = 0.0
    seconds: float = 0.0
    unexplained_mask: np.ndarray | None = None
    explained_masks: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def undeclared(self) -> dict[str, str]:
        """Settings that explain the image but that the oracle does not declare: a finding about the oracle."""
        return {k: v for k, v in self.rules_explaining.items() if self.declared.get(k) != v}

    @property
    def not_needed(self) -> dict[str, str]:
        """Declared settings the diagnosis did not need: they change nothing this image shows (e.g. the offset
        under clamping, where a point facing away from the light is dark whether it shadows itself or not)."""
        return {k: v for k, v in self.declared.items() if k not in self.rules_explaining}

    def as_dict(self) -> dict[str, Any]:
        if not self.ran:
            return {"ran": False, "reason": self.reason}
        d: dict[str, Any] = {
            "ran": True,
            "rules_explaining": self.rules_explaining,
            "explained": self.explained,
            "cannot_tell": self.cannot_tell,
            "mismatch_pixels": self.mismatch_pixels,
            "as_given_pixels": self.as_given_pixels,
            "ill_conditioned_pixels": self.ill_conditioned_pixels,
            "pixels": self.pixels,
            "tolerance": "1 level per channel (8-bit)",
            "declared": self.declared,
            "undeclared": self.undeclared,
            "not_needed": self.not_needed,
            "renders": self.renders,
            "seconds": round(self.seconds, 3),
        }
        if self.reason:
            d["reason"] = self.reason
        return d


@dataclass
class BackendCheck:
    backend: str
    verdict: str
    reason: str = ""
    checks: dict[str, Check] = field(default_factory=dict)
    # Rule effects (JSON "rule_effects"): per rule the oracle cannot follow, the pixels of the scene-rules
    # reference that flipping that rule alone changes, and their masks (``attribute_rules``).
    rules: dict[str, int] = field(default_factory=dict)
    rule_masks: dict[str, np.ndarray] = field(default_factory=dict)
    rules_followed: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0
    result: RenderResult | None = None
    reference: RenderResult | None = None
    # Rule diagnosis (JSON "rule_diagnosis"): the settings that explain the oracle's own image.
    rule_diagnosis: RuleDiagnosis = field(default_factory=lambda: RuleDiagnosis(reason="not run"))

    @property
    def rule_effects(self) -> dict[str, int]:
        return self.rules

    @property
    def inconclusive(self) -> bool:
        """A WARN whose only cause is checks that could not have failed (the report shows it as inconclusive)."""
        warned = [c for c in self.checks.values() if c.verdict == "warn"]
        return self.verdict == "warn" and bool(warned) and all(c.inconclusive for c in warned)

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"verdict": self.verdict, "inconclusive": self.inconclusive}
        if self.reason:
            d["reason"] = self.reason
        for name, c in self.checks.items():
            d[name] = c.as_dict()
        d["rule_effects"] = self.rules
        d["rule_diagnosis"] = self.rule_diagnosis.as_dict()
        d["rules_followed"] = self.rules_followed
        d["seconds"] = round(self.seconds, 3)
        if self.result is not None:
            d["version"] = self.result.meta.get("version")
        return d


@dataclass
class SceneCheck:
    scene: str
    file: str  # as the user gave it; a bundled scene by its name (minirt.harness.run.scene_label)
    verdict: str
    backends: dict[str, BackendCheck] = field(default_factory=dict)
    reference: RenderResult | None = None
    description: str = ""
    reason: str = ""
    path: str = ""  # where it was read from (for this run only: not in the document); "": ``file``

    def as_dict(self) -> dict[str, Any]:
        d = {"scene": self.scene, "file": self.file, "verdict": self.verdict, "description": self.description}
        if self.reason:
            d["reason"] = self.reason
        d["backends"] = {k: v.as_dict() for k, v in self.backends.items()}
        return d


@dataclass
class CheckResult:
    verdict: str
    scenes: list[SceneCheck]
    meta: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "scenes": [s.as_dict() for s in self.scenes],
            "thresholds": {k: {"value": t.value, "why": t.why} for k, t in THRESHOLDS.items()},
            **self.meta,
        }

    def exit_code(self) -> int:
        if self.verdict == "error":
            return 2
        return 1 if self.verdict == "fail" else 0
