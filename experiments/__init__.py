"""Reproducible studies and benchmarks of brdfscale; each script is one command writing JSON
(and figures) to experiments/results/. See docs/benchmarks.md and docs/results.md."""
