"""The engine's command-line tools, run from Python: every call of `dance-features` and `dance-generate` made
by training/ goes through this module (training reaches C++ only through files and these CLIs).

    from training import tools
    tools.dance_features("song.ogg", out="f.npy", summary=True)     # -> the CLI's stdout
    tools.dance_generate("models/default.dncw", "song.ogg", "dance.json", seed=0, style="waltz")

The binaries are found in $DANCE_BUILD_DIR/bin when DANCE_BUILD_DIR is set, else in the repository's build/bin
(`cmake --preset release && cmake --build --preset release --target dance-features dance-generate`). A missing
binary raises ToolMissing naming where it looked and how to build it; a tool that exits with an error raises
RuntimeError with its stderr. Both tools are single-threaded and deterministic for the same inputs.
"""
from __future__ import annotations

import json
import os
import pathlib
import subprocess

REPO = pathlib.Path(__file__).resolve().parents[1]


class ToolMissing(RuntimeError):
  """A C++ tool was not found (build the project first, or set DANCE_BUILD_DIR)."""


def build_dir() -> pathlib.Path:
  """$DANCE_BUILD_DIR when set, else <repository>/build."""
  return pathlib.Path(os.environ.get("DANCE_BUILD_DIR") or REPO / "build")


def tool_path(name: str) -> pathlib.Path:
  """Where the tool `name` is expected (it may not exist: see require)."""
  return build_dir() / "bin" / name


def require(name: str) -> pathlib.Path:
  """The path of the built tool `name`, or ToolMissing."""
  path = tool_path(name)
  if path.is_file() and os.access(path, os.X_OK):
    return path
  raise ToolMissing(f"{name} not found at {path}: build it with `cmake --preset release && cmake --build "
                    f"--preset release --target {name}` or set DANCE_BUILD_DIR to a build directory that has it")


def _run(cmd: list[str], what: str) -> str:
  proc = subprocess.run(cmd, capture_output=True, text=True)
  if proc.returncode != 0:
    raise RuntimeError(f"{what} failed: {proc.stderr.strip()}")
  return proc.stdout


def dance_features(audio, *, out=None, pre=None, pre_input=None, summary: bool = False,
                   chunk_samples: int | None = None, clock=None, tempo_ref: float | None = None,
                   bar_beats: int = 0, fold_tempo: bool = False, clock_starts=None,
                   cli: pathlib.Path | None = None) -> str:
  """Runs `dance-features AUDIO` (docs/features.md) and returns its stdout (with summary: the summary JSON
  on its last line). out / pre / pre_input: .npy paths for the per-frame features (T, 108), PRE (T, 128) and
  PRE's input channels (T, 4); chunk_samples: feed the audio in chunks of this size; clock: a .npy path for
  the engine's tempo clock at tempo_ref BPM (`--clock`, with bar_beats > 0 the bar clock's phase, with
  fold_tempo the folded tempo features; engine/audio/tempo_clock.h); clock_starts (with clock): a .npy path
  for each real frame's warped start W_n and rate r_n (`--clock-starts`). cli: a specific binary (default:
  require("dance-features"))."""
  cmd = [str(cli or require("dance-features")), str(audio)]
  if out is not None:
    cmd += ["--out", str(out)]
  if pre is not None:
    cmd += ["--pre", str(pre)]
  if pre_input is not None:
    cmd += ["--pre-input", str(pre_input)]
  if summary:
    cmd += ["--summary"]
  if chunk_samples is not None:
    cmd += ["--chunk-samples", str(int(chunk_samples))]
  if clock is not None:
    cmd += ["--clock", str(clock), "--tempo-ref", f"{tempo_ref:g}"]
    if bar_beats > 0:
      cmd += ["--bar-beats", str(int(bar_beats))]
    if fold_tempo:
      cmd += ["--fold-tempo"]
    if clock_starts is not None:
      cmd += ["--clock-starts", str(clock_starts)]
  what = "dance-features" + (" --clock" if clock is not None else "") + f" on {audio}"
  return _run(cmd, what)


def dance_generate(model, audio, out, *, seed: int, temperature: float = 1.0, style: str | None = None,
                   top_p: float | None = None, guidance: float | None = None,
                   period_lock: float | None = None) -> pathlib.Path:
  """Runs `dance-generate` (the engine offline: one session over the whole file) and returns `out`, the
  dance-motion/v1 JSON it wrote (positions at 30 fps, the per-frame codes, the style prompt). style: a style
  name (default: the model's "none"); top_p, guidance, period_lock None = the model's defaults."""
  cmd = [str(require("dance-generate")), "--audio", str(audio), "--out", str(out), "--model", str(model),
         "--seed", str(seed), "--temperature", str(temperature), "--quiet"]
  if style:
    cmd += ["--style", style]
  for flag, value in (("--top-p", top_p), ("--guidance", guidance), ("--period-lock", period_lock)):
    if value is not None:
      cmd += [flag, str(value)]
  _run(cmd, f"dance-generate on {audio}")
  return pathlib.Path(out)


def dance_generate_summary(model, audio, out, *, seed: int, style: str | None = None, extra=()) -> dict:
  """Runs `dance-generate` with extra flags (`extra`, e.g. the controls' `--seed-motion FILE`; docs/controls.md)
  and returns its one-line JSON summary (frames, steps, audio_s, wall_s, x_real_time, model_id, out)."""
  cmd = [str(require("dance-generate")), "--audio", str(audio), "--out", str(out), "--model", str(model),
         "--seed", str(seed)]
  if style:
    cmd += ["--style", style]
  cmd += [str(a) for a in extra]
  stdout = _run(cmd, f"dance-generate {' '.join(str(a) for a in extra)} on {audio}")
  return json.loads(stdout.strip().splitlines()[-1])
