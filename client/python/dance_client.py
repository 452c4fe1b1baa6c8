#!/usr/bin/python3
"""Example Python client for dance-server: streams an audio file over gRPC Perform and saves the dance.

Proves the protocol from a second language with Debian's python3-grpcio and python3-protobuf only.

    /usr/bin/python3 client/python/dance_client.py --server localhost:50051 \
        --audio song.ogg --out dance.json [--realtime] [--seed 3] [--style NAME]

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
    yield dance_pb2.PerformRequest(header=header)
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
    args = p.parse_args()

    pcm, rate, channels = read_audio(args.audio)
    channel = grpc.insecure_channel(args.server, options=[("grpc.max_receive_message_length", 16 << 20)])
    stub = dance_pb2_grpc.DanceServiceStub(channel)
    metadata = [("authorization", "Bearer " + args.token)] if args.token else None
    info, frames, end = None, [], None
    try:
        for update in stub.Perform(requests(pcm, rate, channels, args), metadata=metadata):
            kind = update.WhichOneof("kind")
            if kind == "info":
                info = update.info
                print(f"session {info.session_id} model {info.model_id} latency {info.latency_ms:.1f} ms")
            elif kind == "frame":
                frames.append(update.frame)
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
    with open(args.out, "w") as fh:
        json.dump(dance, fh)
    print(f"{len(frames)} frames ({end.audio_ms / 1000.0:.1f} s of audio) -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
