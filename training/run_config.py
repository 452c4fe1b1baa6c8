"""RunConfig: every setting of one training run, typed, built once from the command line (training.train) and
passed to the stages (training/stages) instead of an argparse namespace.

    from training.run_config import RunConfig
    config = RunConfig(run=pathlib.Path("training/runs/x"), seq_iters=300)   # every other field its default
    config.validate()                                                        # ValueError naming the flag
    pretrain = dataclasses.replace(config, tempo_ref=0.0)                    # a derived run (frozen: no edits)

Field names are the command line's flags (`--seq-iters` is `seq_iters`), and the defaults here are the
command line's defaults: the one command (`python -m training.train`) with no flags trains the shipped recipe.
The values are parsed: `vq_energy_weight` is {"upper": W, "lower": W}, `own_seeds` a tuple of ints,
`music_dropout_features` ((begin, end), ...) per-frame feature columns, `tempo_factors` a tuple of floats.
"""
from __future__ import annotations

import dataclasses
import json
import pathlib

from training.common import clips
from training.features.extract import FEATURE_DIMS

REPO = pathlib.Path(__file__).resolve().parents[1]
STAGES = ("data", "vq", "vqdec", "seq", "export", "owndec", "eval")
PARTS = ("upper", "lower")
MAX_PERIOD_LOCK_PERIODS = 4  # the engine's kMaxPeriodLockPeriods


@dataclasses.dataclass(frozen=True)
class RunConfig:
  # The run
  run: pathlib.Path = REPO / "training" / "runs" / "default"  # checkpoints, log, reports, curves
  stages: tuple[str, ...] = STAGES
  threads: int = 2
  # vq: the pose VQ-VAEs (training.common.vq_training)
  vq_iters: int = 6000
  vq_width: int = 128
  vq_code_dim: int = 64
  codebook_size: int = 512
  vq_path_weight: float = 0.0      # lower body: the integrated root path loss (off: docs/research-log.md)
  mirror: bool = False             # seq: the training dances also mirrored left-right (validation never)
  vq_mirror: bool = False          # vq: the training motion also mirrored
  vq_vel_weight: float = 4.0
  vq_acc_weight: float = 4.0
  # vqdec: the decoders fine-tuned with the energy term (training.common.decoder_tuning)
  vq_dec_iters: int = 1500         # per decoder; 0: no vqdec stage
  vq_energy_weight: dict = dataclasses.field(default_factory=lambda: {"upper": 0.1, "lower": 0.3})
  vq_dec_lr: float = 1e-4
  # owndec: the decoders fitted to the sequence model's own codes
  own_iters: int = 1000            # 0: no owndec stage
  own_weight: dict = dataclasses.field(default_factory=lambda: {"upper": 1.0, "lower": 0.0})
  own_anchor: float = 100.0
  own_seeds: tuple[int, ...] = (10, 11)
  # seq: the sequence model (training.stages.seq)
  seq_iters: int = 1000            # the tempo-normalised phase when pretraining; also fixed-rate runs
  pretrain_iters: int = 1600       # tempo-normalised runs from scratch: the fixed-rate phase first
  finetune_lr: float = 3e-4        # the tempo-normalised phase's learning rate after pretraining
  batch: int = 16
  val_every: int = 100
  lr: float = 1e-3
  seq_minutes: float = 0.0         # stop the seq stage after this (0: no limit)
  d_model: int = 128
  n_head: int = 2
  lookahead: int = 0               # 0 anticipatory, 1 reactive
  code_mask: float = 0.4           # past-motion dropout rate
  music_dropout: float = 0.0       # share of windows whose music stream is replaced by the mean
  music_dropout_features: tuple[tuple[int, int], ...] | None = None  # only these feature columns [b, e)
  own_inputs: float = 0.0          # parallel scheduled sampling: share of input codes replaced by own draws
  own_passes: int = 1
  carry_state: bool = False        # whole songs window by window, the state carried (common.lanes)
  aux_steps: int = 1               # multi-step prediction heads (1: off)
  aux_weight: float = 0.5
  ema: float = 0.0                 # decay of the exported weight average (0: off)
  style_balance: float = 0.5       # a style's share of the windows goes as (its windows) ** B
  self_tokens: pathlib.Path | None = None  # filtered self-training clips (training.experiments.self_rollouts)
  self_share: float = 0.5
  dropout: float = 0.0             # residual dropout, training only
  no_pre: bool = False
  no_gate: bool = False
  shared_mamba: bool = False
  # The time base and sampling written into the exported model (docs/model.md sections 1 and 6)
  fold_tempo: bool = False
  bar_clock: bool = False
  period_lock: float = 8.0
  style_period_lock: dict = dataclasses.field(default_factory=lambda: {"waltz": 0.0})
  period_lock_sharpness: float = 10.0
  period_lock_periods: tuple[int, int] = (1, 2)  # (upper, lower)
  guidance: float = 3.0
  music_guidance: float = 1.0
  tempo_factors: tuple[float, ...] = clips.TEMPO_FACTORS  # the fixed-rate phase's tempo augmentation
  warp_tempo_factors: tuple[float, ...] = (1.0,)         # the tempo-normalised phase's music speeds
  warp_tempo_styles: tuple[str, ...] = ()                # () = every style
  # Where the models come from and go
  vq_run: pathlib.Path | None = None      # take the VQ-VAEs (and token caches) from this run directory
  vq_model: pathlib.Path | None = None    # take the VQ-VAEs from this exported .dncw file
  init_model: pathlib.Path | None = None  # fine-tune the sequence model of this .dncw file
  tempo_ref: float = 105.0                # > 0: tempo-normalised time at this BPM; 0: fixed 30 fps rate
  out: pathlib.Path = REPO / "models" / "default.dncw"
  weights_dtype: str = "f16"
  eval_songs: int = 8
  model_id: str | None = None             # export: default <out stem>-<date>

  @property
  def tempo_normalised(self) -> bool:
    return self.tempo_ref > 0

  @property
  def vq_dir(self) -> pathlib.Path:
    """Where the VQ-VAEs' checkpoints and the token caches are: --vq-run, else the run itself."""
    return self.vq_run if self.vq_run is not None else self.run

  def own_parts(self) -> list[str]:
    """The parts whose decoder the owndec stage fits: those with an own-codes weight above 0."""
    return [part for part in PARTS if self.own_weight[part] > 0]

  def as_log_dict(self) -> dict:
    """The settings as plain JSON values (paths as strings), for the log."""
    return json.loads(json.dumps(dataclasses.asdict(self), default=str))

  def validate(self) -> None:
    """ValueError (naming the flag) for a setting outside its range or one that needs another."""
    def need(ok: bool, message: str) -> None:
      if not ok:
        raise ValueError(message)

    need(set(self.stages) <= set(STAGES), f"--stages: unknown stage in {','.join(self.stages)} "
         f"(known: {','.join(STAGES)})")
    need(0.0 <= self.period_lock <= 100.0, f"--period-lock must be in [0, 100], got {self.period_lock}")
    need(1.0 <= self.period_lock_sharpness <= 100.0,
         f"--period-lock-sharpness must be in [1, 100], got {self.period_lock_sharpness}")
    need(not (self.warp_tempo_styles and tuple(self.warp_tempo_factors) == (1.0,)),
         "--warp-tempo-styles needs --warp-tempo-factors (other speeds than 1)")
    need(not (self.fold_tempo and self.tempo_ref <= 0),
         "--fold-tempo needs the tempo-normalised timeline (--tempo-ref > 0)")
    for st in self.warp_tempo_styles:
      need(st in clips.ALL_STYLES,
           f"--warp-tempo-styles: unknown style '{st}' (known: {', '.join(clips.ALL_STYLES)})")
    need(len(self.period_lock_periods) == 2 and
         all(1 <= n <= MAX_PERIOD_LOCK_PERIODS for n in self.period_lock_periods),
         f"--period-lock-periods must be two integers in 1..4 (upper,lower), got {self.period_lock_periods}")
    need(0.0 <= self.guidance <= 100.0, f"--guidance must be in [0, 100], got {self.guidance}")
    need(0.0 <= self.music_guidance <= 100.0, f"--music-guidance must be in [0, 100], got {self.music_guidance}")
    for name in ("own_iters", "own_anchor"):
      need(getattr(self, name) >= 0, f"--{name.replace('_', '-')} must be >= 0, got {getattr(self, name)}")
    need(0.0 <= self.ema < 1.0, f"--ema must be in [0, 1), got {self.ema}")
    need(1 <= self.aux_steps <= 16 and self.aux_weight >= 0,
         f"--aux-steps must be in 1..16 and --aux-weight >= 0, got {self.aux_steps}, {self.aux_weight}")
    need(0.0 <= self.music_dropout <= 1.0, f"--music-dropout must be in [0, 1], got {self.music_dropout}")
    need(not (self.music_dropout == 1 and self.music_guidance != 0),
         "--music-dropout 1 trains a model that never reads the song's music (in the chosen columns): "
         "give --music-guidance 0, so the engine runs it on the music mean as it was trained")
    need(not (self.music_dropout_features and self.music_dropout == 0),
         "--music-dropout-features chooses the columns --music-dropout replaces: give --music-dropout P > 0 too")
    for b, e in self.music_dropout_features or ():
      need(0 <= b < e <= FEATURE_DIMS, f"--music-dropout-features: range {b}:{e} outside 0:{FEATURE_DIMS} or empty")
    need(0.0 <= self.own_inputs <= 1.0, f"--own-inputs must be in [0, 1], got {self.own_inputs}")
    need(self.own_passes >= 1, f"--own-passes must be at least 1, got {self.own_passes}")
    need(not (self.own_passes > 1 and self.own_inputs == 0),
         "--own-passes repeats --own-inputs' replacement: give --own-inputs P > 0 too")
    need(0.0 < self.self_share < 1.0, f"--self-share must be in (0, 1), got {self.self_share}")
    need(not (self.self_tokens and not pathlib.Path(self.self_tokens).is_file()),
         f"--self-tokens: no file {self.self_tokens}")
    need(not (self.self_tokens and self.carry_state),
         "--self-tokens is not supported with --carry-state (whole-song lanes)")
    need(0.0 <= self.style_balance <= 1.0, f"--style-balance must be in [0, 1], got {self.style_balance}")
    for part in PARTS:
      need(self.vq_energy_weight.get(part, -1.0) >= 0, f"--vq-energy-weight: {part} must be >= 0")
      need(self.own_weight.get(part, -1.0) >= 0, f"--own-weight: {part} must be >= 0")
