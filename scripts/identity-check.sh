#!/usr/bin/env bash
# Behaviour-unchanged check for refactors: runs a dance-generate binary over a fixed set of settings (the
# default model with and without style, guidance, music guidance, a mix with the locks off, another
# chunking, and the fixed-rate tiny model) and prints each dance's sha256. Run it with the binary of the
# commit before a change and after it; the two lists must be equal.
# usage: scripts/identity-check.sh BUILD/bin/dance-generate OUTDIR
set -euo pipefail
bin=$1; out=$2; mkdir -p "$out"
cd "$(dirname "$0")/.."
i=0
while IFS= read -r line; do
  i=$((i+1))
  eval "args=($line)"
  "$bin" --model models/default.dncw --out "$out/$i.json" --quiet "${args[@]}"
done <<'CFG'
--audio "/usr/share/games/fretsonfire/data/songs/sectoid/Feelings/song.ogg"
--audio "/usr/share/games/fretsonfire/data/songs/sectoid/Feelings/song.ogg" --style waltz --seed 3
--audio ../shared/data/tang2018/DANCE_W_1/audio.ogg --style cha-cha --guidance 3 --music-guidance 0.5 --seed 4
--audio ../shared/data/tang2018/DANCE_W_1/audio.ogg --style tango:0.6,rumba:0.4 --period-lock 0 --foot-lock 0 --crouch-guard 0 --temperature 0.8 --top-k 40
--audio ../shared/data/tang2018/DANCE_W_1/audio.ogg --style rumba --chunk-samples 1000 --top-p 0.9 --seed 9
--audio ../shared/data/tang2018/DANCE_C_2/audio.ogg --model models/test-tiny.dncw --style waltz
CFG
sha256sum "$out"/*.json
