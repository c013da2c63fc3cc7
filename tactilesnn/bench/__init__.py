"""Benchmarks (``tactilesnn bench ...``)."""
