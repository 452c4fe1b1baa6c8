"""training.eval.engine_suite: lanes split the seeds, the summary aggregates draws and tempo lanes."""
import json
import math
import pathlib

from training.eval import engine_suite as es


def _metrics(fid_k, div_k):
  row = {"fid_k": fid_k, "fid_g": 2 * fid_k, "div_k": div_k, "div_g": 7.0, "pfc": 0.03, "jitter": 160.0}
  real = {"fid_k": 6.0, "fid_g": 3.4, "div_k": 8.0, "div_g": 7.0, "pfc": 0.015, "jitter": 120.0}
  return {es.MODEL_ROW: row, "real (validation)": real}


def _tempo(seeds, ratios, pooled):
  rows = [{"id": mid, "seed": s, "ratio": r} for (mid, s), r in zip(
      [(m, s) for m in ("a", "b") for s in seeds], ratios)]
  return {"seeds": seeds, "rows": rows,
          "pooled_rows": [{"id": m, "ratio": p, "perfect_follower_ratios": [0.9, float("nan"), None]}
                          for m, p in zip(("a", "b"), pooled)]}


def test_tempo_lanes_take_every_seed_once():
  cmds = es.tempo_commands("m.dncw", pathlib.Path("/o"), seeds=5, lanes=2, passthrough=["--top-p", "0.9"])
  seeds = []
  for report, cmd in cmds:
    i = cmd.index("--seeds")
    seeds += [int(x) for x in cmd[i + 1:cmd.index("--out")]]
    assert cmd[-2:] == ["--top-p", "0.9"]
  assert sorted(seeds) == [0, 1, 2, 3, 4]
  assert [r.name for r, _ in cmds] == ["tempo_0.json", "tempo_1.json"]


def test_summary_means_and_diversity_band(tmp_path):
  for s, (fid, div) in enumerate([(10.0, 8.0), (20.0, 9.0)]):
    (tmp_path / f"s{s}").mkdir()
    (tmp_path / f"s{s}" / "metrics.json").write_text(json.dumps(_metrics(fid, div)))
  (tmp_path / "tempo_0.json").write_text(json.dumps(_tempo([0, 2], [1.0, 0.5, 1.0, float("nan")], [1.0, 0.8])))
  (tmp_path / "tempo_1.json").write_text(json.dumps(_tempo([1], [0.0, 1.0], [0.6, 1.2])))
  s = es.summarize(tmp_path)
  assert s["draw_mean"]["fid_k"] == 15.0 and s["draw_mean"]["fid_g"] == 30.0
  assert s["div_inside_20pct"]  # 8 and 9 against 8: inside
  t = s["tempo"]
  assert t["seeds"] == [0, 1, 2] and t["runs"] == 6 and t["finite_runs"] == 5
  assert math.isclose(t["mean_ratio"], (1.0 + 0.5 + 1.0 + 0.0 + 1.0) / 5)
  assert math.isclose(t["mean_abs_error"], (0.0 + 0.5 + 0.0 + 1.0 + 0.0) / 5) and math.isclose(t["within_20pct"], 0.6)
  assert math.isclose(t["per_song"]["a"], (1.0 + 0.5 + 0.0) / 3)
  # pooled: lane ratios weighted by the lane's seed count (2 and 1)
  assert math.isclose(t["pooled_per_song"]["a"], (2 * 1.0 + 0.6) / 3)
  assert math.isclose(t["pooled_per_song"]["b"], (2 * 0.8 + 1.2) / 3)
  assert t["perfect_follower_mean_ratio"] == 0.9
  assert "| seed 1 | 20 |" in es.markdown(s, "m")


def test_summary_flags_a_draw_outside_the_band(tmp_path):
  (tmp_path / "s0").mkdir()
  (tmp_path / "s0" / "metrics.json").write_text(json.dumps(_metrics(10.0, 6.0)))  # 6 vs 8: -25 %
  assert not es.summarize(tmp_path)["div_inside_20pct"]
  assert "tempo" not in es.summarize(tmp_path)


def test_summary_fills_the_songs_it_did_not_run_from_another_suite(tmp_path):
  import pytest
  base, part = tmp_path / "base", tmp_path / "part"
  base.mkdir()
  part.mkdir()
  (base / "tempo_0.json").write_text(json.dumps(_tempo([0, 2], [1.0, 0.5, 1.0, 0.2], [1.0, 0.8])))
  (base / "tempo_1.json").write_text(json.dumps(_tempo([1], [0.0, 0.4], [0.6, 1.2])))
  # The partial suite ran song "a" only, on the same seeds.
  for lane, seeds, ratios, pooled in ((0, [0, 2], [0.9, 0.7], 0.95), (1, [1], [0.8], 0.85)):
    (part / f"tempo_{lane}.json").write_text(json.dumps(
        {"seeds": seeds, "rows": [{"id": "a", "seed": s, "ratio": r} for s, r in zip(seeds, ratios)],
         "pooled_rows": [{"id": "a", "ratio": pooled}]}))
  t = es.summarize(part, base)["tempo"]
  assert t["seeds"] == [0, 1, 2] and t["runs"] == 6
  assert t["songs"] == ["a", "b"] and t["filled_from"] == str(base)
  assert "over 2 songs" in es.markdown({"draws": {}, "tempo": t}, "m")
  assert es.summarize(part)["tempo"]["songs"] == ["a"]  # alone it says it covers one song
  assert math.isclose(t["per_song"]["a"], (0.9 + 0.7 + 0.8) / 3)      # its own runs
  assert math.isclose(t["per_song"]["b"], (1.0 + 0.2 + 0.4) / 3)      # the base suite's
  assert math.isclose(t["pooled_per_song"]["a"], (2 * 0.95 + 0.85) / 3)
  assert math.isclose(t["pooled_per_song"]["b"], (2 * 0.8 + 1.2) / 3)
  assert math.isclose(t["mean_ratio"], (0.9 + 0.7 + 0.8 + 1.0 + 0.2 + 0.4) / 6)
  # A base suite run at another temperature, or without the songs this one ran, cannot fill in.
  hot = json.loads((base / "tempo_1.json").read_text())
  (base / "tempo_1.json").write_text(json.dumps(dict(hot, temperature=1.1)))
  with pytest.raises(ValueError, match="temperature"):
    es.summarize(part, base)
  (base / "tempo_1.json").write_text(json.dumps(hot))
  only_b = json.loads((base / "tempo_0.json").read_text())
  only_b["rows"] = [r for r in only_b["rows"] if r["id"] == "b"]
  (base / "tempo_0.json").write_text(json.dumps(only_b))
  with pytest.raises(ValueError, match="lacks songs"):
    es.summarize(part, base)
  (base / "tempo_0.json").write_text(json.dumps(_tempo([0, 2], [1.0, 0.5, 1.0, 0.2], [1.0, 0.8])))
  # A base suite on other seeds cannot fill in.
  (base / "tempo_1.json").write_text(json.dumps(_tempo([3], [0.0, 0.4], [0.6, 1.2])))
  with pytest.raises(ValueError, match="seeds"):
    es.summarize(part, base)


def test_engine_eval_refuses_a_bad_song_subset_before_generating(tmp_path):
  import pytest

  from training.eval import engine_eval
  for argv in (["--songs", "tang_DANCE_C_6"],                                   # no --fill-from
               ["--fill-from", str(tmp_path)],                                  # no --songs
               ["--songs", "tang_DANCE_X_1", "--fill-from", str(tmp_path)]):    # not a validation song
    with pytest.raises(SystemExit) as e:
      engine_eval.main(["--out-dir", str(tmp_path / "out")] + argv)
    assert e.value.code == 2
  assert not (tmp_path / "out").exists()
  with pytest.raises(SystemExit):
    es.main(["--model", "m.dncw", "--out-dir", str(tmp_path / "out"), "--songs", "tang_DANCE_C_6"])


def test_markdown_of_a_single_tempo_run_says_what_it_cannot_estimate(tmp_path):
  # One run: no bootstrap s.e.; no pooled rows and no calibration either.
  (tmp_path / "tempo_0.json").write_text(json.dumps(
      {"seeds": [0], "rows": [{"id": "a", "seed": 0, "ratio": 0.9}], "pooled_rows": []}))
  t = es.summarize(tmp_path)["tempo"]
  assert t["mean_ratio_se"] is None and t["perfect_follower_mean_ratio"] is None and t["pooled_mean_ratio"] is None
  md = es.markdown({"draws": {}, "tempo": t}, "m")
  assert "**0.900** (s.e. n/a)" in md and "seeds pooled n/a" in md and "spread n/a" in md
  assert "mean |ratio - 1| per run 0.100, runs within 0.2 of 1: 1.000" in md
  # An overshoot scores as much above 1 as the mean ratio rewards it: 0.8 and 1.6 average 1.2, but miss by 0.4.
  (tmp_path / "tempo_0.json").write_text(json.dumps(
      {"seeds": [0, 1], "rows": [{"id": "a", "seed": 0, "ratio": 0.8}, {"id": "a", "seed": 1, "ratio": 1.6}],
       "pooled_rows": []}))
  t = es.summarize(tmp_path)["tempo"]
  assert math.isclose(t["mean_ratio"], 1.2) and math.isclose(t["mean_abs_error"], 0.4) and t["within_20pct"] == 0.5


def test_suite_prepares_a_missing_motion_cache_once_before_the_draws(tmp_path, monkeypatch):
  # A fresh checkout has no training/cache/motion; every draw needs it (audio paths, styles). The suite must
  # make it once, before the parallel draws start (which would otherwise each find it missing).
  import pytest

  from training.common import clips as td
  from training.data import prepare

  class Stop(Exception):
    pass

  def stop(*_args):
    raise Stop

  events = []
  monkeypatch.setattr(td, "MOTION_CACHE", tmp_path / "empty_cache")
  monkeypatch.setattr(prepare, "main", lambda argv: events.append("prepare"))
  monkeypatch.setattr(es, "run_parallel", lambda cmds, lanes: events.append(f"run {len(cmds)}"))
  monkeypatch.setattr(es, "summarize", stop)
  with pytest.raises(Stop):
    es.main(["--model", "m.dncw", "--out-dir", str(tmp_path / "out"), "--draws", "3", "--tempo-seeds", "2"])
  assert events == ["prepare", "run 3", "run 2"]


def test_summary_scores_the_draws_on_the_real_dances_spans(tmp_path, monkeypatch):
  # With the draws' dance files present the summary adds FID/Div on the real dances' song spans
  # (evaluate.on_real_spans); here a synthetic evaluator whose real dances are a song's 20 s from 10 s.
  import numpy as np

  from tests.training.test_eval_metrics import _dance
  from training.eval import evaluate
  real = [evaluate.Dance(n, _dance(seed=i, seconds=20), audio_offset_s=10.0) for i, n in enumerate(("a", "b"))]
  ev = evaluate.Evaluator([evaluate.Dance(f"r{i}", _dance(seed=10 + i, seconds=30)) for i in range(4)], real)
  monkeypatch.setattr(evaluate.Evaluator, "default", classmethod(lambda cls: ev))
  whole = {n: _dance(seed=20 + i, seconds=60) for i, n in enumerate(("a", "b"))}
  monkeypatch.setattr(evaluate, "load_dance",
                      lambda p: evaluate.Dance(pathlib.Path(p).stem, whole[pathlib.Path(p).stem]))
  (tmp_path / "s0" / "dances").mkdir(parents=True)
  (tmp_path / "s0" / "metrics.json").write_text(json.dumps(_metrics(10.0, 8.0)))
  for n in whole:
    (tmp_path / "s0" / "dances" / f"{n}.json").write_text("{}")
  s = es.summarize(tmp_path)
  spans = s["real_spans"]
  cut = [evaluate.Dance(n, whole[n][300:900]) for n in ("a", "b")]
  assert spans["draws"][0] == ev.fid_div(cut) and spans["draws"][0]["segments"] == 4
  assert spans["real"] == ev.fid_div(real) and spans["mean"]["fid_k"] == spans["draws"][0]["fid_k"]
  assert "On the real dances' spans" in es.markdown(s, "m")
  # A draw missing a real dance's song: no span scores (rather than a FID over other segments) ...
  (tmp_path / "s0" / "dances" / "b.json").unlink()
  assert "real_spans" not in es.summarize(tmp_path)
  # ... unless a --songs suite takes it from the suite it was filled from (same seed).
  base = tmp_path / "base"
  (base / "s0" / "dances").mkdir(parents=True)
  (base / "s0" / "dances" / "b.json").write_text("{}")
  assert es.span_scores(tmp_path, [0], base)["draws"][0] == ev.fid_div(cut)
  assert np.isfinite(s["draw_mean"]["fid_k"])
