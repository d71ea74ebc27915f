"""The scripts a user runs beside the package: benchmarks, the report, surrogate training and
evaluation, probes (run/README.md). Run them from the repository root as modules,
``python -m run.bench.solver``."""
