"""Tasks: a scene, a sensor model and labels -> windows (each registered in TASKS)."""
