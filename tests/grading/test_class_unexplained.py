"""A class whose students share a bug the rule table does not have: the class page and grades.json list the
group it leaves (the same scene, shapes and conditions) with the students who have it, most students first."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from support.inproc import minirt
from support.plain import Plain
from support.students import noisy, small_scene

from minirt.io.images import write_image
from minirt.model import bitmap, camera
from minirt.model import rules as R
from minirt.model.scene import Ball


def _image(scene, rules, floor_factor: float) -> np.ndarray:
    """The exercise's model by the plain transcription, the floor's diffuse colour times ``floor_factor``."""
    shapes = list(scene.shapes)
    k = next(k for k, s in enumerate(shapes) if not isinstance(s, Ball))
    m = shapes[k].material
    shapes[k] = replace(shapes[k], material=replace(m, diffuse=tuple(floor_factor * c for c in m.diffuse)))
    bug = replace(scene, shapes=tuple(shapes))
    o, d = camera.primary_rays(bug, rules)
    colors = [
        Plain(bug, rules).trace(tuple(map(float, a)), tuple(map(float, b)), bug.max_depth)
        for a, b in zip(o, d, strict=True)
    ]
    h, w = scene.camera.height, scene.camera.width
    return bitmap.bitmap(noisy(np.array(colors).reshape(h, w, 3)), rules)


def test_common_unexplained_groups_across_the_class(tmp_path):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    text = Path(small_scene("exercise").source).read_text(encoding="utf-8")
    small = text.replace("width = 256", "width = 48").replace("height = 256", "height = 48")
    (scenes / "exercise.toml").write_text(small, encoding="utf-8")
    scene = small_scene("exercise", 48, 48)
    rules = R.resolve(scene)
    for student, factor in (("ann", 1.5), ("bob", 1.5), ("cy", 1.0)):
        (tmp_path / "class" / student).mkdir(parents=True)
        write_image(tmp_path / "class" / student / "exercise.png", _image(scene, rules, factor))
    run = minirt("grade", "--class", tmp_path / "class", "--scenes", scenes, "-o", tmp_path / "out", "--workers", "1")
    assert run.returncode == 0, run.stderr
    doc = json.loads((tmp_path / "out" / "grades.json").read_text(encoding="utf-8"))
    common = doc["common_unexplained"]
    floor = next(k for k, s in enumerate(scene.shapes) if not isinstance(s, Ball))
    top = common[0]
    assert top["scene"] == "exercise" and top["shapes"] == [floor] and top["students"] == 2, common
    assert top["conditions"].get("lit") is True and "lit by the light" in top["sentence"]
    rows = {r["student"]: r for r in doc["grades"]}
    assert "unexplained" not in rows["cy"] and rows["ann"]["unexplained"][0]["shapes"] == [floor]
    page = (tmp_path / "out" / "index.html").read_text(encoding="utf-8")
    assert "Most common unexplained groups" in page and top["sentence"].split(":")[0] in page
