#!/usr/bin/python3
"""Integration: the Python example client (client/python/dance_client.py) against a real dance-server.

Run by ctest (label integration). Starts build/bin/dance-server on free ports with models/test-tiny.dncw
(or $DANCE_TEST_MODEL), streams 3 s of generated audio with the Python client, checks the saved
dance-motion/v1 file. Exits 77 (ctest: skipped) when the model does not load.
"""
import json
import math
import os
import re
import signal
import struct
import subprocess
import sys
import tempfile
import wave

src = os.environ.get("DANCE_SOURCE_DIR", ".")
build = os.environ.get("DANCE_BINARY_DIR", os.path.join(src, "build"))
model = os.environ.get("DANCE_TEST_MODEL", os.path.join(src, "models", "test-tiny.dncw"))


def main():
    server = subprocess.Popen([os.path.join(build, "bin", "dance-server"), "--port", "0", "--http-port", "-1",
                               "--model", model, "--host", "127.0.0.1", "--log-level", "warning"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    line = server.stdout.readline()
    m = re.search(r"gRPC on port (\d+)", line)
    if not m:
        err = server.stderr.read()
        server.wait()
        if "model_load_failed" in err:
            print(f"SKIP: {model} does not load: {err.strip()}")
            return 77
        print(f"server did not start: {line} {err}")
        return 1
    port = int(m.group(1))
    try:
        with tempfile.TemporaryDirectory() as tmp:
            wav = os.path.join(tmp, "clicks.wav")
            rate = 16000
            with wave.open(wav, "wb") as w:
                w.setnchannels(1)
                w.setsampwidth(2)
                w.setframerate(rate)
                samples = [0.3 * math.sin(2 * math.pi * 110 * i / rate) + (0.6 if i % 8000 < 200 else 0.0)
                           for i in range(5 * rate)]
                w.writeframes(b"".join(struct.pack("<h", int(max(-1, min(1, s)) * 32000)) for s in samples))
            out = os.path.join(tmp, "dance.json")
            r = subprocess.run([sys.executable, os.path.join(src, "client", "python", "dance_client.py"),
                                "--server", f"127.0.0.1:{port}", "--audio", wav, "--out", out, "--seed", "3"],
                               capture_output=True, text=True, timeout=120)
            print(r.stdout, r.stderr)
            if r.returncode != 0:
                return 1
            d = json.load(open(out))
            assert d["format"] == "dance-motion/v1", d["format"]
            assert len(d["joint_names"]) == 24
            assert len(d["positions"]) >= 140, len(d["positions"])  # 5 s at 30 fps, minus the first period
            assert all(len(p) == 24 and len(p[0]) == 3 for p in d["positions"])
            assert len(d["rotations"]) == len(d["positions"])
            # The server's beats (KIND_BEAT) land in the file: clicks every 0.5 s.
            beats = d.get("beat_times_s", [])
            assert len(beats) >= 3, beats
            gaps = sorted(b - a for a, b in zip(beats, beats[1:]))
            assert abs(gaps[len(gaps) // 2] - 0.5) < 0.05, beats
            n_free = len(d["positions"])
            # Controls from Python: a floor path in the header and a steer mid-stream are accepted ...
            path = os.path.join(tmp, "path.json")
            with open(path, "w") as fh:
                json.dump({"format": "dance-trajectory/v1",
                           "points": [{"t": 0.0, "x": 0.0, "z": 0.0}, {"t": 2.0, "x": 0.5, "z": 0.0}]}, fh)
            r = subprocess.run([sys.executable, os.path.join(src, "client", "python", "dance_client.py"),
                                "--server", f"127.0.0.1:{port}", "--audio", wav, "--out", out, "--seed", "3",
                                "--trajectory", path, "--steer", "1:2.5:0:1"],
                               capture_output=True, text=True, timeout=120)
            print(r.stdout, r.stderr)
            assert r.returncode == 0, "a run with a path and a steer"
            assert len(json.load(open(out))["positions"]) == n_free
            # ... and a path out of time order is refused, naming it.
            with open(path, "w") as fh:
                json.dump({"format": "dance-trajectory/v1",
                           "points": [{"t": 2.0, "x": 0.0, "z": 0.0}, {"t": 1.0, "x": 0.5, "z": 0.0}]}, fh)
            r = subprocess.run([sys.executable, os.path.join(src, "client", "python", "dance_client.py"),
                                "--server", f"127.0.0.1:{port}", "--audio", wav, "--out", out,
                                "--trajectory", path], capture_output=True, text=True, timeout=120)
            assert r.returncode != 0 and "INVALID_ARGUMENT" in r.stderr and "trajectory" in r.stderr, r.stderr
            print("python client OK:", n_free, "frames; controls accepted and refused as they should be")
            return 0
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(timeout=30)


if __name__ == "__main__":
    sys.exit(main())
