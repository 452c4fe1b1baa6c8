#!/usr/bin/python3
"""Example Python client for dance-server: streams an audio file over gRPC Perform and saves the dance.

Proves the protocol from a second language with Debian's python3-grpcio and python3-protobuf only.

    /usr/bin/python3 client/python/dance_client.py --server localhost:50051 \
        --audio song.ogg --out dance.json [--realtime] [--seed 3] [--style NAME]

Controls (docs/controls.md): --seed-motion/--given-upper/--given-lower/--keyframes/--inpaint FILE (motion
files are sent as they are: dance-motion/v1 JSON or BVH), --mask MASK.json, --trajectory PATH.json;
--steer AT:T:X:Z (once the audio reaches AT s, be at (X, Z) m at T s); --live-poses DANCE.json --live-part
upper|lower|all sends that dance's poses as a live rig would, one PoseInput per frame beside the audio.

Audio: WAV is read with the standard library; anything else (Ogg, FLAC, MP3) is converted with the `sox`
command line tool to 16-bit mono PCM at 24 kHz. The stubs in dance/v1/ were generated from
proto/dance/v1/dance.proto with:
    protoc -I proto --python_out=client/python --grpc_out=client/python \
        --plugin=protoc-gen-grpc=/usr/bin/grpc_python_plugin proto/dance/v1/dance.proto
(regenerate them whenever the proto changes).
"""
import argparse
import json
import os
import subprocess
import sys
import time
import wave

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import grpc  # noqa: E402

from dance.v1 import dance_pb2, dance_pb2_grpc  # noqa: E402


def read_audio(path):
    """Returns (pcm_bytes as s16le interleaved, sample_rate, channels)."""
    if path.lower().endswith(".wav"):
        with wave.open(path, "rb") as w:
            if w.getsampwidth() == 2:
                return w.readframes(w.getnframes()), w.getframerate(), w.getnchannels()
    raw = subprocess.run(["sox", path, "-t", "raw", "-e", "signed-integer", "-b", "16", "-L", "-c", "1",
                          "-r", "24000", "-"], check=True, capture_output=True).stdout
    return raw, 24000, 1


def motion_controls(args):
    """The MotionControls the flags name (None if none)."""
    c = dance_pb2.MotionControls()
    for flag, field in (("seed_motion", c.seed), ("given_upper", c.given_upper), ("given_lower", c.given_lower),
                        ("keyframes", c.keyframes), ("inpaint", c.inpaint)):
        path = getattr(args, flag)
        if path:
            with open(path, "rb") as fh:
                field.file = fh.read()
    if args.mask:
        with open(args.mask) as fh:
            mask = json.load(fh)
        for k in mask["known"]:
            c.inpaint_known.add(start_ms=k["start_s"] * 1000.0, end_ms=k["end_s"] * 1000.0, joints=k["joints"])
    if args.trajectory:
        with open(args.trajectory) as fh:
            path = json.load(fh)
        for q in path["points"]:
            point = c.trajectory.add(t_ms=q["t"] * 1000.0, x=q["x"], z=q["z"])
            if "facing" in q:
                point.facing = q["facing"]
    return c if c.ListFields() else None


def timed_controls(args):
    """[(audio seconds, Control)] from --steer AT:T:X:Z, ascending."""
    out = []
    for s in args.steer:
        at, t, x, z = (float(v) for v in s.split(":"))
        control = dance_pb2.Control()
        control.steer.point.t_ms, control.steer.point.x, control.steer.point.z = t * 1000.0, x, z
        out.append((at, control))
    return sorted(out, key=lambda c: c[0])


def live_poses(args):
    """{frame: positions (72 floats)} from --live-poses (a dance-motion/v1 file on the audio timeline)."""
    if not args.live_poses:
        return {}
    with open(args.live_poses) as fh:
        d = json.load(fh)
    first = round(d.get("audio_offset_s", 0.0) * 30)
    return {first + i: [v for joint in frame for v in joint] for i, frame in enumerate(d["positions"])}


PARTS = {"upper": dance_pb2.BODY_PART_UPPER, "lower": dance_pb2.BODY_PART_LOWER, "all": dance_pb2.BODY_PART_ALL}


def requests(pcm, rate, channels, args):
    header = dance_pb2.StreamHeader(sample_rate_hz=rate, channels=channels,
                                    sample_format=dance_pb2.SAMPLE_FORMAT_S16LE, seed=args.seed,
                                    client_name="python-example", client_time_us=int(time.time() * 1e6))
    header.sampling.temperature = args.temperature
    if args.period_lock is not None:  # absent: the model's default
        header.sampling.period_lock = args.period_lock
    header.raw_feet = args.raw_feet
    if args.style:
        header.style.add(name=args.style, weight=1.0)
    controls = motion_controls(args)
    if controls is not None:
        header.controls.CopyFrom(controls)
    yield dance_pb2.PerformRequest(header=header)
    pending = timed_controls(args)
    poses = live_poses(args)
    next_pose = min(poses) if poses else 0
    frame_bytes = 2 * channels
    chunk = rate * args.chunk_ms // 1000 * frame_bytes
    start = time.monotonic()
    for off in range(0, len(pcm), chunk):
        part = pcm[off:off + chunk]
        sample_offset = off // frame_bytes
        if args.realtime:  # do not send audio before its time
            due = start + sample_offset / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        while pending and sample_offset >= pending[0][0] * rate:
            yield dance_pb2.PerformRequest(control=pending.pop(0)[1])
        # The rig's poses up to the end of this chunk, as they would be captured.
        end_frame = (sample_offset + len(part) // frame_bytes) * 30 // rate
        while poses and next_pose <= end_frame and next_pose in poses:
            yield dance_pb2.PerformRequest(poses=dance_pb2.PoseInput(
                time_ms=next_pose * 1000.0 / 30.0, positions=poses[next_pose], part=PARTS[args.live_part]))
            next_pose += 1
        yield dance_pb2.PerformRequest(audio=dance_pb2.AudioChunk(sample_offset=sample_offset, pcm=part))
    yield dance_pb2.PerformRequest(end=dance_pb2.EndOfAudio())


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--server", default="localhost:50051")
    p.add_argument("--audio", required=True)
    p.add_argument("--out", required=True, help="dance-motion/v1 JSON output")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--temperature", type=float, default=1.0)
    p.add_argument("--style", default="")
    p.add_argument("--period-lock", type=float, default=None, help="0 = off (default: the model's)")
    p.add_argument("--raw-feet", action="store_true", help="foot lock off: legs and feet as decoded")
    p.add_argument("--chunk-ms", type=int, default=40)
    p.add_argument("--realtime", action="store_true")
    p.add_argument("--token", default="", help="bearer token if the server requires one")
    for flag in ("--seed-motion", "--given-upper", "--given-lower", "--keyframes", "--inpaint"):
        p.add_argument(flag, default="", help="motion file (dance-motion/v1 JSON or BVH)")
    p.add_argument("--mask", default="", help="dance-mask/v1 of --inpaint")
    p.add_argument("--trajectory", default="", help="dance-trajectory/v1 floor path")
    p.add_argument("--steer", action="append", default=[], help="AT:T:X:Z (repeatable)")
    p.add_argument("--live-poses", default="", help="dance-motion/v1 file sent as live PoseInput")
    p.add_argument("--live-part", default="upper", choices=sorted(PARTS))
    args = p.parse_args()

    pcm, rate, channels = read_audio(args.audio)
    channel = grpc.insecure_channel(args.server, options=[("grpc.max_receive_message_length", 16 << 20)])
    stub = dance_pb2_grpc.DanceServiceStub(channel)
    metadata = [("authorization", "Bearer " + args.token)] if args.token else None
    info, frames, end, beats = None, [], None, []
    try:
        for update in stub.Perform(requests(pcm, rate, channels, args), metadata=metadata):
            kind = update.WhichOneof("kind")
            if kind == "info":
                info = update.info
                print(f"session {info.session_id} model {info.model_id} latency {info.latency_ms:.1f} ms")
            elif kind == "frame":
                frames.append(update.frame)
            elif kind == "event" and update.event.kind == dance_pb2.Event.KIND_BEAT:
                beats.append(round(update.event.time_ms) / 1000.0)  # the server's beats, for the file
            elif kind == "event" and update.event.kind == dance_pb2.Event.KIND_WARNING:
                print(f"dance_client.py: server warning at {update.event.time_ms / 1000.0:.2f} s: "
                      f"{update.event.message}", file=sys.stderr)
            elif kind == "end":
                end = update.end
    except grpc.RpcError as e:
        print(f"dance_client.py: {e.code().name}: {e.details()}", file=sys.stderr)
        return 1
    sk = info.skeleton
    dance = {
        "format": "dance-motion/v1", "fps": info.fps, "units": "m", "up_axis": "y",
        "joint_names": list(sk.joint_names), "parents": list(sk.parents),
        "rest_offsets": [list(sk.rest_offsets[i:i + 3]) for i in range(0, len(sk.rest_offsets), 3)],
        "positions": [[list(f.positions[i:i + 3]) for i in range(0, 72, 3)] for f in frames],
        "rotations": [[list(f.rotations[i:i + 4]) for i in range(0, 96, 4)] for f in frames],
        "audio_offset_s": frames[0].time_ms / 1000.0 if frames else 0.0,
        "codes": {"upper": [f.upper_code for f in frames], "lower": [f.lower_code for f in frames]},
        "model_id": info.model_id, "session_id": info.session_id, "seed": args.seed,
    }
    if beats:
        dance["beat_times_s"] = beats
    with open(args.out, "w") as fh:
        json.dump(dance, fh)
    print(f"{len(frames)} frames ({end.audio_ms / 1000.0:.1f} s of audio) -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
