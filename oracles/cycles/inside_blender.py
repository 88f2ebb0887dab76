"""The half of the Cycles oracle that runs inside Blender's Python (``bpy``): a job file in, EXR passes
(and, for an export, a .blend file) out.

It is a script, not a module minirt imports: minirt.oracles.cycles runs it as ``PYTHON inside_blender.py
--serve`` (jobs one after another, a job file's path a line of standard input; or one job, ``PYTHON
inside_blender.py JOB.json``) with the Python that has ``bpy`` (a child process: see that package's
docstring for why), so it imports nothing but ``bpy`` and the standard library. The job says
everything in Blender's own frame and units -- the parent has already mirrored the exercise's
left-handed scene, sized the planes, placed the camera's principal point and chosen the light's power --
so this side only builds what it is told:

- a ball is a mesh of one vertex at its centre, turned into a point of its radius by a geometry-nodes
  "Mesh to Points" modifier: Cycles draws a point as an exact sphere (a ray-sphere root), not a mesh;
- a plane is a quad of four given corners, wound so that its face normal is the plane's;
- each shape's ``pass_index`` is its index in the scene file + 1 (0: nothing hit), read back from the
  Object Index pass;
- materials: a Diffuse BSDF of the diffuse colour plus (Add Shader) a Glossy BSDF of roughness 0 -- a
  perfect mirror -- of the reflection colour, named as in the scene file;
- the light: a point light of radius 0 without soft falloff, of the given colour and power;
- the world: a Background of the given colour that lights nothing (its importance sampling off, and
  invisible to diffuse rays): it is what a camera or mirror ray that leaves the scene sees.

Every render takes a run of Cycles' own sample sequence (``sample_offset`` and a count: one sample
alone, or the first n), the box filter, no denoising, no adaptive sampling, a fixed seed: the same job
gives the same bytes.

Output: one multilayer EXR per entry of ``job["renders"]`` (float32, lossless; an entry may give its own
world colour, its samples and which of Cycles' samples it starts at), and a line of JSON on standard
output with Blender's version and the timings.
"""

from __future__ import annotations

import json
import sys
import time

import bpy

PASSES = {
    "position": "use_pass_position",
    "normal": "use_pass_normal",
    "object_index": "use_pass_object_index",
    "diffuse_direct": "use_pass_diffuse_direct",
    "diffuse_color": "use_pass_diffuse_color",
}


def _ball_nodes(mat: bpy.types.Material) -> bpy.types.NodeTree:
    """Geometry nodes turning each vertex into a point of the radius in its ``radius`` attribute, of
    material ``mat`` ("Mesh to Points" keeps no material of the mesh's: one node group per material)."""
    ng = bpy.data.node_groups.new(f"ball {mat.name}", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gi, go = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    points = ng.nodes.new("GeometryNodeMeshToPoints")
    radius = ng.nodes.new("GeometryNodeInputNamedAttribute")
    radius.data_type = "FLOAT"
    radius.inputs["Name"].default_value = "radius"
    material = ng.nodes.new("GeometryNodeSetMaterial")
    material.inputs["Material"].default_value = mat
    ng.links.new(gi.outputs[0], points.inputs["Mesh"])
    ng.links.new(radius.outputs["Attribute"], points.inputs["Radius"])
    ng.links.new(points.outputs["Points"], material.inputs["Geometry"])
    ng.links.new(material.outputs["Geometry"], go.inputs[0])
    return ng


def _material(m: dict) -> bpy.types.Material:
    mat = bpy.data.materials.new(m["name"])
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    out.target = "CYCLES"
    diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (*m["diffuse"], 1.0)
    diffuse.inputs["Roughness"].default_value = 0.0  # Lambert
    shader = diffuse.outputs[0]
    if any(v != 0 for v in m["reflection"]):
        mirror = nt.nodes.new("ShaderNodeBsdfGlossy")
        mirror.inputs["Color"].default_value = (*m["reflection"], 1.0)
        mirror.inputs["Roughness"].default_value = 0.0  # a perfect mirror
        add = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(diffuse.outputs[0], add.inputs[0])
        nt.links.new(mirror.outputs[0], add.inputs[1])
        shader = add.outputs[0]
    nt.links.new(shader, out.inputs["Surface"])
    mat.diffuse_color = (*m["diffuse"], 1.0)  # the viewport's solid colour, for a user opening the file
    return mat


# one piece: Blender's scene set up step by step in the order bpy needs it (factory settings, render and
# film, world, camera, objects and materials) -- each step a few assignments to bpy's shared state,
# which runs in Blender's own Python where the job's dict is all there is
def build(job: dict) -> bpy.types.Scene:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.name = job.get("name", "Scene")
    sc.render.engine = "CYCLES"
    r = sc.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = job["width"], job["height"], 100
    r.pixel_aspect_x, r.pixel_aspect_y = job["pixel_aspect"]
    r.use_compositing = False
    r.use_sequencer = False
    r.film_transparent = bool(job.get("transparent"))  # a camera ray that misses: alpha 0 (and black)
    if job.get("threads"):
        r.threads_mode, r.threads = "FIXED", int(job["threads"])
    # linear output: the EXR holds Cycles' radiance as it is
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure = 0.0
    sc.view_settings.gamma = 1.0
    cy = sc.cycles
    cy.device = "CPU"
    cy.samples = int(job["samples"])
    cy.seed = int(job["seed"])
    cy.use_animated_seed = False
    cy.use_denoising = False
    cy.use_adaptive_sampling = False
    cy.pixel_filter_type = "BOX"  # width 1 pixel (Cycles ignores the width for BOX); sample 0 at the centre
    cy.light_sampling_threshold = 0.0
    cy.sample_clamp_direct = 0.0
    cy.sample_clamp_indirect = 0.0
    cy.blur_glossy = 0.0
    cy.caustics_reflective = True
    cy.caustics_refractive = False
    cy.use_light_tree = False
    bounces = int(job["bounces"])
    cy.max_bounces = bounces
    cy.glossy_bounces = bounces
    cy.diffuse_bounces = 0  # the exercise has no indirect diffuse light
    cy.transmission_bounces = 0
    cy.volume_bounces = 0
    cy.transparent_max_bounces = 0

    world = bpy.data.worlds.new("background")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (*job["world"], 1.0)
    bg.inputs["Strength"].default_value = 1.0
    world.cycles.sampling_method = "NONE"  # never sampled as a light ...
    vis = world.cycles_visibility  # ... nor seen by a diffuse bounce: it lights nothing
    vis.camera, vis.glossy = True, True
    vis.diffuse = vis.transmission = vis.scatter = False
    sc.world = world

    mats = [_material(m) for m in job["materials"]]
    nodes: dict[int, bpy.types.NodeTree] = {}
    for b in job["balls"]:
        me = bpy.data.meshes.new(b["name"])
        me.from_pydata([tuple(b["center"])], [], [])
        me.attributes.new("radius", "FLOAT", "POINT").data[0].value = b["radius"]
        me.materials.append(mats[b["material"]])
        ob = bpy.data.objects.new(b["name"], me)
        ob.pass_index = b["index"]
        if b["material"] not in nodes:
            nodes[b["material"]] = _ball_nodes(mats[b["material"]])
        ob.modifiers.new("ball", "NODES").node_group = nodes[b["material"]]
        sc.collection.objects.link(ob)
    for p in job["planes"]:
        me = bpy.data.meshes.new(p["name"])
        me.from_pydata([tuple(v) for v in p["corners"]], [], [(0, 1, 2, 3)])
        me.materials.append(mats[p["material"]])
        ob = bpy.data.objects.new(p["name"], me)
        ob.pass_index = p["index"]
        sc.collection.objects.link(ob)

    lj = job["light"]
    light = bpy.data.lights.new("light", "POINT")
    light.color = lj["color"]
    light.energy = lj["energy"]
    light.shadow_soft_size = 0.0  # a point: no soft shadows
    light.use_soft_falloff = False  # exactly 1/r^2 (Blender's default softens it near the light)
    lo = bpy.data.objects.new("light", light)
    lo.location = lj["location"]
    sc.collection.objects.link(lo)

    cj = job["camera"]
    cam = bpy.data.cameras.new("camera")
    cam.type = "PERSP"
    cam.sensor_fit = "HORIZONTAL"
    cam.lens_unit = "MILLIMETERS"
    cam.sensor_width = cj["sensor_width"]
    cam.lens = cj["lens"]
    cam.shift_x, cam.shift_y = cj["shift"]
    cam.clip_start, cam.clip_end = cj["clip_start"], cj["clip_end"]
    co = bpy.data.objects.new("camera", cam)
    co.location = cj["location"]  # no rotation: Blender's camera looks down -z, +x to the right, +y up
    sc.collection.objects.link(co)
    sc.camera = co

    vl = sc.view_layers[0]
    for name in job["passes"]:
        setattr(vl, PASSES[name], True)
    ims = r.image_settings
    ims.media_type = "MULTI_LAYER_IMAGE"
    ims.file_format = "OPEN_EXR_MULTILAYER"
    ims.color_depth = "32"
    ims.exr_codec = "ZIP"
    return sc


def main(path: str) -> None:
    with open(path, encoding="utf-8") as f:
        job = json.load(f)
    t0 = time.perf_counter()
    sc = build(job)
    timings = {"setup": time.perf_counter() - t0, "render": 0.0}
    if job.get("blend"):
        bpy.ops.wm.save_as_mainfile(filepath=job["blend"], check_existing=False)
    background = sc.world.node_tree.nodes["Background"].inputs["Color"]
    for render in job["renders"]:
        background.default_value = (*render.get("world", job["world"]), 1.0)
        # samples [offset, offset + n) of Cycles' sequence (a subset of one: that sample alone)
        n = int(render.get("samples", job["samples"]))
        sc.cycles.use_sample_subset = True
        sc.cycles.sample_offset = int(render["sample_offset"])
        sc.cycles.sample_subset_length = n
        sc.cycles.samples = int(render["sample_offset"]) + n
        t0 = time.perf_counter()
        bpy.ops.render.render()
        timings["render"] += time.perf_counter() - t0
        # Blender's multilayer EXR writer refuses a pixel aspect other than 1 (each pass's part carries
        # it, and it reports them as conflicting): the passes are saved with it at 1, after the render.
        aspect = sc.render.pixel_aspect_x, sc.render.pixel_aspect_y
        sc.render.pixel_aspect_x = sc.render.pixel_aspect_y = 1.0
        bpy.data.images["Render Result"].save_render(filepath=render["exr"], scene=sc)
        sc.render.pixel_aspect_x, sc.render.pixel_aspect_y = aspect
    print("minirt-cycles " + json.dumps({"blender": bpy.app.version_string, "timings": timings}), flush=True)


def serve() -> None:
    """Jobs one after another until the end of standard input: a job file's path a line, each answered by
    ``main``'s line of JSON (or one saying why the job failed) and then the line "minirt-cycles-done"; the
    line "--version" is answered with Blender's version, as ``--version`` on the command line is. Each
    job builds its scene from Blender's empty factory settings (``build``): no state is carried over."""
    for line in sys.stdin:
        if line.strip() == "--version":  # the parent's first question: which Blender this is
            print("minirt-cycles " + json.dumps({"blender": bpy.app.version_string}), flush=True)
            print("minirt-cycles-done", flush=True)
            continue
        try:
            main(line.strip())
        except Exception as e:  # the job's own failure; the process serves the next one
            why = " ".join(f"{type(e).__name__}: {e}".split())[:300]
            print("minirt-cycles " + json.dumps({"failed": why}), flush=True)
        print("minirt-cycles-done", flush=True)


if __name__ == "__main__":
    if sys.argv[1:] == ["--version"]:
        print("minirt-cycles " + json.dumps({"blender": bpy.app.version_string}), flush=True)
    elif sys.argv[1:] == ["--serve"]:
        serve()
    else:
        main(sys.argv[1])
