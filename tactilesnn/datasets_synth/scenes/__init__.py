"""Scenes: what touches a sensor, and when (scans, indentations, presses, faults)."""
