"""Experiments: sequence runner, output writing, reference cache, comparisons."""
