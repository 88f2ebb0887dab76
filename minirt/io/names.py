"""Output file names made from a scene and what a render changed: the one place that names render files.

A plain ``minirt render SCENE`` writes ``SCENE.BACKEND.png`` (and ``.exr``, ``.json``). A render under
another model -- another profile or rule than the scene's own -- is a variant, named by what differs:
``exercise.reference+clamp=true.png``, ``exercise.povray+profile=conventional+offset=0.001.png``. So a
variant never overwrites the render of the scene's own model (or another variant), and the name says how
to make it again. Only what actually differs counts: ``--rule clamp=false`` on a scene that does not clamp
is the plain render. Size, samples and precision are the same model rendered finer or coarser: they keep
the plain name (``--out`` separates them).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from minirt.io.untrusted import file_stem, name_part
from minirt.model.rules import Rules, format_rule_value, resolve
from minirt.model.scene import Scene

MAX_TAG = 96  # a longer tag is cut, and a hash of the whole keeps it unique


def variant_tag(plain: Scene, scene: Scene, rules: Rules) -> str:
    """What the model of a render of ``scene`` under ``rules`` changes from the scene's own (``plain``, the
    scene as loaded): ``"profile=conventional+clamp=true"``, or ``""`` for the scene's own model."""
    parts = []
    if scene.profile != plain.profile:
        parts.append(f"profile={scene.profile}")
    profile_rules = resolve(scene)  # the scene's own model under the render's profile
    parts += [f"{k}={format_rule_value(k, getattr(rules, k))}" for k in sorted(rules.differs(profile_rules))]
    tag = "+".join(name_part(p) for p in parts)  # '+' separates the parts
    if len(tag) > MAX_TAG:
        tag = f"{tag[: MAX_TAG - 13]}+{hashlib.sha256(tag.encode()).hexdigest()[:12]}"
    return tag


def render_stem(scene: Scene, backend: str, tag: str = "") -> str:
    """``SCENE.BACKEND`` or ``SCENE.BACKEND+TAG``: the stem of a render's .png, .exr and .json (a program,
    ``program:SPEC``, is ``program``)."""
    backend = backend.partition(":")[0].partition("(")[0]
    return f"{scene_stem(scene)}.{backend}" + (f"+{tag}" if tag else "")


def contact_sheet_name(scene: Scene, tag: str = "") -> str:
    return f"{scene_stem(scene)}.contact" + (f"+{tag}" if tag else "") + ".png"


def scene_stem(scene: Scene) -> str:
    """The scene's part of every output name: its name made a safe file stem (see minirt.io.untrusted), so a
    name like ``../../x`` or ``/etc/x`` still writes inside --out; an unusable name falls back to the
    file's stem."""
    fallback = file_stem(Path(scene.source).stem) if scene.source else "scene"
    return file_stem(scene.name, fallback)
