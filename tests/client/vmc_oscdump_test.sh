#!/usr/bin/env bash
# CTest driver for vmc_oscdump_test (label integration): a real third-party OSC receiver, liblo-tools'
# oscdump, listens on a free loopback port while `dance-client play --vmc` sends a generated dance over
# the VMC protocol, once bundled at the stream's rate and once one message per datagram at 60 fps. The
# dump must hold, per pose, /VMC/Ext/OK, /VMC/Ext/T (increasing), /VMC/Ext/Root/Pos and the 22 humanoid
# /VMC/Ext/Bone/Pos messages with VMC's type tags. With DANCE_SERVER given, also live: a dance-server on free
# loopback ports, `dance-client perform --vmc` of a 4 s song (the client watches its own session and relays
# it), oscdump receiving. Exits 77 (CTest SKIP_RETURN_CODE) without oscdump.
# Usage: vmc_oscdump_test.sh DANCE_GENERATE DANCE_CLIENT MODEL.dncw [DANCE_SERVER]
set -euo pipefail
generate="${1:?usage: vmc_oscdump_test.sh DANCE_GENERATE DANCE_CLIENT MODEL.dncw}"
client="${2:?usage}"
model="${3:?usage}"
server="${4:-}"
if ! command -v oscdump >/dev/null 2>&1; then
  echo "SKIP: oscdump is not on PATH (Debian: apt-get install liblo-tools)"
  exit 77
fi
work="$(mktemp -d "${TMPDIR:-/tmp}/vmc_oscdump_test.XXXXXX")"
dump_pid=""
server_pid=""
cleanup() {
  if [ -n "$dump_pid" ]; then kill "$dump_pid" 2>/dev/null || true; wait "$dump_pid" 2>/dev/null || true; fi
  if [ -n "$server_pid" ]; then kill "$server_pid" 2>/dev/null || true; wait "$server_pid" 2>/dev/null || true; fi
  rm -rf "$work"
}
trap cleanup EXIT

# A 2 s click track (120 BPM) -> a 2 s dance; a 4 s one for the live run.
for seconds in 2 4; do
python3 - "$work/click$seconds.wav" "$seconds" <<'PY'
import math, struct, sys, wave
rate = 22050
n = int(sys.argv[2]) * rate
s = []
for i in range(n):
    t = (i % (rate // 2)) / rate
    v = 0.1 * math.sin(2 * math.pi * 220 * i / rate) + (0.8 * math.exp(-t / 0.008) * math.sin(2 * math.pi * 1000 * t) if t < 0.03 else 0)
    s.append(int(max(-1, min(1, v)) * 32767))
with wave.open(sys.argv[1], "wb") as w:
    w.setnchannels(1); w.setsampwidth(2); w.setframerate(rate); w.writeframes(struct.pack("<%dh" % n, *s))
PY
done
"$generate" --audio "$work/click2.wav" --model "$model" --seed 0 --out "$work/dance.json" --quiet
frames="$(python3 -c 'import json,sys; print(len(json.load(open(sys.argv[1]))["positions"]))' "$work/dance.json")"
echo "dance: $frames frames"

free_port() { python3 -c 'import socket; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }

run() {  # run NAME COMMAND CLIENT_FLAGS...  (the client gets --vmc 127.0.0.1:PORT appended)
  local name="$1"; shift
  local port; port="$(free_port)"
  # oscdump takes a port (all interfaces; a host in its URL means multicast); the sender targets 127.0.0.1.
  # oscdump takes a port (all interfaces; a host in its URL means multicast); the sender targets 127.0.0.1.
  oscdump -L "$port" >"$work/$name.txt" 2>"$work/$name.err" &
  dump_pid=$!
  sleep 0.5
  "$client" "$@" --vmc "127.0.0.1:$port"
  sleep 0.5
  kill "$dump_pid"; wait "$dump_pid" 2>/dev/null || true; dump_pid=""
  python3 - "$work/$name.txt" "$name" "$@" <<'PY'
import sys
path, name, flags = sys.argv[1], sys.argv[2], sys.argv[3:]
bones = {"Hips", "LeftUpperLeg", "RightUpperLeg", "Spine", "LeftLowerLeg", "RightLowerLeg", "Chest", "LeftFoot",
         "RightFoot", "UpperChest", "LeftToes", "RightToes", "Neck", "LeftShoulder", "RightShoulder", "Head",
         "LeftUpperArm", "RightUpperArm", "LeftLowerArm", "RightLowerArm", "LeftHand", "RightHand"}
poses, fails = [], []
for line in open(path):
    w = line.split()
    if not w:
        continue
    # oscdump prints bundled messages after a timetag; find the path.
    i = next((k for k, x in enumerate(w) if x.startswith("/")), None)
    if i is None:
        continue
    p, types, args = w[i], w[i + 1], w[i + 2:]
    if p == "/VMC/Ext/OK":
        poses.append({"ok": (types, args), "bones": {}})
        continue
    if not poses:
        fails.append("message before /VMC/Ext/OK: " + line.strip()); continue
    cur = poses[-1]
    if p == "/VMC/Ext/T":
        if types != "f": fails.append("T types " + types)
        cur["t"] = float(args[0])
    elif p == "/VMC/Ext/Root/Pos":
        if types != "sfffffff" or args[0] != '"root"': fails.append("Root/Pos " + line.strip())
        cur["root"] = True
    elif p == "/VMC/Ext/Bone/Pos":
        if types != "sfffffff": fails.append("Bone/Pos types " + types)
        q = [float(x) for x in args[4:8]]
        if abs(sum(x * x for x in q) - 1) > 1e-3: fails.append("non-unit rotation " + line.strip())
        cur["bones"][args[0].strip('"')] = q
    else:
        fails.append("unexpected " + p)
for k, pose in enumerate(poses):
    if pose["ok"] != ("iii", ["1", "3", "0"]): fails.append("pose %d OK %s" % (k, pose["ok"]))
    if set(pose["bones"]) != bones: fails.append("pose %d bones %s" % (k, sorted(set(pose["bones"]) ^ bones)))
    if "t" not in pose or "root" not in pose: fails.append("pose %d lacks T or Root/Pos" % k)
times = [p.get("t", -1) for p in poses]
if any(b <= a for a, b in zip(times, times[1:])): fails.append("T not increasing")
print("%s: %d poses, T %.3f..%.3f s" % (name, len(poses), times[0] if times else -1, times[-1] if times else -1))
if fails:
    print("\n".join("FAIL: " + f for f in fails[:20])); sys.exit(1)
open(path + ".poses", "w").write(str(len(poses)))
PY
}

run bundle play --in "$work/dance.json" --vmc-fps 0
test "$(cat "$work/bundle.txt.poses")" -eq "$frames" || { echo "FAIL: $(cat "$work/bundle.txt.poses") poses, $frames frames"; exit 1; }
run messages play --in "$work/dance.json" --vmc-fps 60 --vmc-bundle=false
n60="$(cat "$work/messages.txt.poses")"
# 60 poses/s over (frames - 1) / 30 s: about 2 per frame (at least 1.5: a loaded machine may oversleep).
test "$n60" -ge $(( (frames - 1) * 3 / 2 )) || { echo "FAIL: only $n60 poses at 60 fps for $frames frames"; exit 1; }

if [ -n "$server" ]; then
  grpc_port="$(free_port)"; http_port="$(free_port)"
  "$server" --model="$model" --port="$grpc_port" --http_port="$http_port" >"$work/server.log" 2>&1 &
  server_pid=$!
  for _ in $(seq 100); do
    "$client" info --server "127.0.0.1:$grpc_port" >/dev/null 2>&1 && break
    sleep 0.2
  done
  run live perform --server "127.0.0.1:$grpc_port" --audio "$work/click4.wav" --quiet --vmc-fps 30
  nlive="$(cat "$work/live.txt.poses")"
  # 4 s at 30 poses/s; the watcher joins a few frames in.
  test "$nlive" -ge 60 || { echo "FAIL: perform --vmc relayed only $nlive poses of a 4 s song"; exit 1; }
  kill "$server_pid"; wait "$server_pid" 2>/dev/null || true; server_pid=""
fi
echo "vmc_oscdump_test: OK"
