"""Sequence-model stages of training.train: tokens, training with past-motion dropout, evaluation, export.

Making the music matter (docs/training.md): tempo-augmented pairs (train_data.TEMPO_FACTORS), the rhythm
clock (beat/bar phase and tempo features + PRE) and past-motion dropout: each input code is replaced by
BOS with probability --code-mask and by a random code with probability code_mask / 4, so that the past
motion alone cannot carry the timing and the model has to read the clock from the music.

Own-code inputs (--own-inputs P, parallel scheduled sampling): the model first predicts every step of the
window from the corrupted inputs (no gradient), one code per step is drawn from those logits, and each
input code that is not BOS is replaced by the model's own draw with probability P before the step that
is learnt; the targets stay the real codes. A model trained only on real histories reproduces its training
songs teacher-forced but drifts to calmer motion on its own codes (docs/training.md, "Free-running loses
the energetic styles' energy").
"""
from __future__ import annotations

import collections
import json
import math
import pathlib
import time

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from training import train_data as td
from training.model.config import SeqConfig
from training.model.danceba import Danceba
from training.model.layers import set_residual_dropout
from training.train_lanes import Lanes, detach, mask_codes, reset_rows

STEPS = 64          # training window, code steps (8.5 s)
BATCH = 16
STYLE_DROPOUT = 0.15


def tokenize(clip: td.Clip, vqs) -> dict:
  """Codes of every period and the per-step music of one clip; music arrays cover 4 * n_periods frames."""
  n = len(clip.upper) // 4
  out = {"id": clip.motion_id, "factor": clip.factor, "style": clip.style}
  for part in ("upper", "lower"):
    vq = vqs[part]
    x = torch.from_numpy(getattr(clip, part)[:4 * n])
    out[part] = vq.encode(vq.normalise(x)[None])[0].numpy().astype(np.int64)
  out["music"] = clip.features[:4 * n].reshape(n, -1)
  out["pre"] = clip.pre[:4 * n][3::4]
  return out


def build_tokens(ids, factors, vqs, log, cache: pathlib.Path | None = None,
                 style_refs: dict[str, float] | None = None, bar_clock: dict | None = None,
                 mirror: bool = False, warp_factors: tuple[float, ...] = (1.0,),
                 fold_tempo: bool = False) -> list[dict]:
  """Tokens of every (clip, factor); cached in `cache` (a file next to the VQ-VAE checkpoints) if given.
  style_refs: clips on the engine's tempo-normalised timeline (train_data.load_warped_clip) at their
  style's reference tempo, one per song and factor of `warp_factors` (`factors` are not used: the clock
  removes the tempo from the motion; the warp factors stretch the music only, whose features still carry
  the tempo).
  bar_clock (with style_refs): the bar phase features are the bar clock's (train_data.BAR_CLOCK).
  mirror: every clip also reflected left-right (skeleton.mirror_positions) on the same music: twice the
  dances, the turns and the arm styling in both directions.
  fold_tempo (with style_refs): the tempo features folded to the reference (train_data.load_warped_clip)."""
  if style_refs:
    factors = tuple(warp_factors)
  if cache is not None and cache.is_file():
    toks = torch.load(cache)
    if (sorted({t["id"] for t in toks}) == sorted(ids) and sorted({t["factor"] for t in toks}) == sorted(factors)
        and {t.get("mirror", False) for t in toks} == ({False, True} if mirror else {False})):
      return toks
  toks = []
  for i in tqdm(ids, desc="tokens", mininterval=10):
    for f in factors:
      for m in ((False, True) if mirror else (False,)):
        if style_refs:
          style = str(np.load(td.MOTION_CACHE / f"{i}.npz")["style"])
          clip = td.load_warped_clip(i, style_refs[style], bar_beats=td.bar_beats_of(style, bar_clock), mirror=m,
                                     factor=f, fold_tempo=fold_tempo)
        else:
          clip = td.load_clip(i, f, mirror=m)
        toks.append(dict(tokenize(clip, vqs), mirror=m))
  log(f"tokens: {len(toks)} clips, {sum(len(t['upper']) for t in toks)} steps")
  if cache is not None:
    torch.save(toks, cache)
  return toks


def window_probs(toks, ok, steps: int, style_balance: float = 1.0, self_share: float | None = None) -> np.ndarray:
  """How often each usable clip (indices `ok`) is drawn: in proportion to its number of window starts, with
  each style's total share then set in proportion to (its windows) ** style_balance. 1 keeps the data's
  shares (waltz ~58 % of the Tang training steps, tango ~4 %); 0 gives every style the same share; 0.5 is
  in between. Within a style the clips keep their relative weights. A song's versions (tempo factors,
  mirror images) share its weight: augmenting some songs more than others does not change their shares.
  self_share: the model's own kept draws (clips marked "own_draw", training.self_rollouts) then get this
  share of the windows and the real clips the rest (None: by their lengths like any clip)."""
  lens = np.array([len(toks[j]["upper"]) for j in ok], np.float64) - steps
  versions = collections.Counter(toks[j].get("id") for j in ok)
  if len(set(versions.values())) > 1:  # (equal counts: the same shares, left bit-exact)
    lens /= np.array([versions[toks[j].get("id")] for j in ok], np.float64)
  probs = lens / lens.sum()
  if style_balance != 1.0:
    styles = np.array([toks[j]["style"] for j in ok])
    for st in np.unique(styles):
      share = probs[styles == st].sum()
      probs[styles == st] *= share ** style_balance / share
    probs /= probs.sum()
  if self_share is not None:
    own = np.array([bool(toks[j].get("own_draw", False)) for j in ok])
    if own.any() and (~own).any():
      probs[own] *= self_share / probs[own].sum()
      probs[~own] *= (1.0 - self_share) / probs[~own].sum()
  return probs


def make_batch(toks, cfg: SeqConfig, rng, batch=BATCH, steps=STEPS, code_mask=0.0, style_dropout=0.0,
               music_from=None, style_balance: float = 1.0, self_share: float | None = None):
  """Random windows. Inputs: codes of periods t0..t0+L-1 (BOS at the song start), music of t+s.
  music_from: optional list of clips to take the music from instead (music-ablation); style_balance:
  window_probs; self_share: window_probs."""
  s, k = cfg.music_lookahead_steps, cfg.codebook_size
  lens = np.array([len(t["upper"]) for t in toks])
  ok = np.flatnonzero(lens > steps + s + 1)
  probs = window_probs(toks, ok, steps, style_balance, self_share)
  mus, pres, us, ls, tu, tl, sw = [], [], [], [], [], [], []
  for j in rng.choice(ok, batch, p=probs):
    t = toks[j]
    t0 = 0 if rng.random() < 0.1 else int(rng.integers(0, len(t["upper"]) - steps - s))
    src = t if music_from is None else music_from[j]
    m = src["music"][t0 + s:t0 + s + steps]
    p = src["pre"][t0 + s:t0 + s + steps]
    if len(m) < steps:  # another song shorter than this window: wrap it
      reps = math.ceil(steps / max(len(m), 1)) + 1
      m = np.concatenate([src["music"]] * reps)[:steps]
      p = np.concatenate([src["pre"]] * reps)[:steps]
    u = t["upper"][t0:t0 + steps].copy()
    l = t["lower"][t0:t0 + steps].copy()
    if t0 == 0:
      u[0] = l[0] = k
    for c in (u, l):
      mask_codes(c, k, code_mask, rng)
    mus.append(m)
    pres.append(p)
    us.append(u)
    ls.append(l)
    tu.append(t["upper"][t0 + 1:t0 + steps + 1])
    tl.append(t["lower"][t0 + 1:t0 + steps + 1])
    w = np.zeros(cfg.n_styles + 1, np.float32)
    w[cfg.n_styles if rng.random() < style_dropout else t["style"]] = 1
    sw.append(w)
  f = lambda a, dt=torch.float32: torch.from_numpy(np.stack(a)).to(dt)  # noqa: E731
  return (f(mus), f(pres), f(us, torch.long), f(ls, torch.long), f(sw)), (f(tu, torch.long), f(tl, torch.long))


def style_refs_of(args, run: pathlib.Path, log) -> dict[str, float] | None:
  """Per-style reference tempi of a tempo-normalised run (None for a fixed-rate run), computed once from
  the training songs and kept in <run>/style_reference_bpm.json (the export writes them into the model)."""
  if args.tempo_ref <= 0:
    return None
  path = run / "style_reference_bpm.json"
  if path.is_file():
    return json.loads(path.read_text())
  split = td.load_split()
  # Every style row gets a reference, also a style whose songs all validate (AIST++'s test list).
  refs = td.style_reference_tempi(td.paired_ids(split["train"]), args.tempo_ref, td.run_styles(split))
  log(f"style reference tempi (BPM): {json.dumps(refs)}")
  run.mkdir(parents=True, exist_ok=True)
  path.write_text(json.dumps(refs))
  return refs


def dance_periods_of(args, run: pathlib.Path, log) -> dict[str, int]:
  """Each style's dance period in beats on the tempo-normalised timeline (train_data.dance_period_beats),
  measured once on the training dances and kept in <run>/dance_period_beats.json; the export writes it into
  the model for the engine's period lock."""
  path = run / "dance_period_beats.json"
  if path.is_file():
    return json.loads(path.read_text())
  periods = td.dance_period_beats(td.paired_ids(td.load_split()["train"]), style_refs_of(args, run, log))
  log(f"dance periods (beats): {json.dumps(periods)}")
  path.write_text(json.dumps(periods))
  return periods


def warp_tag(refs: dict[str, float], bar_clock: dict | None = None, fold_tempo: bool = False) -> str:
  tag = "warp_" + "_".join(f"{refs[s]:g}" for s in sorted(refs))
  if bar_clock:
    tag += "_bar" + "_".join(str(td.bar_beats_of(s, bar_clock)) for s in sorted(refs))
  return tag + ("_fold" if fold_tempo else "")


def fold_tempo_of(args) -> bool:
  """A tempo-normalised run with --fold-tempo: the tempo features folded to the style's reference."""
  return args.tempo_ref > 0 and bool(getattr(args, "fold_tempo", False))


def bar_clock_of(args) -> dict | None:
  """The bar clock of a tempo-normalised run with --bar-clock (None otherwise)."""
  return td.BAR_CLOCK if args.tempo_ref > 0 and getattr(args, "bar_clock", False) else None


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


def sampling_meta(args) -> dict:
  """The exported file's sampling defaults (metadata "sampling"; docs/model.md section 6): the style guidance
  weight, the music guidance weight when it is not 1 (off), and the feature columns the music dropout
  replaced when it replaced only some (music_guidance_features: the engine's music-mean lanes replace the
  same)."""
  meta = {"guidance": float(getattr(args, "guidance", 1.0))}
  music = float(getattr(args, "music_guidance", 1.0))
  if music != 1.0:
    meta["music_guidance"] = music
  ranges = getattr(args, "music_dropout_features", None)
  if ranges and float(getattr(args, "music_dropout", 0.0)) > 0:
    meta["music_guidance_features"] = [[int(b), int(e)] for b, e in ranges]
  return meta


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
  its metadata sampling.music_guidance_features = ranges; docs/training.md, "Music guidance")."""
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


def as_the_engine_reads(args, model, toks) -> list:
  """Validation tokens as the engine runs the exported model: at music guidance 0 (sampling_meta's
  music_guidance) its music-mean lanes alone set the logits, so the song's music is replaced by the mean (in
  the music_guidance_features columns, if any); at any other weight `toks` as they are. A model trained with
  music dropout 1 (which train.py allows only with guidance 0) is validated on what it was trained to read."""
  meta = sampling_meta(args)
  if meta.get("music_guidance", 1.0) != 0:
    return toks
  return mean_music_tokens(model, toks, meta.get("music_guidance_features"))


def loss_of(model, inputs, targets) -> torch.Tensor:
  lu, ll = model(*inputs)
  return code_loss(lu, ll, targets)


class AuxHeads(torch.nn.Module):
  """Training-only heads that read the sequence model's final hidden state (norm_f) at step t and predict
  the codes of steps t + 2 .. t + J (the model's own heads predict t + 1): multi-step prediction, so the
  state carries where the dance goes over the next J periods, not only the next code. Not exported."""

  def __init__(self, d_model: int, codebook_size: int, steps: int):
    super().__init__()
    self.steps = steps
    self.upper = torch.nn.ModuleList(torch.nn.Linear(d_model, codebook_size, bias=False)
                                     for _ in range(steps - 1))
    self.lower = torch.nn.ModuleList(torch.nn.Linear(d_model, codebook_size, bias=False)
                                     for _ in range(steps - 1))

  def loss(self, y: torch.Tensor, targets) -> torch.Tensor:
    """y (B, T, 3, d): the final hidden state; targets: make_batch's (next codes (B, T) per part). Mean over
    j = 2 .. J of code_loss of the j-steps-ahead heads, on the positions whose target is in the window."""
    total = y.new_zeros(())
    for j in range(2, self.steps + 1):
      h = y[:, :y.shape[1] - j + 1]
      total = total + code_loss(self.upper[j - 2](h[..., 1, :]), self.lower[j - 2](h[..., 2, :]),
                                (targets[0][:, j - 1:], targets[1][:, j - 1:]))
    return total / (self.steps - 1)


def code_loss(lu, ll, targets, reduction: str = "mean") -> torch.Tensor:
  """Cross-entropy of the upper and lower logits against the target codes, averaged over the two."""
  return 0.5 * (F.cross_entropy(lu.flatten(0, 1), targets[0].flatten(), reduction=reduction) +
                F.cross_entropy(ll.flatten(0, 1), targets[1].flatten(), reduction=reduction))


@torch.no_grad()
def song_loss(model, toks, cfg, window: int = 128) -> float:
  """Loss over whole songs from their first step, the state carried (the engine's condition): each song's
  codes with BOS at step 0, its music shifted by the music lookahead, its own style; mean over all steps."""
  s, k = cfg.music_lookahead_steps, cfg.codebook_size
  total, count = 0.0, 0
  for t in toks:
    n = len(t["upper"]) - s - 1
    if n < 1:
      continue
    u = torch.as_tensor(np.asarray(t["upper"][:n])).long().clone()[None]
    l = torch.as_tensor(np.asarray(t["lower"][:n])).long().clone()[None]
    u[0, 0] = l[0, 0] = k
    music = torch.as_tensor(np.asarray(t["music"][s:s + n])).float()[None]
    pre = torch.as_tensor(np.asarray(t["pre"][s:s + n])).float()[None]
    targets = (torch.as_tensor(np.asarray(t["upper"][1:n + 1])).long()[None],
               torch.as_tensor(np.asarray(t["lower"][1:n + 1])).long()[None])
    sw = torch.zeros(1, cfg.n_styles + 1)
    sw[0, t["style"]] = 1
    state = None
    for a in range(0, n, window):
      e = min(n, a + window)
      lu, ll, state = model.forward_with_state(music[:, a:e], pre[:, a:e], u[:, a:e], l[:, a:e], sw, state)
      total += float(code_loss(lu, ll, (targets[0][:, a:e], targets[1][:, a:e]), reduction="sum"))
      count += e - a
  return total / max(count, 1)


@torch.no_grad()
def validation(model, val_toks, cfg, n_batches=6) -> dict:
  """Loss with the true music and with another validation song's music (same windows): the gap; and the
  loss over whole songs with the state carried (song_loss)."""
  was_training = model.training
  model.eval()
  wrong = val_toks[1:] + val_toks[:1]
  out = {"true": [], "wrong": []}
  for key, mf in (("true", None), ("wrong", wrong)):
    rng = np.random.default_rng(123)
    for _ in range(n_batches):
      inputs, targets = make_batch(val_toks, cfg, rng, music_from=mf)
      out[key].append(float(loss_of(model, inputs, targets)))
  song = song_loss(model, val_toks, cfg)
  model.train(was_training)
  vt, vw = float(np.mean(out["true"])), float(np.mean(out["wrong"]))
  return {"val_loss": vt, "val_loss_wrong_music": vw, "music_gap": vw - vt, "val_loss_song": song}


def stage_seq(args, cfg: SeqConfig, vqs, factors, run: pathlib.Path, log) -> None:
  ck_path = run / "seq.pt"
  split = td.load_split()
  train_ids = td.paired_ids(split["train"])
  val_ids = td.paired_ids(split["validation"])
  vq_dir = pathlib.Path(args.vq_run) if args.vq_run else run
  refs = style_refs_of(args, run, log)
  bars = bar_clock_of(args)
  warp_factors = tuple(float(f) for f in str(getattr(args, "warp_tempo_factors", "1")).split(","))
  fold = fold_tempo_of(args)
  tag = warp_tag(refs, bars, fold) if refs else "_".join(f"{f:g}" for f in factors)
  train_tag = tag + ("_x" + "_".join(f"{f:g}" for f in warp_factors) if refs and warp_factors != (1.0,) else "")
  vq_dir.mkdir(parents=True, exist_ok=True)
  mirror = bool(getattr(args, "mirror", False))
  train_toks = build_tokens(train_ids, factors, vqs, log,
                            vq_dir / f"tokens_train_{train_tag}{'_mirror' if mirror else ''}.pt", refs, bars, mirror,
                            warp_factors if refs else (1.0,), fold)
  warp_styles = str(getattr(args, "warp_tempo_styles", "") or "")
  if refs and warp_styles:  # the other styles keep only their songs at their own tempo
    keep = {td.style_index(st) for st in warp_styles.split(",")}
    train_toks = [t for t in train_toks if t["factor"] == 1.0 or t["style"] in keep]
    log(f"seq: tempo factors {warp_factors} for {warp_styles} only: {len(train_toks)} clips")
  val_toks = build_tokens(val_ids, (1.0,), vqs, log, vq_dir / f"tokens_val_{tag}.pt", refs, bars, fold_tempo=fold)
  self_tokens, self_share = getattr(args, "self_tokens", None), getattr(args, "self_share", None)
  if self_tokens:  # filtered self-training (training.self_rollouts): the model's own kept draws
    extra = torch.load(self_tokens)
    if extra and len(extra[0]["music"][0]) != len(train_toks[0]["music"][0]):
      raise SystemExit(f"seq: {self_tokens} has music features of another width than this run's tokens")
    train_toks = train_toks + [dict(t, own_draw=True) for t in extra]  # (files written before the mark too)
    log(f"seq: {len(extra)} clips of the model's own kept draws from {self_tokens} "
        f"({sum(len(t['upper']) for t in extra)} steps), share of the windows {self_share}")
  torch.manual_seed(0)
  rng = np.random.default_rng(0)
  if args.init_model:
    # Fine-tune an exported model (its music normalisation and its PRE BatchNorm, folded, stay as they are).
    import dataclasses
    from training.export import load_models
    parent = load_models(args.init_model)[0]
    # Ablation flags (and the music shift) override the parent's architecture; every parameter whose name
    # and shape still match is copied, the rest starts fresh (fine-tuned ablations from one parent).
    want = dataclasses.replace(parent.cfg, use_pre=parent.cfg.use_pre and not args.no_pre,
                               use_gate=parent.cfg.use_gate and not args.no_gate,
                               shared_mamba=parent.cfg.shared_mamba or args.shared_mamba,
                               music_lookahead_steps=args.lookahead or parent.cfg.music_lookahead_steps)
    if want == parent.cfg:
      model = parent
    else:
      model = Danceba(want)
      mine = model.state_dict()
      theirs = parent.state_dict()
      copied = {k: v for k, v in theirs.items() if k in mine and mine[k].shape == v.shape}
      model.load_state_dict(copied, strict=False)
      log(f"seq: architecture changed from the parent ({len(copied)}/{len(mine)} tensors copied)")
    cfg = model.cfg
    log(f"seq: initialised from {args.init_model}")
  else:
    model = Danceba(cfg)
    base = [t for t in train_toks if t["factor"] == 1.0]
    allm = np.concatenate([t["music"] for t in base])
    with torch.no_grad():
      model.music_mean.copy_(torch.from_numpy(allm.mean(0)))
      model.music_std.copy_(torch.from_numpy(np.maximum(allm.std(0), 1e-2)))
  n_params = sum(p.numel() for p in model.parameters())
  log(f"seq: {n_params} parameters, cfg {json.dumps(cfg.to_dict())}")
  dropout = float(getattr(args, "dropout", 0.0))
  if dropout > 0:
    n_drop = set_residual_dropout(model, dropout)
    log(f"seq: residual dropout {dropout:g} on {n_drop} residual branches (training only)")
  aux_steps, aux_weight = int(getattr(args, "aux_steps", 1)), float(getattr(args, "aux_weight", 0.0))
  aux = AuxHeads(cfg.d_model, cfg.codebook_size, aux_steps) if aux_steps > 1 and aux_weight > 0 else None
  if aux is not None:
    log(f"seq: multi-step prediction, codes 2..{aux_steps} steps ahead at weight {aux_weight:g} (training only)")
  opt = torch.optim.AdamW(list(model.parameters()) + (list(aux.parameters()) if aux is not None else []),
                          lr=args.lr, weight_decay=0.05)
  lr0 = opt.param_groups[0]["lr"]
  history, start, elapsed = [], 0, 0.0
  ema_decay = float(getattr(args, "ema", 0.0))
  ema = {k: v.detach().clone() for k, v in model.state_dict().items()} if ema_decay > 0 else None
  if ck_path.is_file():
    ck = torch.load(ck_path)
    model.load_state_dict(ck["model"])
    if ema is not None and ck.get("ema") is not None:
      ema = ck["ema"]
    if (aux is None) != (ck.get("aux") is None):
      raise SystemExit(f"seq: {ck_path} was trained {'without' if aux is not None else 'with'} --aux-steps "
                       "(its optimizer state does not fit): resume with the same option or use another --run")
    if aux is not None:
      aux.load_state_dict(ck["aux"])
    opt.load_state_dict(ck["opt"])
    history, start, elapsed = ck["history"], ck["iter"], ck.get("elapsed", 0.0)
    if "rng" in ck:  # the batch sampler and torch continue where they stopped: a resume changes nothing
      rng.bit_generator.state = ck["rng"]
      torch.set_rng_state(ck["torch_rng"])
    else:  # a checkpoint from before the random states were saved
      rng = np.random.default_rng(start)
  iters = args.seq_iters

  def train_mode():
    model.train()
    if args.init_model and cfg.use_pre:
      model.pre.bn.eval()  # keep the folded statistics (identity) of the exported model

  carry = bool(getattr(args, "carry_state", False))
  own = float(getattr(args, "own_inputs", 0.0))
  own_passes = int(getattr(args, "own_passes", 1))
  music_dropout = float(getattr(args, "music_dropout", 0.0))
  music_ranges = getattr(args, "music_dropout_features", None)
  if music_dropout > 0:
    log(f"seq: music dropout {music_dropout:g} (a window's music replaced by the mean, PRE kept"
        + (f"; feature columns {music_ranges} only)" if music_ranges else ")"))
  engine_val = as_the_engine_reads(args, model, val_toks)
  if engine_val is not val_toks:
    val_toks = engine_val
    log("seq: validation reads the music mean, as the engine does at music guidance 0")
  balance = float(getattr(args, "style_balance", 1.0))
  lanes = Lanes(train_toks, cfg, rng, args.batch, STEPS, balance) if carry else None
  carried = None
  if lanes is not None and ck_path.is_file() and ck.get("lanes") is not None:
    lanes.restore(ck["lanes"])
    carried = ck.get("carried")
  train_mode()
  t_start = time.time() - elapsed

  def save(it):
    torch.save({"model": model.state_dict(), "ema": ema, "opt": opt.state_dict(), "history": history,
                "iter": it, "cfg": cfg.to_dict(), "elapsed": time.time() - t_start, "rng": rng.bit_generator.state,
                "torch_rng": torch.get_rng_state(),
                "lanes": lanes.snapshot() if lanes is not None else None, "carried": carried,
                "aux": aux.state_dict() if aux is not None else None}, ck_path)

  for it in tqdm(range(start, iters), desc="seq", initial=start, total=iters, mininterval=10):
    warm = min(1.0, (it + 1) / 200)
    for g in opt.param_groups:
      g["lr"] = lr0 * warm * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * it / iters)))
    if lanes is not None:
      inputs, targets, fresh = lanes.next(code_mask=args.code_mask, style_dropout=STYLE_DROPOUT)
      carried = reset_rows(detach(carried), fresh)
    else:
      inputs, targets = make_batch(train_toks, cfg, rng, batch=args.batch, code_mask=args.code_mask,
                                   style_dropout=STYLE_DROPOUT,
                                   style_balance=balance, self_share=self_share if self_tokens else None)
    if music_dropout > 0:  # (only then: a run without it draws exactly the batches it drew before)
      inputs = drop_music(model, inputs, music_dropout, rng, music_ranges)
    if own > 0:
      inputs = own_code_inputs(model, inputs, own, state=carried, passes=own_passes)
    trace = {} if aux is not None else None
    lu, ll, after = model.forward_with_state(*inputs, carried, trace)
    if lanes is not None:
      carried = detach(after)
    loss = code_loss(lu, ll, targets)
    total = loss + aux_weight * aux.loss(trace["norm_f"], targets) if aux is not None else loss
    opt.zero_grad()
    total.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
    opt.step()
    if ema is not None:
      update_ema(ema, model, ema_decay)
    if it % 25 == 0:
      history.append({"iter": it, "loss": float(loss)})
    if it % args.val_every == args.val_every - 1 or it == iters - 1:
      v = validation(model, val_toks, cfg)
      train_mode()
      history.append(dict(v, iter=it + 1, minutes=(time.time() - t_start) / 60))
      log(f"seq iter {it + 1}/{iters} train {float(loss):.3f} {json.dumps(v)}")
      save(it + 1)
      (run / "seq_history.json").write_text(json.dumps(history))
      if args.seq_minutes and (time.time() - t_start) / 60 > args.seq_minutes:
        log(f"seq: time budget of {args.seq_minutes} min reached at iter {it + 1}")
        break
  save(it + 1 if iters > start else start)
  (run / "seq_history.json").write_text(json.dumps(history))
  if ema is not None:
    averaged = load_seq(run)
    v = validation(averaged, val_toks, cfg)
    log(f"seq: weight average (decay {ema_decay:g}, exported): {json.dumps(v)}")
  log(f"seq: {(time.time() - t_start) / 60:.1f} min")


@torch.no_grad()
def update_ema(ema: dict, model, decay: float) -> None:
  """ema <- decay ema + (1 - decay) weights, for every floating-point tensor (buffers copied)."""
  for k, v in model.state_dict().items():
    if v.dtype.is_floating_point:
      ema[k].mul_(decay).add_(v, alpha=1.0 - decay)
    else:
      ema[k].copy_(v)


def load_seq(run: pathlib.Path) -> Danceba:
  ck = torch.load(run / "seq.pt")
  model = Danceba(SeqConfig.from_dict(ck["cfg"]))
  # the exponential average of the weights when training kept one (--ema), else the last weights
  model.load_state_dict(ck["ema"] if ck.get("ema") is not None else ck["model"])
  return model.eval()


def stage_eval(args, vqs, run: pathlib.Path, log) -> dict:
  if args.tempo_ref > 0:
    return stage_engine_eval(args, vqs, run, log)
  from training.train_eval import evaluate_model
  model = load_seq(run)
  report = evaluate_model(model, vqs, run, log, n_songs=args.eval_songs)
  (run / "eval_report.json").write_text(json.dumps(report, indent=1))
  return report


def stage_engine_eval(args, vqs, run: pathlib.Path, log) -> dict:
  """Tempo-normalised models run on the engine's warped timeline, which the torch generator does not
  reproduce: the losses come from the warped validation tokens, tempo following and the metric table
  from the exported file run by the engine itself (`dance-generate`), i.e. the product."""
  from training.eval import engine_eval, engine_tempo
  model = load_seq(run)
  split = td.load_split()
  refs = style_refs_of(args, run, log)
  bars = bar_clock_of(args)
  val_toks = build_tokens(td.paired_ids(split["validation"]), (1.0,), vqs, log,
                          (pathlib.Path(args.vq_run) if args.vq_run else run)
                          / f"tokens_val_{warp_tag(refs, bars, fold_tempo_of(args))}.pt",
                          refs, bars, fold_tempo=fold_tempo_of(args))
  val_toks = as_the_engine_reads(args, model, val_toks)
  report = {"losses": validation(model, val_toks, model.cfg, n_batches=12)}
  log(f"eval losses: {json.dumps(report['losses'])}")
  if not pathlib.Path(args.out).is_file():
    log(f"eval: {args.out} does not exist yet (run the export stage first); engine evaluation skipped")
  else:
    engine_tempo.main(["--model", args.out, "--out", str(run / "engine_tempo.json")])
    report["tempo"] = json.loads((run / "engine_tempo.json").read_text())
    log(f"eval tempo-following (engine) mean ratio {report['tempo']['mean_ratio']}")
    try:
      engine_eval.main(["--model", args.out, "--out-dir", str(run / "engine")])
      report["metrics"] = json.loads((run / "engine" / "metrics.json").read_text())
    except Exception as e:  # the metric table needs librosa (the .venv); report, do not fail the run
      log(f"eval metrics skipped: {e!r}")
  (run / "eval_report.json").write_text(json.dumps(report, indent=1))
  return report


def time_base_meta(args, run: pathlib.Path, log) -> dict:
  """The exported model's time_base metadata (docs/model.md sections 1 and 6): fixed-rate, or tempo-normalised
  with the style reference tempi, the bar clock if on, the dance periods and the period lock's default weight,
  per-style weights, kernel sharpness and reach (periods back per stream)."""
  if args.tempo_ref <= 0:
    return {"kind": "fixed"}
  tb = {"kind": "tempo", "reference_bpm": float(args.tempo_ref), "style_reference_bpm": style_refs_of(args, run, log)}
  if bar_clock_of(args):
    tb["bar_clock"] = bar_clock_of(args)
  if fold_tempo_of(args):
    tb["fold_tempo"] = True
  tb["dance_period_beats"] = dance_periods_of(args, run, log)
  tb["period_lock"] = float(getattr(args, "period_lock", 0.0))
  sharpness = getattr(args, "period_lock_sharpness", None)
  if sharpness is not None:
    tb["period_lock_sharpness"] = float(sharpness)
  style_locks = getattr(args, "style_period_lock", None)
  if style_locks:
    tb["style_period_lock"] = {name: float(b) for name, b in style_locks.items()}
  periods = getattr(args, "period_lock_periods", None)
  if periods:
    tb["period_lock_periods"] = {"upper": int(periods[0]), "lower": int(periods[1])}
  return tb


def stage_export(args, vqs, run: pathlib.Path, log) -> None:
  from training.export import export_model
  from training.fixtures import FEATURES_META, skeleton_meta, write_fixtures
  model = load_seq(run)
  out = pathlib.Path(args.out)
  model_id = getattr(args, "model_id", None) or out.stem + "-" + time.strftime("%Y%m%d")
  extra = {"model_id": model_id, "features": FEATURES_META,
           "skeleton": skeleton_meta(), "styles": td.ALL_STYLES[:model.cfg.n_styles], "training": {"run": str(run)},
           "time_base": time_base_meta(args, run, log)}
  extra["sampling"] = sampling_meta(args)
  for name in ("vq_report.json", "vqdec_report.json", "eval_report.json"):
    if (run / name).is_file():
      extra["training"][name.removesuffix(".json")] = json.loads((run / name).read_text())
  from training.train import owndec_current
  own = owndec_current(run, args)  # only when fitted to this sequence model with these settings
  if own is not None:
    extra["training"]["owndec_report"] = own
  export_model(str(out), model, vqs, extra, weights_dtype=args.weights_dtype)
  log(f"export: {out} ({out.stat().st_size / 1e6:.1f} MB)")
  if out.parent.resolve() == (td.REPO / "models").resolve():
    idx = write_fixtures(out.resolve(), td.REPO / "tests" / "golden" / out.stem)
    log(f"fixtures: tests/golden/{out.stem} ({len(idx['arrays'])} arrays)")
