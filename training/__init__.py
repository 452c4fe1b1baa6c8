"""Training side of the dance project: data, models, training, export, golden fixtures, evaluation."""
