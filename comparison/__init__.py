"""Comparing estimators: the Cramér-Rao bound, Monte Carlo runs, metrics, reports, the CLI."""
