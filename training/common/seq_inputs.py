"""What the sequence model reads in training besides the real history and music: its own draws in place of
input codes (parallel scheduled sampling, --own-inputs), and the music mean in place of the song's music
(music dropout, --music-dropout, which trains the prediction music guidance contrasts with).

Own-code inputs (--own-inputs P): the model first predicts every step of the window from the corrupted
inputs (no gradient), one code per step is drawn from those logits, and each input code that is not BOS is
replaced by the model's own draw with probability P before the step that is learnt; the targets stay the real
codes. A model trained only on real histories reproduces its training songs teacher-forced but drifts to
calmer motion on its own codes (docs/research-log.md, "Free-running loses the energetic styles' energy").

    inputs = drop_music(model, inputs, 0.5, rng, ranges=[(0, 52)])    # (music, pre, u, l, style_w)
    inputs = own_code_inputs(model, inputs, 0.3, passes=2)
"""
from __future__ import annotations

import numpy as np
import torch

from training.common import run_meta
from training.run_config import RunConfig


def own_code_inputs(model, inputs, p: float, generator: torch.Generator | None = None,
                    state: dict | None = None, passes: int = 1) -> tuple:
  """`inputs` with each non-BOS input code of steps 1.. replaced, with probability p, by a code drawn from
  the model's own prediction for that step (from the same inputs and carried `state`, no gradient). Step 0
  and BOS stay. passes > 1 repeats this on the mixed inputs, so a draw of pass k was predicted from a
  history that holds draws of pass k - 1: after k passes an input can be k steps of the model's own drift
  from the real history (multi-pass parallel scheduled sampling)."""
  music, pre, u, l, sw = inputs
  k = model.cfg.codebook_size
  with torch.no_grad():
    for _ in range(passes):
      lu, ll, _ = model.forward_with_state(music, pre, u, l, sw, state)
      out = []
      for codes, logits in ((u, lu), (l, ll)):
        drawn = torch.multinomial(torch.softmax(logits[:, :-1].flatten(0, 1), -1), 1, generator=generator)
        drawn = drawn.view(codes.shape[0], codes.shape[1] - 1)
        swap = (torch.rand(drawn.shape, generator=generator) < p) & (codes[:, 1:] != k)
        mixed = codes.clone()
        mixed[:, 1:] = torch.where(swap, drawn, codes[:, 1:])
        out.append(mixed)
      u, l = out
  return music, pre, u, l, sw


def feature_mask(ranges, feature_dim: int, frames: int) -> torch.Tensor | None:
  """(frames x feature_dim) booleans, frame-major like a music token: True at the per-frame feature columns
  in `ranges` ([(begin, end), ...]); None for no ranges (every column)."""
  if not ranges:
    return None
  cols = torch.zeros(feature_dim, dtype=torch.bool)
  for b, e in ranges:
    cols[b:e] = True
  return cols.repeat(frames)


def drop_music(model, inputs, p: float, rng: np.random.Generator, ranges=None) -> tuple:
  """`inputs` with each window's music stream replaced, with probability p, by the model's music mean (zero
  after the model's normalisation); PRE, codes and style kept. With `ranges` ([(begin, end), ...] per-frame
  feature columns) only those columns are replaced, the others keep the song's. Trains the prediction
  without the song's music that music guidance contrasts with (the engine's SamplingOptions::music_guidance,
  its metadata sampling.music_guidance_features = ranges; docs/research-log.md, "Music guidance")."""
  music, pre, u, l, sw = inputs
  drop = torch.from_numpy(rng.random(music.shape[0]) < p)
  music = music.clone()
  mask = feature_mask(ranges, model.cfg.feature_dim, model.cfg.frames_per_step)
  if mask is None:
    music[drop] = model.music_mean
  else:
    music[drop] = torch.where(mask, model.music_mean, music[drop])
  return music, pre, u, l, sw


def mean_music_tokens(model, toks, ranges=None) -> list:
  """Copies of `toks` whose music has the model's music mean in the per-frame feature columns `ranges`
  (every column for None): what a model trained with music dropout 1 reads, and the engine's music-mean
  lanes read, in place of the song's music."""
  mean = model.music_mean.detach().numpy()
  mask = feature_mask(ranges, model.cfg.feature_dim, model.cfg.frames_per_step)
  cols = np.ones(len(mean), bool) if mask is None else mask.numpy()
  out = []
  for t in toks:
    music = np.array(t["music"], dtype=np.float32)
    music[:, cols] = mean[cols]
    out.append(dict(t, music=music))
  return out


def as_the_engine_reads(config: RunConfig, model, toks) -> list:
  """Validation tokens as the engine runs the exported model: at music guidance 0 (sampling_meta's
  music_guidance) its music-mean lanes alone set the logits, so the song's music is replaced by the mean (in
  the music_guidance_features columns, if any); at any other weight `toks` as they are. A model trained with
  music dropout 1 (which RunConfig.validate allows only with guidance 0) is validated on what it was trained to read."""
  meta = run_meta.sampling_meta(config)
  if meta.get("music_guidance", 1.0) != 0:
    return toks
  return mean_music_tokens(model, toks, meta.get("music_guidance_features"))
