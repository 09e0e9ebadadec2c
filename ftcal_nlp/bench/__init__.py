"""Benchmarks (issue 8): accuracy against the Cramer-Rao bound, speed, scaling, profile."""
