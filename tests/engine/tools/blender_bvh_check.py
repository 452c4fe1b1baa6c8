# Imports a BVH written by `dance-generate --bvh` into Blender and checks it against the dance JSON
# written by the same run (`--out`). Runs inside Blender:
#   blender -b --factory-startup --python-exit-code 1 \
#       --python tests/engine/tools/blender_bvh_check.py -- DANCE.bvh DANCE.json [--tolerance 0.05]
# Exits 0 and prints a one-line JSON summary ("blender_bvh_check: {...}") when every check passes,
# 1 with "blender_bvh_check: FAIL: ..." lines otherwise. Driven by blender_bvh_test.sh (CTest).
#
# Checks, after bpy.ops.import_anim.bvh (BVH Y up -> Blender Z up, scale 1, scene fps from the file):
#  - exactly one armature with 24 bones, named as the JSON's joint_names (the writer uses the skeleton's
#    joint names for ROOT/JOINT, engine/runtime/dance_writer.cc), parented as the JSON's parents;
#  - the action has one keyframe per JSON frame, on Blender frames 1..N (the BVH's "Frames:" agrees);
#  - the scene runs at the JSON's fps (30);
#  - at every frame, every bone head in world space (converted back to our Y-up frame):
#      * within --fk-tolerance (1 mm) of forward kinematics of the JSON's rotations + rest_offsets: the
#        BVH channels (ZXY Euler, root translation) were imported as written;
#      * within --tolerance (5 cm) of the JSON's positions: the BVH reproduces the dance. It is not exact,
#        because rotations only approximate generated positions (docs/rotations.md, "What it reproduces");
#        the default model measured 2.3-2.4 cm at worst (seeds 0-3), so 5 cm leaves room for a retrained one.
import argparse
import json
import math
import sys
import traceback

import addon_utils
import bpy
from mathutils import Matrix, Quaternion, Vector

PREFIX = "blender_bvh_check:"

# Blender's importer with axis_forward='-Z', axis_up='Y' (its defaults, passed explicitly below) maps our
# Y-up, +Z-forward frame to Blender's Z-up one as (x, y, z) -> (x, -z, y). Written out here rather than
# taken from bpy_extras.io_utils.axis_conversion, so a changed importer convention fails the test.
OURS_TO_BLENDER = Matrix(((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0)))
BLENDER_TO_OURS = OURS_TO_BLENDER.transposed()


class CheckFailed(Exception):
    pass


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="blender_bvh_check.py")
    p.add_argument("bvh")
    p.add_argument("json")
    p.add_argument("--tolerance", type=float, default=0.05,
                   help="max distance (m) of a bone head from the JSON position (default 0.05)")
    p.add_argument("--fk-tolerance", type=float, default=0.001,
                   help="max distance (m) of a bone head from FK of the JSON rotations (default 0.001)")
    return p.parse_args(argv)


def apply_open_mode_workaround(module):
    """Debian 12's Blender 3.4.1 importer opens the file with mode 'rU' (import_bvh.py, read_bvh), which
    Python 3.11 removed ("ValueError: invalid mode: 'rU'"), so every BVH import fails. Give that module
    alone an open() that drops the 'U' (universal newlines are the default in Python 3 anyway) and
    leaves every other call untouched. Harmless where the importer is already fixed."""
    import builtins

    def open_without_u(file, mode="r", *args, **kwargs):
        if isinstance(mode, str) and "U" in mode:
            mode = mode.replace("U", "") or "r"
        return builtins.open(file, mode, *args, **kwargs)

    module.open = open_without_u  # module globals shadow builtins for this module only


def read_bvh_text(path):
    """Joint names (ROOT/JOINT order), the "Frames:" header and the motion lines of the file."""
    names, frames_header, motion_lines, in_motion = [], None, [], False
    with open(path) as f:
        for line in f:
            words = line.split()
            if not words:
                continue
            if in_motion:
                if words[0] == "Frames:":
                    frames_header = int(words[1])
                elif words[0] != "Frame":
                    motion_lines.append(words)
            elif words[0] in ("ROOT", "JOINT"):
                names.append(words[1])
            elif words[0] == "MOTION":
                in_motion = True
    return names, frames_header, motion_lines


def depth_first(names, parents):
    """Joint names in the BVH hierarchy's order: depth first, children in joint index order."""
    order = []

    def visit(j):
        order.append(names[j])
        for c, p in enumerate(parents):
            if p == j:
                visit(c)

    visit(parents.index(-1))
    return order


def forward_kinematics(parents, offsets, root, rotations):
    """Global joint positions from local rotations (w, x, y, z), docs/rotations.md conventions."""
    glob, pos = [], []
    for j, p in enumerate(parents):
        local = Quaternion(rotations[j])
        if p < 0:
            glob.append(local)
            pos.append(Vector(root))
        else:
            glob.append(glob[p] @ local)
            pos.append(pos[p] + glob[p] @ Vector(offsets[j]))
    return pos


def check(args, failures):
    def expect(ok, message):
        if not ok:
            failures.append(message)
        return ok

    with open(args.json) as f:
        dance = json.load(f)
    names = dance["joint_names"]
    parents = dance["parents"]
    positions = dance["positions"]
    rotations = dance["rotations"]
    n_frames = len(positions)
    fps = float(dance["fps"])
    expect(len(names) == 24, "JSON has %d joint_names, expected 24" % len(names))
    expect(fps == 30.0, "JSON fps is %g, expected 30" % fps)
    if n_frames == 0:
        raise CheckFailed("JSON has no frames")

    bvh_names, frames_header, motion_lines = read_bvh_text(args.bvh)
    expect(bvh_names == depth_first(names, parents),
           "BVH joint names %s differ from the JSON's joint_names in depth-first order %s"
           % (bvh_names, depth_first(names, parents)))
    expect(frames_header == n_frames,
           "BVH header says Frames: %s, the JSON has %d frames" % (frames_header, n_frames))
    expect(len(motion_lines) == n_frames,
           "BVH has %d motion lines, the JSON has %d frames" % (len(motion_lines), n_frames))
    channels = 3 + 3 * len(names)  # root translation + ZXY rotation per joint
    short = [i for i, words in enumerate(motion_lines) if len(words) != channels]
    expect(not short, "BVH motion lines %s do not have %d values" % (short[:5], channels))

    # Import. --factory-startup enables io_anim_bvh by default; enable it explicitly to be independent of
    # that default, then patch the module the operator will use.
    addon_utils.enable("io_anim_bvh", default_set=True)
    from io_anim_bvh import import_bvh
    apply_open_mode_workaround(import_bvh)

    scene = bpy.context.scene
    expect(scene.unit_settings.scale_length == 1.0,
           "scene unit scale is %g, expected 1 (1 Blender unit = 1 m)" % scene.unit_settings.scale_length)
    before = set(bpy.data.objects)
    result = bpy.ops.import_anim.bvh(
        filepath=args.bvh, target="ARMATURE", global_scale=1.0, frame_start=1, use_fps_scale=False,
        update_scene_fps=True, update_scene_duration=True, rotate_mode="NATIVE",
        axis_forward="-Z", axis_up="Y")
    if result != {"FINISHED"}:
        raise CheckFailed("bpy.ops.import_anim.bvh returned %s" % result)
    new_objects = [o for o in bpy.data.objects if o not in before]
    armatures = [o for o in new_objects if o.type == "ARMATURE"]
    if len(armatures) != 1:
        raise CheckFailed("import created %d armature objects (%s), expected 1"
                          % (len(armatures), [o.name for o in new_objects]))
    arm = armatures[0]

    # Bones: count, names, hierarchy.
    bones = arm.data.bones
    bone_names = [b.name for b in bones]
    expect(len(bones) == 24, "armature has %d bones, expected 24" % len(bones))
    expect(sorted(bone_names) == sorted(names),
           "bone names %s differ from the JSON's joint_names %s" % (sorted(bone_names), sorted(names)))
    for j, name in enumerate(names):
        if name not in bones:
            continue
        parent = bones[name].parent
        want = names[parents[j]] if parents[j] >= 0 else None
        got = parent.name if parent is not None else None
        expect(got == want, "bone %s has parent %s, expected %s" % (name, got, want))

    # Frames: one keyframe per JSON frame on frames 1..N, for every animated channel.
    action = arm.animation_data.action if arm.animation_data else None
    if action is None:
        raise CheckFailed("imported armature has no action")
    first, last = action.frame_range
    expect((round(first), round(last)) == (1, n_frames),
           "action frame range %g..%g, expected 1..%d (%d frames)" % (first, last, n_frames, n_frames))
    counts = sorted({len(c.keyframe_points) for c in action.fcurves})
    expect(counts == [n_frames], "keyframes per F-curve %s, expected %d" % (counts, n_frames))
    # 24 joints x 3 rotation channels (Euler) + 3 root location channels.
    expect(len(action.fcurves) == 24 * 3 + 3, "action has %d F-curves, expected %d"
           % (len(action.fcurves), 24 * 3 + 3))

    # Frame rate (the importer sets it from "Frame Time: 0.03333333").
    scene_fps = scene.render.fps / scene.render.fps_base
    expect(scene.render.fps == round(fps) and abs(scene_fps - fps) < 1e-3,
           "scene fps %d / %g = %.6f, expected %g" % (scene.render.fps, scene.render.fps_base, scene_fps, fps))

    if failures:  # no point comparing poses of the wrong skeleton or frames
        return None

    # Poses: every frame (cheap: ~300 frame_set calls), every bone head.
    offsets = dance["rest_offsets"]
    worst_json = (0.0, None, None)
    worst_fk = (0.0, None, None)
    sum_json, count = 0.0, 0
    for i in range(n_frames):
        scene.frame_set(i + 1)
        fk = forward_kinematics(parents, offsets, positions[i][0], rotations[i])
        for j, name in enumerate(names):
            head = BLENDER_TO_OURS @ (arm.matrix_world @ arm.pose.bones[name].head)
            d_json = (head - Vector(positions[i][j])).length
            d_fk = (head - fk[j]).length
            if not math.isfinite(d_json) or d_json > worst_json[0]:
                worst_json = (d_json, i, name)
            if not math.isfinite(d_fk) or d_fk > worst_fk[0]:
                worst_fk = (d_fk, i, name)
            sum_json += d_json
            count += 1
    expect(worst_fk[0] <= args.fk_tolerance,
           "bone head %s at frame %s is %.4f m from FK of the JSON rotations (tolerance %g m): the BVH "
           "channels were not imported as written" % (worst_fk[2], worst_fk[1], worst_fk[0], args.fk_tolerance))
    expect(worst_json[0] <= args.tolerance,
           "bone head %s at frame %s is %.4f m from the JSON position (tolerance %g m)"
           % (worst_json[2], worst_json[1], worst_json[0], args.tolerance))
    summary = {
        "bones": len(bones),
        "frames": n_frames,
        "action_frame_range": [round(first), round(last)],
        "scene_fps": round(scene_fps, 6),
        "max_dist_to_json_m": round(worst_json[0], 6),
        "max_dist_to_json_at": {"frame": worst_json[1], "joint": worst_json[2]},
        "mean_dist_to_json_m": round(sum_json / count, 6),
        "max_dist_to_fk_m": round(worst_fk[0], 7),
        "tolerance_m": args.tolerance,
        "fk_tolerance_m": args.fk_tolerance,
    }
    return summary


def main():
    args = parse_args()
    failures, summary = [], None
    try:
        summary = check(args, failures)
    except CheckFailed as e:
        failures.append(str(e))
    except Exception:  # a crash in the importer (e.g. a truncated line) is a failure, not a pass
        failures.append("exception:\n" + traceback.format_exc())
    if summary is not None:
        print(PREFIX, json.dumps(summary))
    if failures:
        for message in failures:
            print(PREFIX, "FAIL:", message)
        sys.stdout.flush()
        sys.exit(1)
    print(PREFIX, "OK")
    sys.stdout.flush()
    sys.exit(0)


main()
