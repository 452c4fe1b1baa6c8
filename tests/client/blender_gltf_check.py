# Imports a .glb written by `dance-generate --gltf` into Blender (its bundled glTF importer) and checks it
# against the dance JSON written by the same run (`--out`). Runs inside Blender:
#   blender -b --factory-startup --python-exit-code 1 \
#       --python tests/client/blender_gltf_check.py -- DANCE.glb DANCE.json
# Exits 0 and prints "blender_gltf_check: {...}" when every check passes, 1 with "FAIL:" lines otherwise.
# Driven by blender_gltf_test.sh (CTest).
#
# Checks, after bpy.ops.import_scene.gltf (glTF Y up -> Blender Z up):
#  - one armature with 24 bones named and parented as the JSON's joints;
#  - a mesh skinned to it (an Armature modifier, one vertex group per joint);
#  - the action spans one key per JSON frame (the scene set to the JSON's 30 fps before importing);
#  - at every frame, every bone head in world space (back in our Y-up frame) within 1 mm of forward
#    kinematics of the JSON's rotations and within --tolerance (5 cm, as the BVH test) of its positions;
#  - at every 10th frame, every deformed mesh vertex within 1 mm of where rigid skinning to its joint puts
#    it: Blender deforms the mesh with the dance.
import argparse
import json
import math
import sys
import traceback

import bpy
from mathutils import Matrix, Quaternion, Vector

PREFIX = "blender_gltf_check:"
# glTF's +Y up, +Z forward to Blender's +Z up, -Y forward: (x, y, z) -> (x, -z, y) (the importer's fixed
# conversion, written out so a changed convention fails the test).
OURS_TO_BLENDER = Matrix(((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0)))
BLENDER_TO_OURS = OURS_TO_BLENDER.transposed()


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="blender_gltf_check.py")
    p.add_argument("glb")
    p.add_argument("json")
    p.add_argument("--tolerance", type=float, default=0.05)
    p.add_argument("--fk-tolerance", type=float, default=0.001)
    return p.parse_args(argv)


def fk(parents, offsets, root, rotations):
    glob, pos = [], []
    for j, p in enumerate(parents):
        q = Quaternion(rotations[j])
        if p < 0:
            glob.append(q)
            pos.append(Vector(root))
        else:
            glob.append(glob[p] @ q)
            pos.append(pos[p] + glob[p] @ Vector(offsets[j]))
    return glob, pos


def apply_numpy_bool_workaround():
    """Debian 12's Blender 3.4 glTF importer uses np.bool, which the system's NumPy (1.24) removed
    ("module 'numpy' has no attribute 'bool'"), so every mesh import fails. The alias meant the builtin
    bool; put it back. Harmless where the importer or NumPy is already fixed."""
    import numpy
    if "bool" not in numpy.__dict__:
        numpy.bool = bool


def check(args, failures):
    def expect(ok, msg):
        if not ok:
            failures.append(msg)
        return ok

    dance = json.load(open(args.json))
    names, parents, offsets = dance["joint_names"], dance["parents"], dance["rest_offsets"]
    positions, rotations = dance["positions"], dance["rotations"]
    n = len(positions)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = int(dance["fps"]), 1.0
    apply_numpy_bool_workaround()
    before = set(bpy.data.objects)
    result = bpy.ops.import_scene.gltf(filepath=args.glb)
    if result != {"FINISHED"}:
        failures.append("import_scene.gltf returned %s" % result)
        return None
    new = [o for o in bpy.data.objects if o not in before]
    arms = [o for o in new if o.type == "ARMATURE"]
    meshes = [o for o in new if o.type == "MESH"]
    if not expect(len(arms) == 1, "import made %d armatures (%s)" % (len(arms), [o.name for o in new])):
        return None
    arm = arms[0]
    bones = arm.data.bones
    expect(sorted(b.name for b in bones) == sorted(names), "bones %s" % sorted(b.name for b in bones))
    for j, name in enumerate(names):
        if name in bones:
            par = bones[name].parent
            want = names[parents[j]] if parents[j] >= 0 else None
            expect((par.name if par else None) == want, "bone %s parent %s, want %s" % (name, par and par.name, want))
    if not expect(len(meshes) == 1, "import made %d meshes" % len(meshes)):
        return None
    mesh = meshes[0]
    mods = [m for m in mesh.modifiers if m.type == "ARMATURE"]
    expect(len(mods) == 1 and mods[0].object == arm, "the mesh has no Armature modifier on the armature")
    expect(sorted(g.name for g in mesh.vertex_groups) == sorted(names), "vertex groups %s"
           % sorted(g.name for g in mesh.vertex_groups))
    action = arm.animation_data.action if arm.animation_data else None
    if not expect(action is not None, "the armature has no action"):
        return None
    first, last = (round(f) for f in action.frame_range)
    expect(last - first + 1 == n, "action frames %d..%d, the JSON has %d frames" % (first, last, n))
    if failures:
        return None

    # Rest data for the skinning check: each vertex's joint and rest position (ours).
    group_joint = {g.index: names.index(g.name) for g in mesh.vertex_groups}
    rest_world = fk(parents, offsets, [0.0, 0.0, 0.0], [[1, 0, 0, 0]] * len(names))[1]
    # The file's root rest height (the rest pose stands on the floor).
    lowest = min(p.y for p in rest_world)
    rest_world = [p - Vector((0.0, lowest, 0.0)) for p in rest_world]
    verts = []
    for v in mesh.data.vertices:
        gs = [g for g in v.groups if g.weight > 0.5]
        if len(gs) == 1:
            verts.append((v.index, group_joint[gs[0].group], BLENDER_TO_OURS @ (mesh.matrix_world @ v.co)))
    expect(len(verts) == len(mesh.data.vertices), "%d of %d vertices have one joint" % (len(verts), len(mesh.data.vertices)))

    worst_fk = worst_json = worst_skin = 0.0
    for i in range(n):
        scene.frame_set(first + i)
        glob, pos = fk(parents, offsets, positions[i][0], rotations[i])
        for j, name in enumerate(names):
            head = BLENDER_TO_OURS @ (arm.matrix_world @ arm.pose.bones[name].head)
            worst_fk = max(worst_fk, (head - pos[j]).length)
            worst_json = max(worst_json, (head - Vector(positions[i][j])).length)
        if i % 10 == 0:
            deps = bpy.context.evaluated_depsgraph_get()
            ev = mesh.evaluated_get(deps)
            data = ev.to_mesh()
            for index, j, r in verts:
                want = glob[j] @ (r - rest_world[j]) + pos[j]
                got = BLENDER_TO_OURS @ (ev.matrix_world @ data.vertices[index].co)
                worst_skin = max(worst_skin, (got - want).length)
            ev.to_mesh_clear()
    expect(worst_fk <= args.fk_tolerance, "bone heads %.4f m from FK of the JSON rotations" % worst_fk)
    expect(worst_json <= args.tolerance, "bone heads %.4f m from the JSON positions" % worst_json)
    expect(worst_skin <= args.fk_tolerance, "deformed vertices %.4f m from rigid skinning" % worst_skin)
    return {"bones": len(bones), "frames": n, "vertices": len(verts), "action_frames": [first, last],
            "max_dist_to_fk_m": round(worst_fk, 7), "max_dist_to_json_m": round(worst_json, 6),
            "max_skin_error_m": round(worst_skin, 7)}


def main():
    args = parse_args()
    failures, summary = [], None
    try:
        summary = check(args, failures)
    except Exception:
        failures.append("exception:\n" + traceback.format_exc())
    if summary is not None:
        print(PREFIX, json.dumps(summary))
    for m in failures:
        print(PREFIX, "FAIL:", m)
    sys.stdout.flush()
    sys.exit(1 if failures else 0)


main()
