#!/usr/bin/env python3
"""The live cost of each control (issue 39): the same load with and without controls in every stream header.

Starts dance-server on free loopback ports with the default model, runs `dance-client load` once per
condition (no controls, a floor path, keyframes every 2 s, a given upper body, a seed clip), all cut from one
validation dance (the files training.eval.controls_eval writes), and prints a markdown table: frames/s,
latency p50/p99, dropped frames, and the server's CPU seconds per second of dance (utime + stime of the
server process over the run, from /proc, divided by the stream-seconds danced). docs/controls.md quotes it.

Usage: DANCE_BUILD_DIR=build .venv/bin/python scripts/reports/controls_load.py \\
           --inputs training/runs/controls/inputs/tang_DANCE_W_3 [--streams 60] [--duration 20]
(the inputs directory comes from `python -m training.eval.controls_eval --out-dir D`: D/inputs/<song>/)
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import socket
import subprocess
import sys
import time

REPO = pathlib.Path(__file__).resolve().parents[2]


def free_port() -> int:
  with socket.socket() as s:
    s.bind(("127.0.0.1", 0))
    return s.getsockname()[1]


def cpu_seconds(pid: int) -> float:
  fields = pathlib.Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
  return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime


def wait_port(port: int, timeout: float = 30.0) -> None:
  end = time.time() + timeout
  while time.time() < end:
    try:
      socket.create_connection(("127.0.0.1", port), timeout=1).close()
      return
    except OSError:
      time.sleep(0.2)
  sys.exit(f"dance-server did not listen on {port}")


def main() -> None:
  ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
  ap.add_argument("--inputs", required=True, help="controls_eval's inputs/<song> directory")
  ap.add_argument("--audio", default="", help="the song (default: ../shared/data/tang2018/<DANCE id>/audio.ogg)")
  ap.add_argument("--model", default=str(REPO / "models" / "default.dncw"))
  ap.add_argument("--streams", type=int, default=60)
  ap.add_argument("--duration", type=float, default=20.0)
  ap.add_argument("--json", default="", help="also write the rows here")
  args = ap.parse_args()
  build = pathlib.Path(os.environ.get("DANCE_BUILD_DIR", REPO / "build"))
  inputs = pathlib.Path(args.inputs)
  audio = args.audio or str(REPO.parent / "shared" / "data" / "tang2018" / inputs.name.replace("tang_", "") / "audio.ogg")
  conditions = [("none", []), ("trajectory", ["--trajectory", str(inputs / "path.json")]),
                ("keyframes", ["--keyframes", str(inputs / "keys.json")]),
                ("given upper body", ["--given_upper", str(inputs / "real.json")]),
                ("seed clip (4 s)", ["--seed_motion", str(inputs / "seed.json")])]
  port = free_port()
  server = subprocess.Popen([str(build / "bin" / "dance-server"), "--port", str(port), "--http_port", "-1",
                             "--model", args.model, "--editor_model", "off", "--max_sessions", str(args.streams + 8)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
  rows = []
  try:
    wait_port(port)
    for name, flags in conditions:
      c0, t0 = cpu_seconds(server.pid), time.time()
      out = subprocess.run([str(build / "bin" / "dance-client"), "load", "--server", f"127.0.0.1:{port}", "--audio", audio,
                            "--streams", str(args.streams), "--duration", str(args.duration), "--quiet", *flags],
                           capture_output=True, text=True)
      cpu, wall = cpu_seconds(server.pid) - c0, time.time() - t0
      lines = [l for l in out.stdout.splitlines() if l.startswith("{")]
      if not lines:
        sys.exit(f"{name}: dance-client load printed no report:\n{out.stdout}\n{out.stderr}")
      r = json.loads(lines[-1])
      r.update({"condition": name, "server_cpu_s": cpu, "wall_s": wall,
                "cpu_per_dance_s": cpu / max(1e-9, args.streams * args.duration)})
      rows.append(r)
      print(f"{name}: {r['frames_per_s']:.0f} frames/s, p99 {r['p99_ms']:.0f} ms, errors {r['errors']}, "
            f"cpu {cpu:.1f} s", file=sys.stderr)
  finally:
    server.terminate()
    server.wait(timeout=30)
  base = rows[0]["cpu_per_dance_s"]
  print(f"| control ({args.streams} streams x {args.duration:g} s) | frames/s | p50 ms | p99 ms | dropped | errors |"
        " server CPU s per dance s | vs none |")
  print("|---|---|---|---|---|---|---|---|")
  for r in rows:
    print(f"| {r['condition']} | {r['frames_per_s']:.0f} | {r['p50_ms']:.0f} | {r['p99_ms']:.0f} | {r['dropped_frames']} |"
          f" {r['errors']} | {r['cpu_per_dance_s']:.4f} | {r['cpu_per_dance_s'] / base:.2f}x |")
  if args.json:
    pathlib.Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
  main()
