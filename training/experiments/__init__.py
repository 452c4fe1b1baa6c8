"""The lab: finished experiments and one-off measurements, each runnable as `python -m training.experiments.X`.

No pipeline module imports from here (tests/training/test_import_graph.py checks it); an experiment may use
anything in training/. What each one found is in docs/research-log.md (and docs/evaluation.md for the
measurement tools).

    fid_parts        where a FID_k comes from (mean / covariance terms, per style, style reach, per song)
    real_spread      the real row's FID over other real held-out song sets
    style_probe      a linear style classifier on 10-s segments: does a dance look like its style?
    vq_recon         the pose VQ-VAEs' ceiling: the metric table of real dances encoded and decoded
    free_run         teacher-forced against free-running draws of the sequence model, decoded
    self_rollouts    filtered self-training data: the model's own best draws (train.py --self-tokens)
    free_run_tune    fine-tuning through the model's own free-running draws (energy moments)
    tracker_levels   does the engine's beat tracker keep its metrical level under time-stretching?
    period_in_bars   the generated dances' dominant period in bars of their music
    foot_plot        the foot lock, seen: one foot's speed, height and path, lock on and off
    librosa_compare  the engine's features against ground truth and librosa (scripts/reports/audio_report.py)
    pre_reference    batch PRE, the same numbers as the engine's incremental PRE
    engine_gap       the free-running screen against the engine, one difference at a time (start, time base, locks)
    style_recognizer can the music alone tell the style, causally, within the first seconds? (LDA screen)
    tang_sides       which side of the Tang dancer is which: head, top line, hold and heel cues per take
    ablations.sh     the architecture ablations of the research log, each a fine-tune through training.train
"""
