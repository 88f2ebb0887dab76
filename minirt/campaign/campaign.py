"""The adversarial campaign behind ``minirt fuzz``: generated hard scenes × oracles, as Dask jobs, cached.

A campaign is a matrix of independent jobs, one per (scene, oracle): the scene's text comes from a
family of minirt.campaign.families (deterministic for family, seed and index), the job checks the oracle against the
reference exactly as ``minirt check`` does, and -- with ``defects`` -- checks it again against the
reference with each injected defect, reusing the oracle's render. Jobs run through minirt.jobs.batch (in
this process, an embedded LocalCluster, or a running Dask cluster); the client alone reads and writes
files, so remote workers need minirt and the renderers, not a shared file system. Scenes are made as
their jobs are handed out, and of each finished job the campaign keeps only what fuzz.json counts (an
``Outcome``; its evidence is written at once), so a campaign of a million scenes holds ~0.4 GB, and one
the machine cannot hold is refused before it starts (``fits_in_memory``). A job's result -- from a worker
or the cache -- is checked against ``JobResult`` before it is used.

**Cache.** A job's result is stored as ``OUT/cache/KEY.json`` (JSON: data, never code), KEY the SHA-256
of everything the result depends on: the scene text, the oracle, the defects, the versions of minirt's
own code (a digest of its sources), of Dr.Jit and of the oracle (its version line). A rerun does only the
jobs whose key is new; the campaign's JSON is the same bytes either way (no timings in it).

**Defects.** Each kind stands for a bug a student's tracer could have, applied to the reference (its
scene, rules, traced effects or buffers) while the oracle's image stays the same. A defect *changes
the image* of a scene for an oracle when the defective reference differs from the correct one in what
that oracle's check judges (``changes``: geometry for all; colour beyond rounding for an oracle that
shades); it is *caught* when the check of that oracle against it is FAIL. The campaign's catch rate is
over the scenes where the defect changes the image for some oracle; caught means some oracle that it
changes failed. ``rate_judged`` counts only the changes that oracle's check can see: on the pixels it
judges (outside its bands, depth ties and edges), beyond its per-pixel t and normal tolerances there,
in scenes it can judge (its check of the correct reference conclusive).

**The judge of last resort** (minirt.harness.judge). Every check, of the correct reference and of each
defective one, goes before a certified oracle when the registry has one: a float oracle's FAIL stands
only where the judge certifies the reference wrong (elsewhere its disagreement is its own imprecision: a
WARN, the ruling in its evidence), and the certified oracle's own check FAILs exactly where the reference
is certified wrong -- at every pixel whose decisions are robust, edges and bands included.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, Required, TypedDict

import numpy as np

from minirt.jobs.cache import Codec, digest, json_codec
from minirt.jobs.data import Schema
from minirt.model.result import RenderResult
from minirt.model.rules import Rules
from minirt.model.scene import Ball, Material, Scene

VERDICTS = ("pass", "warn", "fail", "error", "skip")
Verdict = Literal["pass", "warn", "fail", "error", "skip"]
CHANGE_REL = 1e-9  # t and normals differing by more than this (relative) change the image's geometry


# ---------------------------------------------------------------------------------------------
# Defects


@dataclass(frozen=True)
class Defect:
    name: str
    summary: str  # the tracer bug it stands for
    scene: Callable[[Scene], Scene] | None = None
    rules: Callable[[Rules], Rules] | None = None
    effects: dict[str, Any] = field(default_factory=dict)  # traced effects switched off (Effects fields)
    buffers: Callable[[RenderResult], None] | None = None  # changes the result's buffers in place


def _materials(scene: Scene, fn: Callable[[Material], Material]) -> Scene:
    shapes = tuple(replace(s, material=fn(s.material)) for s in scene.shapes)
    return replace(scene, shapes=shapes, materials={k: fn(m) for k, m in scene.materials.items()})


def _flip_normals(r: RenderResult) -> None:
    if r.normal is not None:
        r.normal = -r.normal


def _scale_t(r: RenderResult) -> None:
    if r.t is not None and r.hit is not None:
        r.t = np.where(r.hit, r.t * 1.01, r.t)


def _swap_ids(r: RenderResult) -> None:
    if r.shape_id is not None:
        s = r.shape_id
        r.shape_id = np.where(s == 0, 1, np.where(s == 1, 0, s)).astype(s.dtype)


DEFECTS: dict[str, Defect] = {
    d.name: d
    for d in (
        Defect("last-shape-skipped", "the shape loop stops one short: the last shape is never hit",
               scene=lambda s: replace(s, shapes=s.shapes[:-1])),
        Defect("radius-off", "a wrong quadratic coefficient: every ball 2 % larger",
               scene=lambda s: replace(s, shapes=tuple(
                   replace(b, radius=b.radius * 1.02) if isinstance(b, Ball) else b for b in s.shapes))),
        Defect("t-scaled", "distances along an unnormalised direction: t 1 % too long", buffers=_scale_t),
        Defect("normal-flipped", "normals pointing into the surface", buffers=_flip_normals),
        Defect("ids-swapped", "shape ids off: shapes 0 and 1 reported as each other", buffers=_swap_ids),
        Defect("no-shadows", "shadow rays never cast", effects={"shadows": False}),
        Defect("no-reflection", "the recursion never follows the mirror ray", effects={"reflection": False}),
        Defect("no-ambient", "the ambient term left out",
               scene=lambda s: _materials(s, lambda m: replace(m, ambient=(0.0, 0.0, 0.0)))),
        Defect("light-moved", "the light 5 % off its position",
               scene=lambda s: replace(s, light=replace(s.light, position=tuple(1.05 * x for x in s.light.position)))),
        Defect("specular-exponent", "the specular term raised to the 7th power, not the 8th",
               rules=lambda r: replace(r, specular_exponent=7 if r.specular_exponent != 7 else 9)),
    )
}  # fmt: skip


def parse_families(spec: str) -> tuple[str, ...]:
    """``--families``: all, or a comma list of the families' names (minirt.campaign.families)."""
    from minirt.campaign.families import FAMILIES
    from minirt.errors import MinirtError

    fams = tuple(FAMILIES) if spec.strip().lower() == "all" else tuple(f.strip() for f in spec.split(",") if f.strip())
    unknown = [f for f in fams if f not in FAMILIES]
    if unknown or not fams:
        raise MinirtError(
            f"--families: unknown family {', '.join(unknown) or repr(spec)} (known: all, {', '.join(FAMILIES)})"
        )
    return fams


def parse_defects(spec: str | None) -> tuple[str, ...]:
    """``--defects``: none (default), all, or a comma list of DEFECTS' names."""
    from minirt.errors import MinirtError

    if spec is None or spec.strip().lower() in ("", "none"):
        return ()
    if spec.strip().lower() == "all":
        return tuple(DEFECTS)
    names = tuple(n.strip() for n in spec.split(",") if n.strip())
    unknown = [n for n in names if n not in DEFECTS]
    if unknown:
        raise MinirtError(f"--defects: unknown defect {', '.join(unknown)} (known: none, all, {', '.join(DEFECTS)})")
    return names


class _DefectiveReference:
    """What the harness's reference cache gives (``get(rules, samples)``), rendered with a defect."""

    def __init__(self, scene: Scene, defect: Defect):
        self.scene, self.defect, self.cache = scene, defect, {}

    def get(self, rules: Rules, samples: int | None = None) -> RenderResult:
        from minirt.harness.references import CHECKED_TERMS
        from minirt.reference import tracer

        key = (rules, samples)
        if key not in self.cache:
            d = self.defect
            sc = self.scene if samples is None else self.scene.with_overrides(samples=samples)
            sc = d.scene(sc) if d.scene else sc
            ru = d.rules(rules) if d.rules else rules
            t = tracer.Tracer(sc, ru)
            if d.effects:
                t.effects = replace(t.effects, **d.effects)
            r = t.render(diagnostics=True, terms=CHECKED_TERMS)
            if d.buffers:
                d.buffers(r)
            r.meta["shapes"] = len(self.scene.shapes)
            self.cache[key] = r
        return self.cache[key]


def changes(
    a: RenderResult,
    b: RenderResult,
    model: str | None,
    where: np.ndarray | None = None,
    tolerance: tuple[np.ndarray, np.ndarray] | None = None,
) -> bool:
    """Whether two reference renders differ in what a check of an oracle shading ``model`` judges
    (the backend's shading_model), on the pixels ``where`` (default all): the geometry -- hit mask, shape ids,
    t and normals beyond CHANGE_REL, or with ``tolerance`` (per-pixel t and normal-angle tolerances of
    the check) beyond those -- for every oracle; for the exercise's model also the 8-bit image beyond
    the check's own tolerance (THRESHOLDS color8_levels, rounding); for the physical one its diffuse
    term beyond one level."""
    from minirt.harness.geometry import angle_deg
    from minirt.harness.tolerances import THRESHOLDS

    w = np.ones_like(a.hit) if where is None else where
    ida, idb = np.where(a.hit, a.shape_id, -1), np.where(b.hit, b.shape_id, -1)
    if ((a.hit != b.hit) & w).any() or ((ida != idb) & w).any():
        return True
    h = a.hit & w
    if h.any() and tolerance is not None:
        t_tol, n_tol = tolerance
        if a.t is not None and b.t is not None and (np.abs(a.t[h] - b.t[h]) > t_tol[h]).any():
            return True
        if a.normal is not None and b.normal is not None and (angle_deg(a.normal[h], b.normal[h]) > n_tol[h]).any():
            return True
    elif h.any():
        for x, y in ((a.t, b.t), (a.normal, b.normal)):
            if x is not None and y is not None:
                dx = np.abs(x[h] - y[h])
                if (dx > CHANGE_REL * np.maximum(1.0, np.abs(x[h]))).any():
                    return True
    level = THRESHOLDS["color8_levels"].value
    if model == "exercise":
        d8 = np.abs(a.color8().astype(int) - b.color8().astype(int)).max(-1)
        return bool(((d8 > level) & w).any())
    if model == "physical":
        da, db = a.terms.get("diffuse"), b.terms.get("diffuse")
        return da is not None and db is not None and bool((np.abs(da - db).max(-1)[h] > level / 255).any())
    return False


def tolerance(bc) -> tuple[np.ndarray, np.ndarray] | None:
    """A backend check's per-pixel t and normal-angle tolerances (None when it has no geometry check)."""
    geom = bc.checks.get("geometry")
    if geom is None or "t_tolerance" not in geom.images:
        return None
    return geom.images["t_tolerance"], geom.images["normal_tolerance"]


def judged(bc, defective=None) -> np.ndarray | None:
    """The pixels a backend check judges: outside its geometry band, its depth ties and its shading's edges
    -- and, given the check against a defective reference, outside that one's edges too. Edges come from
    the reference under test (its silhouettes, shadows, terminators): a moved light moves them, and the
    check rightly sets its own edges aside. The band does not: it is the scene's and the oracle's, so it
    comes from the correct check alone -- a band that grew with a defect would be a hole in the harness,
    and must show as a miss (it did: Embree's depth ties, measured against a reference that missed)."""
    geom, shade = bc.checks.get("geometry"), bc.checks.get("shading")
    if geom is None or "band" not in geom.images:
        return None
    out = ~geom.images["band"].astype(bool) & ~geom.images.get("ties", np.zeros_like(geom.images["band"]))
    for c in (bc, defective):
        shade = None if c is None else c.checks.get("shading")
        if shade is not None and "edges" in shade.images:
            out &= ~shade.images["edges"].astype(bool)
    return out


# ---------------------------------------------------------------------------------------------
# Jobs


@dataclass(frozen=True)
class Job:
    scene: str  # the scene's name (family_seed_index)
    family: str
    text: str  # the scene file's text
    backend: str
    defects: tuple[str, ...] = ()


JUDGE = "judge"  # the certified oracle's version line, under this key of ``job_key``'s versions


def job_key(job: Job, versions: dict[str, str]) -> str:
    """The cache key: SHA-256 over everything the job's result depends on (module docstring)."""
    return digest(
        {"text": job.text, "backend": job.backend, "defects": list(job.defects),
         "minirt": versions["minirt"], "drjit": versions["drjit"], "oracle": versions.get(job.backend, ""),
         "judge": versions.get(JUDGE, "")}
    )  # fmt: skip


def run_job(job: Job) -> dict[str, Any]:
    """One (scene, oracle) check and its defect checks, as a plain dict (what the cache stores).
    Non-PASS verdicts carry their evidence: the check's JSON and the two images as PNG bytes."""
    from minirt.harness import backends, judge
    from minirt.harness import compare as harness

    t0 = time.perf_counter()
    scene, rules, refs, bc = harness.check_text(job.text, f"{job.scene}.toml", job.backend, explain=False)
    certified, renders = judge.certified_oracle(), {}

    def judged_check(c):
        """The judge of last resort on a check (minirt.harness.judge): a certified oracle's verdict is the
        judge's; a float oracle's FAIL stands only where the reference is certified wrong."""
        if judge.is_certified(job.backend):
            return judge.certify(c)
        return judge.review(c, scene, rules, certified, renders)

    bc = judged_check(bc)
    out: dict[str, Any] = {
        "scene": job.scene, "family": job.family, "backend": job.backend, "verdict": bc.verdict,
        "inconclusive": bc.inconclusive, "reason": bc.reason,
    }  # fmt: skip
    if bc.verdict != "pass":
        from minirt.io.jsonout import dumps

        out["evidence"] = {"check": dumps(bc.as_dict()), "images": _images(bc)}
    if job.defects and bc.result is not None and bc.result.ok:
        followed = harness.backends.rules_for(job.backend, rules)
        clean = refs.get(followed, samples=1)
        found = {}
        for name in job.defects:
            bad = _DefectiveReference(scene, DEFECTS[name])
            try:
                got = bad.get(followed, samples=1)
            except Exception as e:  # a defect the tracer cannot render (no shape left) changes nothing judged
                found[name] = {"changes": False, "changes_judged": False, "verdict": "skip", "reason": str(e)}
                continue
            model = backends.get(job.backend).shading_model
            changed = changes(clean, got, model)
            dc = (
                judged_check(harness.check_backend(scene, rules, job.backend, bad, rendered=bc.result, explain=False))
                if changed
                else None
            )
            found[name] = {
                "changes": changed,
                # a change the check could see: on pixels it judges (outside the band, the ties and both
                # checks' edges), beyond its tolerances there, in a scene it can judge (clean check conclusive)
                "changes_judged": changed
                and not bc.inconclusive
                and changes(clean, got, model, judged(bc, dc), tolerance(bc)),
                "verdict": dc.verdict if dc else "pass",
            }
        out["defects"] = found
    out["seconds"] = time.perf_counter() - t0
    return out


def _images(bc) -> dict[str, bytes]:
    """The oracle's and the reference's colour images (or shape ids as grey levels) as PNG bytes."""
    import tempfile

    from minirt.io.images import write_image

    pics = {}
    for role, r in (("oracle", bc.result), ("reference", bc.reference)):
        if r is None or not r.ok:
            continue
        img = r.color8()
        if img is None and r.shape_id is not None:
            ids = np.where(r.hit, r.shape_id + 1, 0).astype(np.float64)
            img = np.repeat((255 * ids / max(1.0, ids.max()))[..., None], 3, -1).astype(np.uint8)
        if img is None:
            continue
        with tempfile.TemporaryDirectory() as d:
            p = Path(d) / "x.png"
            write_image(p, img)
            pics[role] = p.read_bytes()
    return pics


def failed_job(job: Job, message: str) -> dict[str, Any]:
    """A job whose call raised or whose worker died: an ERROR verdict naming why."""
    return {"scene": job.scene, "family": job.family, "backend": job.backend, "verdict": "error",
            "inconclusive": False, "reason": message, "seconds": 0.0}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# What a job gives back


class DefectFound(TypedDict, total=False):
    changes: Required[bool]
    changes_judged: Required[bool]
    verdict: Required[Verdict]
    reason: str  # why the defect could not be rendered


class Evidence(TypedDict):
    check: str  # the check's JSON
    images: dict[str, bytes]  # role -> PNG bytes


class JobResult(TypedDict, total=False):
    """What ``run_job`` (or ``failed_job``) gives back, and what the cache holds: checked before use."""

    scene: Required[str]
    family: Required[str]
    backend: Required[str]
    verdict: Required[Verdict]
    inconclusive: Required[bool]
    reason: Required[str]
    seconds: Required[float]
    evidence: Evidence
    defects: dict[str, DefectFound]


RESULT = Schema(JobResult)


def result_fits(job: Job, result: JobResult) -> None:
    """Raise ValueError unless ``result`` -- from a worker or the cache -- is a result of ``job``."""
    RESULT.check(result)
    if (result["scene"], result["family"], result["backend"]) != (job.scene, job.family, job.backend):
        raise ValueError(f"a result of {result['scene']!r} on {result['backend']!r}, not of this job")
    if not set(result.get("defects") or {}) <= set(job.defects):
        raise ValueError("a result of other defects")


def _encode(result: dict[str, Any]) -> bytes:
    d = dict(result)
    if "evidence" in d:  # the images' PNG bytes, as hex
        d["evidence"] = {**d["evidence"], "images": {k: v.hex() for k, v in d["evidence"]["images"].items()}}
    return json_codec.encode(d)


def _decode(data: bytes) -> dict[str, Any]:
    d = json_codec.decode(data)
    ev = d.get("evidence")
    if isinstance(ev, dict) and isinstance(ev.get("images"), dict):
        ev["images"] = {k: bytes.fromhex(v) for k, v in ev["images"].items()}
    return d


CODEC = Codec("json", _encode, _decode, RESULT.check)


# ---------------------------------------------------------------------------------------------
# The campaign


@dataclass(slots=True)
class Outcome:
    """What the campaign keeps of a job's result once its evidence is written: what fuzz.json counts."""

    verdict: str
    inconclusive: bool
    reason: str
    defects: dict[str, DefectFound] | None


# Bytes the campaign keeps per job (an Outcome and its list slot; a non-PASS's reason adds its length) and
# per defect checked in a job (its entry, as read from JSON), measured with tracemalloc over 100,000 of
# them: 80 and 344 bytes; rounded up here for the reasons and the per-scene tallies of fuzz.json.
OUTCOME_BYTES = 128
DEFECT_BYTES = 384


@dataclass
class Campaign:
    seed: int
    families: tuple[str, ...]
    size: tuple[int, int]
    backends: tuple[str, ...]
    defects: tuple[str, ...]
    count: int = 0  # scenes
    outcomes: list[Outcome | None] = field(default_factory=list)  # per job: scene i's oracle j at i * B + j
    cached: int = 0
    seconds: float = 0.0

    def scene(self, i: int) -> tuple[str, str]:
        """Scene ``i``'s name and family: family i mod F's number i // F."""
        fam = self.families[i % len(self.families)]
        return f"{fam}_{self.seed}_{i // len(self.families)}", fam

    def job(self, k: int) -> tuple[str, str, str]:
        """Job ``k``'s scene name, family and oracle."""
        name, fam = self.scene(k // len(self.backends))
        return name, fam, self.backends[k % len(self.backends)]

    def jobs(self) -> Iterator[Job]:
        """Every job, scene by scene, each scene's text made as its jobs are taken (never a list of them)."""
        from minirt.campaign import families as fuzz

        for i in range(self.count):
            name, fam = self.scene(i)
            text = fuzz.scene_text(fam, self.seed, i // len(self.families), *self.size)
            for b in self.backends:
                yield Job(name, fam, text, b, self.defects)


def scenes(count: int, seed: int, families: Sequence[str], size: tuple[int, int]) -> list[tuple[str, str, str]]:
    """``count`` scenes as (name, family, text), the families taken in turn: scene i is family i mod F's
    number i // F (``Campaign.jobs`` makes the same scenes one at a time)."""
    c = Campaign(seed, tuple(families), size, ("",), (), count)
    return [(j.scene, j.family, j.text) for j in c.jobs()]


def fits_in_memory(c: Campaign, local_workers: int) -> None:
    """Bad input before any work (minirt.jobs.memory): a campaign this machine cannot hold, as one line --
    what it keeps per job (OUTCOME_BYTES, DEFECT_BYTES per defect), and a check of one scene at its size
    running here or in each of ``local_workers`` processes."""
    from minirt.harness import backends
    from minirt.jobs import memory

    total = c.count * len(c.backends)
    kept = total * (OUTCOME_BYTES + len(c.defects) * DEFECT_BYTES)
    w, h = c.size
    memory.require(
        kept + backends.check_bytes([w * h], list(c.backends), local_workers),
        f"a campaign of {c.count} scenes x {len(c.backends)} oracles at {w}x{h}",
        "fuzz fewer scenes at a time (--count, a new --seed for the next ones), or at a smaller --size",
    )


def run(
    campaign: Campaign,
    cache: Path | None,
    workers: int = 1,
    scheduler: str | None = None,
    on_done: Callable[[Job, dict[str, Any]], None] | None = None,
    out: Path | None = None,
) -> Campaign:
    """Every job of the campaign, from ``cache`` (a folder; None: no cache) where it holds the job's key;
    ``out``: the folder that gets each non-PASS job's evidence as it finishes (``write_evidence``). Jobs
    are made and handed out as they are needed; what is kept of each is its Outcome."""
    import contextlib

    from minirt.harness.backends import versions
    from minirt.jobs import batch as jobs
    from minirt.jobs.cache import Cache

    t0 = time.perf_counter()
    from minirt.harness.judge import certified_oracle

    certified = certified_oracle()  # the judge every job goes before: its version is part of each job's key
    v = versions([*campaign.backends, *([certified] if certified else [])])
    v[JUDGE] = v.get(certified, "") if certified else ""
    # an error may be passing (a dead worker, a renderer missing here): never stored, redone next time
    store = None if cache is None else Cache(cache, lambda j: job_key(j, v), CODEC, _not_error, label="fuzz cache")
    campaign.outcomes = [None] * (campaign.count * len(campaign.backends))
    done = jobs.stream(run_job, campaign.jobs(), workers=workers, scheduler=scheduler, on_error=failed_job,
                       cache=store, check=result_fits)  # fmt: skip
    with contextlib.closing(done):
        for k, job, res, ok in done:
            if ok and on_done:
                on_done(job, res)
            if out is not None:
                write_evidence(job, res, out)
            campaign.outcomes[k] = Outcome(res["verdict"], bool(res.get("inconclusive")), res["reason"],
                                           res.get("defects"))  # fmt: skip
    campaign.cached = store.hits if store else 0
    campaign.seconds = time.perf_counter() - t0
    return campaign


def _not_error(result: dict[str, Any]) -> bool:
    return result["verdict"] != "error"


def _results(c: Campaign) -> Iterator[tuple[str, str, str, Outcome]]:
    for k, o in enumerate(c.outcomes):
        if o is not None:
            yield (*c.job(k), o)


def summary(c: Campaign) -> dict[str, Any]:
    """The campaign's JSON document (no timings: the same bytes for the same command)."""
    verdicts = dict.fromkeys(VERDICTS, 0)
    failures, inconclusive, jobs = [], 0, 0
    for scene, family, backend, o in _results(c):
        jobs += 1
        verdicts[o.verdict] += 1
        inconclusive += o.inconclusive
        if o.verdict in ("fail", "error"):
            failures.append({"scene": scene, "family": family, "backend": backend, "verdict": o.verdict,
                             "reason": o.reason})  # fmt: skip
    doc: dict[str, Any] = {
        "seed": c.seed,
        "families": list(c.families),
        "size": list(c.size),
        "backends": list(c.backends),
        "scenes": c.count,
        "jobs": jobs,
        "verdicts": verdicts,
        "inconclusive": inconclusive,
        "failures": failures,
        "by_family": _by_family(c),
    }
    if c.defects:
        doc["defects"] = _defects(c)
    return doc


def _by_family(c: Campaign) -> dict[str, dict[str, int]]:
    out = {f: dict.fromkeys(VERDICTS, 0) for f in c.families}
    for _, family, _, o in _results(c):
        out[family][o.verdict] += 1
    return out


def _defects(c: Campaign) -> dict[str, Any]:
    """Per defect, over scenes: those it changes for some oracle, those it changes on pixels that oracle's
    check judges (outside its band and edges), those where an oracle it changes FAILed, and the rates."""
    by_scene: dict[str, dict[str, list[bool]]] = {}
    for scene, _, _, o in _results(c):
        for name, d in (o.defects or {}).items():
            s = by_scene.setdefault(name, {}).setdefault(scene, [False, False, False])
            s[0] |= bool(d["changes"])
            s[1] |= bool(d.get("changes_judged"))
            s[2] |= bool(d["changes"]) and d["verdict"] == "fail"
    out = {}
    for name in c.defects:
        per = by_scene.get(name, {})
        changed = sorted(s for s, v in per.items() if v[0])
        on_judged = [s for s in changed if per[s][1]]
        caught = [s for s in changed if per[s][2]]
        out[name] = {
            "summary": DEFECTS[name].summary,
            "changes": len(changed),
            "changes_judged": len(on_judged),
            "caught": len(caught),
            "rate": len(caught) / len(changed) if changed else None,
            "rate_judged": sum(per[s][2] for s in on_judged) / len(on_judged) if on_judged else None,
            "missed": [s for s in changed if not per[s][2]],
            "missed_judged": [s for s in on_judged if not per[s][2]],
        }
    return out


def write_evidence(job: Job, r: dict[str, Any], out: Path) -> None:
    """A non-PASS job's scene file, check JSON and images under ``out`` (nothing for a PASS)."""
    from minirt.io.atomic import atomic_path

    if r["verdict"] == "pass":
        return
    scene = out / f"{job.scene}.toml"
    if not scene.exists():
        with atomic_path(scene) as tmp:
            tmp.write_text(job.text, encoding="utf-8")
    ev = r.get("evidence") or {}
    files = {f"{job.scene}.{job.backend}.check.json": ev.get("check", "").encode()}
    for role, png in (ev.get("images") or {}).items():
        files[f"{job.scene}.{job.backend}.{role}.png"] = png
    for name, data in files.items():
        if data:
            with atomic_path(out / name) as tmp:
                tmp.write_bytes(data)


def fuzz(
    c: Campaign,
    count: int,
    out_dir: Path,
    workers: int = 1,
    scheduler: str | None = None,
    use_cache: bool = True,
    on_done: Callable[[Job, dict[str, Any]], None] | None = None,
) -> dict[str, Any]:
    """``minirt fuzz``: ``count`` scenes, every (scene, oracle) job (cached in ``out_dir/cache`` unless
    ``use_cache`` is false) -- after a memory pre-check (``fits_in_memory``), the scenes made as their jobs
    are handed out -- the evidence of what failed and ``out_dir/fuzz.json``; return that document."""
    from minirt.io.images import write_json

    c.count = count
    fits_in_memory(c, 0 if scheduler else workers if workers > 1 else 0)
    run(c, out_dir / "cache" if use_cache else None, workers=workers, scheduler=scheduler, on_done=on_done,
        out=out_dir)  # fmt: skip
    doc = summary(c)
    write_json(out_dir / "fuzz.json", doc)
    return doc
