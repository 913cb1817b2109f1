"""Concave development scenes for GTSR-rs, rendered with Blender Cycles.

Every scene is rendered as `../shared/data` was (its README gives the settings): the object
normalised to a bounding radius of 1 around the origin, a Principled BSDF with random-walk
subsurface scattering (weight 1, specular 0.5), one 400 W point light of zero radius
parented to the camera, a black world, transparent film (alpha = the mask), the "Standard"
view transform, 256 x 256 px, horizontal field of view 0.6911 rad, cameras at distance 4
looking at the origin on Fibonacci spheres (80 training views, 16 test views with another
offset), 128 samples per pixel without a denoiser, and `mesh.ply`, the watertight ground
truth in world space.

The shapes have concavities that the masks cannot see:

- `deep_cup`: a thick-walled cup, its inside 1.4 times deeper than it is wide;
- `shallow_dish`: a wide dish, its inside 0.11 of its width deep;
- `pitted_ball`: a ball with twelve spherical pits;
- `split_block`: two blocks with a narrow gap (0.05) between them.

Each shape comes in two materials: `short` (wax_knot's colour, a quarter of its scattering radius) and
`long` (amber_ingot's colour, twice wax_knot's radius). A third, `mottled` (`long` with its
colour darkened in patches by a noise fixed to the object, as amber with inclusions), is
rendered only when `--scenes` names it: its patches move with the surface between views, the
parallax a uniform material lacks.

`--light studio` renders the same scenes under fixed lights instead of the flash: a sun
(3 W/m^2, from above and to one side, the same in every view) and a dim grey world (0.3 grey
at strength 0.3), into `DIR/<shape>_<material>_studio/`: the case where the light does not
move with the camera. `--mesh NAME=PLY` adds a shape read from a watertight binary or ASCII
PLY (normalised like the others), e.g. `--mesh knot=../shared/data/wax_knot/mesh.ply` with
the `wax` material (wax_knot's own) for the knot under studio lights.

Usage (Debian's `blender` package, 3.4, renders headless):

    blender -b --python scripts/blender/concave_scenes.py -- --out DIR [--scenes a,b]
        [--light flash|studio] [--mesh NAME=PLY] [--samples 128] [--resolution 256]
        [--train 80] [--test 16]

writes `DIR/<shape>_<material>[_studio]/` in the NeRF/Blender layout (`transforms_train.json`,
`transforms_test.json`, `train/r_K.png`, `test/r_K.png`, `mesh.ply`). A scene whose
folder already holds every image is skipped, so an interrupted run resumes.
"""

import argparse
import json
import math
import os
import struct
import sys

import bpy
from mathutils import Matrix, Vector

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
CAMERA_DISTANCE = 4.0
FOV_X = 0.6911112070083618
LIGHT_WATTS = 400.0
# `--light studio`: a fixed sun and a dim grey world, the same in every view.
SUN_STRENGTH = 3.0
SUN_DIRECTION = (0.45, -0.35, 0.82)  # towards the sun, world space (z up)
WORLD_GREY = 0.3
WORLD_STRENGTH = 0.3

MATERIALS = {
    # name: (base colour, subsurface radius, roughness, mottled)
    "short": ((0.9, 0.85, 0.75), (0.1, 0.075, 0.05), 0.45, False),
    "long": ((0.95, 0.65, 0.2), (0.8, 0.6, 0.3), 0.2, False),
    # `long` whose colour is mottled by a noise fixed to the object (amber with inclusions):
    # texture that moves with the surface between views, i.e. parallax.
    "mottled": ((0.95, 0.65, 0.2), (0.8, 0.6, 0.3), 0.2, True),
    # wax_knot's own material (`../shared/data/README.md`), for shapes read with `--mesh`.
    "wax": ((0.9, 0.85, 0.75), (0.4, 0.3, 0.2), 0.45, False),
}
# The materials every run of the script renders unless `--scenes` names others.
DEFAULT_MATERIALS = ("short", "long")


# ---------------------------------------------------------------- shapes
def arc(cx, cz, radius, start, end, steps):
    """Points (r, z) on a circular arc of the profile, angles in radians, both ends kept."""
    return [
        (cx + radius * math.cos(start + (end - start) * k / steps),
         cz + radius * math.sin(start + (end - start) * k / steps))
        for k in range(steps + 1)
    ]


def lathe(profile, segments):
    """A closed surface of revolution about z from a profile (r, z) that starts and ends on
    the axis (r = 0), traced so that the outside lies to its right. Returns (vertices, faces)."""
    verts, rings = [], []
    for r, z in profile:
        if r <= 1e-9:
            rings.append([len(verts)])
            verts.append((0.0, 0.0, z))
        else:
            ring = []
            for s in range(segments):
                a = 2.0 * math.pi * s / segments
                ring.append(len(verts))
                verts.append((r * math.cos(a), r * math.sin(a), z))
            rings.append(ring)
    faces = []
    for lower, upper in zip(rings, rings[1:]):
        for s in range(segments):
            t = (s + 1) % segments
            if len(lower) == 1 and len(upper) == 1:
                raise ValueError("two axis points in a row")
            if len(lower) == 1:
                faces.append((lower[0], upper[t], upper[s]))
            elif len(upper) == 1:
                faces.append((lower[s], lower[t], upper[0]))
            else:
                faces.append((lower[s], lower[t], upper[t], upper[s]))
    return verts, faces


def cup_profile(outer, height, wall, floor, rim_steps=8, corner=0.08):
    """Bottom centre -> outer wall -> rounded rim -> inner wall -> inside floor centre."""
    z0, z1 = -height / 2.0, height / 2.0
    inner = outer - wall
    c = corner
    prof = [(0.0, z0)]
    prof += arc(outer - c, z0 + c, c, -math.pi / 2, 0.0, rim_steps)      # outer bottom corner
    prof += arc(outer - wall / 2, z1 - wall / 2, wall / 2, 0.0, math.pi, rim_steps)  # rim
    ci = min(c, 0.5 * inner)
    prof += arc(inner - ci, z0 + floor + ci, ci, 0.0, -math.pi / 2, rim_steps)  # inner corner
    prof.append((0.0, z0 + floor))
    # The inside is traced downwards then inwards: the outward normal points into the cup.
    return prof


def deep_cup():
    return lathe(cup_profile(outer=0.55, height=1.5, wall=0.1, floor=0.16, corner=0.1), 128)


def shallow_dish():
    return lathe(cup_profile(outer=1.0, height=0.34, wall=0.08, floor=0.1, corner=0.08), 160)


def icosphere(level):
    t = (1.0 + math.sqrt(5.0)) / 2.0
    verts = [Vector(v).normalized() for v in (
        (-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
        (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1))]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
             (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
             (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(level):
        cache, out = {}, []

        def mid(a, b):
            key = (min(a, b), max(a, b))
            if key not in cache:
                cache[key] = len(verts)
                verts.append(((verts[a] + verts[b]) / 2.0).normalized())
            return cache[key]

        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            out += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = out
    return verts, faces


def pitted_ball():
    """A unit ball with twelve spherical pits (centred on an icosahedron's vertices, rotated
    off the axes): each pit is a sphere's cap of angular radius 0.32 rad and depth 0.26."""
    verts, faces = icosphere(6)
    centres, _ = icosphere(0)
    rot = Matrix.Rotation(0.4, 3, "X") @ Matrix.Rotation(0.3, 3, "Z")
    centres = [rot @ c for c in centres]
    ang, depth = 0.32, 0.26
    a = math.sin(ang)                       # the pit's rim radius on the unit sphere
    # A pit sphere through the rim circle, its bottom `depth` below the unit sphere.
    h = math.cos(ang)                       # the rim plane's distance from the centre
    # centre distance d and radius R: R^2 = a^2 + (d - h)^2 (rim), d - R = 1 - depth (bottom)
    bottom = 1.0 - depth
    d = (a * a + h * h - bottom * bottom) / (2.0 * (h - bottom))
    big_r = d - bottom
    out = []
    for v in verts:
        r = 1.0
        for c in centres:
            if v.dot(c) > math.cos(ang):
                # Where the ray from the origin along v meets the pit sphere (nearer root).
                p = d * v.dot(c)
                disc = p * p - (d * d - big_r * big_r)
                r = min(r, p - math.sqrt(max(disc, 0.0)))
        out.append(tuple(v * r))
    return out, faces


def rounded_box(cx, cy, cz, hx, hy, hz, radius, level=5):
    """A box with rounded edges, from a subdivided sphere pushed onto the rounded box."""
    verts, faces = icosphere(level)
    out = []
    for v in verts:
        # Project the direction onto the rounded box's surface by bisection along the ray.
        lo, hi = 0.0, 4.0 * max(hx, hy, hz)
        for _ in range(60):
            m = (lo + hi) / 2.0
            p = v * m
            q = Vector((max(abs(p.x) - (hx - radius), 0.0), max(abs(p.y) - (hy - radius), 0.0),
                        max(abs(p.z) - (hz - radius), 0.0)))
            if q.length > radius:
                hi = m
            else:
                lo = m
        p = v * lo
        out.append((p.x + cx, p.y + cy, p.z + cz))
    return out, faces


def split_block():
    """Two blocks side by side with a 0.06-wide gap between them, one lower than the other."""
    gap = 0.06
    v1, f1 = rounded_box(0.0, -(0.35 + gap / 2), 0.0, 0.8, 0.35, 0.4, 0.06)
    v2, f2 = rounded_box(0.0, 0.35 + gap / 2, -0.08, 0.8, 0.35, 0.32, 0.06)
    n = len(v1)
    return v1 + v2, f1 + [tuple(i + n for i in f) for f in f2]


SHAPES = {
    "deep_cup": deep_cup,
    "shallow_dish": shallow_dish,
    "pitted_ball": pitted_ball,
    "split_block": split_block,
}


def normalise(verts):
    """Centre the bounding box on the origin and scale to a bounding radius of 1."""
    lo = [min(v[i] for v in verts) for i in range(3)]
    hi = [max(v[i] for v in verts) for i in range(3)]
    c = [(lo[i] + hi[i]) / 2.0 for i in range(3)]
    moved = [tuple(v[i] - c[i] for i in range(3)) for v in verts]
    radius = max(math.sqrt(sum(x * x for x in v)) for v in moved)
    return [tuple(x / radius for x in v) for v in moved]


PLY_TYPES = {
    "char": "b", "int8": "b", "uchar": "B", "uint8": "B", "short": "h", "int16": "h",
    "ushort": "H", "uint16": "H", "int": "i", "int32": "i", "uint": "I", "uint32": "I",
    "float": "f", "float32": "f", "double": "d", "float64": "d",
}


def read_ply(path):
    """Vertices and faces of a binary little-endian PLY (the layout Blender and this script write)."""
    with open(path, "rb") as fh:
        data = fh.read()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply") or end < 0:
        sys.exit(f"error: {path}: not a PLY file")
    header = data[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in header:
        sys.exit(f"error: {path}: only binary little-endian PLY is read")
    elements = []
    for line in header:
        words = line.split()
        if words[:1] == ["element"]:
            elements.append((words[1], int(words[2]), []))
        elif words[:1] == ["property"]:
            elements[-1][2].append(words[1:])
    offset = end + len("end_header\n")
    verts, faces = [], []
    for name, count, props in elements:
        for _ in range(count):
            row = {}
            for prop in props:
                if prop[0] == "list":
                    (n,) = struct.unpack_from("<" + PLY_TYPES[prop[1]], data, offset)
                    offset += struct.calcsize(PLY_TYPES[prop[1]])
                    fmt = "<" + PLY_TYPES[prop[2]] * n
                    row[prop[3]] = struct.unpack_from(fmt, data, offset)
                    offset += struct.calcsize(fmt)
                else:
                    fmt = "<" + PLY_TYPES[prop[0]]
                    (row[prop[1]],) = struct.unpack_from(fmt, data, offset)
                    offset += struct.calcsize(fmt)
            if name == "vertex":
                verts.append((row["x"], row["y"], row["z"]))
            elif name == "face":
                faces.append(tuple(row.get("vertex_indices", row.get("vertex_index", ()))))
    if not verts or not faces:
        sys.exit(f"error: {path}: no vertices or no faces")
    return verts, faces


def write_ply(path, verts, faces):
    """Binary little-endian PLY, triangles only, written atomically."""
    tris = []
    for f in faces:
        for k in range(1, len(f) - 1):
            tris.append((f[0], f[k], f[k + 1]))
    tmp = path + ".tmp"
    with open(tmp, "wb") as fh:
        fh.write((
            "ply\nformat binary_little_endian 1.0\ncomment GTSR-rs concave_scenes.py\n"
            f"element vertex {len(verts)}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face {len(tris)}\nproperty list uchar uint vertex_indices\nend_header\n"
        ).encode("ascii"))
        for v in verts:
            fh.write(struct.pack("<3f", *v))
        for t in tris:
            fh.write(struct.pack("<B3I", 3, *t))
    os.replace(tmp, path)


# ---------------------------------------------------------------- cameras
def fibonacci_eyes(count, phase):
    eyes = []
    for i in range(count):
        z = 1.0 - (2.0 * i + 1.0) / count
        r = math.sqrt(max(0.0, 1.0 - z * z))
        phi = phase + i * GOLDEN_ANGLE
        eyes.append(Vector((r * math.cos(phi), r * math.sin(phi), z)) * CAMERA_DISTANCE)
    return eyes


def look_at_origin(eye):
    """Camera-to-world: the camera's -z looks at the origin, by the shortest rotation of +z."""
    back = eye.normalized()
    rot = Vector((0.0, 0.0, 1.0)).rotation_difference(back).to_matrix().to_4x4()
    rot.translation = eye
    return rot


# ---------------------------------------------------------------- scene
def build_scene(verts, faces, material, samples, resolution, light):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.render.use_persistent_data = True
    scene.render.film_transparent = True
    scene.render.resolution_x = resolution
    scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGBA"
    scene.render.image_settings.color_depth = "8"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"

    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    background = world.node_tree.nodes["Background"]
    if light == "studio":
        background.inputs["Color"].default_value = (WORLD_GREY, WORLD_GREY, WORLD_GREY, 1)
        background.inputs["Strength"].default_value = WORLD_STRENGTH
    else:
        background.inputs["Color"].default_value = (0, 0, 0, 1)
        background.inputs["Strength"].default_value = 0.0
    scene.world = world

    mesh = bpy.data.meshes.new("object")
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    for poly in mesh.polygons:
        poly.use_smooth = True
    obj = bpy.data.objects.new("object", mesh)
    scene.collection.objects.link(obj)

    base, radius, roughness, mottled = MATERIALS[material]
    mat = bpy.data.materials.new(material)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.subsurface_method = "RANDOM_WALK"
    bsdf.inputs["Base Color"].default_value = (*base, 1.0)
    bsdf.inputs["Subsurface Color"].default_value = (*base, 1.0)
    if mottled:
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        coords = nodes.new("ShaderNodeTexCoord")
        noise = nodes.new("ShaderNodeTexNoise")
        noise.inputs["Scale"].default_value = 6.0
        noise.inputs["Detail"].default_value = 2.0
        links.new(coords.outputs["Object"], noise.inputs["Vector"])
        ramp = nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.elements[0].position = 0.45
        ramp.color_ramp.elements[0].color = (*(0.25 * c for c in base), 1.0)
        ramp.color_ramp.elements[1].position = 0.55
        ramp.color_ramp.elements[1].color = (*base, 1.0)
        links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
        links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
        links.new(ramp.outputs["Color"], bsdf.inputs["Subsurface Color"])
    bsdf.inputs["Subsurface"].default_value = 1.0
    bsdf.inputs["Subsurface Radius"].default_value = radius
    bsdf.inputs["Specular"].default_value = 0.5
    bsdf.inputs["Roughness"].default_value = roughness
    obj.data.materials.append(mat)

    cam_data = bpy.data.cameras.new("camera")
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.angle = FOV_X
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    scene.camera = cam

    if light == "studio":
        sun_data = bpy.data.lights.new("sun", type="SUN")
        sun_data.energy = SUN_STRENGTH
        sun_data.angle = math.radians(2.0)
        sun = bpy.data.objects.new("sun", sun_data)
        # A sun shines along its local -z: turn +z towards the sun.
        toward = Vector(SUN_DIRECTION).normalized()
        sun.matrix_world = Vector((0.0, 0.0, 1.0)).rotation_difference(toward).to_matrix().to_4x4()
        scene.collection.objects.link(sun)
    else:
        light_data = bpy.data.lights.new("flash", type="POINT")
        light_data.energy = LIGHT_WATTS
        light_data.shadow_soft_size = 0.0
        flash = bpy.data.objects.new("flash", light_data)
        scene.collection.objects.link(flash)
        flash.parent = cam
    return scene, cam


def render_split(scene, cam, folder, split, eyes):
    os.makedirs(os.path.join(folder, split), exist_ok=True)
    frames = []
    for k, eye in enumerate(eyes):
        matrix = look_at_origin(eye)
        cam.matrix_world = matrix
        rel = f"./{split}/r_{k}"
        path = os.path.join(folder, split, f"r_{k}.png")
        if not os.path.exists(path):
            scene.render.filepath = path + ".part.png"
            bpy.ops.render.render(write_still=True)
            os.replace(path + ".part.png", path)
        frames.append({"file_path": rel, "transform_matrix": [list(row) for row in matrix]})
    tmp = os.path.join(folder, f"transforms_{split}.json.tmp")
    with open(tmp, "w") as fh:
        json.dump({"camera_angle_x": FOV_X, "frames": frames}, fh, indent=1)
    os.replace(tmp, os.path.join(folder, f"transforms_{split}.json"))


def main():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="folder for the scenes (outside the repository)")
    names = [f"{s}_{m}" for s in SHAPES for m in MATERIALS]
    default = [f"{s}_{m}" for s in SHAPES for m in DEFAULT_MATERIALS]
    parser.add_argument(
        "--scenes",
        default=",".join(default),
        help="comma-separated; default: every shape in the short and long materials",
    )
    parser.add_argument("--light", choices=("flash", "studio"), default="flash")
    parser.add_argument(
        "--mesh",
        action="append",
        default=[],
        metavar="NAME=PLY",
        help="add a shape read from a watertight PLY (binary little-endian)",
    )
    parser.add_argument("--samples", type=int, default=128)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--train", type=int, default=80)
    parser.add_argument("--test", type=int, default=16)
    args = parser.parse_args(argv)

    shapes = dict(SHAPES)
    for item in args.mesh:
        shape, _, path = item.partition("=")
        if not shape or not path or "_" in shape:
            sys.exit(f"error: --mesh '{item}': expected NAME=PLY with a NAME without '_'")
        shapes[shape] = lambda path=path: read_ply(path)
    names += [f"{s}_{m}" for s in shapes if s not in SHAPES for m in MATERIALS]
    wanted = [s for s in args.scenes.split(",") if s]
    for name in wanted:
        if name not in names:
            sys.exit(f"error: unknown scene '{name}' (known: {', '.join(names)})")
    for name in wanted:
        shape, material = name.rsplit("_", 1)
        suffix = "_studio" if args.light == "studio" else ""
        folder = os.path.join(os.path.abspath(args.out), name + suffix)
        os.makedirs(folder, exist_ok=True)
        verts, faces = shapes[shape]()
        verts = normalise(verts)
        write_ply(os.path.join(folder, "mesh.ply"), verts, faces)
        scene, cam = build_scene(verts, faces, material, args.samples, args.resolution, args.light)
        render_split(scene, cam, folder, "train", fibonacci_eyes(args.train, 0.0))
        render_split(scene, cam, folder, "test", fibonacci_eyes(args.test, 1.234))
        print(f"scene {name}{suffix}: {folder}", flush=True)


main()
