"""Evaluation: metrics, baselines, tempo following, renderers (docs/evaluation.md)."""
