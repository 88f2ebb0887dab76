"""The harness: compare any backend's RenderResult with the reference, pixel by pixel and statistically.

For each scene and oracle (``check_backend``):
1. Pre-flight: the buffers are there, of the right size, in range (minirt.harness.geometry).
2. The reference is rendered under the rules the oracle can follow (``oracle.adapt``), so the
   comparison is like with like (minirt.harness.references).
3. Geometry on the same rays, with a per-pixel silhouette band and tolerances derived from the
   oracle's own precision (minirt.harness.geometry, minirt.harness.tolerances).
4. Shading, deterministic per pixel where the oracle shades the same rays (minirt.harness.shading).
   For stochastic renders (scene samples > 1): a per-pixel Z-test and per-shape means (Mitsuba's
   sensor, minirt.harness.stochastic); and, from an oracle that can shoot the reference's own
   stratified samples (POV-Ray's mesh camera), the averaged image compared per pixel like a one-ray
   render, with the band taken over every sample's ray (``_samples_run``).
5. Rules, two ways: rule effects, what each rule the oracle cannot follow does in the reference, and
   rule diagnosis, which settings explain the oracle's own image (minirt.harness.attribution).
Verdicts (minirt.harness.results): PASS, WARN, FAIL, ERROR (the backend broke), SKIP (does not apply,
with the reason). Whole scene files and runs of them: minirt.harness.run.
"""

from __future__ import annotations

import contextlib
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Any

from minirt.errors import MinirtError
from minirt.harness import backends
from minirt.harness.attribution import attribute_rules, diagnose_oracle
from minirt.harness.geometry import check_geometry, preflight
from minirt.harness.image_only import check_image_only, gives_only_an_image
from minirt.harness.references import ReferenceCache
from minirt.harness.results import ORDER, BackendCheck, Check, RuleDiagnosis, worst
from minirt.harness.shading import check_shading, edge_classes, edge_pixels, shading_exercise
from minirt.harness.stochastic import check_stochastic
from minirt.jit import engine
from minirt.model.rules import Rules, resolve
from minirt.model.scene import Scene
from minirt.model.tolerance import farthest_hit
from minirt.reference import band


def check_backend(
    scene: Scene,
    rules: Rules,
    name: str,
    refs: ReferenceCache,
    options: dict | None = None,
    variants=None,
    rendered=None,
    explain: bool = True,
    samples_rendered=None,
    busy=None,
) -> BackendCheck:
    """``rendered``: the backend's render of (scene, rules, options) when it was started earlier (a
    concurrent.futures.Future or a RenderResult), else it is rendered here; ``samples_rendered``: the same
    for the several-sample render of ``_samples_run`` or ``_stochastic_run`` (``start_samples``).
    ``explain=False`` leaves out what only explains the verdict -- the rule effects and the rule diagnosis,
    renders of their own -- for runs that want verdicts alone (a fuzzing campaign). ``busy()``: whether
    other renders of the check are running beside this one (minirt.harness.run's); the rule diagnosis then
    runs on one Dr.Jit thread."""
    t0 = time.perf_counter()
    followed = backends.rules_for(name, rules) if backends.info(name).available else rules
    bc = BackendCheck(backend=name, verdict="skip", rules_followed=followed.as_dict())
    known = backends.find(name)  # a result no backend made (a test's) has no check options or sample checks
    if rendered is None and known is not None and known.chooses_pixels and backends.info(name).available:
        options = {**_check_options(name, scene, followed, refs), **(options or {})}
    if rendered is None:
        with ThreadPoolExecutor(max_workers=1) as pool:
            started = start_ahead(pool, [name], scene, rules, options)
            if started:  # it renders while the reference it is compared with does
                with contextlib.suppress(MinirtError):  # raised again below, where it always was
                    refs.get(followed, samples=1)
            res = started[name].result() if started else backends.render(name, scene, rules, options)
    else:
        res = rendered.result() if hasattr(rendered, "result") else rendered
    bc.result = res
    if not res.ok:
        bc.verdict, bc.reason = res.status, res.reason
        bc.seconds = time.perf_counter() - t0
        return bc
    only_image = gives_only_an_image(res)  # a program's: minirt.harness.image_only
    if only_image and known is not None and known.scene_as_rendered(scene) != scene:
        scene = known.scene_as_rendered(scene)  # compared with what it was given (a 2014 program's materials)
        refs = ReferenceCache(scene)
    ref = refs.get(followed, samples=1)  # deterministic checks: the one-ray-per-pixel rays the oracle cast
    bc.reference = ref
    bc.checks = check_image_only(scene, followed, name, refs, res) if only_image else {}
    pre = bc.checks.get("preflight") or preflight(ref, res, need_color=False)
    bc.checks["preflight"] = pre
    if pre.verdict == "fail":
        bc.verdict, bc.reason = "fail", f"pre-flight: {pre.reason}"
    elif only_image:
        _verdict(bc)
        if all(c.verdict == "skip" for k, c in bc.checks.items() if k != "preflight"):  # nothing compared
            bc.verdict, bc.reason = "skip", bc.checks["shading"].reason
    else:
        # the primary rays' margins, shared by the scene's oracles (a stand-in cache, the campaign's defective
        # reference, has none: check_geometry makes them)
        rays = refs.rays(followed) if isinstance(refs, ReferenceCache) else None
        geom = check_geometry(scene, followed, ref, res, rays)
        bc.checks["geometry"] = geom
        bc.checks["shading"] = check_shading(scene, ref, res, geom)
        model = known.shading_model if known else None
        if scene.samples > 1 and model == "physical":
            bc.checks["stochastic"] = _stochastic_run(scene, followed, name, refs, geom, samples_rendered)
        if scene.samples > 1 and model == "exercise":
            bc.checks["samples"] = _samples_run(scene, followed, name, refs, samples_rendered)
        _verdict(bc)
    if not explain:
        bc.rule_diagnosis = RuleDiagnosis(reason="not asked for")
        bc.seconds = time.perf_counter() - t0
        return bc
    bc.rules, bc.rule_masks = attribute_rules(refs, rules, followed)
    bc.rule_diagnosis = _rule_diagnosis(scene, rules, followed, name, res, pre, variants, busy)
    bc.seconds = time.perf_counter() - t0
    return bc


def _verdict(bc: BackendCheck) -> None:
    """The backend's verdict from its checks, and its reason: worst first; an inconclusive check's reason as
    it is ("inconclusive: ..."), ahead of other warnings."""
    bc.verdict = worst([c.verdict for c in bc.checks.values()])
    said = [(k, c) for k, c in bc.checks.items() if c.verdict in ("fail", "warn", "error")]
    said.sort(key=lambda kc: (-ORDER.index(kc[1].verdict), not kc[1].inconclusive))
    bc.reason = "; ".join(c.reason if c.inconclusive else f"{k}: {c.reason}" for k, c in said)


def _rule_diagnosis(scene: Scene, rules: Rules, followed: Rules, name: str, res, pre, variants, busy) -> RuleDiagnosis:
    """The rule diagnosis of the backend's colour (which rule settings explain it), or why it has none."""
    model = backends.shading_model(name, res.color is not None)
    if model != "exercise" or res.color is None:
        why = "does not shade" if model is None or res.color is None else f"shades a {model} model, not the exercise's"
        return RuleDiagnosis(reason=f"{name} {why}: no rule setting can explain its colour")
    if pre.verdict == "fail":
        return RuleDiagnosis(reason=f"{name}'s image failed pre-flight")
    # The diagnosis traces hundreds of candidates, each a kernel of a few milliseconds on a few-ball scene.
    # While other renders fill the cores (``busy``), Dr.Jit's second thread mostly waits for a core at each
    # kernel's end: without it the bundled scenes' check used 0.93x the CPU in the same wall time (0.99x,
    # 5 pairs; the same documents), a core's share the other processes then have. Longer kernels pay for
    # both threads even then: a 1,024-ball scene's diagnosis (3.4 s, Blender rendering beside it) on one
    # thread made its check 1.9 s longer.
    one_thread = busy is not None and small_kernels(scene) and busy()
    with engine.threads(1) if one_thread else contextlib.nullcontext():
        return diagnose_oracle(scene, rules, followed, res, variants)


def small_kernels(scene: Scene) -> bool:
    """Whether the scene's renders in this process are short kernels: at most FULL_RENDER_BALLS balls (beyond which a
    ray's cost grows with the balls it passes, minirt.diagnose.variants)."""
    from minirt.diagnose.variants import FULL_RENDER_BALLS
    from minirt.model.scene import Ball

    return sum(isinstance(s, Ball) for s in scene.shapes) <= FULL_RENDER_BALLS


def _check_options(name: str, scene: Scene, followed: Rules, refs: ReferenceCache) -> dict[str, Any]:
    """The options a backend that ``chooses_pixels`` asks for in a check, named from the reference it is
    compared with (rendered first, one ray a pixel); none for the others."""
    b = backends.get(name)
    return b.check_options(scene, refs.get(followed, samples=1)) if b.chooses_pixels else {}


def _sensor_options(name: str, scene: Scene, followed: Rules, refs: ReferenceCache) -> dict[str, Any]:
    return {"mode": "sensor", "spp": scene.samples}


def _stochastic_run(scene: Scene, rules: Rules, name: str, refs: ReferenceCache, geom: Check, rendered=None) -> Check:
    """A physical model's own several-sample render (its sensor, ``spp`` the scene's samples; ``rendered``: that
    render started earlier, a Future) against the reference's, statistically (minirt.harness.stochastic)."""
    if rendered is not None:
        res = rendered.result()
    else:
        res = backends.render(name, scene, rules, _sensor_options(name, scene, rules, refs))
    if not res.ok:
        return Check("skip" if res.status == "skip" else "error", reason=res.reason)
    ref = refs.get(rules)
    centre = refs.get(replace(rules, pixel_sample="center"), samples=1)
    classes = edge_classes(ref)
    edges = edge_pixels(classes, geom.images["band"])
    return check_stochastic(scene, ref, res, classes, edges, centre)


def _samples_options(name: str, scene: Scene, followed: Rules, refs: ReferenceCache) -> dict[str, Any]:
    return {**_check_options(name, scene, followed, refs), "samples": scene.samples}


def _samples_run(scene: Scene, rules: Rules, name: str, refs: ReferenceCache, rendered=None) -> Check:
    """An oracle of the exercise's model rendering the reference's own stratified samples (option
    ``samples``; ``rendered``: that render started earlier, a Future): the averaged colour is compared per
    pixel like a one-ray render, with the band taken over every sample's ray."""
    n = scene.samples
    if rendered is not None:
        res = rendered.result()
    else:
        res = backends.render(name, scene, rules, _samples_options(name, scene, rules, refs))
    if not res.ok:
        return Check("skip" if res.status == "skip" else "error", reason=res.reason)
    ref = refs.get(rules)
    p = res.meta.get("precision") or {}
    band_px = band.sample_band(
        scene,
        rules,
        n,
        p.get("band_threshold", 0.0),
        p.get("min_distance", 0.0),
        p.get("start_err", 0.0),
        p.get("band_scale"),
        p.get("band_origin_scale"),
        farthest_hit(p),
        p.get("band_inside_scale"),
    )
    classes = edge_classes(ref)
    edges = edge_pixels(classes, band_px)
    check = shading_exercise(ref, res, classes, edges)
    check.figures = {"samples": n, "sample_band_pixels": int(band_px.sum()), **check.figures}
    return check


def check_text(
    text: str, source: str, backend: str, size: tuple[int, int] | None = None, explain: bool = True
) -> tuple[Scene, Rules, ReferenceCache, BackendCheck]:
    """One oracle's check of a scene given as text (what a job carries to a worker): the scene, its
    rules, the reference renders made for the check (to reuse) and the check itself."""
    from minirt.model.scene import parse_scene

    scene = parse_scene(text, source=source)
    if size:
        scene = scene.with_overrides(width=size[0], height=size[1])
    rules = resolve(scene)
    refs = ReferenceCache(scene)
    return scene, rules, refs, check_backend(scene, rules, backend, refs, explain=explain)


# Backends whose renders run in a child process, started ahead by ``check_backend`` and by
# minirt.harness.run's ``run`` and ``check_scene``.
def start_ahead(pool: ThreadPoolExecutor, names, scene: Scene, rules: Rules, options=None) -> dict[str, Any]:
    """Start on ``pool`` the renders of those of ``names`` that run as a child process and are installed
    (the backend's ``runs_apart`` with these options): name -> Future. Such a render mostly waits for its
    processes, so it overlaps the work this process does meanwhile; the results are the same."""
    return {
        n: pool.submit(backends.render, n, scene, rules, options)
        for n in names
        if backends.get(n).runs_apart(options or {}) and backends.info(n).available
    }


def start_chosen(pool: ThreadPoolExecutor, names, scene: Scene, rules: Rules, refs: ReferenceCache) -> dict[str, Any]:
    """``start_ahead`` for those of ``names`` that choose their pixels from the reference (``chooses_pixels``):
    started once the reference it is compared with is rendered, with their check options."""
    return _start_after_reference(pool, names, rules, lambda b: b.chooses_pixels, scene, refs, _check_options)


def start_samples(pool: ThreadPoolExecutor, names, scene: Scene, rules: Rules, refs: ReferenceCache) -> dict[str, Any]:
    """``start_ahead`` for the several-sample renders of a scene of samples > 1, once the reference is
    rendered: of an oracle of the exercise's model, the reference's own samples (``_samples_run``); of a
    physical model, its sensor's (``_stochastic_run``) -- those that run apart."""
    if scene.samples <= 1:
        return {}
    return {
        **_start_after_reference(pool, names, rules, lambda b: b.shading_model == "exercise", scene, refs,
                                 _samples_options),
        **_start_after_reference(pool, names, rules, lambda b: b.shading_model == "physical", scene, refs,
                                 _sensor_options),
    }  # fmt: skip


def _start_after_reference(pool, names, rules: Rules, wanted, scene: Scene, refs: ReferenceCache, options_for):
    """The renders of those of ``names`` whose backend is ``wanted`` and installed, with the options
    ``options_for(name, scene, followed, refs)`` names from the reference, where they run apart."""
    started = {}
    for n in names:
        b = backends.get(n)
        if not (wanted(b) and backends.info(n).available):
            continue
        followed = backends.rules_for(n, rules)
        options = options_for(n, scene, followed, refs)
        if b.runs_apart(options):
            started[n] = pool.submit(backends.render, n, scene, followed, options)
    return started
