"""Benchmarks: each prints its figures with the baseline measured in the same run."""
