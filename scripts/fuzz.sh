#!/usr/bin/env bash
# Builds the libFuzzer targets with the `fuzz` preset (clang) and runs the audio decode + feature fuzzer
# for a bounded time, then the controls' file readers (motion_fuzz) and the browser's JSON messages
# (web_json_fuzz: /ws/perform and /ws/edit, with the server's validators) for half that each. Usage: scripts/fuzz.sh [SECONDS]   (default 60). Exit status 0 = no crash found.
# Seeds: small WAV/FLAC/OGG/MP3 files made with sox, plus raw-PCM inputs; crashes land in build-fuzz/crashes/
# (or $DANCE_FUZZ_BUILD_DIR/crashes/ when that variable names another build directory).
set -euo pipefail
cd "$(dirname "$0")/.."
seconds="${1:-60}"
jobs="${DANCE_JOBS:-2}"
dir="${DANCE_FUZZ_BUILD_DIR:-build-fuzz}"   # the preset's binaryDir unless overridden
cmake --preset fuzz -B "$dir" >/dev/null
cmake --build "$dir" -j "$jobs" --target audio_fuzz motion_fuzz web_json_fuzz

corpus="$dir/corpus"
seeds="$dir/seeds"
mkdir -p "$corpus" "$seeds" "$dir/crashes"
if [ -z "$(ls -A "$seeds")" ]; then
  tmp=$(mktemp -d)
  for spec in "wav 44100 2" "flac 22050 1" "ogg 24000 1" "mp3 16000 1" "wav 8000 3"; do
    set -- $spec
    f="$tmp/seed-$1-$2.$1"
    if sox -n -r "$2" -c "$3" "$f" synth 0.3 sine 440 synth 0.3 pluck 220 2>/dev/null; then
      # Byte 0 even = encoded-file mode, byte 1 = chunking.
      { printf '\x00\x07'; cat "$f"; } > "$seeds/$(basename "$f").bin"
    fi
  done
  # Raw PCM mode: byte 0 odd, rate 44100 (little-endian), 2 channels, then floats.
  { printf '\x01\x03\x44\xac\x00\x00\x02'; head -c 4000 /dev/urandom; } > "$seeds/raw-44100.bin"
  rm -rf "$tmp"
fi
ASAN_OPTIONS=detect_leaks=1 LSAN_OPTIONS="suppressions=$PWD/tests/fuzz/lsan.supp" "$dir/bin/audio_fuzz" "$corpus" "$seeds" -max_total_time="$seconds" \
  -max_len=65536 -rss_limit_mb=2048 -timeout=20 -artifact_prefix="$dir/crashes/" -print_final_stats=1
# The controls' file readers, seeded with one file of each kind (tests/fuzz/motion_seeds/), half the time.
mkdir -p "$dir/motion_corpus"
ASAN_OPTIONS=detect_leaks=1 "$dir/bin/motion_fuzz" "$dir/motion_corpus" tests/fuzz/motion_seeds \
  -max_total_time="$(( (seconds + 1) / 2 ))" -max_len=65536 -rss_limit_mb=2048 -timeout=20 \
  -artifact_prefix="$dir/crashes/" -print_final_stats=1
# The browser's JSON messages, seeded with one of each (tests/fuzz/web_json_seeds/), half the time.
mkdir -p "$dir/web_json_corpus"
ASAN_OPTIONS=detect_leaks=1 "$dir/bin/web_json_fuzz" "$dir/web_json_corpus" tests/fuzz/web_json_seeds \
  -max_total_time="$(( (seconds + 1) / 2 ))" -max_len=65536 -rss_limit_mb=2048 -timeout=20 \
  -artifact_prefix="$dir/crashes/" -print_final_stats=1
echo "fuzz.sh: no crash in ${seconds}s (audio) + $(( (seconds + 1) / 2 ))s (motion) + $(( (seconds + 1) / 2 ))s (web JSON)"
