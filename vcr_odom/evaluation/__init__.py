"""Scoring: trajectory files against ground truth, the pairs protocol, the gap sweep, comparisons."""
