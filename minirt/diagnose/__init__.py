"""Diagnosis: which rule settings explain an image?

Given a scene and an image that some tracer made of it (a student's, or an oracle's colour buffer),
search the space of model rules (minirt.model.rules) for the setting whose render reproduces the image, and
say how many pixels each differing rule explains. ``grade`` uses it for outside images; ``check``
uses it for an oracle's remaining difference. It sits beside the harness: it consumes renders of the
reference tracer and rule sets, and never changes the tracer.

One module per concern, and this package's names are its API (``from minirt import diagnose as dg``):

- minirt.diagnose.target: the image to explain (``Target``) and how a render is scored against it
  (``FLOAT_TOL``, ``LEVEL_TOL``);
- minirt.diagnose.variants: the candidates' renders and the ``VariantCache`` a class run shares
  (``EPS_REL``: the ill-conditioned pixels);
- minirt.diagnose.search: the greedy descent in rule space;
- minirt.diagnose.evidence: what the image shows of each rule (leave-one-out) and "one of" where it cannot
  decide; minirt.diagnose.fit: the exercise's formula fitted to what no rule explains; minirt.diagnose.rest:
  where that lies; minirt.diagnose.joint: one diagnosis for several images of one program (``diagnose_joint``);
- minirt.diagnose.explain: ``diagnose`` (the search, then what each changed rule explains) and the settings
  a scene cannot tell apart (``indistinguishable``, ``tells_apart``, ``GRADING_SET``).

May import: minirt.reference, minirt.model and below.
"""

from minirt.diagnose.explain import (
    GRADING_SET,
    SAME_UNDER_EXERCISE,
    Diagnosis,
    Explained,
    diagnose,
    distinct_pixels,
    indistinguishable,
    tells_apart,
    why_same,
)
from minirt.diagnose.joint import JointDiagnosis, diagnose_joint
from minirt.diagnose.target import FLOAT_TOL, LEVEL_TOL, Target
from minirt.diagnose.variants import EPS_REL, Variant, VariantCache

__all__ = [
    "EPS_REL",
    "FLOAT_TOL",
    "GRADING_SET",
    "LEVEL_TOL",
    "SAME_UNDER_EXERCISE",
    "Diagnosis",
    "Explained",
    "JointDiagnosis",
    "Target",
    "Variant",
    "VariantCache",
    "diagnose",
    "diagnose_joint",
    "distinct_pixels",
    "indistinguishable",
    "tells_apart",
    "why_same",
]
