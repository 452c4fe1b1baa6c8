"""Teacher-forced against free-running: does the sequence model keep a song's motion when it reads its own
codes? (docs/research-log.md, "Free-running loses the energetic styles' energy").

    /usr/bin/python3 -m training.experiments.free_run --model M.dncw --tokens RUN/tokens_train_warp_....pt
        [--songs ID ...] [--draws 4] [--guidance 1] [--seed 0] [--history-guidance H --history-mask P]
        [--music-guidance M] [--fid]

For each song of a token cache (a training run's `tokens_*.pt`; the tempo factor 1 clips), on the warped
timeline the model was trained on and with the model's VQ decoders:
- real: the song's real codes, decoded;
- teacher-forced: every step's codes drawn from the model's prediction given the real codes before it;
- free-running: the codes drawn step by step from BOS, the model reading its own draws (as the engine
  does, without the period lock and foot lock).
Each is cut into the evaluator's 10-s segments; the table gives each set's mean normalised kinetic feature
(higher = more energetic) and the distance of its average kinetic features to the real decode's. A model
that fits its training songs but drifts on its own codes shows a small teacher-forced distance and a large
free-running one. --fid adds the FID of each set with the songs pooled (on a validation token cache, whose
clips are the real dances' spans: where the model's FID comes from, docs/research-log.md "How the model scales
with its training songs").
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

from training.data import representation as rep
from training.data import skeleton as sk
from training.eval.evaluate import Dance, Evaluator, segment_table
from training.export import load_models
from training.model.danceba import one_hot_style
from training.common.seq_inputs import feature_mask


def _codes_tensor(t: dict, part: str, n: int) -> torch.Tensor:
  return torch.from_numpy(np.asarray(t[part][:n])).long()


def decode_codes(vqs: dict, upper: np.ndarray, lower: np.ndarray, name: str, skel) -> Dance:
  """Codes (T,) per part -> a Dance of 4T frames (the VQ decoders, root integrated from the origin)."""
  parts = {}
  for part, codes in (("upper", upper), ("lower", lower)):
    vq = vqs[part]
    with torch.no_grad():
      parts[part] = vq.denormalise(vq.decode_codes(torch.as_tensor(codes)[None]))[0].numpy()
  return Dance(name, sk.project_bone_lengths(rep.decode(parts["upper"], parts["lower"]), skel), 30.0)


@torch.no_grad()
def teacher_forced_draws(model, t: dict, draws: int, gen: torch.Generator) -> tuple[np.ndarray, np.ndarray]:
  """(draws, T) upper and lower codes of steps 1..T, each drawn given the real codes before it."""
  cfg = model.cfg
  n = len(t["upper"]) - 1
  music = torch.from_numpy(np.asarray(t["music"][:n])).float()[None]
  pre = torch.from_numpy(np.asarray(t["pre"][:n])).float()[None]
  u, l = _codes_tensor(t, "upper", n)[None].clone(), _codes_tensor(t, "lower", n)[None].clone()
  u[0, 0] = l[0, 0] = cfg.codebook_size
  lu, ll = model(music, pre, u, l, one_hot_style(1, t["style"], cfg.n_styles))
  out = []
  for logits in (lu[0], ll[0]):
    p = torch.softmax(logits, -1)
    out.append(torch.stack([torch.multinomial(p, 1, generator=gen)[:, 0] for _ in range(draws)]).numpy())
  return out[0], out[1]


@torch.no_grad()
def free_running_draws(model, t: dict, draws: int, gen: torch.Generator, guidance: float = 1.0,
                       history_guidance: float = 0.0, history_mask: float = 1.0, mask_seed: int = 0,
                       music_guidance: float = 1.0, music_ranges=None):
  """(draws, T) codes drawn step by step from BOS, the model reading its own draws; style guidance w
  combines the logits as the engine does (docs/model.md section 6).
  history_guidance h (an experiment, not in the engine): logits + h (l_c - l_nh), l_c the style-conditioned
  prediction and l_nh the same model (its own state set) reading the draws with each input code replaced by
  BOS with probability history_mask (1: every code, the prediction from the music and style alone; 0.4: the
  training's past-motion dropout); h > 0 favours what the dance's own history adds over the music alone.
  music_guidance m (the engine's SamplingOptions::music_guidance): l_nm + m (l - l_nm), l the (style-guided)
  logits and l_nm the same model in its own states reading the music mean instead of the song's music (PRE
  kept; with music_ranges, [(begin, end), ...] per-frame feature columns, the model's
  sampling.music_guidance_features, only those columns): m < 1 weakens what the song's music stream adds to
  the style and the rhythm (needs a model trained with --music-dropout; docs/research-log.md, "Music
  guidance"). m = 1: the draws are exactly those without it."""
  cfg, k = model.cfg, model.cfg.codebook_size
  n = len(t["upper"]) - 1
  music = torch.from_numpy(np.asarray(t["music"][:n])).float()
  pre = torch.from_numpy(np.asarray(t["pre"][:n])).float()
  cond = one_hot_style(draws, t["style"], cfg.n_styles)
  uncond = one_hot_style(draws, -1, cfg.n_styles)
  u, l = torch.full((draws,), k), torch.full((draws,), k)
  sc = su = sn = smc = smu = None
  mean_music = model.music_mean.expand(draws, -1) if music_guidance != 1.0 else None
  mask = feature_mask(music_ranges, cfg.feature_dim, cfg.frames_per_step) if music_ranges else None
  rng = np.random.default_rng(mask_seed)
  gu, gl = [], []
  for i in range(n):
    m, p = music[i].expand(draws, -1), pre[i].expand(draws, -1)
    cu, cl, sc = model.step(m, p, u, l, cond, sc)
    lu, ll = cu, cl
    if guidance != 1.0:
      uu, ul, su = model.step(m, p, u, l, uncond, su)
      lu, ll = uu + guidance * (cu - uu), ul + guidance * (cl - ul)
    if music_guidance != 1.0:
      mm = mean_music if mask is None else torch.where(mask, mean_music, m)
      mu_, ml_, smc = model.step(mm, p, u, l, cond, smc)
      if guidance != 1.0:
        uu, ul, smu = model.step(mm, p, u, l, uncond, smu)
        mu_, ml_ = uu + guidance * (mu_ - uu), ul + guidance * (ml_ - ul)
      lu, ll = mu_ + music_guidance * (lu - mu_), ml_ + music_guidance * (ll - ml_)
    if history_guidance != 0.0:
      nu, nl = u.clone(), l.clone()
      nu[torch.from_numpy(rng.random(draws) < history_mask)] = k
      nl[torch.from_numpy(rng.random(draws) < history_mask)] = k
      hu, hl, sn = model.step(m, p, nu, nl, cond, sn)
      lu, ll = lu + history_guidance * (cu - hu), ll + history_guidance * (cl - hl)
    u = torch.multinomial(torch.softmax(lu, -1), 1, generator=gen)[:, 0]
    l = torch.multinomial(torch.softmax(ll, -1), 1, generator=gen)[:, 0]
    gu.append(u)
    gl.append(l)
  return torch.stack(gu, 1).numpy(), torch.stack(gl, 1).numpy()


def kinetic_mean(ev: Evaluator, dances: list[Dance]) -> np.ndarray:
  """Average normalised kinetic features over the dances' 10-s segments."""
  t = segment_table(dances, beats_of=lambda d: np.zeros(0))
  return ev.norm_k.apply(t["kinetic"]).mean(0)


def compare_song(model, vqs, ev: Evaluator, t: dict, draws: int, seed: int, guidance: float, skel,
                 history_guidance: float = 0.0, history_mask: float = 1.0, music_guidance: float = 1.0,
                 music_ranges=None) -> dict:
  """The song's table row; under "dances" the decoded sets (real: one dance; the others: one per draw)."""
  gen = torch.Generator().manual_seed(seed)
  n = len(t["upper"]) - 1
  real_dance = decode_codes(vqs, np.asarray(t["upper"][1:n + 1]), np.asarray(t["lower"][1:n + 1]), t["id"], skel)
  real = kinetic_mean(ev, [real_dance])
  out = {"song": t["id"], "real": float(real.mean()), "dances": {"real": [real_dance]}}
  for label, (cu, cl) in (("teacher_forced", teacher_forced_draws(model, t, draws, gen)),
                          ("free_running", free_running_draws(model, t, draws, gen, guidance, history_guidance,
                                                              history_mask, seed, music_guidance, music_ranges))):
    dances = [decode_codes(vqs, cu[i], cl[i], t["id"], skel) for i in range(draws)]
    x = kinetic_mean(ev, dances)
    out["dances"][label] = dances
    out[label] = float(x.mean())
    out[label + "_distance"] = float(np.linalg.norm(x - real))
  return out


def fid_of_sets(ev: Evaluator, rows: list[dict]) -> dict[str, list[dict]]:
  """Per set (real codes, teacher-forced, free-running) and draw: FID_k / FID_g / Div of the draw's dances of
  every song pooled (Evaluator.fid_div), so the FID splits into what decoding real codes costs, what drawing
  each step given the real history adds, and what reading the model's own draws adds."""
  out = {}
  for label in ("real", "teacher_forced", "free_running"):
    n = len(rows[0]["dances"][label])
    out[label] = [ev.fid_div([r["dances"][label][i] for r in rows]) for i in range(n)]
  return out


def main(argv=None) -> None:
  ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
  ap.add_argument("--model", required=True, help="a .dncw file (its sequence model and VQ decoders)")
  ap.add_argument("--tokens", required=True, help="a token cache of a training run (tokens_*.pt)")
  ap.add_argument("--songs", nargs="*", default=None, help="song ids (default: every song in the cache)")
  ap.add_argument("--draws", type=int, default=4)
  ap.add_argument("--guidance", type=float, default=1.0, help="style guidance of the free-running draws")
  ap.add_argument("--seed", type=int, default=0)
  ap.add_argument("--history-guidance", type=float, default=0.0,
                  help="free-running draws: + H (l_c - l_nh), l_nh the prediction with the history masked")
  ap.add_argument("--history-mask", type=float, default=1.0,
                  help="share of input codes set to BOS for l_nh (1: all; 0.4: the training's dropout)")
  ap.add_argument("--music-guidance", type=float, default=1.0,
                  help="free-running draws: l_nm + M (l - l_nm), l_nm with the music mean for the song's music "
                       "(a model trained with --music-dropout; only its sampling.music_guidance_features columns "
                       "if it has them)")
  ap.add_argument("--fid", action="store_true",
                  help="also FID_k / FID_g of each set with every song pooled (use a validation token cache)")
  args = ap.parse_args(argv)
  if not 0.0 <= args.history_mask <= 1.0:
    ap.error("--history-mask must be in [0, 1]")
  if args.draws < 1:
    ap.error("--draws must be at least 1")
  torch.set_grad_enabled(False)
  model, vqs, meta = load_models(args.model)
  ranges = meta.get("sampling", {}).get("music_guidance_features")  # the columns its music dropout replaced
  toks = [t for t in torch.load(args.tokens) if t.get("factor", 1.0) == 1.0]
  if args.songs:
    missing = set(args.songs) - {t["id"] for t in toks}
    if missing:
      raise SystemExit(f"free_run: not in {args.tokens}: {sorted(missing)}")
    toks = [t for t in toks if t["id"] in args.songs]
  ev, skel = Evaluator.default(), sk.load_skeleton()
  print("song               mean normalised kinetic feature: real / teacher-forced / free-running | "
        "distance to real: teacher-forced / free-running")
  rows = []
  for t in toks:
    r = compare_song(model, vqs, ev, t, args.draws, args.seed, args.guidance, skel, args.history_guidance,
                     args.history_mask, args.music_guidance, ranges)
    rows.append(r)
    print(f"{r['song']:<18} {r['real']:+6.2f} / {r['teacher_forced']:+6.2f} / {r['free_running']:+6.2f} | "
          f"{r['teacher_forced_distance']:5.2f} / {r['free_running_distance']:5.2f}", flush=True)
  if len(rows) > 1:
    print(f"{'mean':<18} {np.mean([r['real'] for r in rows]):+6.2f} / "
          f"{np.mean([r['teacher_forced'] for r in rows]):+6.2f} / {np.mean([r['free_running'] for r in rows]):+6.2f} | "
          f"{np.mean([r['teacher_forced_distance'] for r in rows]):5.2f} / "
          f"{np.mean([r['free_running_distance'] for r in rows]):5.2f}")
  if args.fid:
    for label, draws in fid_of_sets(ev, rows).items():
      fk, fg = [d["fid_k"] for d in draws], [d["fid_g"] for d in draws]
      print(f"FID {label:<15} FID_k {np.mean(fk):6.2f} ({' '.join(f'{v:.2f}' for v in fk)})  "
            f"FID_g {np.mean(fg):5.2f} ({' '.join(f'{v:.2f}' for v in fg)})  segments {draws[0]['segments']}")


if __name__ == "__main__":
  main()
