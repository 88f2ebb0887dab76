"""The Embree oracle (trimesh + embreex) against the reference tracer, with its recorded error bounds.

What "agree" means here (oracles/embree.py derives every bound):
- hit masks and shape ids agree except on rays inside the band: silhouette margin |h - r|/r below
  ``band_abs`` (= radial gap g + float32 allowance; factor 1 because the inscribed-polyhedron
  argument is exact: a ray with h <= r(1 - g) must hit the mesh and one with h > r must miss it),
  grazing margin |n·d| below ``grazing_abs`` (plane hits beyond the far distance), ray origins within
  the same relative distance of a ball's surface (``origin_band_abs``), and depth ties closer than
  the per-pixel t bound plus the float32 allowance;
- on agreed hits, |Δt| <= aux["t_bound"] and the normal angle <= aux["normal_bound_deg"] per pixel,
  and the global ``t_abs`` / ``normal_deg`` off the band.
A failure writes the evidence (both results' buffers and the masks) to an .npz named in the message.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from minirt.harness.backends import get
from minirt.model import camera
from minirt.model.rules import resolve
from minirt.model.scene import Ball, load_scene
from minirt.oracles.embree import EmbreeOracle, scene_to_mesh, tessellation
from minirt.reference import band, tracer

SIZE = 64
SNAPSHOTS = Path(__file__).resolve().parents[1] / "snapshots" / "embree"
UPDATE = os.environ.get("MINIRT_UPDATE_SNAPSHOTS") == "1"

pytestmark = pytest.mark.skipif(not EmbreeOracle().available()[0], reason="installed by make test; never skipped")


def _small(path: Path):
    return load_scene(path).with_overrides(width=SIZE, height=SIZE, samples=1)


def _compare(scene, level: int, tmp_path: Path) -> dict:
    """Render both; return masks and errors (and dump evidence to tmp_path)."""
    orc = EmbreeOracle()
    rules = orc.adapt(resolve(scene))
    ref = tracer.render(scene, rules)
    res = orc.render(scene, rules, {"subdivisions": level})
    assert res.ok, res.reason
    p = res.meta["precision"]
    o, d = camera.primary_rays(scene, rules)
    with np.errstate(invalid="ignore"):  # band.margins computes inf - inf for rays that hit < 2 shapes
        mg = {k: v.reshape(SIZE, SIZE) for k, v in band.margins(scene, o, d).items()}
    origin = np.full(len(o), np.inf)
    for s in scene.shapes:
        if isinstance(s, Ball):
            dist = np.linalg.norm(o - np.asarray(s.center), axis=1)
            origin = np.minimum(origin, np.abs(dist - s.radius) / s.radius)
    origin = origin.reshape(SIZE, SIZE)
    t1 = np.where(np.isfinite(ref.t), ref.t, 1.0)
    tie_allow = (np.where(res.hit, res.aux["t_bound"], 0.0) + p["eps32_abs"]) / t1
    in_band = (
        (mg["silhouette"] < p["band_abs"])
        | (mg["grazing"] < p["grazing_abs"])
        | (origin < p["origin_band_abs"])
        | (mg["tie"] < tie_allow)
    )
    same = res.hit & ref.hit & (res.shape_id == ref.shape_id)
    dt = np.where(same, np.abs(np.where(same, res.t, 0.0) - np.where(same, ref.t, 0.0)), 0.0)
    cos = np.clip(np.einsum("ijk,ijk->ij", res.normal, ref.normal), -1.0, 1.0)
    ang = np.where(same, np.degrees(np.arccos(cos)), 0.0)
    out = {
        "ref": ref,
        "res": res,
        "p": p,
        "in_band": in_band,
        "same": same,
        "dt": dt,
        "ang": ang,
        "hit_bad": (res.hit != ref.hit) & ~in_band,
        "id_bad": res.hit & ref.hit & (res.shape_id != ref.shape_id) & ~in_band,
        "cos_ref": np.abs(np.einsum("ijk,ijk->ij", ref.normal, d.reshape(SIZE, SIZE, 3))),
    }
    evidence = tmp_path / f"embree_{scene.name}_L{level}.npz"
    np.savez_compressed(
        evidence,
        ref_hit=ref.hit, res_hit=res.hit, ref_id=ref.shape_id, res_id=res.shape_id, ref_t=ref.t, res_t=res.t,
        in_band=in_band, t_bound=res.aux["t_bound"], normal_bound=res.aux["normal_bound_deg"], dt=dt, ang=ang,
    )  # fmt: skip
    out["evidence"] = evidence
    return out


def test_available_and_registered():
    ok, why = EmbreeOracle().available()
    assert ok, why
    assert "trimesh" in why and "embreex" in why
    import trimesh.ray

    assert trimesh.ray.has_embree  # really Embree, not trimesh's pure-Python fallback
    assert isinstance(get("embree"), EmbreeOracle)


def test_geometry_agrees_with_reference(scene_path, tmp_path):
    c = _compare(_small(scene_path), 4, tmp_path)
    res, p, same = c["res"], c["p"], c["same"]
    ev = f"(evidence: {c['evidence']})"
    assert c["hit_bad"].sum() == 0, f"{c['hit_bad'].sum()} hit/miss disagreements outside the band {ev}"
    assert c["id_bad"].sum() == 0, f"{c['id_bad'].sum()} shape-id disagreements outside the band {ev}"
    assert np.all(c["dt"][same] <= res.aux["t_bound"][same]), f"t error above the per-pixel bound {ev}"
    assert np.all(c["ang"][same] <= res.aux["normal_bound_deg"][same]), f"normal error above its bound {ev}"
    off = same & ~c["in_band"]
    assert c["dt"][off].max(initial=0.0) <= p["t_abs"], ev
    assert c["ang"][off].max(initial=0.0) <= p["normal_deg"], ev
    assert res.color is None and res.meta["backend"] == "embree"
    assert res.meta["tessellation"]["subdivisions"] == 4
    assert set(res.meta["timings"]) >= {"tessellation", "bvh_build", "cast", "total"}
    assert res.meta["passes"][0]["rays"] == SIZE * SIZE
    assert res.meta["dropped_hits"] == 0
    # Planes come back exactly as the reference has them (same float64 point-normal form).
    for k, s in enumerate(_small(scene_path).shapes):
        m = same & (res.shape_id == k)
        if not isinstance(s, Ball) and m.any():
            np.testing.assert_allclose(res.t[m], c["ref"].t[m], rtol=1e-12)
            assert np.all(res.normal[m] == np.asarray(s.normal))


def test_bounds_shrink_with_subdivision(tmp_path):
    """Levels 1..5: measured error <= recorded bound, both shrinking (gap 4x per level, normals 2x)."""
    scene = _small(Path(__file__).resolve().parents[2] / "scenes" / "three_balls.toml")
    gaps, t_errs, n_errs = [], [], []
    fixed = None  # one pixel set for every level: ball hits seen head-on (cos θ >= 0.5) by the reference
    for level in range(1, 6):
        c = _compare(scene, level, tmp_path)
        res, ref, same = c["res"], c["ref"], c["same"]
        if fixed is None:
            balls = [k for k, s in enumerate(scene.shapes) if isinstance(s, Ball)]
            fixed = np.isin(ref.shape_id, balls) & (c["cos_ref"] >= 0.5)
        sel = fixed & same
        assert sel.sum() >= 0.95 * fixed.sum(), "head-on ball pixels should all agree"
        assert np.all(c["dt"][same] <= res.aux["t_bound"][same])
        assert np.all(c["ang"][same] <= res.aux["normal_bound_deg"][same])
        g = res.meta["tessellation"]["radial_gap_rel"]
        # Head-on: |Δt| <= r·(1-(1-g)^2)/cos θ <= 2 r·(2g) with cos θ >= 0.5.
        rmax = max(s.radius for s in scene.shapes if isinstance(s, Ball))
        assert c["dt"][sel].max() <= rmax * res.meta["precision"]["t_rel_over_cos"] / 0.5
        gaps.append(g)
        t_errs.append(c["dt"][sel].max())
        n_errs.append(c["ang"][sel].max())
    gap_ratio = np.array(gaps[:-1]) / np.array(gaps[1:])
    assert np.all((gap_ratio > 3.0) & (gap_ratio < 4.2)), gap_ratio
    t_ratio = np.array(t_errs[:-1]) / np.array(t_errs[1:])
    assert np.all(t_ratio > 2.5), (t_errs, t_ratio)  # about 4x
    n_ratio = np.array(n_errs[:-1]) / np.array(n_errs[1:])
    assert np.all(n_ratio > 1.5), (n_errs, n_ratio)  # about 2x


def test_tessellation_is_exact_and_cached():
    t4 = tessellation(4)
    assert tessellation(4) is t4
    assert t4.n_faces == 20 * 4**4
    np.testing.assert_allclose(np.linalg.norm(t4.vertices, axis=1), 1.0, atol=1e-15)
    assert tessellation(0).radial_gap_rel == pytest.approx(1 - 0.794654, abs=1e-6)  # icosahedron: inradius
    for level in range(2, 6):  # then 4x per level: g ≈ 0.2917 / 4^N
        assert tessellation(level).radial_gap_rel == pytest.approx(0.2917 / 4**level, rel=0.03)


def _mesh_summary(path: Path) -> dict:
    scene = load_scene(path)
    mesh = scene_to_mesh(scene, 2)
    ids = mesh.face_attributes["shape_id"]
    shapes = []
    for k in range(len(scene.shapes)):
        faces = mesh.faces[ids == k]
        v = mesh.vertices[np.unique(faces)]
        shapes.append(
            {
                "shape": f"shape{k}",
                "faces": len(faces),
                "vertices": len(v),
                "bounds": np.round(np.stack([v.min(axis=0), v.max(axis=0)]), 9).tolist(),
            }
        )
    return {"faces": len(mesh.faces), "vertices": len(mesh.vertices), "shapes": shapes}


def test_scene_to_mesh_snapshot(scene_path):
    got = _mesh_summary(scene_path)
    snap = SNAPSHOTS / f"{scene_path.stem}.json"
    if UPDATE:
        snap.parent.mkdir(parents=True, exist_ok=True)
        snap.write_text(json.dumps(got, indent=1) + "\n")
    assert snap.exists(), f"missing snapshot; create it with: MINIRT_UPDATE_SNAPSHOTS=1 pytest {__file__}"
    want = json.loads(snap.read_text())
    assert got["faces"] == want["faces"] and got["vertices"] == want["vertices"]
    for g, w in zip(got["shapes"], want["shapes"], strict=True):
        assert (g["shape"], g["faces"], g["vertices"]) == (w["shape"], w["faces"], w["vertices"])
        np.testing.assert_allclose(g["bounds"], w["bounds"], rtol=1e-9, atol=1e-9)


def test_face_ids_follow_scene_order_and_normals_point_out():
    scene = load_scene(Path(__file__).resolve().parents[2] / "scenes" / "three_balls.toml")
    mesh = scene_to_mesh(scene, 1)
    ids = mesh.face_attributes["shape_id"]
    assert np.all(np.diff(ids) >= 0) and ids.max() == len(scene.shapes) - 1
    for k, s in enumerate(scene.shapes):
        fn = mesh.face_normals[ids == k]
        cen = mesh.triangles_center[ids == k]
        if isinstance(s, Ball):
            assert np.all(np.einsum("ij,ij->i", fn, cen - np.asarray(s.center)) > 0)
        else:
            np.testing.assert_allclose(fn, np.broadcast_to(s.normal, fn.shape), atol=1e-12)


def test_export_glb(tmp_path):
    import trimesh

    scene = load_scene(Path(__file__).resolve().parents[2] / "scenes" / "exercise.toml")
    orc = EmbreeOracle()
    files = orc.export(scene, orc.adapt(resolve(scene)), tmp_path, {"subdivisions": 2})
    glb = next(f for f in files if f.suffix == ".glb")
    loaded = trimesh.load(glb, force="scene")
    assert sorted(loaded.graph.nodes_geometry) == ["shape0", "shape1"]
    faces = {name: len(g.faces) for name, g in loaded.geometry.items()}
    assert sorted(faces.values()) == [2, 320]
    notes = json.loads(next(f for f in files if f.suffix == ".json").read_text())
    assert [s["node"] for s in notes["shapes"]] == ["shape0", "shape1"]


def test_unavailable_is_a_skip(monkeypatch):
    import trimesh.ray

    monkeypatch.setattr(trimesh.ray, "has_embree", False)
    orc = EmbreeOracle()
    ok, why = orc.available()
    assert not ok and "has_embree" in why
    scene = _small(Path(__file__).resolve().parents[2] / "scenes" / "exercise.toml")
    res = orc.render(scene, orc.adapt(resolve(scene)))
    assert res.status == "skip" and res.reason and "\n" not in res.reason
    assert res.hit is None


def test_failures_are_results_not_exceptions(monkeypatch):
    import minirt.oracles.embree as mod

    scene = _small(Path(__file__).resolve().parents[2] / "scenes" / "exercise.toml")
    orc = EmbreeOracle()
    rules = orc.adapt(resolve(scene))
    bad = orc.render(scene, rules, {"subdivisions": 99})
    assert bad.status == "error" and "subdivisions" in bad.reason
    assert orc.render(scene, rules, {"colour": 1}).status == "error"
    shared = orc.render(scene, rules, {"precision": "f32"})  # the CLI passes it to every backend
    assert shared.ok and shared.meta["options"]["ignored"] == {"precision": "f32"}
    # The literal rule (ball invisible from inside) is not Embree's: the caller must adapt.
    assert orc.render(scene, resolve(scene)).status == "skip"

    def boom(*a, **k):
        raise RuntimeError("embree exploded\nsecond line")

    monkeypatch.setattr(mod, "scene_to_mesh", boom)
    res = orc.render(scene, rules)
    assert res.status == "error" and res.reason == "RuntimeError: embree exploded"


def test_the_default_level_keeps_many_balls_within_the_face_budget(monkeypatch):
    """By default a scene gets level 4 unless its balls would exceed MAX_DEFAULT_FACES faces (10,000 balls
    at level 4: 51 M faces, an 18 GB render); then the finest level under it, recorded with the result. An
    explicit level is taken as given."""
    from minirt.campaign.generate import balls_scene
    from minirt.model.scene import parse_scene
    from minirt.oracles import embree

    assert embree.default_subdivisions(parse_scene(balls_scene(1024, width=8, height=8))) == 4
    assert embree.default_subdivisions(parse_scene(balls_scene(10000, width=8, height=8))) == 2
    sc = load_scene(Path(__file__).resolve().parents[2] / "scenes" / "three_balls.toml").with_overrides(
        width=16, height=16
    )
    monkeypatch.setattr(embree, "MAX_DEFAULT_FACES", 3 * 20 * 4**2)  # three balls: level 2 at most
    rules = EmbreeOracle().adapt(resolve(sc))
    res = EmbreeOracle().render(sc, rules)
    assert res.ok, res.reason
    tess = res.meta["tessellation"]
    assert tess["subdivisions"] == 2 and tess["radial_gap_rel"] == tessellation(2).radial_gap_rel
    assert EmbreeOracle().render(sc, rules, {"subdivisions": 4}).meta["tessellation"]["subdivisions"] == 4


def test_the_hit_faces_normals_are_trimeshs_bit_for_bit():
    """Only the faces hit get a normal (5.2 M faces for 1,024 balls): the same bits as every face's."""
    import trimesh

    from minirt.oracles.embree import _hit_face_normals

    scene = load_scene(Path(__file__).parents[2] / "scenes" / "three_balls.toml")
    mesh = scene_to_mesh(scene, 3)
    rng = np.random.default_rng(5)
    hit = rng.integers(0, len(mesh.faces), 5000)
    got = _hit_face_normals(mesh, hit)(hit)
    assert np.array_equal(got, mesh.face_normals[hit])
    # a degenerate face: a zero normal, as trimesh pads it
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], faces=[[0, 1, 2], [0, 1, 3]],
                           process=False, validate=False)  # fmt: skip
    faces = np.array([1, 0, 1])
    assert np.array_equal(_hit_face_normals(flat, faces)(faces), flat.face_normals[faces])
    assert not _hit_face_normals(flat, faces)(faces)[1].any()
