"""Evaluation: figures, metrics and reports built on the one fusion pipeline."""
