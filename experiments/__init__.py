"""Experiments: the embedded campaign, its generator and scenarios, references and benchmarks.

Not part of the toolkit's logic: :mod:`calib` reads the embedded campaign's folder and runs the
generator for ``calib generate``; the benchmarks and FElupe references are run by hand and by
the tests.
"""
