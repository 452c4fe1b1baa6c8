"""Free-running moment matching: fine-tune the sequence model through its own free-running draws.

    OMP_WAIT_POLICY=PASSIVE /usr/bin/python3 -m training.experiments.free_run_tune --model models/default.dncw \
        --tokens RUN/tokens_train_warp_....pt --out R/model.dncw [--iters 300] [--own-weight 3] [--per-song]

The diagnosis (docs/research-log.md, "Free-running loses the energetic styles' energy"): given a real history
the model continues a song nearly as its dancer did; reading its own draws it hops between the style's codes
and the decoders turn the hops into damped motion. Every earlier remedy changed the model's inputs (own-code
inputs, self-training on kept draws) or its sampling. This one gives the model a gradient from what its own
free-running draws look like, decoded:

- a rollout starts from a real prefix of a training clip (the state after `--prefix` teacher-forced steps;
  a quarter of the style groups from BOS at the song's start, the engine's condition) and runs `--steps` steps
  on its own draws. Each draw is a straight-through Gumbel sample: the forward pass feeds the model and the
  decoders the sampled code's one-hot, exactly a free-running draw; the backward pass goes through its
  softmax, both into the step that drew it and into every later step that read it;
- each part's VQ decoder (frozen) decodes the drawn codes after the prefix's last four real codes, so the
  causal decoder starts from real context; the window's energy statistics (`decoder_tuning.window_energy`:
  per joint, mean squared velocity and mean |acceleration|) are taken in log;
- per style, the mean and the spread over the batch's rollouts of those statistics are matched to the same
  statistics of the style's real codes decoded on the same timeline (the decoders' own rendering of the
  real dances, so the term asks for the real dances' motion as far as the codes can carry it, not more);
  with `--per-song` all of a style group's rollouts come from one song and match that song's statistics.

The term is added at `--own-weight` to the usual teacher-forced cross-entropy on real windows (style
balance 0.5, past-motion dropout 0.4, style dropout as in training), so the model keeps predicting the real
continuation while it is steered on its own. No guidance in the rollouts (the engine applies it on top).
The output is the input file with the sequence model's tensors replaced (decoders unchanged; the metadata
gains a `free_run_tune` entry with the settings). Defaults: the measured run `frt_b` (docs/research-log.md,
"Free-running moment matching"; measured, not shipped).
"""
from __future__ import annotations

import argparse
import json
import math
import pathlib
import time

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from training.export import f16_policy, load_models, read_dncw, seq_tensors, write_dncw
from training.model.danceba import one_hot_style
from training.common.seq_loss import code_loss
from training.common.tokens import STYLE_DROPOUT, make_batch
from training.common.decoder_tuning import channel_groups, window_energy

PARTS = ("upper", "lower")
CONTEXT = 4  # real codes decoded before a rollout's draws (the decoder's warm-up; their frames dropped)


def gumbel_one_hot(logits: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
  """A straight-through sample (B, K): forward the one-hot of a draw from softmax(logits), backward the
  softmax's gradient. argmax(logits + Gumbel noise) is an exact draw from softmax(logits)."""
  u = torch.rand(logits.shape, generator=generator).clamp_(1e-9, 1.0 - 1e-9)
  g = -torch.log(-torch.log(u))
  soft = torch.softmax(logits, -1)
  hard = F.one_hot((logits.detach() + g).argmax(-1), logits.shape[-1]).to(soft.dtype)
  return hard - soft.detach() + soft


def step_soft(model, music, pre, u_oh, l_oh, style_w, state):
  """Danceba.step with the code inputs as (B, K+1) one-hot rows (Danceba.embed takes them as they are)."""
  return model.step(music, pre, u_oh, l_oh, style_w, state)


class EnergyTarget:
  """Per style and part: mean and standard deviation over windows of `steps` codes of the log energy
  statistics of the style's real codes, decoded by the part's decoder (whole clips decoded, then windows)."""

  def __init__(self, vqs, toks, steps: int, rng: np.random.Generator, windows: int = 256):
    self.groups = {p: channel_groups(vqs[p].cfg.in_dim) for p in PARTS}
    frames = 4 * steps
    decoded = {}
    for t in toks:
      with torch.no_grad():
        decoded[id(t)] = {p: vqs[p].denormalise(vqs[p].decode_codes(torch.as_tensor(np.asarray(t[p]))[None].long()))[0]
                          for p in PARTS}
    self.eps, self.stats = {}, {}
    for p in PARTS:
      allw = []
      for s in sorted({t["style"] for t in toks}):
        clips = [decoded[id(t)][p] for t in toks if t["style"] == s and len(t[p]) * 4 >= frames + 4 * CONTEXT]
        lens = np.array([len(c) - frames - 4 * CONTEXT + 1 for c in clips], np.float64)
        wins = []
        for i in rng.choice(len(clips), windows, p=lens / lens.sum()):
          o = 4 * CONTEXT + int(rng.integers(0, lens[i]))
          wins.append(clips[i][o:o + frames])
        e = window_energy(torch.stack(wins), self.groups[p])
        allw.append(e)
        self.stats[(s, p)] = e
      self.eps[p] = 0.01 * torch.cat(allw).mean(0)
    for (s, p), e in list(self.stats.items()):
      le = torch.log(e + self.eps[p])
      self.stats[(s, p)] = (le.mean(0), le.std(0) + 1e-3)
    # Per song: the same statistics over every window of the song (stride one step), for --per-song.
    for t in toks:
      for p in PARTS:
        c = decoded[id(t)][p]
        starts = range(4 * CONTEXT, len(c) - frames + 1, 4)
        if len(starts) < 2:
          continue
        le = torch.log(window_energy(torch.stack([c[o:o + frames] for o in starts]), self.groups[p]) + self.eps[p])
        self.stats[(t["id"], p)] = (le.mean(0), le.std(0) + 1e-3)

  def loss(self, part: str, style: int, decoded: torch.Tensor, song: str | None = None) -> tuple[torch.Tensor, float]:
    """decoded (n, frames, dim) of one style's rollouts (all of one song if `song`) -> squared z-distance of
    their mean and spread from the style's (or the song's) real windows', in units of the style's spread."""
    le = torch.log(window_energy(decoded, self.groups[part]) + self.eps[part])
    mu, sd = self.stats[(style if song is None else song, part)]
    dm = (le.mean(0) - mu) / self.stats[(style, part)][1]
    loss = dm.pow(2).mean()
    if le.shape[0] > 1:
      loss = loss + 0.5 * ((le.std(0) - sd) / sd).pow(2).mean()
    return loss, float(dm[:, 0].mean())


def rollouts(model, vqs, toks, target: EnergyTarget, rng, gen, per_style: int, prefix: int, steps: int,
             bos_share: float = 0.25, per_song: bool = False):
  """One batch of free-running rollouts, `per_style` per style; returns (loss, logs). per_song: the style's
  rollouts are all of one song and matched to that song's real statistics."""
  cfg, k = model.cfg, model.cfg.codebook_size
  styles = sorted({t["style"] for t in toks})
  terms, logs = [], {}
  for s in styles:
    clips = [t for t in toks if t["style"] == s and len(t["upper"]) > prefix + steps + 2]
    from_bos = rng.random() < bos_share  # the whole group: a batched state needs one kind
    batch = []
    song = clips[int(rng.integers(len(clips)))] if per_song else None
    for _ in range(per_style):
      t = song if per_song else clips[int(rng.integers(len(clips)))]
      batch.append((t, 0 if from_bos else int(rng.integers(prefix, len(t["upper"]) - steps - 1))))
    # The state after the real prefix (inputs of steps b - prefix .. b - 1), without gradient: the gradient
    # flows through the draws.
    state = None
    if not from_bos:
      def window(key, dtype):
        return torch.stack([torch.as_tensor(np.asarray(t[key][b - prefix:b])).to(dtype) for t, b in batch])
      u, l = window("upper", torch.long), window("lower", torch.long)
      for row, (t, b) in enumerate(batch):
        if b == prefix:  # the window starts the song: BOS, as in training
          u[row, 0] = l[row, 0] = k
      with torch.no_grad():
        _, _, state = model.forward_with_state(window("music", torch.float32), window("pre", torch.float32),
                                               u, l, one_hot_style(len(batch), s, cfg.n_styles), None)
    first_in = [(k, k) if from_bos else (int(t["upper"][b]), int(t["lower"][b])) for t, b in batch]
    n = len(batch)
    sw = one_hot_style(n, s, cfg.n_styles)
    u_oh = F.one_hot(torch.tensor([f[0] for f in first_in]), k + 1).float()
    l_oh = F.one_hot(torch.tensor([f[1] for f in first_in]), k + 1).float()
    drawn = {"upper": [], "lower": []}
    for i in range(steps):
      m = torch.stack([torch.as_tensor(np.asarray(t["music"][b + i])).float() for t, b in batch])
      p = torch.stack([torch.as_tensor(np.asarray(t["pre"][b + i])).float() for t, b in batch])
      lu, ll, state = step_soft(model, m, p, u_oh, l_oh, sw, state)
      su, sl = gumbel_one_hot(lu, gen), gumbel_one_hot(ll, gen)
      drawn["upper"].append(su)
      drawn["lower"].append(sl)
      pad = su.new_zeros(n, 1)
      u_oh, l_oh = torch.cat([su, pad], -1), torch.cat([sl, pad], -1)
    for part in PARTS:
      vq = vqs[part]
      ctx = []
      for t, b in batch:  # the real codes b - CONTEXT + 1 .. b before the draws (repeated code 0 at the start)
        idx = [max(j, 0) for j in range(b - CONTEXT + 1, b + 1)]
        ctx.append(vq.quantizer.codebook[torch.as_tensor(np.asarray(t[part])[idx]).long()])
      z = torch.cat([torch.stack(ctx), torch.stack(drawn[part], 1) @ vq.quantizer.codebook], 1)
      dec = vq.denormalise(vq.decoder(z))[:, 4 * CONTEXT:]
      loss, mean_z = target.loss(part, s, dec, song["id"] if per_song else None)
      terms.append(loss)
      logs[f"z_{part}_{s}"] = mean_z
  total = torch.stack(terms).mean()
  logs["own"] = float(total)
  return total, logs


def export_seq(src: str, dst: str, model) -> None:
  header, tensors = read_dncw(src)
  new = seq_tensors(model)
  missing = set(new) - set(tensors)
  if missing:
    raise ValueError(f"export_seq: {src} lacks {sorted(missing)[:3]}")
  tensors.update(new)
  meta = dict(header["metadata"])
  meta["free_run_tune"] = getattr(model, "_tune_info", {})
  write_dncw(dst, tensors, meta, f16_policy(tensors))


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  ap.add_argument("--model", required=True)
  ap.add_argument("--tokens", required=True, help="a training run's tokens_train_warp_*.pt")
  ap.add_argument("--out", required=True)
  ap.add_argument("--iters", type=int, default=300)
  ap.add_argument("--lr", type=float, default=1e-4)
  ap.add_argument("--own-weight", type=float, default=3.0)
  ap.add_argument("--per-style", type=int, default=4, help="rollouts per style and iteration")
  ap.add_argument("--prefix", type=int, default=32, help="real teacher-forced steps before a rollout")
  ap.add_argument("--steps", type=int, default=32, help="free-running steps of a rollout")
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--per-song", action="store_true",
                  help="match each rollout group to its song's real statistics, not the style's")
  args = ap.parse_args(argv)
  if args.iters < 1 or args.per_style < 1 or args.prefix < 1 or args.steps < 2:
    ap.error("--iters, --per-style and --prefix must be at least 1, --steps at least 2")
  if not (args.lr > 0 and args.own_weight >= 0):
    ap.error("--lr must be > 0 and --own-weight >= 0")
  torch.manual_seed(args.seed)
  rng = np.random.default_rng(args.seed)
  gen = torch.Generator().manual_seed(args.seed)
  model, vqs, meta = load_models(args.model)
  for vq in vqs.values():
    for p in vq.parameters():
      p.requires_grad_(False)
  toks = [t for t in torch.load(args.tokens) if t["factor"] == 1.0 and not t.get("mirror", False)]
  target = EnergyTarget(vqs, toks, args.steps, rng)
  out = pathlib.Path(args.out)
  out.parent.mkdir(parents=True, exist_ok=True)
  log_path = out.with_suffix(".log")
  opt = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=0.05)
  model.eval()  # no dropout; the folded PRE statistics stay
  t0 = time.time()
  with open(log_path, "w") as log:
    for it in tqdm(range(args.iters), desc="tune", mininterval=10):
      for g in opt.param_groups:
        g["lr"] = args.lr * min(1.0, (it + 1) / 50) * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * it / args.iters)))
      inputs, targets = make_batch(toks, model.cfg, rng, code_mask=0.4, style_dropout=STYLE_DROPOUT,
                                   style_balance=0.5)
      lu, ll = model(*inputs)
      ce = code_loss(lu, ll, targets)
      own, logs = rollouts(model, vqs, toks, target, rng, gen, args.per_style, args.prefix, args.steps,
                           per_song=args.per_song)
      loss = ce + args.own_weight * own
      opt.zero_grad()
      loss.backward()
      torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
      opt.step()
      logs.update(it=it, ce=float(ce), s=round(time.time() - t0, 1))
      log.write(json.dumps(logs) + "\n")
      log.flush()
  model._tune_info = {"iters": args.iters, "lr": args.lr, "own_weight": args.own_weight,
                      "per_style": args.per_style, "prefix": args.prefix, "steps": args.steps,
                      "per_song": args.per_song}
  export_seq(args.model, str(out), model)
  print(f"wrote {out} ({time.time() - t0:.0f} s)")


if __name__ == "__main__":
  main()
