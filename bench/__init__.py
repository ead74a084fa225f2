"""Benchmarks: each module writes results/ files and prints tables; none asserts."""
