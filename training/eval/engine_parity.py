"""The engine against the same model in PyTorch, free-running: does `dance-generate` draw the codes the
PyTorch model draws from the same song, style, seed and sampling? (docs/evaluation.md "Engine parity").

    DANCE_BUILD_DIR=build-h40 /usr/bin/python3 -m training.eval.engine_parity --model models/default.dncw \
        [--songs ID,ID] [--seed 0] [--steps N] [--guidance W] [--music-guidance M] [--temperature T] \
        [--out-dir D]

For each song (default: the 8 validation songs, each in its own style) both sides run the whole song from
its first step with the period lock and the crouch guard off (the two engine locks that change codes):
- PyTorch: the song's music tokens on the engine's warped timeline, built from `dance-features` and
  `dance-features --clock` exactly as the training clips are (clips.load_warped_clip, docs/model.md
  section 1) but from the song's first frame; `SequenceModel.step` lane by lane (style, "none" for style
  guidance, the music mean for music guidance, docs/model.md section 6); each code drawn by `EngineSampler`,
  a transcription of the engine's sampler (engine/nn/sampling.cc: std::mt19937_64 seeded with the seed,
  u = (gen() >> 11) 2^-53, the inverse CDF over the codes sorted by descending probability, upper then
  lower).
- the engine: `dance-generate --codes-out` (every step's sampled codes).
The report: per song the steps both took, the first step where a stream's code differs, the share of
equal codes, and the largest difference between the music tokens the two sides read. The two sides compute the logits in float32 in different orders (~1e-6 relative), so a draw
that falls within that of a cumulative boundary picks the neighbouring code (or two codes whose
probabilities tie within that rounding swap places in the walk) and the streams part from there on: a
healthy engine matches for hundreds of steps (the first divergence is such a draw, not a shared drift);
a wrong input, lane, guidance or sampler parts within the first steps.
The output side: `retime_to_real` plays the PyTorch decode of the engine's codes back on the real timeline
with the clock's starts (`clock_starts`, `dance-features --clock-starts`), as a session does; with the foot
lock off it equals the engine's dance to float rounding (tests/training/test_engine_parity.py).
"""
from __future__ import annotations

import argparse
import json
import pathlib
import tempfile

import numpy as np
import torch

from training import tools
from training.common import clips as td
from training.data import skeleton as sk
from training.export import load_models
from training.features.extract import extract_clock, extract_features
from training.model.danceba import one_hot_style

_MASK64 = (1 << 64) - 1


class Mt19937_64:
  """std::mt19937_64 (the C++ standard's 64-bit Mersenne Twister, default seeding), in Python."""

  _N, _M = 312, 156
  _UPPER, _LOWER = 0xFFFFFFFF80000000, 0x7FFFFFFF

  def __init__(self, seed: int) -> None:
    mt = [seed & _MASK64]
    for i in range(1, self._N):
      mt.append((6364136223846793005 * (mt[-1] ^ (mt[-1] >> 62)) + i) & _MASK64)
    self._mt, self._i = mt, self._N

  def _twist(self) -> None:
    mt, n, m = self._mt, self._N, self._M
    for i in range(n):
      x = (mt[i] & self._UPPER) | (mt[(i + 1) % n] & self._LOWER)
      xa = x >> 1
      if x & 1:
        xa ^= 0xB5026F5AA96619E9
      mt[i] = mt[(i + m) % n] ^ xa
    self._i = 0

  def __call__(self) -> int:
    if self._i >= self._N:
      self._twist()
    y = self._mt[self._i]
    self._i += 1
    y ^= (y >> 29) & 0x5555555555555555
    y ^= (y << 17) & 0x71D67FFFEDA60000
    y ^= (y << 37) & 0xFFF7EEE000000000
    y ^= y >> 43
    return y & _MASK64


class EngineSampler:
  """The engine's SampleCode without top-k and top-p (the default sampling; docs/model.md section 6)."""

  def __init__(self, seed: int, temperature: float = 1.0) -> None:
    self.gen, self.temperature = Mt19937_64(seed), float(temperature)

  def __call__(self, logits: np.ndarray) -> int:
    logits = np.asarray(logits, np.float32)
    if self.temperature == 0.0:
      return int(np.argmax(logits))  # lowest index wins ties, as the engine
    p = np.exp((logits - logits.max()).astype(np.float64) * (1.0 / self.temperature))
    total = 0.0
    for v in p:  # the engine sums in index order (no cut)
      total += float(v)
    u = float(self.gen() >> 11) * 2.0 ** -53 * total
    order = np.lexsort((np.arange(len(p)), -p))  # descending probability, ties by index
    cum = 0.0
    for i in order:
      cum += float(p[i])
      if cum > u:
        return int(i)
    return int(order[-1])


def song_tokens(audio: str, reference_bpm: float, frames_per_step: int = 4,
                cache_dir=td.FEATURE_CACHE) -> tuple[np.ndarray, np.ndarray]:
  """The music tokens (steps, 4F) and PRE (steps, P) a session of a tempo-normalised model reads over the
  whole song: warped frame j takes its source frame's features, step t the frames 4t..4t+3 and the PRE of
  4t+3 (docs/model.md sections 1-2; the training clips' construction from the song's first frame)."""
  m = extract_features(audio, cache_dir=cache_dir)
  clock = extract_clock(audio, reference_bpm, cache_dir=cache_dir)
  src = clock[:, 0].astype(np.int64)
  src = src[src < len(m["features"])]
  n = len(src) // frames_per_step
  src = src[:n * frames_per_step]
  music = m["features"][src].reshape(n, -1).astype(np.float32)
  pre = m["pre"][src[frames_per_step - 1::frames_per_step]].astype(np.float32)
  return music, pre


@torch.no_grad()
def torch_free_run(model, music: np.ndarray, pre: np.ndarray, style: int, seed: int, guidance: float = 1.0,
                   music_guidance: float = 1.0, temperature: float = 1.0, music_ranges=None,
                   steps: int | None = None) -> np.ndarray:
  """(steps, 2) codes drawn step by step from BOS as the engine's session does with the period lock and
  crouch guard off: the lanes it steps (style; "none" if guidance != 1 and the style is not "none"; the
  music mean for music guidance != 1), combined in float32 as engine/runtime/internal/sampling_policy.cc
  does, each stream drawn by EngineSampler (upper first)."""
  cfg, k = model.cfg, model.cfg.codebook_size
  n = len(music) if steps is None else min(steps, len(music))
  sampler = EngineSampler(seed, temperature)
  cond = one_hot_style(1, style, cfg.n_styles)
  uncond = one_hot_style(1, -1, cfg.n_styles)
  use_g = guidance != 1.0 and style >= 0
  use_m = music_guidance != 1.0
  mean = model.music_mean[None]
  if use_m and music_ranges:
    cols = np.zeros(cfg.feature_dim, bool)
    for b, e in music_ranges:
      cols[b:e] = True
    mask = torch.from_numpy(np.tile(cols, cfg.frames_per_step))[None]
  states = {"c": None, "u": None, "mc": None, "mu": None}
  u = torch.full((1,), k, dtype=torch.long)
  l = torch.full((1,), k, dtype=torch.long)
  out = np.zeros((n, 2), np.int64)

  def run(lane, mu, style_w):
    lu, ll, states[lane] = model.step(mu, p, u, l, style_w, states[lane])
    return lu[0], ll[0]

  for t in range(n):
    m = torch.from_numpy(music[t])[None]
    p = torch.from_numpy(pre[t])[None]
    gu, gl = run("c", m, cond)
    if use_g:
      uu, ul = run("u", m, uncond)
      gu, gl = uu + guidance * (gu - uu), ul + guidance * (gl - ul)
    if use_m:
      mm = mean if not music_ranges else torch.where(mask, mean, m)
      mu_, ml_ = run("mc", mm, cond)
      if use_g:
        uu, ul = run("mu", mm, uncond)
        mu_, ml_ = uu + guidance * (mu_ - uu), ul + guidance * (ml_ - ul)
      gu, gl = mu_ + music_guidance * (gu - mu_), ml_ + music_guidance * (gl - ml_)
    cu, cl = sampler(gu.numpy()), sampler(gl.numpy())
    out[t] = cu, cl
    u, l = torch.tensor([cu]), torch.tensor([cl])
  return out


def engine_codes(model: str, audio: str, style: str | None, seed: int, workdir: pathlib.Path,
                 guidance: float | None = None, music_guidance: float | None = None,
                 temperature: float = 1.0, name: str = "song") -> np.ndarray:
  """(steps, 2) codes of `dance-generate` on the song, period lock and crouch guard off; its files go to
  workdir/{codes,tokens,dance}_<name>_s<seed>.* (tokens: every step's music token as the session read it,
  `--tokens-out`; engine_tokens reads them)."""
  codes = workdir / f"codes_{name}_s{seed}.npy"
  extra = ["--codes-out", codes, "--tokens-out", workdir / f"tokens_{name}_s{seed}.npy", "--period-lock", 0,
           "--crouch-guard", 0, "--temperature", temperature]
  if guidance is not None:
    extra += ["--guidance", guidance]
  if music_guidance is not None:
    extra += ["--music-guidance", music_guidance]
  tools.dance_generate_summary(model, audio, workdir / f"dance_{name}_s{seed}.json", seed=seed,
                               style=style, extra=extra)
  return np.load(codes).astype(np.int64)


def clock_starts(audio: str, reference_bpm: float, workdir: pathlib.Path) -> np.ndarray:
  """(real frames, 2) float32: each real frame's warped start W_n and clock rate r_n at reference_bpm, from
  `dance-features --clock --clock-starts` (engine/audio/tempo_clock.h)."""
  workdir.mkdir(parents=True, exist_ok=True)
  starts = workdir / "clock_starts.npy"
  tools.dance_features(audio, clock=workdir / "clock.npy", tempo_ref=reference_bpm, clock_starts=starts)
  return np.load(starts)


def retime_to_real(decoded: np.ndarray, starts: np.ndarray, first_index: int, frames: int, skel) -> np.ndarray:
  """The engine's playback of decoded warped poses on the real 30 fps timeline (docs/model.md section 1):
  real frame m (from first_index, `frames` of them) shows the warped pose at w = max(W_m, 5) as
  lerp(pose_a, pose_a+1, w - a), a = ceil(w) - 1, then bone projection. decoded[i] is warped frame i + 4
  (the codes of step i are period i + 1's); starts is clock_starts' (W_n, r_n). Frames past the decoded poses
  or the clock are left out."""
  m = first_index + np.arange(frames)
  m = m[m < len(starts)]
  w = np.maximum(starts[m, 0].astype(np.float64), 5.0)
  a = np.ceil(w).astype(np.int64) - 1
  keep = a - 3 < len(decoded)
  a, w = a[keep], w[keep]
  f = (w - a)[:, None, None]
  lin = decoded[a - 4] * (1.0 - f) + decoded[a - 3] * f
  return sk.project_bone_lengths(lin, skel)


def engine_tokens(workdir: pathlib.Path, name: str, seed: int) -> np.ndarray:
  """(steps, 4F) the music tokens the engine's session read in engine_codes' run of `name` and `seed`."""
  return np.load(workdir / f"tokens_{name}_s{seed}.npy")


def compare(a: np.ndarray, b: np.ndarray) -> dict:
  """First differing step per stream (the common length if none) and the share of equal codes."""
  n = min(len(a), len(b))
  row = {"steps": n, "steps_torch": int(len(a)), "steps_engine": int(len(b))}
  for s, name in ((0, "upper"), (1, "lower")):
    diff = np.flatnonzero(a[:n, s] != b[:n, s])
    row[f"first_diff_{name}"] = int(diff[0]) if len(diff) else n
    row[f"equal_{name}"] = float(np.mean(a[:n, s] == b[:n, s])) if n else 1.0
  row["first_diff"] = min(row["first_diff_upper"], row["first_diff_lower"])
  return row


def parity(model_path: str, songs: list[str], seed: int, workdir: pathlib.Path, guidance: float | None = None,
           music_guidance: float | None = None, temperature: float = 1.0, steps: int | None = None) -> list[dict]:
  """One row per validation motion id (compare's fields plus song and style)."""
  model, _, meta = load_models(model_path)
  sampling, tb = meta.get("sampling", {}), meta.get("time_base", {})
  w = float(sampling.get("guidance", 1.0)) if guidance is None else guidance
  mg = float(sampling.get("music_guidance", 1.0)) if music_guidance is None else music_guidance
  styles = meta["styles"]
  rows = []
  for mid in songs:
    z = np.load(td.MOTION_CACHE / f"{mid}.npz")
    audio, style = str(z["audio_path"]), str(z["style"])
    ref = float(tb.get("style_reference_bpm", {}).get(style, tb["reference_bpm"]))
    music, pre = song_tokens(audio, ref, model.cfg.frames_per_step)
    ours = torch_free_run(model, music, pre, styles.index(style), seed, w, mg, temperature,
                          sampling.get("music_guidance_features"), steps)
    theirs = engine_codes(model_path, audio, style, seed, workdir, guidance, music_guidance, temperature, mid)
    if steps is not None:
      theirs = theirs[:steps]
    tokens = engine_tokens(workdir, mid, seed)
    n = min(len(tokens), len(music))
    rows.append({"song": mid, "style": style, **compare(ours, theirs),
                 "tokens_max_abs_diff": float(np.abs(tokens[:n] - music[:n]).max())})
  return rows


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("--model", default="models/default.dncw")
  ap.add_argument("--songs", default=None, help="comma-separated motion ids (default: the validation songs)")
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--steps", type=int, default=None, help="compare the first N steps only (default: all)")
  ap.add_argument("--guidance", type=float, default=None, help="default: the model's")
  ap.add_argument("--music-guidance", type=float, default=None, help="default: the model's")
  ap.add_argument("--temperature", type=float, default=1.0)
  ap.add_argument("--out-dir", default=None, help="keep the engine's codes and dances here (default: a temp dir)")
  args = ap.parse_args(argv)
  torch.set_grad_enabled(False)
  td.ensure_motion_cache()
  songs = args.songs.split(",") if args.songs else td.tang_ids(td.load_split()["validation"])
  with tempfile.TemporaryDirectory() as tmp:
    work = pathlib.Path(args.out_dir or tmp)
    work.mkdir(parents=True, exist_ok=True)
    rows = parity(args.model, songs, args.seed, work, args.guidance, args.music_guidance, args.temperature,
                  args.steps)
  for r in rows:
    print(json.dumps(r), flush=True)


if __name__ == "__main__":
  main()
